//! Domain values and state to the protobuf messages of `iogate.v1`, and back.

use std::time::SystemTime;

use iogate_proto::pb;

use crate::cache::{Device, Diagnostics, Link};
use crate::codec::{IecType, Value};
use crate::config::{SerialSettings, Transport};
use crate::profile::{Profile, fb_layout, st_declaration};
use crate::service::{FieldView, Service};
use crate::write_log::{WriteRecord, WriteStatus};

pub(crate) fn iec_type(ty: IecType) -> pb::IecType {
    ty.to_pb()
}

pub(crate) fn value(ty: IecType, v: &Value) -> pb::Value {
    v.to_pb(Some(ty))
}

pub(crate) fn timestamp(t: SystemTime) -> prost_types::Timestamp {
    prost_types::Timestamp::from(t)
}

/// The protobuf of a field's view.
pub(crate) fn field_value(view: &FieldView<'_>) -> pb::FieldValue {
    let field = view.field;
    pb::FieldValue {
        device: view.device.name().to_owned(),
        field: field.name.clone(),
        value: view.value.as_ref().map(|v| value(field.ty, v)),
        quality: view.quality.to_pb().into(),
        timestamp: view.timestamp.map(timestamp),
        error: view
            .error
            .as_ref()
            .map(ToString::to_string)
            .unwrap_or_default(),
        direction: field.direction.to_pb().into(),
        mismatch: view.mismatch(),
        desired: view.desired.as_ref().map(|v| value(field.ty, v)),
        unit: view.unit().unwrap_or_default().to_owned(),
        last_write: view
            .last_write
            .as_ref()
            .map(|r| write_status(r, Some(field.ty))),
    }
}

pub(crate) fn diagnostics(device: &Device, d: &Diagnostics) -> pb::Diagnostics {
    pb::Diagnostics {
        device: device.name().to_owned(),
        connected: d.connected,
        error_code: d.error_code.code().into(),
        io_cycles: d.io_cycles,
        last_response_ms: d.last_response_ms,
    }
}

/// A device with its diagnostics, and with every field's view from `fields` when given.
pub(crate) fn device(device: &Device, fields: Option<&Service>) -> pb::Device {
    let c = &device.config;
    let binding = device.binding();
    pb::Device {
        name: device.name().to_owned(),
        profile: device.profile.name.clone(),
        protocol: device.profile.protocol.name().to_owned(),
        link: binding.link.unwrap_or_default(),
        slave_id: binding.slave_id.map_or(0, u32::from),
        refresh_rate_ms: millis(c.refresh_rate),
        timeout_ms: millis(c.timeout),
        diagnostics: Some(diagnostics(device, &device.diagnostics())),
        fields: fields.map_or_else(Vec::new, |service| {
            (0..device.profile.fields.len())
                .map(|i| field_value(&service.field_view_now(device, i)))
                .collect()
        }),
    }
}

fn millis(d: std::time::Duration) -> u32 {
    u32::try_from(d.as_millis()).unwrap_or(u32::MAX)
}

pub(crate) fn serial(s: &SerialSettings) -> pb::SerialSettings {
    pb::SerialSettings {
        port: s.port.clone(),
        baud: s.baud,
        parity: s.parity.letter().to_string(),
        data_bits: s.data_bits.into(),
        stop_bits: s.stop_bits.into(),
        framing: s.framing.name().to_owned(),
    }
}

pub(crate) fn link(link: &Link) -> pb::Link {
    let d = link.diagnostics();
    let config = link.config();
    let transport = match config.transport {
        Transport::Serial(s) => pb::link::Transport::Serial(serial(&s)),
        Transport::Tcp {
            host,
            port,
            framing,
        } => pb::link::Transport::Tcp(pb::TcpSettings {
            host,
            port: port.into(),
            framing: framing.name().to_owned(),
        }),
        Transport::Driver(d) => pb::link::Transport::Endpoint(pb::EndpointSettings {
            protocol: d.protocol.to_owned(),
            url: d.endpoint,
        }),
    };
    pb::Link {
        name: link.name().to_owned(),
        transport: Some(transport),
        connected: d.connected,
        error_code: d.error_code.code().into(),
        devices: link.members().iter().map(|d| d.name().to_owned()).collect(),
        guard_time_ms: millis(config.guard_time),
        peer: link
            .peer()
            .into_iter()
            .map(|(k, v)| (k.to_owned(), v))
            .collect(),
    }
}

pub(crate) fn profile(p: &Profile, full: bool) -> pb::Profile {
    let mut out = pb::Profile {
        name: p.name.clone(),
        vendor: p.vendor.clone().unwrap_or_default(),
        protocol: p.protocol.name().to_owned(),
        description: p.description.clone().unwrap_or_default(),
        fields: Vec::new(),
        layout: Vec::new(),
        st_declaration: String::new(),
        source: p.source.clone(),
        field_count: p.fields.len() as u32,
    };
    if full {
        out.fields = p
            .fields
            .iter()
            .map(|f| pb::Field {
                name: f.name.clone(),
                r#type: iec_type(f.ty).into(),
                direction: f.direction.to_pb().into(),
                description: f.description.clone().unwrap_or_default(),
                point: f
                    .point
                    .as_ref()
                    .map(|p| p.address.clone())
                    .unwrap_or_default(),
                point_key: f
                    .point
                    .as_ref()
                    .map(|p| p.key.to_owned())
                    .unwrap_or_default(),
                register: Some(pb::Register {
                    address: f.register.address.into(),
                    kind: f.register.kind.name().to_owned(),
                    bit: f.register.bit.map(u32::from),
                    scale: f.register.scale,
                    offset: f.register.offset,
                    unit: f.register.unit.clone().unwrap_or_default(),
                    byte_order: f.register.byte_order.name().to_owned(),
                    word_count: f.register.word_count.into(),
                    raw_type: f.register.raw_type.map_or(0, |t| iec_type(t).into()),
                    on_value: f.register.switch.map(|s| s.on.into()),
                    off_value: f.register.switch.map(|s| s.off.into()),
                }),
            })
            .collect();
        out.layout = fb_layout(p)
            .into_iter()
            .map(|m| pb::LayoutMember {
                name: m.name,
                r#type: iec_type(m.ty).into(),
                section: m.section.name().to_owned(),
                role: m.role.to_owned(),
                description: m.description,
            })
            .collect();
        out.st_declaration = st_declaration(p);
    }
    out
}

pub(crate) fn write_outcome(s: WriteStatus) -> pb::WriteOutcome {
    match s {
        WriteStatus::Pending => pb::WriteOutcome::Pending,
        WriteStatus::Written => pb::WriteOutcome::Written,
        WriteStatus::Superseded => pb::WriteOutcome::Superseded,
        WriteStatus::Failed => pb::WriteOutcome::Failed,
    }
}

pub(crate) fn write_status(r: &WriteRecord, ty: Option<IecType>) -> pb::WriteStatus {
    pb::WriteStatus {
        generation: r.generation,
        device: r.device.clone(),
        field: r.field.clone(),
        value: ty.zip(r.value.as_ref()).map(|(t, v)| value(t, v)),
        outcome: write_outcome(r.status).into(),
        error: r.error.clone().unwrap_or_default(),
        requested: Some(timestamp(r.requested)),
        finished: r.finished.map(timestamp),
        origin: r.origin.name().to_owned(),
        attempts: r.attempts,
    }
}

/// A reload's report.
pub(crate) fn config_report(r: &crate::service::Report) -> pb::ConfigReport {
    pb::ConfigReport {
        changes: r
            .changes
            .iter()
            .map(|c| pb::ConfigChange {
                kind: c.kind.name().to_owned(),
                name: c.name.clone(),
                action: c.action.name().to_owned(),
                details: c.details.clone(),
            })
            .collect(),
        reopened: r.reopened.clone(),
        took_ms: r.took_ms,
        trigger: r.trigger.name().to_owned(),
        config_hash: r.config_hash.clone(),
        at_unix_ms: r.at_unix_ms,
    }
}

/// This gateway in its pair, as `GetHa` answers.
pub(crate) fn ha_status(ha: crate::service::ha::HaView) -> pb::HaStatus {
    let active = ha.active.unwrap_or_else(|| crate::role::Peer {
        node: String::new(),
        addresses: Default::default(),
    });
    pb::HaStatus {
        node: ha.node.unwrap_or_default(),
        role: ha.role.to_owned(),
        paired: ha.paired,
        epoch: ha.epoch,
        active_node: active.node,
        active_addresses: active.addresses.into_iter().collect(),
        takeovers: ha.takeovers,
    }
}

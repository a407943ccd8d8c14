//! Domain values and state to the protobuf messages of `iogate.v1`, and back.

use std::time::SystemTime;

use iogate_proto::pb;

use crate::cache::{Device, Link, Quality, Sample};
use crate::codec::{IecType, Value};
use crate::config::{Parity, SerialSettings, Transport};
use crate::profile::{Direction, Profile, fb_layout, st_declaration};
use crate::writes::{WriteRecord, WriteStatus};

pub fn iec_type(ty: IecType) -> pb::IecType {
    match ty {
        IecType::Bool => pb::IecType::Bool,
        IecType::Sint => pb::IecType::Sint,
        IecType::Int => pb::IecType::Int,
        IecType::Dint => pb::IecType::Dint,
        IecType::Lint => pb::IecType::Lint,
        IecType::Usint => pb::IecType::Usint,
        IecType::Uint => pb::IecType::Uint,
        IecType::Udint => pb::IecType::Udint,
        IecType::Ulint => pb::IecType::Ulint,
        IecType::Real => pb::IecType::Real,
        IecType::Lreal => pb::IecType::Lreal,
        IecType::Byte => pb::IecType::Byte,
        IecType::Word => pb::IecType::Word,
        IecType::Dword => pb::IecType::Dword,
        IecType::Lword => pb::IecType::Lword,
        IecType::String => pb::IecType::String,
        IecType::Time => pb::IecType::Time,
    }
}

/// The IEC type of a protobuf type, `None` for UNSPECIFIED or an unknown number.
pub fn from_pb_type(ty: i32) -> Option<IecType> {
    let ty = pb::IecType::try_from(ty).ok()?;
    IecType::ALL.into_iter().find(|t| iec_type(*t) == ty)
}

pub fn value(ty: IecType, v: &Value) -> pb::Value {
    use pb::value::Kind;
    let kind = match v {
        Value::Bool(b) => Kind::BoolValue(*b),
        Value::Int(i) => Kind::IntValue(*i),
        Value::UInt(u) => Kind::UintValue(*u),
        Value::Real(r) => Kind::RealValue(*r),
        Value::LReal(r) => Kind::LrealValue(*r),
        Value::String(s) => Kind::StringValue(s.clone()),
        Value::Time(t) => Kind::TimeMs(*t),
    };
    pb::Value {
        r#type: iec_type(ty).into(),
        kind: Some(kind),
    }
}

/// A protobuf value as a value of `ty`. Numbers convert when they fit exactly; a string
/// is also a TIME literal such as `T#1s500ms`.
pub fn to_value(ty: IecType, v: &pb::Value) -> Result<Value, String> {
    use pb::value::Kind;
    if let Some(declared) = from_pb_type(v.r#type)
        && declared != ty
    {
        return Err(format!("the field is {ty}, the value says {declared}"));
    }
    let Some(kind) = &v.kind else {
        return Err(format!("{ty} needs a value; none was set"));
    };

    match (ty, kind) {
        (IecType::Bool, Kind::BoolValue(b)) => Ok(Value::Bool(*b)),
        (IecType::String, Kind::StringValue(s)) => Ok(Value::String(s.clone())),
        (IecType::Time, Kind::TimeMs(ms)) => Ok(Value::Time(*ms)),
        (IecType::Time, Kind::StringValue(s)) => crate::duration::parse_ms(s).map(Value::Time),
        (IecType::Bool | IecType::String | IecType::Time, _) => {
            Err(format!("{ty} does not take {}", kind_name(kind)))
        }
        (t, Kind::IntValue(i)) => Value::from_int(t, (*i).into()).map_err(|e| e.to_string()),
        (t, Kind::UintValue(u)) => Value::from_int(t, (*u).into()).map_err(|e| e.to_string()),
        (t, Kind::RealValue(r)) => Value::from_real(t, f64::from(*r)).map_err(|e| e.to_string()),
        (t, Kind::LrealValue(r)) => Value::from_real(t, *r).map_err(|e| e.to_string()),
        (t, other) => Err(format!("{t} does not take {}", kind_name(other))),
    }
}

fn kind_name(kind: &pb::value::Kind) -> &'static str {
    use pb::value::Kind;
    match kind {
        Kind::BoolValue(_) => "a boolean",
        Kind::IntValue(_) | Kind::UintValue(_) => "an integer",
        Kind::RealValue(_) | Kind::LrealValue(_) => "a real number",
        Kind::StringValue(_) => "a string",
        Kind::TimeMs(_) => "a duration",
    }
}

pub fn timestamp(t: SystemTime) -> prost_types::Timestamp {
    prost_types::Timestamp::from(t)
}

pub fn quality(q: Quality) -> pb::Quality {
    match q {
        Quality::Good => pb::Quality::Good,
        Quality::Stale => pb::Quality::Stale,
        Quality::NeverRead => pb::Quality::NeverRead,
        Quality::Bad => pb::Quality::Bad,
    }
}

pub fn direction(d: Direction) -> pb::Direction {
    match d {
        Direction::Input => pb::Direction::Input,
        Direction::Output => pb::Direction::Output,
        Direction::Inout => pb::Direction::Inout,
    }
}

pub fn field_value(device: &Device, idx: usize, sample: &Sample) -> pb::FieldValue {
    let field = device.field(idx);
    let now = tokio::time::Instant::now();
    pb::FieldValue {
        device: device.name().to_owned(),
        field: field.name.clone(),
        value: sample.value.as_ref().map(|v| value(field.ty, v)),
        quality: quality(sample.quality_at(now, device.stale_after())).into(),
        timestamp: sample.updated.map(|(_, wall)| timestamp(wall)),
        error: sample.error.clone().unwrap_or_default(),
        direction: direction(field.direction).into(),
    }
}

pub fn diagnostics(device: &Device) -> pb::Diagnostics {
    let d = device.diagnostics();
    pb::Diagnostics {
        device: device.name().to_owned(),
        connected: d.connected,
        error_code: d.error_code.into(),
        io_cycles: d.io_cycles,
        last_response_ms: d.last_response_ms,
    }
}

pub fn device(device: &Device, with_fields: bool) -> pb::Device {
    let c = &device.config;
    pb::Device {
        name: device.name().to_owned(),
        profile: device.profile.name.clone(),
        protocol: device.profile.protocol.name().to_owned(),
        link: c.link.clone().unwrap_or_default(),
        slave_id: c.slave_id.map_or(0, u32::from),
        refresh_rate_ms: millis(c.refresh_rate),
        timeout_ms: millis(c.timeout),
        diagnostics: Some(diagnostics(device)),
        fields: if with_fields {
            (0..device.profile.fields.len())
                .map(|i| field_value(device, i, &device.sample(i)))
                .collect()
        } else {
            Vec::new()
        },
    }
}

fn millis(d: std::time::Duration) -> u32 {
    u32::try_from(d.as_millis()).unwrap_or(u32::MAX)
}

pub fn serial(s: &SerialSettings) -> pb::SerialSettings {
    pb::SerialSettings {
        port: s.port.clone(),
        baud: s.baud,
        parity: s.parity.letter().to_string(),
        data_bits: s.data_bits.into(),
        stop_bits: s.stop_bits.into(),
    }
}

pub fn link(link: &Link) -> pb::Link {
    let d = link.diagnostics();
    let transport = match &link.config.transport {
        Transport::Serial(s) => pb::link::Transport::Serial(serial(s)),
        Transport::Tcp {
            host,
            port,
            framing,
        } => pb::link::Transport::Tcp(pb::TcpSettings {
            host: host.clone(),
            port: (*port).into(),
            framing: framing.name().to_owned(),
        }),
    };
    pb::Link {
        name: link.name().to_owned(),
        transport: Some(transport),
        connected: d.connected,
        error_code: d.error_code.into(),
        devices: link.members().iter().map(|d| d.name().to_owned()).collect(),
        guard_time_ms: millis(link.config.guard_time),
    }
}

/// A serial link's settings from a declaration; `None` names what is wrong.
pub fn serial_settings(s: &pb::SerialSettings) -> Result<SerialSettings, String> {
    let parity = match s.parity.to_ascii_uppercase().as_str() {
        "" | "N" | "NONE" => Parity::None,
        "E" | "EVEN" => Parity::Even,
        "O" | "ODD" => Parity::Odd,
        other => {
            return Err(format!(
                "Invalid parity configuration: `{other}` (expected N, E or O)"
            ));
        }
    };
    let small = |n: u32, default: u8| {
        if n == 0 {
            Ok(default)
        } else {
            u8::try_from(n).map_err(|_| n.to_string())
        }
    };
    Ok(SerialSettings {
        port: s.port.clone(),
        baud: s.baud,
        parity,
        data_bits: small(s.data_bits, 8)
            .map_err(|n| format!("data_bits must be 7 or 8, not {n}"))?,
        stop_bits: small(s.stop_bits, 1)
            .map_err(|n| format!("Invalid stop bits configuration: {n} (expected 1 or 2)"))?,
    })
}

pub fn profile(p: &Profile, full: bool) -> pb::Profile {
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
                direction: direction(f.direction).into(),
                description: f.description.clone().unwrap_or_default(),
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

pub fn write_outcome(s: WriteStatus) -> pb::WriteOutcome {
    match s {
        WriteStatus::Pending => pb::WriteOutcome::Pending,
        WriteStatus::Written => pb::WriteOutcome::Written,
        WriteStatus::Superseded => pb::WriteOutcome::Superseded,
        WriteStatus::Failed => pb::WriteOutcome::Failed,
    }
}

pub fn write_status(r: &WriteRecord, ty: Option<IecType>) -> pb::WriteStatus {
    pb::WriteStatus {
        generation: r.generation,
        device: r.device.clone(),
        field: r.field.clone(),
        value: ty.map(|t| value(t, &r.value)),
        outcome: write_outcome(r.status).into(),
        error: r.error.clone().unwrap_or_default(),
        requested: Some(timestamp(r.requested)),
        finished: r.finished.map(timestamp),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use pb::value::Kind;

    fn pv(kind: Kind) -> pb::Value {
        pb::Value {
            r#type: 0,
            kind: Some(kind),
        }
    }

    #[test]
    fn every_type_maps_both_ways() {
        for t in IecType::ALL {
            assert_eq!(from_pb_type(iec_type(t).into()), Some(t));
        }
        assert_eq!(from_pb_type(0), None);
        assert_eq!(from_pb_type(99), None);
    }

    #[test]
    fn numbers_convert_when_they_fit() {
        assert_eq!(
            to_value(IecType::Real, &pv(Kind::IntValue(3))),
            Ok(Value::Real(3.0))
        );
        assert_eq!(
            to_value(IecType::Int, &pv(Kind::LrealValue(3.0))),
            Ok(Value::Int(3))
        );
        assert!(to_value(IecType::Int, &pv(Kind::LrealValue(3.5))).is_err());
        assert!(to_value(IecType::Usint, &pv(Kind::IntValue(-1))).is_err());
        assert_eq!(
            to_value(IecType::Time, &pv(Kind::StringValue("T#2s".into()))),
            Ok(Value::Time(2000))
        );
        assert!(to_value(IecType::Bool, &pv(Kind::IntValue(1))).is_err());
        let mislabelled = pb::Value {
            r#type: pb::IecType::Real.into(),
            kind: Some(Kind::RealValue(1.0)),
        };
        assert_eq!(
            to_value(IecType::Int, &mislabelled),
            Err("the field is INT, the value says REAL".to_owned())
        );
        assert!(to_value(IecType::Int, &pb::Value::default()).is_err());
    }
}

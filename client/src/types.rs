//! The values and records the client hands out: Rust types, not protobuf structs.

use std::time::SystemTime;

use iogate_proto::pb;
use serde::Serialize;

pub use iogate_types::{Direction, IecType, Quality, Value, ValueError};

fn system_time(t: Option<&prost_types::Timestamp>) -> Option<SystemTime> {
    t.and_then(|t| SystemTime::try_from(*t).ok())
}

fn millis(t: &Option<SystemTime>) -> Option<u128> {
    t.and_then(|t| t.duration_since(SystemTime::UNIX_EPOCH).ok())
        .map(|d| d.as_millis())
}

/// A field's value with its type, quality and the time it was refreshed.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FieldValue {
    /// The device's name.
    pub device: String,
    /// The field's name.
    pub field: String,
    /// `None` when the value has no type yet (never read).
    #[serde(rename = "type")]
    pub ty: Option<IecType>,
    /// Input, output or inout.
    pub direction: Direction,
    /// `None` until the field is first read.
    pub value: Option<Value>,
    /// Good, stale, never read or bad, as of the answer.
    pub quality: Quality,
    /// When the value was last refreshed; in JSON as REST gives it (RFC 3339, milliseconds).
    #[serde(serialize_with = "rfc3339")]
    pub timestamp: Option<SystemTime>,
    /// Milliseconds since 1970.
    #[serde(skip)]
    pub timestamp_ms: Option<u128>,
    /// Why the quality is bad.
    pub error: Option<String>,
    /// The profile's engineering unit.
    pub unit: Option<String>,
    /// The device holds another value than the newest requested (`desired`), with no write
    /// of it waiting.
    pub mismatch: bool,
    /// The newest value requested, when the device holds another.
    pub desired: Option<Value>,
    /// The latest write to the field, while the gateway's log keeps it.
    pub last_write: Option<Box<WriteStatus>>,
}

impl FieldValue {
    pub(crate) fn from_pb(v: pb::FieldValue) -> FieldValue {
        let timestamp = system_time(v.timestamp.as_ref());
        FieldValue {
            ty: v.value.as_ref().and_then(|x| IecType::from_pb(x.r#type)),
            value: v.value.as_ref().and_then(Value::from_pb),
            quality: Quality::from_pb(v.quality),
            direction: Direction::from_pb(v.direction),
            timestamp_ms: millis(&timestamp),
            timestamp,
            error: (!v.error.is_empty()).then_some(v.error),
            unit: (!v.unit.is_empty()).then_some(v.unit),
            mismatch: v.mismatch,
            desired: v.desired.as_ref().and_then(Value::from_pb),
            last_write: v.last_write.map(|w| Box::new(WriteStatus::from_pb(w))),
            device: v.device,
            field: v.field,
        }
    }
}

/// A device's diagnostics: `error_code` 0 OK, 1 no link, 2 no slave, 10 communication error.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Diagnostics {
    /// The device's name.
    pub device: String,
    /// TRUE if the device is responding.
    pub connected: bool,
    /// 0 OK, 1 no link, 2 no slave, 10 communication error.
    pub error_code: i32,
    /// Successful I/O cycles.
    pub io_cycles: u64,
    /// The last round trip, in milliseconds.
    pub last_response_ms: f64,
}

impl Diagnostics {
    pub(crate) fn from_pb(d: pb::Diagnostics) -> Diagnostics {
        Diagnostics {
            device: d.device,
            connected: d.connected,
            error_code: d.error_code,
            io_cycles: d.io_cycles,
            last_response_ms: d.last_response_ms,
        }
    }
}

/// A device: its binding, settings and diagnostics.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DeviceInfo {
    /// The device's name.
    pub name: String,
    /// Its profile's name.
    pub profile: String,
    /// `modbus-rtu`, `modbus-tcp` or `simulated`.
    pub protocol: String,
    /// Its link, once it has one.
    pub link: Option<String>,
    /// Its slave id, once it has one.
    pub slave_id: Option<u32>,
    /// How often it is polled.
    pub refresh_rate_ms: u32,
    /// Each transaction's timeout.
    pub timeout_ms: u32,
    /// Its diagnostics.
    pub diagnostics: Option<Diagnostics>,
    /// Every field's value (from `device`, not from `devices`).
    pub fields: Vec<FieldValue>,
}

impl DeviceInfo {
    pub(crate) fn from_pb(d: pb::Device) -> DeviceInfo {
        DeviceInfo {
            link: (!d.link.is_empty()).then_some(d.link),
            slave_id: (d.slave_id != 0).then_some(d.slave_id),
            diagnostics: d.diagnostics.map(Diagnostics::from_pb),
            fields: d.fields.into_iter().map(FieldValue::from_pb).collect(),
            name: d.name,
            profile: d.profile,
            protocol: d.protocol,
            refresh_rate_ms: d.refresh_rate_ms,
            timeout_ms: d.timeout_ms,
        }
    }
}

/// A link: its endpoint, state and devices.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LinkInfo {
    /// The link's name.
    pub name: String,
    /// `serial PORT BAUD 8N1`, `tcp HOST:PORT (framing)` or `opcua URL`.
    pub endpoint: String,
    /// TRUE while its port or connection is open.
    pub connected: bool,
    /// 0 OK, 1 no port configured, 2 open failed, 3 port lost.
    pub error_code: i32,
    /// The devices on it.
    pub devices: Vec<String>,
    /// What the gateway learned of the device at the other end (an S7 PLC's
    /// `order_number`, `module`, `serial_number`, `pdu_size`, `cpu_state`).
    pub peer: std::collections::BTreeMap<String, String>,
}

impl LinkInfo {
    pub(crate) fn from_pb(l: pb::Link) -> LinkInfo {
        let endpoint = match l.transport {
            Some(pb::link::Transport::Serial(s)) => format!(
                "serial {} {} {}{}{}",
                s.port, s.baud, s.data_bits, s.parity, s.stop_bits
            ),
            Some(pb::link::Transport::Tcp(t)) => {
                format!("tcp {}:{} ({})", t.host, t.port, t.framing)
            }
            Some(pb::link::Transport::Endpoint(e)) => format!("{} {}", e.protocol, e.url),
            None => String::new(),
        };
        LinkInfo {
            name: l.name,
            endpoint,
            connected: l.connected,
            error_code: l.error_code,
            devices: l.devices,
            peer: l.peer.into_iter().collect(),
        }
    }
}

/// A field of a profile.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FieldInfo {
    /// The field's name.
    pub name: String,
    /// Its IEC type.
    #[serde(rename = "type")]
    pub ty: Option<IecType>,
    /// Input, output or inout.
    pub direction: Direction,
    /// Its register address.
    pub address: u32,
    /// `coil`, `discrete_input`, `holding_register`, `input_register`, `virtual`, or
    /// `point` for a field of another protocol.
    pub kind: String,
    /// Its engineering unit; empty when none.
    pub unit: String,
    /// A field of another protocol: its point (an OPC UA node id or browse path); empty
    /// for a Modbus field.
    pub point: String,
    /// The key the point is written under (`node`, `browse_path`); empty for a Modbus
    /// field.
    pub point_key: String,
}

/// A member of a profile's generated function block.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LayoutMember {
    /// The member's name.
    pub name: String,
    /// Its IEC type.
    #[serde(rename = "type")]
    pub ty: Option<IecType>,
    /// `VAR_INPUT` or `VAR`.
    pub section: String,
    /// Link binding, parameter, diagnostic or I/O field.
    pub role: String,
}

/// A device profile.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ProfileInfo {
    /// The profile's (function block type's) name.
    pub name: String,
    /// Its vendor; empty when not given.
    pub vendor: String,
    /// `modbus-rtu`, `modbus-tcp` or `simulated`.
    pub protocol: String,
    /// Its description; empty when not given.
    pub description: String,
    /// How many fields it has.
    pub field_count: u32,
    /// Its fields (from `profile`, not from `profiles`).
    pub fields: Vec<FieldInfo>,
    /// Its generated function block's members, in order.
    pub layout: Vec<LayoutMember>,
    /// Its function block as an IEC 61131-3 ST declaration.
    pub st_declaration: String,
}

impl ProfileInfo {
    pub(crate) fn from_pb(p: pb::Profile) -> ProfileInfo {
        ProfileInfo {
            fields: p
                .fields
                .into_iter()
                .map(|f| FieldInfo {
                    ty: IecType::from_pb(f.r#type),
                    direction: Direction::from_pb(f.direction),
                    address: f.register.as_ref().map_or(0, |r| r.address),
                    kind: f
                        .register
                        .as_ref()
                        .map(|r| r.kind.clone())
                        .unwrap_or_default(),
                    unit: f.register.map(|r| r.unit).unwrap_or_default(),
                    name: f.name,
                    point: f.point,
                    point_key: f.point_key,
                })
                .collect(),
            layout: p
                .layout
                .into_iter()
                .map(|m| LayoutMember {
                    ty: IecType::from_pb(m.r#type),
                    name: m.name,
                    section: m.section,
                    role: m.role,
                })
                .collect(),
            name: p.name,
            vendor: p.vendor,
            protocol: p.protocol,
            description: p.description,
            field_count: p.field_count,
            st_declaration: p.st_declaration,
        }
    }
}

/// A change on a subscription.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Update {
    /// A field's new value or quality.
    Value(FieldValue),
    /// A device's new diagnostics.
    Diagnostics(Diagnostics),
    /// The field (or, with no field, the whole device) was removed, by a configuration
    /// reload or a removal: its last update.
    Removed {
        /// The device.
        device: String,
        /// The field; none when the whole device was removed.
        field: Option<String>,
        /// Why.
        reason: String,
    },
}

/// Where a write stands.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "outcome", content = "error", rename_all = "snake_case")]
pub enum WriteOutcome {
    /// Waiting for the bus.
    Pending,
    /// The device took it.
    Written,
    /// A newer write to the field replaced it before it was sent.
    Superseded,
    /// It failed, with the reason.
    Failed(String),
}

/// A write and where it stands.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct WriteStatus {
    /// The write's generation (increasing across the gateway).
    pub generation: u64,
    /// The device written.
    pub device: String,
    /// The field written.
    pub field: String,
    /// The value requested; `None` for a relinquish.
    pub value: Option<Value>,
    /// Pending, written, superseded or failed.
    pub outcome: WriteOutcome,
}

impl WriteStatus {
    pub(crate) fn from_pb(s: pb::WriteStatus) -> WriteStatus {
        let outcome = match pb::WriteOutcome::try_from(s.outcome) {
            Ok(pb::WriteOutcome::Written) => WriteOutcome::Written,
            Ok(pb::WriteOutcome::Superseded) => WriteOutcome::Superseded,
            Ok(pb::WriteOutcome::Failed) => WriteOutcome::Failed(s.error),
            _ => WriteOutcome::Pending,
        };
        WriteStatus {
            generation: s.generation,
            value: s.value.as_ref().and_then(Value::from_pb),
            device: s.device,
            field: s.field,
            outcome,
        }
    }
}

/// A time as REST writes it: RFC 3339 in UTC with milliseconds, or null.
fn rfc3339<S: serde::Serializer>(t: &Option<SystemTime>, s: S) -> Result<S::Ok, S::Error> {
    match t {
        Some(t) => s.serialize_str(&humantime::format_rfc3339_millis(*t).to_string()),
        None => s.serialize_none(),
    }
}

#[cfg(test)]
mod json_tests {
    use super::*;

    #[test]
    fn a_fields_json_names_its_time_as_rest_does() {
        let at = SystemTime::UNIX_EPOCH + std::time::Duration::from_millis(1_500);
        let v = FieldValue {
            device: "sim".into(),
            field: "DO_0".into(),
            ty: Some(IecType::Bool),
            direction: Direction::Output,
            value: Some(Value::Bool(true)),
            quality: Quality::Good,
            timestamp: Some(at),
            timestamp_ms: Some(1_500),
            error: None,
            unit: None,
            mismatch: false,
            desired: None,
            last_write: None,
        };
        let json = serde_json::to_value(&v).expect("json");
        assert_eq!(json["timestamp"], "1970-01-01T00:00:01.500Z", "{json}");
        assert!(json.get("timestamp_ms").is_none(), "{json}");
    }
}

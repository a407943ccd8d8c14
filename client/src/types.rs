//! The values and records the client hands out: Rust types, not protobuf structs.

use std::fmt;
use std::time::SystemTime;

use iogate_proto::pb;
use serde::Serialize;

use crate::Error;

/// IEC 61131-3 elementary types.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "UPPERCASE")]
pub enum IecType {
    Bool,
    Sint,
    Int,
    Dint,
    Lint,
    Usint,
    Uint,
    Udint,
    Ulint,
    Real,
    Lreal,
    Byte,
    Word,
    Dword,
    Lword,
    String,
    Time,
}

impl IecType {
    pub(crate) fn from_pb(ty: i32) -> Option<IecType> {
        use pb::IecType as P;
        Some(match P::try_from(ty).ok()? {
            P::Unspecified => return None,
            P::Bool => IecType::Bool,
            P::Sint => IecType::Sint,
            P::Int => IecType::Int,
            P::Dint => IecType::Dint,
            P::Lint => IecType::Lint,
            P::Usint => IecType::Usint,
            P::Uint => IecType::Uint,
            P::Udint => IecType::Udint,
            P::Ulint => IecType::Ulint,
            P::Real => IecType::Real,
            P::Lreal => IecType::Lreal,
            P::Byte => IecType::Byte,
            P::Word => IecType::Word,
            P::Dword => IecType::Dword,
            P::Lword => IecType::Lword,
            P::String => IecType::String,
            P::Time => IecType::Time,
        })
    }

    pub fn name(self) -> &'static str {
        match self {
            IecType::Bool => "BOOL",
            IecType::Sint => "SINT",
            IecType::Int => "INT",
            IecType::Dint => "DINT",
            IecType::Lint => "LINT",
            IecType::Usint => "USINT",
            IecType::Uint => "UINT",
            IecType::Udint => "UDINT",
            IecType::Ulint => "ULINT",
            IecType::Real => "REAL",
            IecType::Lreal => "LREAL",
            IecType::Byte => "BYTE",
            IecType::Word => "WORD",
            IecType::Dword => "DWORD",
            IecType::Lword => "LWORD",
            IecType::String => "STRING",
            IecType::Time => "TIME",
        }
    }
}

impl fmt::Display for IecType {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A field value. `Int` holds SINT..LINT, `UInt` USINT..ULINT and BYTE..LWORD, `Time` a
/// duration in milliseconds (negative allowed, as IEC TIME).
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum Value {
    Bool(bool),
    Int(i64),
    UInt(u64),
    Real(f32),
    LReal(f64),
    String(String),
    Time(i64),
}

impl Value {
    pub(crate) fn from_pb(v: &pb::Value) -> Option<Value> {
        use pb::value::Kind;
        Some(match v.kind.as_ref()? {
            Kind::BoolValue(b) => Value::Bool(*b),
            Kind::IntValue(i) => Value::Int(*i),
            Kind::UintValue(u) => Value::UInt(*u),
            Kind::RealValue(r) => Value::Real(*r),
            Kind::LrealValue(r) => Value::LReal(*r),
            Kind::StringValue(s) => Value::String(s.clone()),
            Kind::TimeMs(t) => Value::Time(*t),
        })
    }

    pub(crate) fn to_pb(&self) -> pb::Value {
        use pb::value::Kind;
        let kind = match self {
            Value::Bool(b) => Kind::BoolValue(*b),
            Value::Int(i) => Kind::IntValue(*i),
            Value::UInt(u) => Kind::UintValue(*u),
            Value::Real(r) => Kind::RealValue(*r),
            Value::LReal(r) => Kind::LrealValue(*r),
            Value::String(s) => Kind::StringValue(s.clone()),
            Value::Time(t) => Kind::TimeMs(*t),
        };
        pb::Value {
            r#type: 0,
            kind: Some(kind),
        }
    }

    /// Parses text as a value of `ty`: `true`/`false`/`1`/`0` for BOOL, numbers, any text for
    /// STRING, milliseconds or `T#1s500ms` for TIME.
    pub fn parse(ty: IecType, text: &str) -> Result<Value, Error> {
        let t = text.trim();
        let bad = || Error::Invalid(format!("`{text}` is not a {ty} value"));
        Ok(match ty {
            IecType::Bool => match t.to_ascii_lowercase().as_str() {
                "true" | "1" | "on" => Value::Bool(true),
                "false" | "0" | "off" => Value::Bool(false),
                _ => return Err(bad()),
            },
            IecType::Sint | IecType::Int | IecType::Dint | IecType::Lint => {
                Value::Int(t.parse().map_err(|_| bad())?)
            }
            IecType::Usint
            | IecType::Uint
            | IecType::Udint
            | IecType::Ulint
            | IecType::Byte
            | IecType::Word
            | IecType::Dword
            | IecType::Lword => match t.strip_prefix("16#").or_else(|| t.strip_prefix("0x")) {
                Some(hex) => {
                    Value::UInt(u64::from_str_radix(&hex.replace('_', ""), 16).map_err(|_| bad())?)
                }
                None => Value::UInt(t.parse().map_err(|_| bad())?),
            },
            IecType::Real => Value::Real(t.parse().map_err(|_| bad())?),
            IecType::Lreal => Value::LReal(t.parse().map_err(|_| bad())?),
            IecType::String => Value::String(text.to_owned()),
            IecType::Time => match t.parse::<i64>() {
                Ok(ms) => Value::Time(ms),
                Err(_) => Value::Time(parse_time(t).ok_or_else(bad)?),
            },
        })
    }
}

/// `T#1m30s500ms`, `1s`, `250ms` to milliseconds.
fn parse_time(text: &str) -> Option<i64> {
    let mut rest = text
        .strip_prefix("T#")
        .or_else(|| text.strip_prefix("t#"))
        .or_else(|| text.strip_prefix("TIME#"))
        .unwrap_or(text);
    let negative = rest.starts_with('-');
    rest = rest.trim_start_matches('-');
    let mut total = 0f64;
    while !rest.is_empty() {
        let end = rest.find(|c: char| !(c.is_ascii_digit() || c == '.'))?;
        let n: f64 = rest[..end].parse().ok()?;
        rest = &rest[end..];
        let (unit, factor) = [
            ("ms", 1.0),
            ("d", 86_400_000.0),
            ("h", 3_600_000.0),
            ("m", 60_000.0),
            ("s", 1000.0),
        ]
        .into_iter()
        .find(|(u, _)| rest.starts_with(u))?;
        total += n * factor;
        rest = &rest[unit.len()..];
    }
    let ms = total.round() as i64;
    Some(if negative { -ms } else { ms })
}

impl fmt::Display for Value {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Value::Bool(b) => write!(f, "{}", if *b { "TRUE" } else { "FALSE" }),
            Value::Int(i) => write!(f, "{i}"),
            Value::UInt(u) => write!(f, "{u}"),
            Value::Real(r) => write!(f, "{r}"),
            Value::LReal(r) => write!(f, "{r}"),
            Value::String(s) => write!(f, "'{s}'"),
            Value::Time(t) => write!(f, "{t} ms"),
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Quality {
    Good,
    Stale,
    NeverRead,
    Bad,
}

impl Quality {
    pub(crate) fn from_pb(q: i32) -> Quality {
        match pb::Quality::try_from(q) {
            Ok(pb::Quality::Good) => Quality::Good,
            Ok(pb::Quality::Stale) => Quality::Stale,
            Ok(pb::Quality::Bad) => Quality::Bad,
            _ => Quality::NeverRead,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Quality::Good => "good",
            Quality::Stale => "stale",
            Quality::NeverRead => "never_read",
            Quality::Bad => "bad",
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Direction {
    Input,
    Output,
    Inout,
}

impl Direction {
    pub(crate) fn from_pb(d: i32) -> Direction {
        match pb::Direction::try_from(d) {
            Ok(pb::Direction::Output) => Direction::Output,
            Ok(pb::Direction::Inout) => Direction::Inout,
            _ => Direction::Input,
        }
    }
}

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
    pub device: String,
    pub field: String,
    /// `None` when the value has no type yet (never read).
    #[serde(rename = "type")]
    pub ty: Option<IecType>,
    pub direction: Direction,
    pub value: Option<Value>,
    pub quality: Quality,
    #[serde(skip)]
    pub timestamp: Option<SystemTime>,
    /// Milliseconds since 1970 (for JSON output).
    pub timestamp_ms: Option<u128>,
    pub error: Option<String>,
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
            device: v.device,
            field: v.field,
        }
    }
}

/// A device's diagnostics: `error_code` 0 OK, 1 no link, 2 no slave, 10 communication error.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Diagnostics {
    pub device: String,
    pub connected: bool,
    pub error_code: i32,
    pub io_cycles: u64,
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

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DeviceInfo {
    pub name: String,
    pub profile: String,
    pub protocol: String,
    pub link: Option<String>,
    pub slave_id: Option<u32>,
    pub refresh_rate_ms: u32,
    pub timeout_ms: u32,
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

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LinkInfo {
    pub name: String,
    /// `serial PORT BAUD 8N1` or `tcp HOST:PORT (framing)`.
    pub endpoint: String,
    pub connected: bool,
    /// 0 OK, 1 no port configured, 2 open failed, 3 port lost.
    pub error_code: i32,
    pub devices: Vec<String>,
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
            None => String::new(),
        };
        LinkInfo {
            name: l.name,
            endpoint,
            connected: l.connected,
            error_code: l.error_code,
            devices: l.devices,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FieldInfo {
    pub name: String,
    #[serde(rename = "type")]
    pub ty: Option<IecType>,
    pub direction: Direction,
    pub address: u32,
    pub kind: String,
    pub unit: String,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LayoutMember {
    pub name: String,
    #[serde(rename = "type")]
    pub ty: Option<IecType>,
    pub section: String,
    pub role: String,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ProfileInfo {
    pub name: String,
    pub vendor: String,
    pub protocol: String,
    pub description: String,
    pub field_count: u32,
    pub fields: Vec<FieldInfo>,
    pub layout: Vec<LayoutMember>,
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
    Value(FieldValue),
    Diagnostics(Diagnostics),
}

/// Where a write stands.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "outcome", content = "error", rename_all = "snake_case")]
pub enum WriteOutcome {
    Pending,
    Written,
    Superseded,
    Failed(String),
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct WriteStatus {
    pub generation: u64,
    pub device: String,
    pub field: String,
    pub value: Option<Value>,
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_parse_by_type() {
        assert!(matches!(
            Value::parse(IecType::Bool, "on"),
            Ok(Value::Bool(true))
        ));
        assert!(matches!(
            Value::parse(IecType::Int, "-5"),
            Ok(Value::Int(-5))
        ));
        assert!(matches!(
            Value::parse(IecType::Word, "16#BEEF"),
            Ok(Value::UInt(0xBEEF))
        ));
        assert!(matches!(Value::parse(IecType::Real, "21.5"), Ok(Value::Real(r)) if r == 21.5));
        assert!(matches!(
            Value::parse(IecType::Time, "T#1m30s"),
            Ok(Value::Time(90_000))
        ));
        assert!(matches!(
            Value::parse(IecType::Time, "250"),
            Ok(Value::Time(250))
        ));
        assert!(Value::parse(IecType::Int, "five").is_err());
        assert!(Value::parse(IecType::Bool, "maybe").is_err());
    }

    #[test]
    fn values_serialize_as_plain_json() {
        assert_eq!(
            serde_json::to_string(&Value::Real(0.1)).ok().as_deref(),
            Some("0.1")
        );
        assert_eq!(
            serde_json::to_string(&Value::Bool(true)).ok().as_deref(),
            Some("true")
        );
        assert_eq!(
            serde_json::to_string(&Value::Time(1500)).ok().as_deref(),
            Some("1500")
        );
    }
}

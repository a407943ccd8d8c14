//! Domain values to JSON and back, and the JSON shapes of the REST API.

use std::time::SystemTime;

use serde::Serialize;
use serde_json::{Number, Value as Json};
use utoipa::ToSchema;

use crate::cache::{Device, Diagnostics, Link};
use crate::codec::{IecType, Value};
use crate::config::Transport;
use crate::profile::{LayoutEntry, Profile, fb_layout};
use crate::service::FieldView;
use crate::write_log::WriteRecord;

mod link;
mod profile;

pub(crate) use link::*;
pub(crate) use profile::*;

/// A value as the JSON of its type: BOOL as true/false, numbers as numbers, STRING as a
/// string, TIME as milliseconds.
pub(crate) fn value_to_json(value: &Value) -> Json {
    match value {
        Value::Bool(b) => Json::Bool(*b),
        Value::Int(i) | Value::Time(i) => Json::from(*i),
        Value::UInt(u) => Json::from(*u),
        Value::Real(r) if !r.is_finite() => not_finite(f64::from(*r)),
        // The shortest text that reads back as the same f32, so 0.1 stays 0.1.
        Value::Real(r) => r
            .to_string()
            .parse::<f64>()
            .ok()
            .and_then(Number::from_f64)
            .map_or(Json::Null, Json::Number),
        Value::LReal(r) => Number::from_f64(*r).map_or_else(|| not_finite(*r), Json::Number),
        Value::String(s) => Json::String(s.clone()),
    }
}

/// A REAL or LREAL that JSON has no number for, as the string JavaScript and Python read
/// back: `"NaN"`, `"Infinity"`, `"-Infinity"` (never `null`, which would say nothing).
fn not_finite(x: f64) -> Json {
    Json::String(not_finite_text(x).to_owned())
}

fn not_finite_text(x: f64) -> &'static str {
    match (x.is_nan(), x > 0.0) {
        (true, _) => "NaN",
        (false, true) => "Infinity",
        (false, false) => "-Infinity",
    }
}

/// A JSON value for a field of type `ty`. BOOL also takes 0 and 1; TIME takes milliseconds
/// or a literal such as `"T#1s500ms"`; integer types take whole numbers only.
pub(crate) fn json_to_value(ty: IecType, json: &Json) -> Result<Value, crate::codec::CodecError> {
    let found = describe(json);

    match (ty, json) {
        (IecType::Bool, Json::Bool(b)) => Ok(Value::Bool(*b)),
        (IecType::Bool, Json::Number(n)) if n.as_u64() == Some(0) => Ok(Value::Bool(false)),
        (IecType::Bool, Json::Number(n)) if n.as_u64() == Some(1) => Ok(Value::Bool(true)),
        (IecType::String, Json::String(s)) => Ok(Value::String(s.clone())),
        (IecType::Time, Json::String(s)) => Ok(Value::Time(crate::duration::parse_ms(s)?)),
        (t, Json::Number(n)) if t != IecType::Bool && t != IecType::String => {
            Ok(if let Some(i) = n.as_i64() {
                Value::from_int(t, i.into())?
            } else if let Some(u) = n.as_u64() {
                Value::from_int(t, u.into())?
            } else {
                let x = n.as_f64().unwrap_or(f64::NAN);
                Value::from_real(t, x)?
            })
        }
        _ => Err(crate::codec::CodecError::Expected {
            ty,
            expected: expected(ty),
            found,
        }),
    }
}

fn expected(ty: IecType) -> &'static str {
    match ty {
        IecType::Bool => "true or false",
        IecType::String => "a string",
        IecType::Time => "milliseconds or a duration such as \"T#1s500ms\"",
        IecType::Real | IecType::Lreal => "a number",
        _ => "a whole number",
    }
}

fn describe(json: &Json) -> &'static str {
    match json {
        Json::Null => "null",
        Json::Bool(_) => "a boolean",
        Json::Number(_) => "a number",
        Json::String(_) => "a string",
        Json::Array(_) => "an array",
        Json::Object(_) => "an object",
    }
}

pub(crate) fn rfc3339(t: SystemTime) -> String {
    humantime::format_rfc3339_millis(t).to_string()
}

/// A value serialised as [`value_to_json`] renders it (`None` as null), written straight to
/// the output: no JSON tree, and a REAL's shortest text without a round trip through a
/// string.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct ValueJson(pub Option<Value>);

impl Serialize for ValueJson {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        match &self.0 {
            None => serializer.serialize_none(),
            Some(Value::Bool(b)) => serializer.serialize_bool(*b),
            Some(Value::Int(i) | Value::Time(i)) => serializer.serialize_i64(*i),
            Some(Value::UInt(u)) => serializer.serialize_u64(*u),
            // serde_json writes an f32 as its shortest text that reads back the same f32.
            Some(Value::Real(r)) if r.is_finite() => serializer.serialize_f32(*r),
            Some(Value::LReal(r)) if r.is_finite() => serializer.serialize_f64(*r),
            Some(Value::Real(r)) => serializer.serialize_str(not_finite_text(f64::from(*r))),
            Some(Value::LReal(r)) => serializer.serialize_str(not_finite_text(*r)),
            Some(Value::String(s)) => serializer.serialize_str(s),
        }
    }
}

/// A wall-clock time serialised as RFC 3339 with milliseconds, formatted into the output.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Timestamp(pub SystemTime);

impl Serialize for Timestamp {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.collect_str(&humantime::format_rfc3339_millis(self.0))
    }
}

/// A field's value with its type, quality and timestamp. Names are borrowed from the device
/// while a response or event is written.
#[derive(Debug, Serialize, ToSchema)]
pub(crate) struct FieldValue<'a> {
    pub(crate) device: &'a str,
    pub(crate) field: &'a str,
    /// IEC 61131-3 type, e.g. `REAL`.
    #[serde(rename = "type")]
    pub(crate) ty: &'static str,
    pub(crate) direction: &'static str,
    /// The value as the JSON of its type; null until first read. A REAL or LREAL JSON has
    /// no number for is the string `"NaN"`, `"Infinity"` or `"-Infinity"`.
    #[schema(value_type = Object)]
    pub(crate) value: ValueJson,
    /// `good`, `stale`, `never_read` or `bad`.
    pub(crate) quality: &'static str,
    /// When the value was last refreshed (RFC 3339).
    #[schema(value_type = Option<String>)]
    pub(crate) timestamp: Option<Timestamp>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) unit: Option<&'a str>,
    /// Why the quality is bad.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) error: Option<String>,
    /// The latest write to this field, if any.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) last_write: Option<WriteInfo>,
    /// True when the device holds another value than the newest one requested (`desired`),
    /// with no write of it waiting: a failed write, a device that changed its own output, a
    /// power-cycled device.
    pub(crate) mismatch: bool,
    /// The newest value requested for this output, when the device holds another.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(value_type = Option<Object>)]
    pub(crate) desired: Option<ValueJson>,
}

/// The JSON of a field's view.
pub(crate) fn field_value<'a>(view: &FieldView<'a>) -> FieldValue<'a> {
    let field = view.field;
    FieldValue {
        device: view.device.name(),
        field: &field.name,
        ty: field.ty.name(),
        direction: field.direction.name(),
        value: ValueJson(view.value.clone()),
        quality: view.quality.name(),
        timestamp: view.timestamp.map(Timestamp),
        unit: field.register.unit.as_deref(),
        error: view.error.as_ref().map(ToString::to_string),
        last_write: view.last_write.as_ref().map(WriteInfo::from),
        mismatch: view.mismatch(),
        desired: view.desired.clone().map(|d| ValueJson(Some(d))),
    }
}

/// Where a write stands.
#[derive(Debug, Serialize, ToSchema)]
pub(crate) struct WriteInfo {
    pub(crate) generation: u64,
    pub(crate) device: String,
    pub(crate) field: String,
    #[schema(value_type = Object)]
    pub(crate) value: Json,
    /// `pending`, `written`, `superseded` or `failed`.
    pub(crate) status: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) error: Option<String>,
    pub(crate) requested: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) finished: Option<String>,
    /// `client`, or the gateway's own: `replay` (after a reconnect), `reconcile` (the device
    /// held another value), `safety` (the writing client was lost).
    pub(crate) origin: String,
    /// Transactions sent for it, retries included (0 until it reached the bus).
    pub(crate) attempts: u32,
}

impl From<&WriteRecord> for WriteInfo {
    fn from(r: &WriteRecord) -> Self {
        WriteInfo {
            generation: r.generation,
            device: r.device.clone(),
            field: r.field.clone(),
            value: r.value.as_ref().map_or(Json::Null, value_to_json),
            status: r.status.name().to_owned(),
            error: r.error.clone(),
            requested: rfc3339(r.requested),
            finished: r.finished.map(rfc3339),
            origin: r.origin.name().to_owned(),
            attempts: r.attempts,
        }
    }
}

/// A device with its diagnostics.
#[derive(Debug, Serialize, ToSchema)]
pub(crate) struct DeviceInfo {
    pub(crate) name: String,
    pub(crate) profile: String,
    pub(crate) protocol: String,
    pub(crate) link: Option<String>,
    pub(crate) slave_id: Option<u8>,
    pub(crate) refresh_rate_ms: u64,
    pub(crate) timeout_ms: u64,
    /// What the gateway does with the outputs it wrote when the device is back after a
    /// reconnect: `on_reconnect` (writes the newest requested values again) or `never`.
    pub(crate) rewrite_outputs: &'static str,
    pub(crate) connected: bool,
    /// 0 OK, 1 no link, 2 no slave, 10 communication error.
    pub(crate) error_code: i16,
    pub(crate) io_cycles: u64,
    pub(crate) last_response_ms: f64,
}

pub(crate) fn device_info(device: &Device) -> DeviceInfo {
    use crate::config::RewriteOutputs;
    let binding = device.binding();
    let Diagnostics {
        connected,
        error_code,
        io_cycles,
        last_response_ms,
    } = device.diagnostics();
    DeviceInfo {
        name: device.name().to_owned(),
        profile: device.profile.name.clone(),
        protocol: device.profile.protocol.name().to_owned(),
        link: binding.link,
        slave_id: binding.slave_id,
        refresh_rate_ms: device.config.refresh_rate.as_millis() as u64,
        timeout_ms: device.config.timeout.as_millis() as u64,
        rewrite_outputs: if device.outputs().rewrites() {
            RewriteOutputs::OnReconnect.name()
        } else {
            RewriteOutputs::Never.name()
        },
        connected,
        error_code: error_code.code(),
        io_cycles,
        last_response_ms,
    }
}

#[derive(Debug, Serialize, ToSchema)]
pub(crate) struct DeviceList {
    pub(crate) devices: Vec<DeviceInfo>,
}

/// A device with its diagnostics and every field's value, in profile order.
#[derive(Debug, ToSchema)]
pub(crate) struct DeviceDetail<'a> {
    #[serde(flatten)]
    pub(crate) device: DeviceInfo,
    /// Field name to value object.
    #[schema(value_type = Object)]
    pub(crate) fields: FieldMap<'a>,
}

impl Serialize for DeviceDetail<'_> {
    /// The device's own keys, then `fields`: what `#[serde(flatten)]` would give, without
    /// its buffering.
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeMap;
        let d = &self.device;
        let mut map = serializer.serialize_map(Some(13))?;
        map.serialize_entry("name", &d.name)?;
        map.serialize_entry("profile", &d.profile)?;
        map.serialize_entry("protocol", &d.protocol)?;
        map.serialize_entry("link", &d.link)?;
        map.serialize_entry("slave_id", &d.slave_id)?;
        map.serialize_entry("refresh_rate_ms", &d.refresh_rate_ms)?;
        map.serialize_entry("timeout_ms", &d.timeout_ms)?;
        map.serialize_entry("rewrite_outputs", &d.rewrite_outputs)?;
        map.serialize_entry("connected", &d.connected)?;
        map.serialize_entry("error_code", &d.error_code)?;
        map.serialize_entry("io_cycles", &d.io_cycles)?;
        map.serialize_entry("last_response_ms", &d.last_response_ms)?;
        map.serialize_entry("fields", &self.fields)?;
        map.end()
    }
}

/// Field values serialised as an object keyed by field name, in profile order, straight
/// from the values (no intermediate JSON tree).
#[derive(Debug)]
pub(crate) struct FieldMap<'a>(pub Vec<FieldValue<'a>>);

impl Serialize for FieldMap<'_> {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeMap;
        let mut map = serializer.serialize_map(Some(self.0.len()))?;
        for value in &self.0 {
            map.serialize_entry(&value.field, value)?;
        }
        map.end()
    }
}

/// A device's diagnostics, as sent on the event stream.
#[derive(Debug, Serialize, ToSchema)]
pub(crate) struct DiagnosticsEvent {
    pub(crate) device: String,
    pub(crate) connected: bool,
    pub(crate) error_code: i16,
    pub(crate) io_cycles: u64,
    pub(crate) last_response_ms: f64,
}

/// The answer to an accepted write.
#[derive(Debug, Serialize, ToSchema)]
pub(crate) struct WriteAccepted {
    pub(crate) device: String,
    pub(crate) field: String,
    pub(crate) generation: u64,
    /// Always `pending`: follow it at `/api/v1/writes/{generation}`.
    pub(crate) status: String,
}

#[derive(Debug, Serialize, ToSchema)]
pub(crate) struct WritesAccepted {
    pub(crate) writes: Vec<WriteAccepted>,
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn reals_print_as_written() {
        assert_eq!(value_to_json(&Value::Real(0.1)).to_string(), "0.1");
        for v in [
            Value::Real(0.1),
            Value::Real(21.5),
            Value::Real(-3.0e-7),
            Value::Real(1.0),
            Value::Real(f32::NAN),
            Value::Real(f32::MAX),
            Value::LReal(0.1),
            Value::LReal(f64::INFINITY),
            Value::Int(-5),
            Value::Time(1500),
            Value::UInt(u64::MAX),
            Value::Bool(true),
            Value::String("a \"quoted\"\n line".into()),
        ] {
            let direct = serde_json::to_string(&ValueJson(Some(v.clone()))).expect("direct");
            let tree = value_to_json(&v).to_string();
            assert_eq!(
                serde_json::from_str::<Json>(&direct).expect("json"),
                serde_json::from_str::<Json>(&tree).expect("json"),
                "{v:?}: {direct} vs {tree}"
            );
        }
        let at = SystemTime::UNIX_EPOCH + std::time::Duration::from_millis(1_795_000_000_123);
        assert_eq!(
            serde_json::to_string(&Timestamp(at)).expect("timestamp"),
            format!("\"{}\"", rfc3339(at))
        );
        assert_eq!(value_to_json(&Value::Real(21.5)).to_string(), "21.5");
        for (v, said) in [
            (Value::Real(f32::NAN), "\"NaN\""),
            (Value::Real(f32::NEG_INFINITY), "\"-Infinity\""),
            (Value::LReal(f64::INFINITY), "\"Infinity\""),
        ] {
            assert_eq!(value_to_json(&v).to_string(), said);
            let direct = serde_json::to_string(&ValueJson(Some(v))).expect("direct");
            assert_eq!(direct, said);
        }
        assert_eq!(value_to_json(&Value::LReal(0.1)).to_string(), "0.1");
    }

    #[test]
    fn json_values_are_checked_against_the_type() {
        assert_eq!(
            json_to_value(IecType::Bool, &json!(1)),
            Ok(Value::Bool(true))
        );
        assert!(json_to_value(IecType::Bool, &json!(2)).is_err());
        assert!(json_to_value(IecType::Bool, &json!("true")).is_err());
        assert_eq!(json_to_value(IecType::Int, &json!(-3)), Ok(Value::Int(-3)));
        assert_eq!(json_to_value(IecType::Int, &json!(3.0)), Ok(Value::Int(3)));
        let err = json_to_value(IecType::Usint, &json!(300)).expect_err("range");
        assert!(err.to_string().contains("out of range for USINT"), "{err}");
        assert!(json_to_value(IecType::Int, &json!(2.5)).is_err());
        assert_eq!(
            json_to_value(IecType::Ulint, &json!(u64::MAX)),
            Ok(Value::UInt(u64::MAX))
        );
        assert_eq!(
            json_to_value(IecType::Real, &json!(12.5)),
            Ok(Value::Real(12.5))
        );
        assert_eq!(
            json_to_value(IecType::Time, &json!("T#1s500ms")),
            Ok(Value::Time(1500))
        );
        assert_eq!(
            json_to_value(IecType::Time, &json!(250)),
            Ok(Value::Time(250))
        );
        let err = json_to_value(IecType::Real, &json!("hot")).expect_err("type");
        assert_eq!(err.to_string(), "REAL needs a number, got a string");
        assert!(json_to_value(IecType::String, &json!(null)).is_err());
    }

    fn any_json() -> impl proptest::strategy::Strategy<Value = Json> {
        use proptest::prelude::*;
        prop_oneof![
            any::<bool>().prop_map(Json::Bool),
            any::<i64>().prop_map(|i| json!(i)),
            any::<u64>().prop_map(|u| json!(u)),
            any::<f64>().prop_map(|f| json!(f)),
            (-1000i64..1000).prop_map(|i| json!(i as f64 / 8.0)),
            "\\PC{0,40}".prop_map(Json::String),
            "T#[0-9]{1,6}(ms|s|m|h)".prop_map(Json::String),
            Just(Json::Null),
            proptest::collection::vec(any::<i32>(), 0..3).prop_map(|v| json!(v)),
        ]
    }

    proptest::proptest! {
        // A long run: `PROPTEST_CASES=1000000 cargo test --release -p iogate --lib json_`.
        #[test]
        fn json_values_convert_or_are_refused_and_round_trip(
            which in 0..IecType::ALL.len(),
            json in any_json(),
        ) {
            let ty = IecType::ALL[which];
            if let Ok(value) = json_to_value(ty, &json) {
                let back = value_to_json(&value);
                proptest::prop_assert_eq!(json_to_value(ty, &back), Ok(value));
            }
        }
    }
}

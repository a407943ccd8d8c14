//! Sparkplug B 3.0 for the edge node: topics, metrics from field views, births, deaths,
//! data, commands and the primary host's STATE. Only encoding and decoding live here; when
//! to send what is the session's (`mod.rs`).
//!
//! - Datatypes from the IEC type: SINT Int8, INT Int16, DINT Int32, LINT Int64, USINT/BYTE
//!   UInt8, UINT/WORD UInt16, UDINT/DWORD UInt32, ULINT/LWORD UInt64, REAL Float, LREAL
//!   Double, BOOL Boolean, STRING String, TIME Int64 in milliseconds (unit `ms`).
//! - Quality as the metric property `Quality` (Int32, as Ignition reads it): 192 good, 500
//!   stale, 0 bad or never read (and `is_null` when there is no value).
//! - Births carry `engUnit`, `scale`, `offset`, `readOnly` and `Documentation` properties.

use std::collections::HashMap;

use iogate_proto::sparkplug::{DataType, Payload, payload};
use iogate_types::{IecType, Quality};
use prost::Message;
use serde::{Deserialize, Serialize};

use crate::api::mqtt::config::SparkplugConfig;
use crate::cache::Diagnostics;
use crate::codec::Value;
use crate::service::FieldView;

pub(crate) type Metric = payload::Metric;
type MetricValue = payload::metric::Value;

pub(crate) const REBIRTH: &str = "Node Control/Rebirth";
const BD_SEQ: &str = "bdSeq";
const VERSION: &str = "Node Info/Version";
const UPTIME: &str = "Node Info/Uptime";
/// The device diagnostics as metrics, in this order after the fields.
pub(crate) const DIAGNOSTICS: [&str; 4] = [
    "Diagnostics/connected",
    "Diagnostics/error_code",
    "Diagnostics/io_cycles",
    "Diagnostics/last_response_ms",
];

/// Ignition's quality codes.
fn quality_code(q: Quality) -> i32 {
    match q {
        Quality::Good => 192,
        Quality::Stale => 500,
        Quality::NeverRead | Quality::Bad => 0,
    }
}

/// The topics of one edge node.
pub(crate) struct Topics {
    group: String,
    node: String,
    host: Option<String>,
}

impl Topics {
    pub(crate) fn new(c: &SparkplugConfig) -> Topics {
        Topics {
            group: c.group_id.clone(),
            node: c.edge_node_id.clone(),
            host: c.primary_host.clone(),
        }
    }
    pub(crate) fn node(&self, kind: &str) -> String {
        format!("spBv1.0/{}/{kind}/{}", self.group, self.node)
    }
    pub(crate) fn device(&self, kind: &str, device: &str) -> String {
        format!("spBv1.0/{}/{kind}/{}/{device}", self.group, self.node)
    }
    pub(crate) fn host_state(&self) -> Option<String> {
        self.host.as_ref().map(|h| format!("spBv1.0/STATE/{h}"))
    }
    /// The device a DCMD topic names, or `None` for NCMD.
    pub(crate) fn command<'t>(&self, topic: &'t str) -> Option<Option<&'t str>> {
        if topic == self.node("NCMD") {
            return Some(None);
        }
        let device = topic.strip_prefix(&self.node("DCMD"))?.strip_prefix('/')?;
        (!device.is_empty() && !device.contains('/')).then_some(Some(device))
    }
}

/// The primary host application's STATE (3.0: JSON).
#[derive(Debug, Deserialize, Serialize, PartialEq)]
pub(crate) struct HostState {
    pub(crate) online: bool,
    #[serde(default)]
    pub(crate) timestamp: u64,
}

pub(crate) fn datatype(ty: IecType) -> DataType {
    match ty {
        IecType::Bool => DataType::Boolean,
        IecType::Sint => DataType::Int8,
        IecType::Int => DataType::Int16,
        IecType::Dint => DataType::Int32,
        IecType::Lint | IecType::Time => DataType::Int64,
        IecType::Usint | IecType::Byte => DataType::UInt8,
        IecType::Uint | IecType::Word => DataType::UInt16,
        IecType::Udint | IecType::Dword => DataType::UInt32,
        IecType::Ulint | IecType::Lword => DataType::UInt64,
        IecType::Real => DataType::Float,
        IecType::Lreal => DataType::Double,
        IecType::String => DataType::String,
    }
}

fn metric_value(v: &Value) -> MetricValue {
    match v {
        Value::Bool(b) => MetricValue::BooleanValue(*b),
        // Int8..Int32 travel sign-extended in the 32-bit field, Int64 in the 64-bit one;
        // the datatype says which.
        Value::Int(i) if i32::try_from(*i).is_ok() => MetricValue::IntValue(*i as i32 as u32),
        Value::Int(i) | Value::Time(i) => MetricValue::LongValue(*i as u64),
        Value::UInt(u) if u32::try_from(*u).is_ok() => MetricValue::IntValue(*u as u32),
        Value::UInt(u) => MetricValue::LongValue(*u),
        Value::Real(x) => MetricValue::FloatValue(*x),
        Value::LReal(x) => MetricValue::DoubleValue(*x),
        Value::String(s) => MetricValue::StringValue(s.clone()),
    }
}

/// The value for `ty`: 64-bit types always in `long_value`.
fn typed_value(ty: IecType, v: &Value) -> MetricValue {
    match (datatype(ty), v) {
        (DataType::Int64, Value::Int(i) | Value::Time(i)) => MetricValue::LongValue(*i as u64),
        (DataType::UInt64, Value::UInt(u)) => MetricValue::LongValue(*u),
        _ => metric_value(v),
    }
}

fn property(
    key: &str,
    ty: DataType,
    value: payload::property_value::Value,
) -> (String, payload::PropertyValue) {
    (
        key.to_owned(),
        payload::PropertyValue {
            r#type: Some(ty as u32),
            is_null: None,
            value: Some(value),
        },
    )
}

fn property_set(props: Vec<(String, payload::PropertyValue)>) -> Option<payload::PropertySet> {
    if props.is_empty() {
        return None;
    }
    let (keys, values) = props.into_iter().unzip();
    Some(payload::PropertySet { keys, values })
}

fn quality_property(q: Quality) -> (String, payload::PropertyValue) {
    property(
        "Quality",
        DataType::Int32,
        payload::property_value::Value::IntValue(quality_code(q) as u32),
    )
}

fn millis(t: std::time::SystemTime) -> u64 {
    t.duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as u64)
}

/// How a field's metric is written.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Form {
    /// In a birth: name, alias and the properties.
    Birth,
    /// In data: neither name nor alias (the record that keeps it carries the name, and the
    /// session's alias is added as it is sent; see [`data_payload`]).
    Data,
}

/// A field's metric from its view; its timestamp is when the value was read (now when it
/// never was).
pub(crate) fn field_metric(view: &FieldView<'_>, alias: u64, form: Form, now_ms: u64) -> Metric {
    let ty = view.field.ty;
    let mut props = Vec::new();
    if form == Form::Birth {
        let r = &view.field.register;
        match (view.unit(), ty) {
            (Some(u), _) => props.push(property(
                "engUnit",
                DataType::String,
                payload::property_value::Value::StringValue(u.to_owned()),
            )),
            (None, IecType::Time) => props.push(property(
                "engUnit",
                DataType::String,
                payload::property_value::Value::StringValue("ms".into()),
            )),
            _ => {}
        }
        if r.scale != 1.0 {
            props.push(property(
                "scale",
                DataType::Double,
                payload::property_value::Value::DoubleValue(r.scale),
            ));
        }
        if r.offset != 0.0 {
            props.push(property(
                "offset",
                DataType::Double,
                payload::property_value::Value::DoubleValue(r.offset),
            ));
        }
        props.push(property(
            "readOnly",
            DataType::Boolean,
            payload::property_value::Value::BooleanValue(!view.field.direction.is_writable()),
        ));
        if let Some(d) = &view.field.description {
            props.push(property(
                "Documentation",
                DataType::String,
                payload::property_value::Value::StringValue(d.clone()),
            ));
        }
    }
    props.push(quality_property(view.quality));
    Metric {
        name: (form == Form::Birth).then(|| view.field.name.clone()),
        alias: (form == Form::Birth).then_some(alias),
        timestamp: Some(view.timestamp.map_or(now_ms, millis)),
        datatype: Some(datatype(ty) as u32),
        is_null: view.value.is_none().then_some(true),
        properties: property_set(props),
        value: view.value.as_ref().map(|v| typed_value(ty, v)),
        ..Metric::default()
    }
}

/// The diagnostics as the four metrics of [`DIAGNOSTICS`], aliases from `alias`.
pub(crate) fn diagnostics_metrics(
    d: &Diagnostics,
    alias: u64,
    named: bool,
    now_ms: u64,
) -> Vec<Metric> {
    let values = [
        (DataType::Boolean, MetricValue::BooleanValue(d.connected)),
        (
            DataType::Int32,
            MetricValue::IntValue(i32::from(d.error_code.code()) as u32),
        ),
        (DataType::UInt64, MetricValue::LongValue(d.io_cycles)),
        (
            DataType::Double,
            MetricValue::DoubleValue(d.last_response_ms),
        ),
    ];
    values
        .into_iter()
        .enumerate()
        .map(|(i, (ty, value))| Metric {
            name: named.then(|| DIAGNOSTICS[i].to_owned()),
            alias: Some(alias + i as u64),
            timestamp: Some(now_ms),
            datatype: Some(ty as u32),
            value: Some(value),
            ..Metric::default()
        })
        .collect()
}

pub(crate) fn encode(timestamp: u64, seq: Option<u8>, metrics: Vec<Metric>) -> Vec<u8> {
    Payload {
        timestamp: Some(timestamp),
        metrics,
        seq: seq.map(u64::from),
        ..Payload::default()
    }
    .encode_to_vec()
}

/// A data metric as a record keeps it: encoded once, without name or alias.
pub(crate) fn kept_metric(m: &Metric) -> Vec<u8> {
    m.encode_to_vec()
}

/// A kept metric as it can be sent: as kept, or, kept by an earlier version with its name,
/// decoded and encoded without it (`None`: not a metric).
pub(crate) fn sendable(kept: &[u8]) -> Option<std::borrow::Cow<'_, [u8]>> {
    // Field 1 (name), length-delimited: the form an earlier version kept.
    if kept.first() != Some(&0x0A) {
        return Some(std::borrow::Cow::Borrowed(kept));
    }
    let mut m = Metric::decode(kept).ok()?;
    m.name = None;
    Some(std::borrow::Cow::Owned(m.encode_to_vec()))
}

/// A DDATA payload of one [`sendable`] metric, sent by `alias` (marked historical when
/// replayed from the buffer): the metric's bytes as kept, its alias and mark appended to
/// them (protobuf takes a message's fields in any order), between the payload's timestamp
/// and `seq`; the value is not encoded again.
pub(crate) fn data_payload(
    timestamp: u64,
    seq: u8,
    metric: &[u8],
    alias: u64,
    historical: bool,
) -> Vec<u8> {
    data_payload_of(timestamp, seq, &[(metric, alias)], historical)
}

/// A DDATA payload of several [`sendable`] metrics of one device, each by its alias, laid
/// out as [`data_payload`]'s one.
pub(crate) fn data_payload_of(
    timestamp: u64,
    seq: u8,
    metrics: &[(&[u8], u64)],
    historical: bool,
) -> Vec<u8> {
    use prost::encoding::{WireType, encode_key, encode_varint};
    let size: usize = metrics.iter().map(|(m, _)| m.len() + 16).sum();
    let mut out = Vec::with_capacity(size + 24);
    prost::encoding::uint64::encode(1, &timestamp, &mut out);
    let mut tail = Vec::with_capacity(12);
    for &(metric, alias) in metrics {
        tail.clear();
        prost::encoding::uint64::encode(2, &alias, &mut tail);
        if historical {
            prost::encoding::bool::encode(5, &true, &mut tail);
        }
        encode_key(2, WireType::LengthDelimited, &mut out);
        encode_varint((metric.len() + tail.len()) as u64, &mut out);
        out.extend_from_slice(metric);
        out.extend_from_slice(&tail);
    }
    prost::encoding::uint64::encode(3, &u64::from(seq), &mut out);
    out
}

fn bd_seq_metric(bd_seq: u8, now_ms: u64) -> Metric {
    Metric {
        name: Some(BD_SEQ.into()),
        timestamp: Some(now_ms),
        // Sparkplug 3.0 types `bdSeq` Int64 (its values wrap at 255).
        datatype: Some(DataType::Int64 as u32),
        value: Some(MetricValue::LongValue(u64::from(bd_seq))),
        ..Metric::default()
    }
}

/// The NDEATH payload (the Will, and what is sent on a clean stop): `bdSeq` only, no `seq`.
pub(crate) fn death(bd_seq: u8, now_ms: u64) -> Vec<u8> {
    encode(now_ms, None, vec![bd_seq_metric(bd_seq, now_ms)])
}

/// The NBIRTH payload: `seq` 0, the same `bdSeq` as the Will, and the node's metrics
/// (aliases 1..=3).
pub(crate) fn node_birth(bd_seq: u8, uptime_s: u64, now_ms: u64) -> Vec<u8> {
    let metric = |name: &str, alias: u64, ty: DataType, value: MetricValue| Metric {
        name: Some(name.into()),
        alias: Some(alias),
        timestamp: Some(now_ms),
        datatype: Some(ty as u32),
        value: Some(value),
        ..Metric::default()
    };
    encode(
        now_ms,
        Some(0),
        vec![
            bd_seq_metric(bd_seq, now_ms),
            metric(
                REBIRTH,
                1,
                DataType::Boolean,
                MetricValue::BooleanValue(false),
            ),
            metric(
                VERSION,
                2,
                DataType::String,
                MetricValue::StringValue(env!("CARGO_PKG_VERSION").into()),
            ),
            metric(
                UPTIME,
                3,
                DataType::UInt64,
                MetricValue::LongValue(uptime_s),
            ),
        ],
    )
}

/// Aliases: unique across the edge node and stable while the gateway runs (a device that
/// goes and comes back keeps its own). The node's metrics take 1..=3.
#[derive(Default)]
pub(crate) struct Aliases {
    bases: HashMap<String, (u64, usize)>,
    next: u64,
}

/// Room each device's aliases leave for its fields: the fields, the diagnostics, a margin.
impl Aliases {
    /// The first alias of `device`'s `fields` field metrics (its diagnostics follow them).
    pub(crate) fn base(&mut self, device: &str, fields: usize) -> u64 {
        if self.next == 0 {
            self.next = 16;
        }
        match self.bases.get(device) {
            Some(&(base, n)) if n == fields => base,
            _ => {
                let base = self.next;
                self.next += (fields + DIAGNOSTICS.len()) as u64;
                self.bases.insert(device.to_owned(), (base, fields));
                base
            }
        }
    }
}

/// A metric of a command: its name (or alias) and value.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Command {
    pub(crate) name: Option<String>,
    pub(crate) alias: Option<u64>,
    pub(crate) value: Option<serde_json::Value>,
}

/// Why a command could not be read.
#[derive(Debug, thiserror::Error)]
pub(crate) enum CommandError {
    #[error("the payload is not a Sparkplug B payload: {0}")]
    Decode(#[from] prost::DecodeError),
}

/// The metrics of an NCMD or DCMD, their values as JSON for the service's conversion.
pub(crate) fn commands(payload: &[u8]) -> Result<Vec<Command>, CommandError> {
    let p = Payload::decode(payload)?;
    Ok(p.metrics
        .into_iter()
        .map(|m| {
            let ty = m.datatype.and_then(|t| DataType::try_from(t as i32).ok());
            // A null metric is a relinquish (JSON null), a metric without a value nothing.
            let value = if m.is_null == Some(true) {
                Some(serde_json::Value::Null)
            } else {
                m.value.and_then(|v| json_of(ty, v))
            };
            Command {
                name: m.name,
                alias: m.alias,
                value,
            }
        })
        .collect())
}

fn json_of(ty: Option<DataType>, v: MetricValue) -> Option<serde_json::Value> {
    use serde_json::Value as J;
    Some(match v {
        MetricValue::BooleanValue(b) => J::Bool(b),
        MetricValue::IntValue(i) => match ty {
            Some(DataType::Int8 | DataType::Int16 | DataType::Int32) => J::from(i as i32),
            _ => J::from(i),
        },
        MetricValue::LongValue(l) => match ty {
            Some(DataType::Int64 | DataType::DateTime) => J::from(l as i64),
            _ => J::from(l),
        },
        MetricValue::FloatValue(x) => J::from(f64::from(x)),
        MetricValue::DoubleValue(x) => J::from(x),
        MetricValue::StringValue(s) => J::String(s),
        _ => return None,
    })
}

#[cfg(test)]
#[path = "sparkplug_tests.rs"]
mod tests;

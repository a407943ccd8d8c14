//! The `transactions:` section of `iogate.yaml`: standing raw transactions, each a read
//! repeated every `refresh_interval` (after the previous one finished) or a write re-sent
//! every `polling_period` (from the start of the previous one) while enabled.

use std::time::Duration;

use crate::duration;
use crate::yaml::{Kind, Node, Report};
use serde::Deserialize;

#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct TransactionSpec {
    /// 1-4 read, 5, 6, 15, 16 write.
    #[serde(default, deserialize_with = "whole")]
    pub(crate) function: Option<i64>,
    /// deviceAddress / network number, 1-255.
    #[serde(default, deserialize_with = "whole")]
    pub(crate) slave: Option<i64>,
    /// registerAddress / data address, 0-65535.
    #[serde(default, deserialize_with = "whole")]
    pub(crate) address: Option<i64>,
    /// FC01/02: bits to read, 1-32.
    #[serde(default, deserialize_with = "whole")]
    pub(crate) bit_count: Option<i64>,
    /// FC03/04: SIGNED_NUMBER16, SIGNED_NUMBER32, UNSIGNED_NUMBER16, UNSIGNED_NUMBER32, FLOAT.
    pub(crate) value_type: Option<String>,
    /// Reads: 1-4294967295 (default 1); the value is divided by it, not rounded.
    #[serde(default, deserialize_with = "whole")]
    pub(crate) divisor: Option<i64>,
    /// Reads: 0-3 digits kept after the point, truncating (default 3).
    #[serde(default, deserialize_with = "whole")]
    pub(crate) precision: Option<i64>,
    /// LittleEndian, BigEndian, SwapBytes, SwapWords, Little-endian, Big-endian, Big-endian (2 bytes).
    pub(crate) byte_order: Option<String>,
    /// responseTimeout, 10-60000 ms (default 1000).
    #[serde(default, deserialize_with = "whole")]
    pub(crate) timeout_ms: Option<i64>,
    /// Writes: uint8, int8, uint16, int16, int32 (an integer), float (IEEE-754), int32/float (IEEE-754 for a number written with a point, else int32).
    #[serde(rename = "type")]
    pub(crate) write_type: Option<String>,
    /// Writes: the values (numbers; for coils, numbers or booleans).
    #[schema(value_type = Vec<Object>)]
    pub(crate) values: Option<Vec<serde_json::Value>>,
}

/// A JSON number as an integer: `7` or `7.0` (JSON Schema counts both as integers); `None`
/// for a fraction or a number an `i64` cannot hold exactly.
pub(crate) fn whole_number(n: &serde_json::Number) -> Option<i64> {
    n.as_i64().or_else(|| {
        n.as_f64()
            .filter(|x| x.fract() == 0.0 && x.abs() < 9.0e15)
            .map(|x| x as i64)
    })
}

/// An integer key ([`whole_number`]), or null.
fn whole<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Option<i64>, D::Error> {
    let n = <Option<serde_json::Number> as Deserialize>::deserialize(d)?;
    n.map(|n| {
        whole_number(&n).ok_or_else(|| serde::de::Error::custom(format!("{n} is not an integer")))
    })
    .transpose()
}

/// One standing transaction as configured (or declared at run time).
#[derive(Debug, Clone, PartialEq, serde::Serialize, Deserialize)]
pub struct StandingConfig {
    pub(crate) name: String,
    pub(crate) link: String,
    pub(crate) spec: TransactionSpec,
    /// Reads: `refresh_interval`; writes: `polling_period`. Zero: only when triggered.
    pub(crate) period: Duration,
    pub(crate) enabled: bool,
    pub(crate) line: u64,
}

/// The YAML value as JSON, for the keys a transaction shares with the REST interface.
fn json(node: &Node) -> serde_json::Value {
    match &node.kind {
        Kind::Null => serde_json::Value::Null,
        Kind::Bool(b) => (*b).into(),
        Kind::Int(i) => i64::try_from(*i).map_or(serde_json::Value::Null, Into::into),
        Kind::Float(f) => {
            serde_json::Number::from_f64(*f).map_or(serde_json::Value::Null, Into::into)
        }
        Kind::Str(s) => s.clone().into(),
        Kind::Seq(items) => items.iter().map(json).collect(),
        Kind::Map(entries) => entries
            .iter()
            .map(|(k, v)| (k.name.clone(), json(v)))
            .collect::<serde_json::Map<_, _>>()
            .into(),
    }
}

pub(super) fn read(node: &Node, report: &mut Report) -> Vec<StandingConfig> {
    let Some(items) = node.seq(report, "transactions") else {
        return Vec::new();
    };
    let mut out: Vec<StandingConfig> = Vec::new();
    for (index, item) in items.iter().enumerate() {
        let ctx = format!("transactions[{index}]");
        let Kind::Map(entries) = &item.kind else {
            report.push(item.line, &ctx, "expected a mapping");
            continue;
        };
        let mut name = None;
        let mut link = None;
        let mut period = None;
        let mut enabled = true;
        let mut spec = serde_json::Map::new();
        for (key, value) in entries {
            let text = || match &value.kind {
                Kind::Str(s) => Some(s.clone()),
                _ => None,
            };
            match key.name.as_str() {
                "name" => name = text(),
                "link" => link = text(),
                "refresh_interval" | "polling_period" => {
                    let parsed = text().map(|t| duration::parse(&t));
                    match parsed {
                        Some(Ok(d)) if d <= Duration::from_secs(3600) => period = Some(d),
                        _ => report.push(
                            value.line,
                            format!("{ctx}: {}", key.name),
                            "Invalid refresh interval configuration. (a duration of 0-3600s, e.g. 1s)",
                        ),
                    }
                }
                "enabled" => match value.kind {
                    Kind::Bool(b) => enabled = b,
                    _ => report.push(
                        value.line,
                        format!("{ctx}: enabled"),
                        "expected true or false",
                    ),
                },
                other => {
                    spec.insert(other.to_owned(), json(value));
                }
            }
        }
        let (Some(name), Some(link)) = (name, link) else {
            report.push(item.line, &ctx, "a transaction needs a `name` and a `link`");
            continue;
        };
        let ctx = format!("transaction {name}");
        if out.iter().any(|t| t.name == name) {
            report.push(item.line, &ctx, "duplicate transaction name");
        }
        let spec: TransactionSpec = match serde_json::from_value(spec.into()) {
            Ok(s) => s,
            Err(e) => {
                report.push(item.line, &ctx, e.to_string());
                continue;
            }
        };
        out.push(StandingConfig {
            name,
            link,
            spec,
            period: period.unwrap_or(Duration::ZERO),
            enabled,
            line: item.line,
        });
    }
    out
}

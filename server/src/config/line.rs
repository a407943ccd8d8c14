//! A serial line's settings as `iogate.yaml` writes them, for a link's `serial` and a
//! Modbus server's `serial` entries alike.

use super::rules::{self, RuleError};
use super::{Framing, Parity, SerialSettings};
use crate::yaml::{MapReader, Report};

/// A serial line's keys.
pub(super) const KEYS: &[&str] = &[
    "port",
    "baud",
    "parity",
    "data_bits",
    "stop_bits",
    "framing",
];

/// The value of a rule's check, or the broken rule reported at `line`.
pub(super) fn ruled<T>(
    checked: Result<T, RuleError>,
    line: u64,
    ctx: &str,
    report: &mut Report,
) -> Option<T> {
    checked
        .map_err(|e| report.push(line, ctx, e.to_string()))
        .ok()
}

/// A serial line's settings (`port`, `baud`, `parity`, `data_bits`, `stop_bits`,
/// `framing`) from a mapping that may hold other keys (a serial server's `unit_id`): the
/// caller reads those and finishes the mapping.
pub(super) fn read_line(
    map: &mut MapReader,
    ctx: &str,
    report: &mut Report,
) -> Option<SerialSettings> {
    let at = |k: &str| format!("{ctx}.{k}");
    let lines: Vec<(&str, u64)> = KEYS
        .iter()
        .copied()
        .filter_map(|k| map.get(k).map(|n| (k, n.line)))
        .collect();
    let port = map
        .require("port", report, ctx)
        .and_then(|n| n.scalar_text(report, &at("port")));
    let baud = map
        .require("baud", report, ctx)
        .and_then(|n| n.int_in(report, &at("baud"), 0, i128::from(u32::MAX)));
    let parity = match map.get("parity") {
        None => Some(Parity::None),
        Some(n) => n
            .scalar_text(report, &at("parity"))
            .and_then(|text| ruled(rules::parse_parity(&text), n.line, &at("parity"), report)),
    };
    let mut bits = |key: &str, default: u8| match map.get(key) {
        None => Some(i128::from(default)),
        Some(n) => n.int_in(report, &at(key), 0, 255),
    };
    let data_bits = bits("data_bits", rules::DEFAULT_DATA_BITS);
    let stop_bits = bits("stop_bits", rules::DEFAULT_STOP_BITS);
    let framing = match map.get("framing") {
        None => Some(Framing::Rtu),
        Some(n) => n.scalar_text(report, &at("framing")).and_then(|text| {
            ruled(
                rules::parse_serial_framing(&text),
                n.line,
                &at("framing"),
                report,
            )
        }),
    };
    // Every rule is checked even when a key was missing or unreadable (that is reported
    // already), so that all problems show at once.
    let complete = port.is_some() && baud.is_some() && parity.is_some();
    let checked = rules::serial(
        port.unwrap_or_else(|| "-".to_owned()),
        baud.map_or(9600, |b| b as u64),
        Ok(parity.unwrap_or(Parity::None)),
        data_bits.map_or(u64::from(rules::DEFAULT_DATA_BITS), |b| b as u64),
        stop_bits.map_or(u64::from(rules::DEFAULT_STOP_BITS), |b| b as u64),
    );
    let settings = checked
        .map_err(|errors| {
            for e in errors {
                // At the key's own line when it is written, else the mapping's.
                let line = lines
                    .iter()
                    .find(|(k, _)| *k == e.key())
                    .map_or(map.line, |(_, l)| *l);
                report.push(line, at(e.key()), e.to_string());
            }
        })
        .ok()?;
    complete.then_some(SerialSettings {
        framing: framing?,
        ..settings
    })
}

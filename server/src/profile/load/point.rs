//! A field of a protocol that names its points (an OPC UA server's variable): its point
//! under the protocol's key (`node`, or `browse_path`), `unit`, `sampling_interval` and,
//! for a STRING, `length`. No register: its value comes typed from the device, checked
//! against the field's type.

use crate::codec::{ByteOrder, IecType, full_words};
use crate::profile::{Point, Register, RegisterKind, Words};
use crate::yaml::{MapReader, Report};

/// The keys a point field may have besides the common ones and its point's.
pub(super) const POINT_KEYS: &[&str] = &["unit", "sampling_interval", "length"];
/// The keys of a point field of a protocol whose devices store raw values.
pub(super) const SCALE_KEYS: &[&str] = &["scale", "offset", "raw_type"];

/// The longest STRING a point field holds, in characters.
const MAX_LENGTH: i128 = 254;

/// Reads a point field's own keys.
pub(super) fn read_point(
    map: &mut MapReader<'_>,
    words: &Words,
    ctx: &str,
    ty: Option<IecType>,
    report: &mut Report,
) -> Option<(Register, Point)> {
    let at = |k: &str| format!("{ctx}: {k}");
    let length = match map.get("length") {
        Some(n) if ty != Some(IecType::String) => {
            report.push(n.line, at("length"), "only a STRING field has a length");
            None
        }
        Some(n) => n
            .int_in(report, &at("length"), 1, MAX_LENGTH)
            .map(|l| l as u16),
        None => None,
    };
    let (scale, offset, raw_type) = if words.scaled {
        scaling(map, ctx, ty, report)?
    } else {
        (1.0, 0.0, None)
    };
    let stored = raw_type.or(ty);
    let (address, browse_path) = address(map, words, ctx, (stored, length), report)?;
    let key = match (browse_path, words.point_alternative) {
        (true, Some(k)) => k,
        _ => words.point_key,
    };
    let unit = map
        .get("unit")
        .and_then(|n| n.scalar_text(report, &at("unit")));
    let sampling = match map.get("sampling_interval") {
        None => None,
        Some(n) => {
            let text = n.scalar_text(report, &at("sampling_interval"))?;
            match crate::duration::parse(&text) {
                Ok(d) => Some(d),
                Err(e) => {
                    report.push(n.line, at("sampling_interval"), e.to_string());
                    return None;
                }
            }
        }
    };
    let extra = extra_keys(map, words, ctx, ty, report)?;
    let ty = ty?;
    let word_count = match ty {
        IecType::String => length.unwrap_or(words.default_length).div_ceil(2),
        t => full_words(t),
    };
    let register = Register {
        address: 0,
        kind: RegisterKind::Point,
        bit: None,
        scale,
        offset,
        unit,
        byte_order: ByteOrder::BigEndian,
        word_count,
        word_count_set: true,
        raw_type,
        switch: None,
    };
    let point = Point {
        key,
        address,
        browse_path,
        sampling,
        length,
        extra,
    };
    Some((register, point))
}

/// The protocol's further keys the field carries, each checked.
fn extra_keys(
    map: &mut MapReader<'_>,
    words: &Words,
    ctx: &str,
    ty: Option<IecType>,
    report: &mut Report,
) -> Option<Vec<(&'static str, String)>> {
    let mut extra = Vec::new();
    let mut valid = true;
    for k in words.field_keys {
        let Some(n) = map.get(k.key) else { continue };
        let at = format!("{ctx}: {}", k.key);
        // A flag (IEC 104's `select: true`) is a scalar like the rest.
        let text = match n.kind {
            crate::yaml::Kind::Bool(b) => Some(b.to_string()),
            _ => n.scalar_text(report, &at),
        };
        let Some(text) = text else {
            valid = false;
            continue;
        };
        match (k.check)(&text, ty) {
            Ok(()) => extra.push((k.key, text)),
            Err(why) => {
                report.push(n.line, at, why);
                valid = false;
            }
        }
    }
    valid.then_some(extra)
}

/// The field's point under the protocol's key (or its alternative), checked: the text and
/// whether it is under the alternative key (a browse path).
fn address(
    map: &mut MapReader<'_>,
    words: &Words,
    ctx: &str,
    (ty, length): (Option<IecType>, Option<u16>),
    report: &mut Report,
) -> Option<(String, bool)> {
    let at = |k: &str| format!("{ctx}: {k}");
    let main = map.get(words.point_key);
    let other = words
        .point_alternative
        .and_then(|k| map.get(k).map(|n| (k, n)));
    let (key, node, alternative) = match (main, other) {
        (Some(n), None) => (words.point_key, n, false),
        (None, Some((k, n))) => (k, n, true),
        (Some(_), Some((k, n))) => {
            report.push(
                n.line,
                ctx,
                format!("a field has a `{}` or a `{k}`, not both", words.point_key),
            );
            return None;
        }
        (None, None) => {
            let or = words
                .point_alternative
                .map(|k| format!(" or `{k}`"))
                .unwrap_or_default();
            report.push(
                map.line,
                ctx,
                format!(
                    "missing `{}` (the point it reads, e.g. `{}`){or}",
                    words.point_key, words.example
                ),
            );
            return None;
        }
    };
    let text = node.scalar_text(report, &at(key))?;
    if let Err(why) = (words.check_point)(key, &text, ty, length) {
        report.push(node.line, at(key), why);
        return None;
    }
    Some((text, alternative))
}

/// A field's `scale`, `offset` and `raw_type` (the type the device stores, where not the
/// field's): numbers only, a scale other than zero.
fn scaling(
    map: &mut MapReader<'_>,
    ctx: &str,
    ty: Option<IecType>,
    report: &mut Report,
) -> Option<(f64, f64, Option<IecType>)> {
    let at = |k: &str| format!("{ctx}: {k}");
    let mut ok = true;
    let mut number = |key: &str, default: f64, report: &mut Report| match map.get(key) {
        None => default,
        Some(n) if ty.is_some_and(|t| !t.is_numeric()) => {
            report.push(
                n.line,
                at(key),
                format!("{} values cannot be scaled", ty.map_or("", |t| t.name())),
            );
            ok = false;
            default
        }
        Some(n) => match n.number(report, &at(key)) {
            Some(0.0) if key == "scale" => {
                report.push(
                    n.line,
                    at(key),
                    "scale must not be zero (writes divide by it)",
                );
                ok = false;
                default
            }
            Some(v) => v,
            None => {
                ok = false;
                default
            }
        },
    };
    let scale = number("scale", 1.0, report);
    let offset = number("offset", 0.0, report);
    let raw_type = match map.get("raw_type") {
        None => None,
        Some(n) => {
            let raw = n
                .str(report, &at("raw_type"))
                .map(|t| (t, IecType::parse(t)));
            match (raw, ty) {
                (Some((_, Some(r))), Some(t))
                    if r.is_numeric() && r != IecType::Time && t.is_numeric() =>
                {
                    Some(r)
                }
                (Some((text, _)), _) => {
                    report.push(
                        n.line,
                        at("raw_type"),
                        format!("`{text}`: raw_type is the number type the device stores, for a number field"),
                    );
                    ok = false;
                    None
                }
                (None, _) => {
                    ok = false;
                    None
                }
            }
        }
    };
    ok.then_some((scale, offset, raw_type))
}

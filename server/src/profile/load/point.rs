//! A field of a protocol that addresses fields by name (an OPC UA server's variable): its
//! `node` (or `browse_path`), `unit`, `sampling_interval` and, for a STRING, `length`. No
//! register: its value comes typed from the device, checked against the field's type.

use crate::codec::{ByteOrder, IecType, full_words};
use crate::profile::point::{parse_browse_path, parse_node};
use crate::profile::{Point, Register, RegisterKind};
use crate::yaml::{MapReader, Report};

/// The keys a point field may have besides the common ones.
pub(super) const POINT_KEYS: &[&str] =
    &["node", "browse_path", "unit", "sampling_interval", "length"];

/// The longest STRING a point field holds, in characters.
const MAX_LENGTH: i128 = 250;
/// A STRING point's length when the profile does not say.
const DEFAULT_LENGTH: u16 = 64;

/// Reads a point field's own keys (`key` is the protocol's point key, `node`).
pub(super) fn read_point(
    map: &mut MapReader<'_>,
    ctx: &str,
    ty: Option<IecType>,
    report: &mut Report,
) -> Option<(Register, Point)> {
    let at = |k: &str| format!("{ctx}: {k}");
    let (address, browse_path) = address(map, ctx, report)?;
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
    let ty = ty?;
    let word_count = match ty {
        IecType::String => length.unwrap_or(DEFAULT_LENGTH).div_ceil(2),
        t => full_words(t),
    };
    let register = Register {
        address: 0,
        kind: RegisterKind::Point,
        bit: None,
        scale: 1.0,
        offset: 0.0,
        unit,
        byte_order: ByteOrder::BigEndian,
        word_count,
        word_count_set: true,
        raw_type: None,
        switch: None,
    };
    let point = Point {
        address,
        browse_path,
        sampling,
    };
    Some((register, point))
}

/// The field's `node` or `browse_path`, checked: the text and whether it is a path.
fn address(map: &mut MapReader<'_>, ctx: &str, report: &mut Report) -> Option<(String, bool)> {
    let at = |k: &str| format!("{ctx}: {k}");
    let node = map.get("node");
    let path = map.get("browse_path");
    match (node, path) {
        (Some(n), None) => {
            let text = n.scalar_text(report, &at("node"))?;
            if let Err(why) = parse_node(&text) {
                report.push(n.line, at("node"), why);
                return None;
            }
            Some((text, false))
        }
        (None, Some(n)) => {
            let text = n.scalar_text(report, &at("browse_path"))?;
            if let Err(why) = parse_browse_path(&text) {
                report.push(n.line, at("browse_path"), why);
                return None;
            }
            Some((text, true))
        }
        (Some(_), Some(p)) => {
            report.push(
                p.line,
                ctx,
                "a field has a `node` or a `browse_path`, not both",
            );
            None
        }
        (None, None) => {
            report.push(
                map.line,
                ctx,
                "missing `node` (the variable's node id, e.g. `ns=3;s=Line1.Speed`) or `browse_path`",
            );
            None
        }
    }
}

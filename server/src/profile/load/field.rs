//! One entry of a profile's `fields`: name, type, direction, description, deadband and register,
//! with the encoding that follows from them.

use super::point::{POINT_KEYS, SCALE_KEYS, read_point};
use super::register::read_register;
use super::{FIELD_KEYS, identifier, iec_type, one_of};
use crate::codec::Encoding;
use crate::profile::{Direction, Field, Protocol, Words, raw_of};
use crate::yaml::{Node, Report};

pub(super) fn read_field(
    node: &Node,
    index: usize,
    protocol: Option<Protocol>,
    report: &mut Report,
) -> Option<Field> {
    let fallback = format!("fields[{index}]");
    let mut map = node.map(report, &fallback)?;
    let name = map
        .require("name", report, &fallback)
        .and_then(|n| identifier(n, report, &format!("{fallback}: name")));
    let ctx = name.as_ref().map_or(fallback, |n| format!("field {n}"));
    let ty = map
        .require("type", report, &ctx)
        .and_then(|n| iec_type(n, report, &format!("{ctx}: type")));
    let direction = map.require("direction", report, &ctx).and_then(|n| {
        one_of(
            n,
            report,
            &format!("{ctx}: direction"),
            &Direction::ALL,
            |d| d.name(),
        )
    });
    let description = map
        .get("description")
        .and_then(|n| n.scalar_text(report, &format!("{ctx}: description")));
    let deadband = map.get("deadband").and_then(|n| {
        crate::profile::deadband::read_deadband(n, report, &format!("{ctx}: deadband"))
    });
    let (register, point) = if let Some(words) = protocol.and_then(Protocol::words) {
        if let Some(n) = map.get("register") {
            report.push(
                n.line,
                &ctx,
                format!(
                    "a field of this protocol names its `{}`, not a Modbus `register`",
                    words.point_key
                ),
            );
        }
        let read = read_point(&mut map, words, &ctx, ty, report);
        map.finish(report, &ctx, &point_field_keys(words));
        let (register, point) = read?;
        (register, Some(point))
    } else {
        let register = map
            .require("register", report, &ctx)
            .and_then(|n| read_register(n, &ctx, ty, direction, protocol, report));
        map.finish(report, &ctx, FIELD_KEYS);
        (register?, None)
    };
    let (name, ty, direction) = (name?, ty?, direction?);
    let encoding = Encoding {
        ty,
        raw: raw_of(ty, &register),
        order: register.byte_order,
        scale: register.scale,
        offset: register.offset,
        switch: register.switch,
    };
    Some(Field {
        name,
        ty,
        direction,
        register,
        description,
        deadband,
        encoding,
        point,
        line: node.line,
    })
}

/// The keys a field of a protocol that names its points may have.
fn point_field_keys(words: &Words) -> Vec<&'static str> {
    FIELD_KEYS[..]
        .iter()
        .filter(|k| **k != "register")
        .copied()
        .chain([words.point_key])
        .chain(words.point_alternative)
        .chain(POINT_KEYS.iter().copied())
        .chain(SCALE_KEYS.iter().copied().filter(|_| words.scaled))
        .chain(words.field_keys.iter().map(|k| k.key))
        .collect()
}

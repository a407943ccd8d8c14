//! A field's `register` block: its keys read, then checked against the register kind, the
//! field's type and direction and the profile's protocol; `word_count` resolved.

use super::{MAX_STRING_WORDS, REGISTER_KEYS, iec_type, one_of};
use crate::codec::{ByteOrder, IecType, Switch, full_words};
use crate::profile::{Direction, Protocol, Register, RegisterKind};
use crate::yaml::{MapReader, Node, Report};

/// The keys of a register block as written, each with its node (for the line of a problem).
struct Keys<'a> {
    line: u64,
    ctx: String,
    address: Option<u16>,
    kind: Option<RegisterKind>,
    kind_node: Option<&'a Node>,
    bit: Option<u8>,
    bit_node: Option<&'a Node>,
    scale: Option<f64>,
    scale_node: Option<&'a Node>,
    offset: Option<f64>,
    offset_node: Option<&'a Node>,
    unit: Option<String>,
    byte_order: Option<ByteOrder>,
    order_node: Option<&'a Node>,
    word_count: Option<u16>,
    words_node: Option<&'a Node>,
    raw_type: Option<IecType>,
    raw_node: Option<&'a Node>,
    on_value: Option<u16>,
    on_node: Option<&'a Node>,
    off_value: Option<u16>,
    off_node: Option<&'a Node>,
}

impl Keys<'_> {
    fn at(&self, key: &str) -> String {
        format!("{}.{key}", self.ctx)
    }

    fn line_of(&self, node: Option<&Node>) -> u64 {
        node.map_or(self.line, |n| n.line)
    }

    /// Reports each of the keys that shape a register's value, where they do not apply.
    fn inapplicable(&self, why: &str, report: &mut Report) {
        for (key, n) in [
            ("bit", self.bit_node),
            ("scale", self.scale_node),
            ("offset", self.offset_node),
            ("byte_order", self.order_node),
            ("raw_type", self.raw_node),
        ] {
            if let Some(n) = n {
                report.push(n.line, self.at(key), why);
            }
        }
    }
}

fn read_keys<'a>(node: &'a Node, ctx: String, report: &mut Report) -> Option<Keys<'a>> {
    let mut map: MapReader<'_> = node.map(report, &ctx)?;
    let at = |key: &str| format!("{ctx}.{key}");
    let address = map
        .require("address", report, &ctx)
        .and_then(|n| n.int_in(report, &at("address"), 0, 65535))
        .map(|a| a as u16);
    let kind_node = map.require("kind", report, &ctx);
    let kind =
        kind_node.and_then(|n| one_of(n, report, &at("kind"), &RegisterKind::ALL, |k| k.name()));
    let bit_node = map.get("bit");
    let bit = bit_node
        .and_then(|n| n.int_in(report, &at("bit"), 0, 15))
        .map(|b| b as u8);
    let scale_node = map.get("scale");
    let scale = scale_node.and_then(|n| n.number(report, &at("scale")));
    let offset_node = map.get("offset");
    let offset = offset_node.and_then(|n| n.number(report, &at("offset")));
    let unit = map
        .get("unit")
        .and_then(|n| n.scalar_text(report, &at("unit")));
    let order_node = map.get("byte_order");
    let byte_order = match order_node {
        None => Some(ByteOrder::BigEndian),
        Some(n) => one_of(n, report, &at("byte_order"), &ByteOrder::ALL, |o| o.name()),
    };
    let words_node = map.get("word_count");
    let word_count = words_node
        .and_then(|n| n.int_in(report, &at("word_count"), 1, i128::from(MAX_STRING_WORDS)))
        .map(|w| w as u16);
    let raw_node = map.get("raw_type");
    let raw_type = raw_node.and_then(|n| iec_type(n, report, &at("raw_type")));
    let on_node = map.get("on_value");
    let on_value = on_node
        .and_then(|n| n.int_in(report, &at("on_value"), 0, 65535))
        .map(|v| v as u16);
    let off_node = map.get("off_value");
    let off_value = off_node
        .and_then(|n| n.int_in(report, &at("off_value"), 0, 65535))
        .map(|v| v as u16);
    map.finish(report, &ctx, REGISTER_KEYS);
    Some(Keys {
        line: node.line,
        ctx,
        address,
        kind,
        kind_node,
        bit,
        bit_node,
        scale,
        scale_node,
        offset,
        offset_node,
        unit,
        byte_order,
        order_node,
        word_count,
        words_node,
        raw_type,
        raw_node,
        on_value,
        on_node,
        off_value,
        off_node,
    })
}

/// Reads a field's `register` block and checks it against the field's type and direction.
pub(super) fn read_register(
    node: &Node,
    field: &str,
    ty: Option<IecType>,
    direction: Option<Direction>,
    protocol: Option<Protocol>,
    report: &mut Report,
) -> Option<Register> {
    let keys = read_keys(node, format!("{field}: register"), report)?;
    // Everything below needs the kind; problems of the type alone were reported already.
    let kind = keys.kind?;
    check_kind(&keys, kind, ty, direction, protocol, report);
    let ty = ty?;
    check_type(&keys, ty, report);
    let word_count = word_count(&keys, kind, ty, report);
    let switch = switch(&keys, kind, ty, report);
    let address = keys.address?;
    let span = if kind.is_bit() {
        1
    } else {
        u32::from(word_count)
    };
    if u32::from(address) + span - 1 > 65535 {
        report.push(
            keys.line_of(keys.words_node).max(keys.line),
            &keys.ctx,
            format!("address {address} + {span} registers runs past 65535"),
        );
    }
    Some(Register {
        address,
        kind,
        bit: keys.bit,
        scale: keys.scale.unwrap_or(1.0),
        offset: keys.offset.unwrap_or(0.0),
        unit: keys.unit,
        byte_order: keys.byte_order?,
        word_count,
        word_count_set: keys.word_count.is_some(),
        raw_type: keys.raw_type,
        switch,
    })
}

/// A BOOL's `on_value`/`off_value`: on a bit (a coil, a discrete input, a register's `bit`)
/// each is 0 or 1, the missing one the other bit, so `on_value: 0` is an inverted switch; on
/// a whole register any two 16-bit values, the missing one 1 (on) or 0 (off). The two must
/// differ: a write must say one thing.
fn switch(keys: &Keys<'_>, kind: RegisterKind, ty: IecType, report: &mut Report) -> Option<Switch> {
    let node = keys.on_node.or(keys.off_node)?;
    let key = keys.at(if keys.on_node.is_some() {
        "on_value"
    } else {
        "off_value"
    });
    if kind == RegisterKind::Virtual {
        report.push(
            node.line,
            key,
            "has no effect on a virtual register (simulated fields hold typed values)",
        );
        return None;
    }
    if ty != IecType::Bool {
        report.push(
            node.line,
            key,
            format!("on_value/off_value are the raw values of a BOOL switch, not of {ty}"),
        );
        return None;
    }
    let on_bit = kind.is_bit() || keys.bit.is_some();
    let (on, off) = match (keys.on_value, keys.off_value) {
        (Some(on), Some(off)) => (on, off),
        (Some(on), None) if on_bit => (on, 1 - on.min(1)),
        (None, Some(off)) if on_bit => (1 - off.min(1), off),
        (Some(on), None) => (on, 0),
        (None, Some(off)) => (1, off),
        (None, None) => return None, // a value out of range, reported
    };
    if on_bit && (on > 1 || off > 1) {
        let what = if kind.is_bit() {
            kind.name()
        } else {
            "register bit"
        };
        report.push(
            node.line,
            keys.at("on_value"),
            format!("a {what} is 0 or 1: on_value {on} and off_value {off} must each be 0 or 1"),
        );
        return None;
    }
    if on == off {
        report.push(
            node.line,
            keys.at("on_value"),
            format!("on_value and off_value are both {on}: a switch needs two different values"),
        );
        return None;
    }
    Some(Switch { on, off })
}

/// What the register kind allows: virtual registers only in simulated profiles, outputs
/// only on writable kinds, bit kinds only for BOOL with no value shaping.
fn check_kind(
    keys: &Keys<'_>,
    kind: RegisterKind,
    ty: Option<IecType>,
    direction: Option<Direction>,
    protocol: Option<Protocol>,
    report: &mut Report,
) {
    let kind_line = keys.line_of(keys.kind_node);
    if kind == RegisterKind::Virtual && protocol.is_some_and(|p| p != Protocol::Simulated) {
        report.push(
            kind_line,
            keys.at("kind"),
            "`virtual` registers exist only in simulated profiles (protocol: simulated)",
        );
    }
    if let Some(d) = direction
        && d.is_writable()
        && kind.is_read_only()
    {
        report.push(
            kind_line,
            &keys.ctx,
            format!(
                "direction `{}` on a read-only {} (only coils and holding registers can be written)",
                d.name(),
                kind.name()
            ),
        );
    }
    if kind == RegisterKind::Virtual {
        keys.inapplicable(
            "has no effect on a virtual register (simulated fields hold typed values)",
            report,
        );
    }
    if kind.is_bit() {
        if ty.is_some_and(|t| t != IecType::Bool) {
            report.push(
                kind_line,
                &keys.ctx,
                format!(
                    "a {} holds one bit: the type must be BOOL, not {}",
                    kind.name(),
                    ty.map_or("?", IecType::name)
                ),
            );
        }
        keys.inapplicable(&format!("does not apply to a {}", kind.name()), report);
        if keys.word_count.is_some_and(|w| w != 1) {
            report.push(
                keys.line_of(keys.words_node),
                keys.at("word_count"),
                format!("a {} is one bit: word_count must be 1", kind.name()),
            );
        }
    }
}

/// What the field's type allows: `bit` only for BOOL, scaling only for numbers, a non-zero
/// scale, `raw_type` only as the integer behind a REAL/LREAL.
fn check_type(keys: &Keys<'_>, ty: IecType, report: &mut Report) {
    if keys.bit.is_some() && ty != IecType::Bool {
        report.push(
            keys.line_of(keys.bit_node),
            keys.at("bit"),
            format!("`bit` is for BOOL fields packed into a register, not {ty}"),
        );
    }
    if !ty.is_numeric() {
        for (key, n) in [("scale", keys.scale_node), ("offset", keys.offset_node)] {
            if let Some(n) = n {
                report.push(
                    n.line,
                    keys.at(key),
                    format!("{ty} values cannot be scaled"),
                );
            }
        }
    }
    if keys.scale == Some(0.0) {
        report.push(
            keys.line_of(keys.scale_node),
            keys.at("scale"),
            "scale must not be zero (writes divide by it)",
        );
    }
    if let Some(raw) = keys.raw_type {
        let line = keys.line_of(keys.raw_node);
        if !ty.is_real() {
            report.push(
                line,
                keys.at("raw_type"),
                format!("raw_type is for REAL/LREAL fields stored as integers, not {ty}"),
            );
        } else if raw.int_bits().is_none() || raw == IecType::Time {
            report.push(
                line,
                keys.at("raw_type"),
                format!("raw_type must be an integer type, not {raw}"),
            );
        }
    }
}

/// The registers the field takes: `word_count` as given, else the raw type's size, else
/// the type's default; checked against what the type allows.
fn word_count(keys: &Keys<'_>, kind: RegisterKind, ty: IecType, report: &mut Report) -> u16 {
    let raw_words = keys
        .raw_type
        .filter(|r| ty.is_real() && r.int_bits().is_some() && *r != IecType::Time)
        .map(full_words);
    let words_line = keys.line_of(keys.words_node);
    let word_count = match (keys.word_count, raw_words) {
        (Some(w), Some(r)) if w != r => {
            report.push(
                words_line,
                keys.at("word_count"),
                format!(
                    "word_count {w} does not fit raw_type {} ({r} registers)",
                    keys.raw_type.map_or("?", IecType::name)
                ),
            );
            w
        }
        (Some(w), _) => w,
        (None, Some(r)) => r,
        (None, None) if kind.is_bit() => 1,
        (None, None) => 1,
    };
    if !kind.is_bit() && raw_words.is_none() && !word_count_fits(ty, word_count) {
        report.push(
            words_line,
            keys.at("word_count"),
            format!(
                "{ty} does not fit in {word_count} register(s) (allowed: {})",
                allowed_word_counts(ty)
            ),
        );
    }
    word_count
}

fn word_count_fits(ty: IecType, words: u16) -> bool {
    match ty {
        IecType::Bool => words == 1,
        IecType::String => (1..=MAX_STRING_WORDS).contains(&words),
        IecType::Real => matches!(words, 1 | 2),
        IecType::Lreal => matches!(words, 1 | 2 | 4),
        IecType::Time => matches!(words, 1 | 2 | 4),
        t => words == 1 || words == full_words(t),
    }
}

fn allowed_word_counts(ty: IecType) -> String {
    match ty {
        IecType::String => format!("1 to {MAX_STRING_WORDS}, two characters each"),
        IecType::Real => "1 = scaled 16-bit integer, 2 = IEEE-754 single".to_owned(),
        IecType::Lreal => {
            "1 = scaled 16-bit integer, 2 = IEEE-754 single, 4 = IEEE-754 double".to_owned()
        }
        IecType::Time => {
            "1 = 16-bit milliseconds, 2 = 32-bit milliseconds, 4 = 64-bit milliseconds".to_owned()
        }
        t if full_words(t) > 1 => format!(
            "1 = a 16-bit register widened, {} = the full {}-bit value",
            full_words(t),
            16 * full_words(t)
        ),
        _ => "1".to_owned(),
    }
}

#[cfg(test)]
mod tests {
    use crate::codec::{Switch, Value};
    use crate::profile::load_str;

    fn field(register: &str) -> String {
        format!(
            "name: X\nfields:\n  - {{ name: A, type: BOOL, direction: output, register: {{ {register} }} }}\n"
        )
    }

    fn problems(text: &str) -> String {
        load_str("p.yaml", text)
            .err()
            .map(|p| p.to_string())
            .unwrap_or_default()
    }

    #[test]
    fn on_value_zero_makes_a_coil_inverted() {
        let p = load_str("p.yaml", &field("address: 54, kind: coil, on_value: 0")).expect("loads");
        let f = &p.fields[0];
        assert_eq!(f.register.switch, Some(Switch { on: 0, off: 1 }));
        assert!(!f.encoding.wire_bit(true), "TRUE is written as 0");
        assert_eq!(f.encoding.decode_bit(false), Value::Bool(true));
    }

    #[test]
    fn a_register_switch_takes_two_sixteen_bit_values() {
        let p = load_str(
            "p.yaml",
            &field("address: 3, kind: holding_register, on_value: 0xA5, off_value: 0x5A"),
        )
        .expect("loads");
        assert_eq!(
            p.fields[0].encoding.encode(&Value::Bool(true)),
            Ok(vec![0xA5])
        );
        let only_on = load_str(
            "p.yaml",
            &field("address: 3, kind: holding_register, on_value: 7"),
        )
        .expect("loads");
        assert_eq!(
            only_on.fields[0].register.switch,
            Some(Switch { on: 7, off: 0 })
        );
    }

    #[test]
    fn switch_values_that_cannot_be_written_faithfully_are_refused_with_their_line() {
        let text = field("address: 0, kind: coil, on_value: 2");
        assert!(
            problems(&text).contains("p.yaml:3: field A: register.on_value: a coil is 0 or 1"),
            "{}",
            problems(&text)
        );
        let text = field("address: 0, kind: holding_register, on_value: 5, off_value: 5");
        assert!(problems(&text).contains("both 5"), "{}", problems(&text));
        let text = "name: X\nfields:\n  - { name: A, type: INT, direction: output, register: { address: 0, kind: holding_register, on_value: 1 } }\n";
        assert!(
            problems(text).contains("raw values of a BOOL switch, not of INT"),
            "{}",
            problems(text)
        );
        let text = field("address: 0, kind: holding_register, bit: 3, off_value: 1, on_value: 1");
        assert!(problems(&text).contains("both 1"), "{}", problems(&text));
    }
}

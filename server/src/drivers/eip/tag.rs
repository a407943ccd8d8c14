//! A Logix tag as its users write it (`tag:` of an `ab-eip` field): controller scope
//! (`Speed`), program scope (`Program:Main.Speed`), array elements (`Counts[3]`,
//! `Grid[1,2]`), structure members (`Motor.Status.Running`) and a bit of an integer
//! (`Flags.5`); and its CIP symbolic path (ANSI extended symbol segments, member ids for
//! the indexes).

use crate::codec::IecType;

/// A tag: its path as CIP carries it, and the bit of an integer it names, if any.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct Tag {
    /// The request path (an even number of bytes).
    pub(crate) path: Vec<u8>,
    /// `Flags.5`: bit 5 of the integer `Flags`.
    pub(crate) bit: Option<u8>,
    /// `Counts[3]`, `Motor.Hist[3]`: an element of a one-dimensional array, as the length
    /// of the path before its index and the index (consecutive elements are read together).
    pub(crate) element: Option<(usize, u32)>,
}

/// The longest name of one segment Logix allows.
const MAX_NAME: usize = 40;

/// Parses `text`; why not, if not.
pub(crate) fn parse(text: &str) -> Result<Tag, String> {
    let text = text.trim();
    if text.is_empty() {
        return Err("an empty tag".into());
    }
    let mut parts: Vec<&str> = text.split('.').collect();
    // `Program:Main.Speed`: the program's name is part of the first segment.
    let mut bit = None;
    if parts.len() > 1
        && let Some(last) = parts.last()
        && !last.is_empty()
        && last.bytes().all(|b| b.is_ascii_digit())
    {
        let n: u8 = last
            .parse()
            .ok()
            .filter(|&n| n < 64)
            .ok_or_else(|| format!("`{text}`: bit {last} past an integer's 64"))?;
        bit = Some(n);
        parts.pop();
    }
    let mut path = Vec::new();
    let mut element = None;
    for (k, part) in parts.iter().enumerate() {
        element = segment(part, k == 0, &mut path).map_err(|e| format!("`{text}`: {e}"))?;
    }
    Ok(Tag { path, bit, element })
}

/// One segment: a name and its indexes; the path's length before the index and the
/// index, when there is one index.
fn segment(part: &str, first: bool, path: &mut Vec<u8>) -> Result<Option<(usize, u32)>, String> {
    let (name, indexes) = match part.split_once('[') {
        Some((name, rest)) => {
            let inner = rest
                .strip_suffix(']')
                .ok_or_else(|| format!("`{part}` has no closing `]`"))?;
            (name, Some(inner))
        }
        None => (part, None),
    };
    let program = first && name.len() > 8 && name[..8].eq_ignore_ascii_case("program:");
    let plain = if program { &name[8..] } else { name };
    if plain.is_empty()
        || !plain
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'_')
        || plain.as_bytes()[0].is_ascii_digit()
    {
        return Err(format!(
            "`{name}` is not a tag name (letters, digits and `_`, not starting with a digit)"
        ));
    }
    if name.len() > MAX_NAME + 8 || plain.len() > MAX_NAME {
        return Err(format!(
            "`{name}` is longer than Logix's {MAX_NAME} characters"
        ));
    }
    path.push(0x91);
    path.push(name.len() as u8);
    path.extend_from_slice(name.as_bytes());
    if name.len() % 2 == 1 {
        path.push(0);
    }
    if let Some(inner) = indexes {
        let numbers: Vec<&str> = inner.split(',').map(str::trim).collect();
        if numbers.len() > 3 {
            return Err(format!("`{part}`: Logix arrays have at most 3 dimensions"));
        }
        let one = numbers.len() == 1;
        let before = path.len();
        let mut last = 0;
        for n in numbers {
            last = n
                .parse()
                .map_err(|_| format!("`{n}` in `{part}` is not an index"))?;
            member(last, path);
        }
        return Ok(one.then_some((before, last)));
    }
    Ok(None)
}

/// An element index as a member id segment of the smallest size that holds it.
fn member(i: u32, path: &mut Vec<u8>) {
    logical(0x28, i, path);
}

/// A logical segment (`kind`: its 8-bit form, 0x24 an instance, 0x28 a member id) of the
/// smallest size that holds `value`: the 16- and 32-bit forms follow a pad byte.
pub(crate) fn logical(kind: u8, value: u32, path: &mut Vec<u8>) {
    if let Ok(b) = u8::try_from(value) {
        path.extend_from_slice(&[kind, b]);
    } else if let Ok(w) = u16::try_from(value) {
        path.extend_from_slice(&[kind + 1, 0]);
        path.extend_from_slice(&w.to_le_bytes());
    } else {
        path.extend_from_slice(&[kind + 2, 0]);
        path.extend_from_slice(&value.to_le_bytes());
    }
}

/// The CIP data type code of an atomic Logix type, for the IEC type a field reads it as.
pub(crate) fn type_code(ty: IecType) -> Option<u16> {
    Some(match ty {
        IecType::Bool => 0xC1,
        IecType::Sint => 0xC2,
        IecType::Int => 0xC3,
        IecType::Dint => 0xC4,
        IecType::Lint => 0xC5,
        IecType::Usint => 0xC6,
        IecType::Uint => 0xC7,
        IecType::Udint => 0xC8,
        IecType::Ulint => 0xC9,
        IecType::Real => 0xCA,
        IecType::Lreal => 0xCB,
        _ => return None,
    })
}

/// An atomic type's size in bytes.
pub(crate) fn type_len(code: u16) -> usize {
    match code {
        0xC1 | 0xC2 | 0xC6 => 1,
        0xC3 | 0xC7 => 2,
        0xC4 | 0xC8 | 0xCA | 0xD3 => 4,
        _ => 8,
    }
}

/// The bytes a Read Tag reply of a field of `ty` carries after its type, at most as the
/// packing counts them: an atomic value, or a Logix STRING (its structure handle, its
/// DINT length and 82 characters, padded).
pub(crate) fn reply_value_len(ty: IecType, code: Option<u16>) -> usize {
    match (ty, code) {
        (IecType::String, _) => 2 + 4 + 84,
        (_, Some(code)) => type_len(code),
        (_, None) => 8,
    }
}

/// The Logix name of a CIP data type code, for messages.
pub(crate) fn type_name(code: u16) -> String {
    let name = match code {
        0xC1 => "BOOL",
        0xC2 => "SINT",
        0xC3 => "INT",
        0xC4 => "DINT",
        0xC5 => "LINT",
        0xC6 => "USINT",
        0xC7 => "UINT",
        0xC8 => "UDINT",
        0xC9 => "ULINT",
        0xCA => "REAL",
        0xCB => "LREAL",
        0xD3 => "DWORD (BOOL array)",
        0xD0 => "STRING (CIP)",
        0xDA => "SHORT_STRING",
        0x02A0 => "a structure",
        other => return format!("type {other:#06x}"),
    };
    name.to_owned()
}

/// Checks a field's tag for its type (the profile's check): why not, if not.
pub(crate) fn check(
    _key: &str,
    text: &str,
    ty: Option<IecType>,
    _length: Option<u16>,
) -> Result<(), String> {
    let tag = parse(text)?;
    match ty {
        Some(IecType::Bool) | None => Ok(()),
        Some(IecType::String) if tag.bit.is_none() => Ok(()),
        Some(_) if tag.bit.is_some() => Err(format!(
            "`{}` is a bit of an integer: its field is a BOOL",
            text.trim()
        )),
        Some(ty) if type_code(ty).is_none() => Err(format!(
            "Logix has no {ty}: an `ab-eip` field is BOOL, SINT, INT, DINT, LINT, USINT, UINT, UDINT, ULINT, REAL, LREAL or STRING"
        )),
        Some(_) => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tags_as_logix_users_write_them_make_symbolic_paths() {
        let speed = parse("Speed").expect("tag");
        assert_eq!(speed.path, b"\x91\x05Speed\x00".to_vec());
        assert_eq!(speed.bit, None);
        let program = parse("Program:Main.Speed").expect("tag");
        assert_eq!(
            program.path,
            [&b"\x91\x0cProgram:Main"[..], b"\x91\x05Speed\x00"].concat()
        );
        let element = parse("Counts[3]").expect("tag");
        assert_eq!(element.path, b"\x91\x06Counts\x28\x03".to_vec());
        let big = parse("Grid[1,300]").expect("tag");
        assert_eq!(big.path, b"\x91\x04Grid\x28\x01\x29\x00\x2c\x01".to_vec());
        let member = parse("Motor.Status.Running").expect("tag");
        assert_eq!(member.path.len(), 2 + 6 + 2 + 6 + 2 + 8);
        let bit = parse("Flags.5").expect("tag");
        assert_eq!(
            (bit.path, bit.bit),
            (b"\x91\x05Flags\x00".to_vec(), Some(5))
        );
    }

    #[test]
    fn a_tag_that_is_not_one_is_refused_naming_why() {
        for (text, why) in [
            ("", "empty"),
            ("9Lives", "not a tag name"),
            ("Counts[3", "closing"),
            ("Counts[x]", "not an index"),
            ("A[1,2,3,4]", "3 dimensions"),
            ("Flags.64", "bit 64"),
            ("Bad-Name", "not a tag name"),
        ] {
            let e = parse(text).expect_err(text);
            assert!(e.contains(why), "{text}: {e}");
        }
        assert!(check("tag", "Flags.3", Some(IecType::Dint), None).is_err());
        assert!(check("tag", "Flags.3", Some(IecType::Bool), None).is_ok());
        let e = check("tag", "Speed", Some(IecType::Word), None).expect_err("WORD");
        assert!(e.contains("Logix has no WORD"), "{e}");
    }
}

//! Atomic Logix values ⇄ IEC values: a Read Tag reply's type and bytes decoded as its
//! field's type (a type that differs is the field's error, naming both), a value encoded
//! for Write Tag, a bit of an integer as Read-Modify-Write masks.

use super::tag::{type_code, type_name};
use crate::codec::IecType;
use iogate_types::Value;

/// A Read Tag reply's data (type, then the element) as a field of `ty`, or bit `bit` of
/// the integer it holds.
pub(crate) fn decode(data: &[u8], ty: IecType, bit: Option<u8>) -> Result<(u16, Value), String> {
    let code = data
        .get(..2)
        .map(|b| u16::from_le_bytes([b[0], b[1]]))
        .ok_or("a reply without its type")?;
    if ty == IecType::String && bit.is_none() {
        return string(code, data.get(2..).unwrap_or_default()).map(|v| (code, v));
    }
    if code == 0x02A0 {
        return Err(format!(
            "the tag is a structure on the controller; the profile reads it as {}: name one of its members",
            if bit.is_some() {
                "a bit".to_owned()
            } else {
                ty.to_string()
            }
        ));
    }
    let bytes = data.get(2..).unwrap_or_default();
    let len = super::cip::value_len(code);
    let raw = bytes
        .get(..len)
        .ok_or_else(|| format!("a reply of {} bytes for a {}", bytes.len(), type_name(code)))?;
    let int = |signed: bool| -> i128 {
        let mut b = [0u8; 8];
        b[..len].copy_from_slice(raw);
        let u = u64::from_le_bytes(b);
        if signed {
            let shift = 64 - 8 * len as u32;
            i128::from(((u << shift) as i64) >> shift)
        } else {
            i128::from(u)
        }
    };
    if let Some(bit) = bit {
        if !matches!(code, 0xC2..=0xC9 | 0xD3) {
            return Err(format!(
                "the tag is a {} on the controller: a bit is of an integer",
                type_name(code)
            ));
        }
        if usize::from(bit) >= 8 * len {
            return Err(format!("bit {bit} is past a {}", type_name(code)));
        }
        return Ok((code, Value::Bool((int(false) >> bit) & 1 == 1)));
    }
    if Some(code) != type_code(ty) {
        return Err(format!(
            "the tag is a {} on the controller, the profile reads it as {ty}",
            type_name(code)
        ));
    }
    let value = match code {
        0xC1 => Value::Bool(raw[0] != 0),
        0xC2..=0xC5 => Value::Int(int(true) as i64),
        0xC6..=0xC9 => Value::UInt(int(false) as u64),
        0xCA => Value::Real(f32::from_le_bytes(raw.try_into().map_err(|_| "REAL")?)),
        _ => Value::LReal(f64::from_le_bytes(raw.try_into().map_err(|_| "LREAL")?)),
    };
    Ok((code, value))
}

/// A string as the controller holds it: a Logix STRING (a structure: its handle, a DINT
/// length, the characters), a CIP STRING (a UINT length) or SHORT_STRING (a USINT one).
fn string(code: u16, bytes: &[u8]) -> Result<Value, String> {
    let (len, at) = match code {
        0x02A0 => {
            let b = bytes.get(2..6).ok_or("a STRING without its length")?;
            (u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize, 6)
        }
        0xD0 => {
            let b = bytes.get(..2).ok_or("a STRING without its length")?;
            (usize::from(u16::from_le_bytes([b[0], b[1]])), 2)
        }
        0xDA => (
            usize::from(*bytes.first().ok_or("a STRING without its length")?),
            1,
        ),
        other => {
            return Err(format!(
                "the tag is a {} on the controller, the profile reads it as STRING",
                type_name(other)
            ));
        }
    };
    let chars = bytes.get(at..at + len).ok_or_else(|| {
        format!(
            "a STRING of length {len} with {} characters",
            bytes.len().saturating_sub(at)
        )
    })?;
    Ok(Value::String(String::from_utf8_lossy(chars).into_owned()))
}

/// A structure's handle and size from a Read Tag reply's data (type, handle, bytes).
pub(crate) fn layout(data: &[u8]) -> Option<(u16, usize)> {
    if data.get(..2)? != [0xA0, 0x02] {
        return None;
    }
    let handle = u16::from_le_bytes([*data.get(2)?, *data.get(3)?]);
    Some((handle, data.len().checked_sub(4)?))
}

/// A string's bytes for Write Tag as the controller last answered its type (`code`, and
/// for a Logix STRING the structure's handle and size).
pub(crate) fn encode_string(
    text: &str,
    code: u16,
    layout: Option<(u16, usize)>,
) -> Result<Vec<u8>, String> {
    let b = text.as_bytes();
    match (code, layout) {
        (0xD0, _) if b.len() <= usize::from(u16::MAX) => {
            let mut out = 0xD0u16.to_le_bytes().to_vec();
            out.extend_from_slice(&1u16.to_le_bytes());
            out.extend_from_slice(&(b.len() as u16).to_le_bytes());
            out.extend_from_slice(b);
            // Padded to an even length, as CIP lays a STRING out.
            if b.len() % 2 == 1 {
                out.push(0);
            }
            Ok(out)
        }
        (0x02A0, Some((handle, size))) if size >= 4 && b.len() <= size - 4 => {
            let mut out = 0x02A0u16.to_le_bytes().to_vec();
            out.extend_from_slice(&handle.to_le_bytes());
            out.extend_from_slice(&1u16.to_le_bytes());
            out.extend_from_slice(&(b.len() as u32).to_le_bytes());
            out.extend_from_slice(b);
            out.resize(2 + 2 + 2 + size, 0);
            Ok(out)
        }
        (0xDA, _) if b.len() <= usize::from(u8::MAX) => {
            // SHORT_STRING: a USINT length, then the characters.
            let mut out = 0xDAu16.to_le_bytes().to_vec();
            out.extend_from_slice(&1u16.to_le_bytes());
            out.push(b.len() as u8);
            out.extend_from_slice(b);
            Ok(out)
        }
        (0xDA, _) => Err(format!(
            "{} characters do not fit a SHORT_STRING (255 at most)",
            b.len()
        )),
        (0x02A0, Some((_, size))) => Err(format!(
            "{} characters do not fit the tag's {}",
            b.len(),
            size.saturating_sub(4)
        )),
        _ => Err("the tag's string type was not read yet".into()),
    }
}

/// A value's bytes for Write Tag of a field of `ty`: its type code and bytes.
pub(crate) fn encode(value: &Value, ty: IecType) -> Result<(u16, Vec<u8>), String> {
    let code = type_code(ty).ok_or_else(|| format!("Logix has no {ty}"))?;
    let len = super::cip::value_len(code);
    let bytes = match value {
        Value::Bool(b) if code == 0xC1 => vec![if *b { 0xFF } else { 0 }],
        Value::Int(i) => i.to_le_bytes()[..len].to_vec(),
        Value::UInt(u) => u.to_le_bytes()[..len].to_vec(),
        Value::Real(r) => r.to_le_bytes().to_vec(),
        Value::LReal(r) => r.to_le_bytes().to_vec(),
        other => return Err(format!("{other:?} cannot be written as {ty}")),
    };
    Ok((code, bytes))
}

/// Read-Modify-Write Tag's data for bit `bit` of an integer of type `code` set to `on`:
/// the mask size, the OR mask and the AND mask (only that bit changes, on the controller).
pub(crate) fn bit_masks(code: u16, bit: u8, on: bool) -> Result<Vec<u8>, String> {
    let len = super::cip::value_len(code);
    if !matches!(code, 0xC2..=0xC9 | 0xD3) || usize::from(bit) >= 8 * len {
        return Err(format!("bit {bit} of a {}", type_name(code)));
    }
    let one = 1u64 << bit;
    let (or, and) = if on { (one, u64::MAX) } else { (0, !one) };
    let mut data = (len as u16).to_le_bytes().to_vec();
    data.extend_from_slice(&or.to_le_bytes()[..len]);
    data.extend_from_slice(&and.to_le_bytes()[..len]);
    Ok(data)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_atomic_type_decodes_as_its_iec_type_and_a_different_one_is_named() {
        let cases: [(&[u8], IecType, Value); 8] = [
            (b"\xc1\x00\x01", IecType::Bool, Value::Bool(true)),
            (b"\xc2\x00\xff", IecType::Sint, Value::Int(-1)),
            (b"\xc3\x00\x00\x80", IecType::Int, Value::Int(-32768)),
            (b"\xc4\x00\x07\x00\x00\x00", IecType::Dint, Value::Int(7)),
            (b"\xc6\x00\xff", IecType::Usint, Value::UInt(255)),
            (
                b"\xc8\x00\xff\xff\xff\xff",
                IecType::Udint,
                Value::UInt(u32::MAX as u64),
            ),
            (
                b"\xca\x00\x00\x00\x48\x41",
                IecType::Real,
                Value::Real(12.5),
            ),
            (
                b"\xc5\x00\xfe\xff\xff\xff\xff\xff\xff\xff",
                IecType::Lint,
                Value::Int(-2),
            ),
        ];
        for (data, ty, want) in cases {
            assert_eq!(decode(data, ty, None).map(|d| d.1), Ok(want), "{ty}");
        }
        let e = decode(b"\xc4\x00\x07\x00\x00\x00", IecType::Real, None).expect_err("type");
        assert!(e.contains("DINT") && e.contains("REAL"), "{e}");
        assert!(decode(b"\xc4\x00\x07", IecType::Dint, None).is_err());
        assert!(decode(b"\xc4", IecType::Dint, None).is_err());
        assert_eq!(
            decode(b"\xc4\x00\x20\x00\x00\x00", IecType::Bool, Some(5)).map(|d| d.1),
            Ok(Value::Bool(true))
        );
        assert!(decode(b"\xca\x00\x00\x00\x48\x41", IecType::Bool, Some(5)).is_err());
    }

    #[test]
    fn writes_encode_the_value_and_a_bit_changes_only_that_bit() {
        assert_eq!(
            encode(&Value::Int(-2), IecType::Int),
            Ok((0xC3, vec![0xFE, 0xFF]))
        );
        assert_eq!(
            encode(&Value::Real(12.5), IecType::Real),
            Ok((0xCA, 12.5f32.to_le_bytes().to_vec()))
        );
        assert_eq!(
            bit_masks(0xC4, 3, true),
            Ok(vec![4, 0, 8, 0, 0, 0, 0xFF, 0xFF, 0xFF, 0xFF])
        );
        assert_eq!(bit_masks(0xC3, 0, false), Ok(vec![2, 0, 0, 0, 0xFE, 0xFF]));
        assert!(bit_masks(0xCA, 0, true).is_err());
        assert!(bit_masks(0xC2, 8, true).is_err());
    }

    #[test]
    fn strings_of_every_layout_are_read_and_written_as_the_controller_holds_them() {
        // A Logix STRING: structure, handle 0x0FCE, LEN 2, "hi", the rest of its 82.
        let mut logix = b"\xa0\x02\xce\x0f\x02\x00\x00\x00hi".to_vec();
        logix.resize(4 + 88, 0);
        assert_eq!(
            decode(&logix, IecType::String, None).map(|d| d.1),
            Ok(Value::String("hi".into()))
        );
        assert_eq!(layout(&logix), Some((0x0FCE, 88)));
        let cip = b"\xd0\x00\x03\x00abc\x00";
        assert_eq!(
            decode(cip, IecType::String, None).map(|d| d.1),
            Ok(Value::String("abc".into()))
        );
        assert!(decode(b"\xd0\x00\x09\x00abc", IecType::String, None).is_err());
        assert!(decode(b"\xc4\x00\x01\x00\x00\x00", IecType::String, None).is_err());
        assert_eq!(
            encode_string("abc", 0xD0, None),
            Ok(b"\xd0\x00\x01\x00\x03\x00abc\x00".to_vec())
        );
        let written = encode_string("hi", 0x02A0, Some((0x0FCE, 88))).expect("STRING");
        assert_eq!(
            &written[..12],
            b"\xa0\x02\xce\x0f\x01\x00\x02\x00\x00\x00hi"
        );
        assert_eq!(written.len(), 6 + 88);
        assert!(encode_string(&"x".repeat(85), 0x02A0, Some((0x0FCE, 88))).is_err());
        assert!(encode_string("x", 0xC4, None).is_err());
    }
}

//! A field's value from the bytes the PLC stores and back, by the field's form: numbers
//! big-endian, STRING and WSTRING with their length bytes, CHAR and WCHAR, DATE_AND_TIME
//! (BCD) and DTL, timers (S5TIME) and counters (BCD). A value the form cannot hold exactly
//! is refused, never rounded or cut.

use super::form::{Form, number_bytes};
use crate::codec::{IecType, Value};

use super::clock::{self, Civil};

fn be(bytes: &[u8], n: usize) -> Option<u64> {
    let b = bytes.get(..n)?;
    Some(b.iter().fold(0u64, |acc, &x| acc << 8 | u64::from(x)))
}

/// Three BCD digits of a word's low 12 bits.
fn bcd3(word: u16) -> Result<u16, String> {
    let digits = [word >> 8 & 0xF, word >> 4 & 0xF, word & 0xF];
    if digits.iter().any(|&d| d > 9) {
        return Err(format!("{word:#06x} is not BCD"));
    }
    Ok(digits[0] * 100 + digits[1] * 10 + digits[2])
}

fn to_bcd3(n: u16) -> u16 {
    ((n / 100) << 8) | ((n / 10 % 10) << 4) | (n % 10)
}

/// The time bases of S5TIME, in milliseconds.
const S5_BASES: [i64; 4] = [10, 100, 1000, 10_000];

/// A field's value from its bytes (`bytes` starts at the field).
pub(crate) fn decode(form: Form, ty: IecType, bytes: &[u8]) -> Result<Value, String> {
    let short = || format!("{} bytes answered for a {ty}", bytes.len());
    let word = || be(bytes, 2).map(|w| w as u16).ok_or_else(short);
    let fits = |r: Result<Value, iogate_types::ValueError>| r.map_err(|e| e.to_string());
    match form {
        Form::Bit(b) => Ok(Value::Bool(be(bytes, 1).ok_or_else(short)? >> b & 1 == 1)),
        Form::Number => number(ty, bytes).ok_or_else(short)?,
        Form::Char => Ok(Value::String(
            char::from(*bytes.first().ok_or_else(short)?).to_string(),
        )),
        Form::WChar => utf16(&[word()?]).map(Value::String),
        Form::String(_) => {
            let (max, len) = (
                bytes.first().ok_or_else(short)?,
                bytes.get(1).ok_or_else(short)?,
            );
            if len > max {
                return Err(format!(
                    "the PLC's STRING says it holds {len} characters in a STRING[{max}]"
                ));
            }
            let chars = bytes.get(2..2 + usize::from(*len)).ok_or_else(short)?;
            Ok(Value::String(
                chars.iter().map(|&c| char::from(c)).collect(),
            ))
        }
        Form::WString(_) => {
            let head = bytes.get(..4).ok_or_else(short)?;
            let max = u16::from_be_bytes([head[0], head[1]]);
            let len = u16::from_be_bytes([head[2], head[3]]);
            if len > max {
                return Err(format!(
                    "the PLC's WSTRING says it holds {len} characters in a WSTRING[{max}]"
                ));
            }
            let len = usize::from(len);
            let body = bytes.get(4..4 + 2 * len).ok_or_else(short)?;
            let units: Vec<u16> = body
                .chunks_exact(2)
                .map(|c| u16::from_be_bytes([c[0], c[1]]))
                .collect();
            utf16(&units).map(Value::String)
        }
        Form::Dt | Form::Dtl => {
            let at = if form == Form::Dt {
                clock::from_dt(bytes.get(..8).ok_or_else(short)?)?
            } else {
                clock::from_dtl(bytes.get(..12).ok_or_else(short)?)?
            };
            Ok(match ty {
                IecType::String => Value::String(at.to_string()),
                _ => Value::Int(at.millis_since_1970()),
            })
        }
        Form::Timer => {
            let w = word()?;
            match ty {
                IecType::Word => Ok(Value::UInt(u64::from(w))),
                _ => {
                    let ms = i64::from(bcd3(w)?) * S5_BASES[usize::from(w >> 12 & 3)];
                    if ty == IecType::Time {
                        Ok(Value::Time(ms))
                    } else {
                        fits(Value::from_int(ty, i128::from(ms)))
                    }
                }
            }
        }
        Form::Counter => {
            let w = word()?;
            match ty {
                IecType::Word => Ok(Value::UInt(u64::from(w))),
                _ => fits(Value::from_int(ty, i128::from(bcd3(w)?))),
            }
        }
    }
}

fn utf16(units: &[u16]) -> Result<String, String> {
    String::from_utf16(units).map_err(|_| "the PLC's text is not UTF-16".to_owned())
}

/// A number of an IEC type, big-endian; `None` when the bytes are too few.
fn number(ty: IecType, bytes: &[u8]) -> Option<Result<Value, String>> {
    let n = usize::from(number_bytes(ty));
    let v = be(bytes, n)?;
    let signed = || {
        let shift = 64 - 8 * n as u32;
        i128::from(((v << shift) as i64) >> shift)
    };
    let fits = |r: Result<Value, iogate_types::ValueError>| r.map_err(|e| e.to_string());
    Some(match ty {
        IecType::Sint | IecType::Int | IecType::Dint | IecType::Lint => {
            fits(Value::from_int(ty, signed()))
        }
        IecType::Time => Ok(Value::Time(signed() as i64)),
        IecType::Real => Ok(Value::Real(f32::from_bits(v as u32))),
        IecType::Lreal => Ok(Value::LReal(f64::from_bits(v))),
        _ => fits(Value::from_int(ty, i128::from(v))),
    })
}

/// A value's bytes as the PLC stores them, and how many bytes into the field they start
/// (a STRING's maximum byte and a WSTRING's maximum word are left as they are).
pub(crate) fn encode(form: Form, ty: IecType, value: &Value) -> Result<(u16, Vec<u8>), String> {
    let n = usize::from(number_bytes(ty));
    let int = |v: i128| -> Vec<u8> { v.to_be_bytes()[16 - n..].to_vec() };
    let text = || match value {
        Value::String(s) => Ok(s.as_str()),
        v => Err(format!("a {ty} does not take {v}")),
    };
    Ok(match (form, value) {
        (Form::Bit(_), Value::Bool(b)) => (0, vec![u8::from(*b)]),
        (Form::Number, Value::Int(v)) => (0, int(i128::from(*v))),
        (Form::Number, Value::UInt(v)) => (0, int(i128::from(*v))),
        (Form::Number, Value::Time(ms)) => (0, int(i128::from(*ms))),
        (Form::Number, Value::Real(x)) if ty == IecType::Real => (0, x.to_be_bytes().to_vec()),
        (Form::Number, Value::LReal(x)) if ty == IecType::Lreal => (0, x.to_be_bytes().to_vec()),
        (Form::Char, _) => (0, vec![latin1(text()?, 1)?[0]]),
        (Form::WChar, _) => {
            let units: Vec<u16> = text()?.encode_utf16().collect();
            if units.len() != 1 {
                return Err("a WCHAR holds one character".to_owned());
            }
            (0, units[0].to_be_bytes().to_vec())
        }
        (Form::String(max), _) => {
            let chars = latin1(text()?, max)?;
            let mut out = vec![chars.len() as u8];
            out.extend_from_slice(&chars);
            (1, out)
        }
        (Form::WString(max), _) => {
            let units: Vec<u16> = text()?.encode_utf16().collect();
            if units.len() > usize::from(max) {
                return Err(format!(
                    "{} characters do not fit the PLC's WSTRING[{max}]",
                    units.len()
                ));
            }
            let mut out = (units.len() as u16).to_be_bytes().to_vec();
            out.extend(units.iter().flat_map(|u| u.to_be_bytes()));
            (2, out)
        }
        (Form::Dt | Form::Dtl, v) => {
            let at = match v {
                Value::String(s) => Civil::parse(s)?,
                Value::Int(ms) => Civil::from_millis(*ms)?,
                v => return Err(format!("a date and time does not take {v}")),
            };
            let bytes = if form == Form::Dt {
                clock::to_dt(&at)?
            } else {
                clock::to_dtl(&at)
            };
            (0, bytes)
        }
        (Form::Timer, v) => (0, timer(ty, v)?.to_be_bytes().to_vec()),
        (Form::Counter, v) => (0, counter(ty, v)?.to_be_bytes().to_vec()),
        (_, v) => return Err(format!("a {ty} does not take {v}")),
    })
}

/// Characters one byte each (Latin-1, as the PLC's STRING and CHAR hold them), at most `max`.
fn latin1(text: &str, max: u16) -> Result<Vec<u8>, String> {
    let bytes: Vec<u8> = text
        .chars()
        .map(|c| u8::try_from(u32::from(c)))
        .collect::<Result<_, _>>()
        .map_err(|_| "an S7 STRING or CHAR holds characters of one byte (Latin-1)".to_owned())?;
    if bytes.len() > usize::from(max) {
        return Err(format!(
            "{} characters do not fit the PLC's {}",
            bytes.len(),
            if max == 1 {
                "CHAR".to_owned()
            } else {
                format!("STRING[{max}]")
            }
        ));
    }
    Ok(bytes)
}

fn whole(v: &Value) -> Option<i128> {
    match v {
        Value::Int(x) => Some(i128::from(*x)),
        Value::UInt(x) => Some(i128::from(*x)),
        Value::Time(x) => Some(i128::from(*x)),
        _ => None,
    }
}

/// S5TIME of a number of milliseconds: the finest time base that holds it exactly.
fn timer(ty: IecType, v: &Value) -> Result<u16, String> {
    let raw = whole(v).ok_or_else(|| format!("a timer does not take {v}"))?;
    if ty == IecType::Word {
        return u16::try_from(raw).map_err(|_| format!("{raw} is not a WORD"));
    }
    for (base, step) in S5_BASES.iter().enumerate() {
        let step = i128::from(*step);
        if raw >= 0 && raw % step == 0 && raw / step <= 999 {
            return Ok((base as u16) << 12 | to_bcd3((raw / step) as u16));
        }
    }
    Err(format!(
        "S5TIME cannot hold {raw} ms exactly (10 ms steps to 9.99 s, 100 ms to 99.9 s, 1 s to 999 s, 10 s to 9990 s)"
    ))
}

fn counter(ty: IecType, v: &Value) -> Result<u16, String> {
    let raw = whole(v).ok_or_else(|| format!("a counter does not take {v}"))?;
    if ty == IecType::Word {
        return u16::try_from(raw).map_err(|_| format!("{raw} is not a WORD"));
    }
    match u16::try_from(raw) {
        Ok(n) if n <= 999 => Ok(to_bcd3(n)),
        _ => Err(format!("a counter counts 0-999, not {raw}")),
    }
}

//! S7 addresses as S7 users write them: data blocks (`DB10.DBX0.1`, `DB10.DBB2`,
//! `DB10.DBW4`, `DB10.DBD6`, and `DB10,X0.1` / `DB10.6` forms), merkers (`M0.1`, `MB1`,
//! `MW2`, `MD4`), inputs (`I0.0`, German `E0.0`, `IB1`, `IW2`, `ID4`) and outputs (`Q0.1`,
//! German `A0.1`, `QB1`, `QW4`, `QD8`), timers (`T5`) and counters (`C3`, German `Z3`).
//! Only the syntax and the size it names; the field's type decides how many bytes a
//! byte-addressed item takes where the address does not say (`DB10.DBB2` of a LREAL).

use crate::codec::IecType;

/// A memory area of the PLC.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub(crate) enum Area {
    Inputs,
    Outputs,
    Merkers,
    DataBlock,
    Counters,
    Timers,
}

impl Area {
    /// The area's code in S7comm.
    pub(crate) fn code(self) -> u8 {
        match self {
            Area::Inputs => 0x81,
            Area::Outputs => 0x82,
            Area::Merkers => 0x83,
            Area::DataBlock => 0x84,
            Area::Counters => 0x1C,
            Area::Timers => 0x1D,
        }
    }
}

/// What an address names: an area, its block, a byte offset, and a bit or a width.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Address {
    pub(crate) area: Area,
    pub(crate) db: u16,
    pub(crate) byte: u32,
    pub(crate) width: Width,
}

/// The width an address says.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Width {
    Bit(u8),
    Byte,
    Word,
    DWord,
    /// A timer or counter (two bytes).
    Cell,
    /// A data block offset without a width (`DB10.6`): the field's type says it.
    Unsized,
    /// A data block offset with its S7 type (`DB10.REAL6`, `DB10.DTL20`, `DB10.STRING40`).
    Typed(S7Type),
}

/// The S7 types an address may name (`DB10.<TYPE><offset>`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum S7Type {
    /// An elementary type stored as the IEC type of the same name (BYTE…LREAL, TIME).
    Elementary(IecType),
    Char,
    WChar,
    String,
    WString,
    /// DATE_AND_TIME (8 bytes of BCD).
    Dt,
    /// DTL (12 bytes).
    Dtl,
}

impl S7Type {
    /// The type named by a word of a typed address.
    fn named(word: &str) -> Option<S7Type> {
        Some(match word {
            "CHAR" => S7Type::Char,
            "WCHAR" => S7Type::WChar,
            "STRING" => S7Type::String,
            "WSTRING" => S7Type::WString,
            "DT" | "DATE_AND_TIME" => S7Type::Dt,
            "DTL" => S7Type::Dtl,
            "BOOL" | "STR" => return None,
            other => S7Type::Elementary(IecType::parse(other)?),
        })
    }
}

impl Width {
    /// Bytes it takes, where the address says.
    pub(crate) fn bytes(self) -> Option<u16> {
        match self {
            Width::Bit(_) | Width::Byte => Some(1),
            Width::Word | Width::Cell => Some(2),
            Width::DWord => Some(4),
            Width::Unsized | Width::Typed(_) => None,
        }
    }
}

/// The largest byte offset accepted (the S7 address field has 21 bits of bytes).
const MAX_BYTE: u32 = (1 << 21) - 1;

fn number<T: std::str::FromStr>(text: &str, what: &str) -> Result<T, String> {
    if text.is_empty() || !text.bytes().all(|b| b.is_ascii_digit()) {
        return Err(format!("`{text}` is not a {what}"));
    }
    text.parse()
        .map_err(|_| format!("{what} `{text}` is too large"))
}

fn byte_offset(text: &str) -> Result<u32, String> {
    let n: u32 = number(text, "byte offset")?;
    if n > MAX_BYTE {
        return Err(format!("byte offset {n} is past {MAX_BYTE}"));
    }
    Ok(n)
}

/// `B.b` (a bit) after an area letter.
fn bit(text: &str) -> Result<(u32, u8), String> {
    let (byte, bit) = text
        .split_once('.')
        .ok_or_else(|| format!("`{text}`: a bit is BYTE.BIT, e.g. 0.1"))?;
    let bit: u8 = number(bit, "bit")?;
    if bit > 7 {
        return Err(format!("bit {bit}: a byte has bits 0-7"));
    }
    Ok((byte_offset(byte)?, bit))
}

/// A width letter (B, W, D, X) and what follows it.
fn sized(area: Area, db: u16, text: &str) -> Result<Address, String> {
    let (width, rest) = match text.chars().next() {
        Some('X') => {
            let (byte, b) = bit(&text[1..])?;
            return Ok(Address {
                area,
                db,
                byte,
                width: Width::Bit(b),
            });
        }
        Some('B') => (Width::Byte, &text[1..]),
        Some('W') => (Width::Word, &text[1..]),
        Some('D') => (Width::DWord, &text[1..]),
        _ => {
            let (byte, b) = bit(text)?;
            return Ok(Address {
                area,
                db,
                byte,
                width: Width::Bit(b),
            });
        }
    };
    Ok(Address {
        area,
        db,
        byte: byte_offset(rest)?,
        width,
    })
}

/// Parses an address; a problem says what is wrong and how to write it.
pub(crate) fn parse(text: &str) -> Result<Address, String> {
    let t = text.trim().to_ascii_uppercase();
    let fail = |why: String| {
        format!(
            "`{}`: {why} (write e.g. DB10.DBD6, DB10.DBX0.1, MW2, I0.0, QB4, T5, C3)",
            text.trim()
        )
    };
    if let Some(rest) = t.strip_prefix("DB") {
        let (db, rest) = rest.split_once(['.', ',']).ok_or_else(|| {
            fail("a data block address is DBn.DBXb.x, DBn.DBBb, DBn.DBWb or DBn.DBDb".into())
        })?;
        let db: u16 = number(db, "data block number").map_err(fail)?;
        if db == 0 {
            return Err(fail("data blocks are numbered from 1".into()));
        }
        let rest = rest.strip_prefix("DB").unwrap_or(rest);
        let word_end = rest
            .find(|c: char| c.is_ascii_digit())
            .unwrap_or(rest.len());
        if word_end > 1 {
            let (word, at) = rest.split_at(word_end);
            let ty = S7Type::named(word)
                .ok_or_else(|| fail(format!("`{word}` is not an S7 type of a typed address")))?;
            return Ok(Address {
                area: Area::DataBlock,
                db,
                byte: byte_offset(at).map_err(fail)?,
                width: Width::Typed(ty),
            });
        }
        if rest.bytes().all(|b| b.is_ascii_digit()) {
            let byte = byte_offset(rest).map_err(fail)?;
            return Ok(Address {
                area: Area::DataBlock,
                db,
                byte,
                width: Width::Unsized,
            });
        }
        return sized(Area::DataBlock, db, rest).map_err(fail);
    }
    let (area, rest) = match t.chars().next() {
        Some('M') => (Area::Merkers, &t[1..]),
        Some('I' | 'E') => (Area::Inputs, &t[1..]),
        Some('Q' | 'A') => (Area::Outputs, &t[1..]),
        Some('T') => {
            let n = number(&t[1..], "timer number").map_err(fail)?;
            return Ok(Address {
                area: Area::Timers,
                db: 0,
                byte: n,
                width: Width::Cell,
            });
        }
        Some('C' | 'Z') => {
            let n = number(&t[1..], "counter number").map_err(fail)?;
            return Ok(Address {
                area: Area::Counters,
                db: 0,
                byte: n,
                width: Width::Cell,
            });
        }
        _ => return Err(fail("unknown area".into())),
    };
    sized(area, 0, rest).map_err(fail)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_notations_s7_users_write_parse() {
        let a = |area, db, byte, width| Address {
            area,
            db,
            byte,
            width,
        };
        for (text, want) in [
            ("DB10.DBX0.1", a(Area::DataBlock, 10, 0, Width::Bit(1))),
            ("db10.dbb2", a(Area::DataBlock, 10, 2, Width::Byte)),
            ("DB10.DBW4", a(Area::DataBlock, 10, 4, Width::Word)),
            ("DB10.DBD6", a(Area::DataBlock, 10, 6, Width::DWord)),
            ("DB10,X0.1", a(Area::DataBlock, 10, 0, Width::Bit(1))),
            ("DB10.6", a(Area::DataBlock, 10, 6, Width::Unsized)),
            ("M0.1", a(Area::Merkers, 0, 0, Width::Bit(1))),
            ("MB1", a(Area::Merkers, 0, 1, Width::Byte)),
            ("MW2", a(Area::Merkers, 0, 2, Width::Word)),
            ("MD4", a(Area::Merkers, 0, 4, Width::DWord)),
            ("I0.0", a(Area::Inputs, 0, 0, Width::Bit(0))),
            ("E0.7", a(Area::Inputs, 0, 0, Width::Bit(7))),
            ("IW2", a(Area::Inputs, 0, 2, Width::Word)),
            ("Q0.1", a(Area::Outputs, 0, 0, Width::Bit(1))),
            ("A0.1", a(Area::Outputs, 0, 0, Width::Bit(1))),
            ("QW4", a(Area::Outputs, 0, 4, Width::Word)),
            ("T5", a(Area::Timers, 0, 5, Width::Cell)),
            ("C3", a(Area::Counters, 0, 3, Width::Cell)),
            ("Z3", a(Area::Counters, 0, 3, Width::Cell)),
            (
                "DB10.LREAL8",
                a(
                    Area::DataBlock,
                    10,
                    8,
                    Width::Typed(S7Type::Elementary(IecType::Lreal)),
                ),
            ),
            (
                "DB2.DTL12",
                a(Area::DataBlock, 2, 12, Width::Typed(S7Type::Dtl)),
            ),
            (
                "DB2.WSTRING0",
                a(Area::DataBlock, 2, 0, Width::Typed(S7Type::WString)),
            ),
        ] {
            assert_eq!(parse(text), Ok(want), "{text}");
        }
    }

    #[test]
    fn a_wrong_address_says_what_is_wrong() {
        for (text, says) in [
            ("DB0.DBW2", "numbered from 1"),
            ("DB10", "a data block address is"),
            ("DB10.DBX0.8", "bits 0-7"),
            ("DB10.DBW", "not a byte offset"),
            ("MW-1", "not a byte offset"),
            ("X5", "unknown area"),
            ("DB70000.DBW0", "too large"),
            ("MD99999999", "past"),
            ("DB1.FLOAT4", "not an S7 type"),
            ("DB1.REAL", "not a byte offset"),
        ] {
            let e = parse(text).expect_err(text);
            assert!(e.contains(says), "{text}: {e}");
        }
    }
}

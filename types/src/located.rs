//! IEC 61131-3 located addresses (`%IX0.0`, `%QW2`, `%MD10`, source document 003): a
//! location prefix (I input, Q output, M memory), a size prefix (X bit, B byte, W word,
//! D double word, L long word) and a hierarchical address: two parts for X (`byte.bit`, the
//! bit 0-7, the byte at most 1023), one part for every other size.

use std::fmt;
use std::str::FromStr;

use serde::Serialize;

/// I (input), Q (output) or M (memory).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
pub enum Area {
    /// `%I`: inputs.
    Input,
    /// `%Q`: outputs.
    Output,
    /// `%M`: memory.
    Memory,
}

impl Area {
    /// The location prefix: I, Q or M.
    pub fn letter(self) -> char {
        match self {
            Area::Input => 'I',
            Area::Output => 'Q',
            Area::Memory => 'M',
        }
    }
}

/// X (1 bit), B (8 bits), W (16 bits), D (32 bits) or L (64 bits).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
pub enum Size {
    /// `X`: 1 bit.
    Bit,
    /// `B`: 8 bits.
    Byte,
    /// `W`: 16 bits.
    Word,
    /// `D`: 32 bits.
    Double,
    /// `L`: 64 bits.
    Long,
}

impl Size {
    /// The size prefix: X, B, W, D or L.
    pub fn letter(self) -> char {
        match self {
            Size::Bit => 'X',
            Size::Byte => 'B',
            Size::Word => 'W',
            Size::Double => 'D',
            Size::Long => 'L',
        }
    }

    /// Width in bits.
    pub fn bits(self) -> u32 {
        match self {
            Size::Bit => 1,
            Size::Byte => 8,
            Size::Word => 16,
            Size::Double => 32,
            Size::Long => 64,
        }
    }
}

/// The most significant part of a bit address: at most 1023.
pub const MAX_BIT_BYTE: u32 = 1023;

/// A located address, e.g. `%QX2.6` or `%MD0`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
pub struct Location {
    /// I, Q or M.
    pub area: Area,
    /// X, B, W, D or L.
    pub size: Size,
    /// The address; for X the byte (most significant part).
    pub index: u32,
    /// For X: the bit in the byte (least significant part, 0-7).
    pub bit: Option<u8>,
}

/// Why text is not a located address, in the words of source document 003 where it has
/// them.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LocationError {
    /// No `%` at the start.
    #[error("`{0}`: a located address starts with `%`")]
    NoPercent(String),
    /// Not I, Q or M.
    #[error("`{0}`: the location prefix must be I (input), Q (output) or M (memory)")]
    Area(String),
    /// Not X, B, W, D or L.
    #[error("`{0}`: the size prefix must be X, B, W, D or L")]
    Size(String),
    /// The address is not a natural number.
    #[error("`{0}`: the address must be a natural number")]
    Number(String),
    /// `%IX0.8`.
    #[error("`{0}`: the least significant index is greater than 7")]
    BitIndex(String),
    /// A bit address past byte 1023.
    #[error("`{0}`: the most significant part must be no more than {MAX_BIT_BYTE}")]
    ByteIndex(String),
    /// `%QX0.0.1`.
    #[error("`{0}`: three part hierarchy is not permitted")]
    ThreeParts(String),
    /// `%IB1.1`.
    #[error("`{0}`: two part hierarchy is only permitted for X data size")]
    TwoParts(String),
    /// `%IX0..1`, `%IX0.`: a part missing between periods.
    #[error("`{0}`: parts are separated by a single period, each a number")]
    EmptyPart(String),
    /// `%IX3`: a bit address without its bit.
    #[error("`{0}`: a bit address has two parts, byte.bit (e.g. %IX0.0)")]
    OnePartBit(String),
}

impl Location {
    /// The location of these parts (unchecked: [`Location::parse`] checks text).
    pub fn new(area: Area, size: Size, index: u32, bit: Option<u8>) -> Self {
        Location {
            area,
            size,
            index,
            bit,
        }
    }

    /// Parses `%` + I/Q/M + X/B/W/D/L + address, checking the hierarchy rules.
    pub fn parse(text: &str) -> Result<Location, LocationError> {
        let owned = || text.to_owned();
        let rest = text
            .trim()
            .strip_prefix('%')
            .ok_or_else(|| LocationError::NoPercent(owned()))?;
        let mut chars = rest.chars();
        let area = match chars.next().map(|c| c.to_ascii_uppercase()) {
            Some('I') => Area::Input,
            Some('Q') => Area::Output,
            Some('M') => Area::Memory,
            _ => return Err(LocationError::Area(owned())),
        };
        let size = match chars.next().map(|c| c.to_ascii_uppercase()) {
            Some('X') => Size::Bit,
            Some('B') => Size::Byte,
            Some('W') => Size::Word,
            Some('D') => Size::Double,
            Some('L') => Size::Long,
            _ => return Err(LocationError::Size(owned())),
        };
        let parts: Vec<&str> = chars.as_str().split('.').collect();
        let number = |p: &str| -> Result<u32, LocationError> {
            if p.is_empty() || !p.bytes().all(|b| b.is_ascii_digit()) {
                return Err(LocationError::Number(owned()));
            }
            p.parse().map_err(|_| LocationError::Number(owned()))
        };
        if parts.len() > 1 && parts.iter().any(|p| p.is_empty()) {
            return Err(LocationError::EmptyPart(owned()));
        }
        match (size, parts.as_slice()) {
            (_, [_, _, _, ..]) => Err(LocationError::ThreeParts(owned())),
            (Size::Bit, [byte, bit]) => {
                let (byte, bit) = (number(byte)?, number(bit)?);
                if bit > 7 {
                    return Err(LocationError::BitIndex(owned()));
                }
                if byte > MAX_BIT_BYTE {
                    return Err(LocationError::ByteIndex(owned()));
                }
                Ok(Location::new(area, size, byte, Some(bit as u8)))
            }
            (Size::Bit, [_]) => Err(LocationError::OnePartBit(owned())),
            (_, [_, _]) => Err(LocationError::TwoParts(owned())),
            (_, [index]) => Ok(Location::new(area, size, number(index)?, None)),
            (_, []) => Err(LocationError::Number(owned())),
        }
    }

    /// Bit locations only: the bit's number counting from bit 0 of byte 0 (`byte * 8 + bit`,
    /// the Modbus data address of source document 001).
    pub fn bit_number(&self) -> Option<u32> {
        self.bit.map(|b| self.index * 8 + u32::from(b))
    }
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "%{}{}{}",
            self.area.letter(),
            self.size.letter(),
            self.index
        )?;
        if let Some(bit) = self.bit {
            write!(f, ".{bit}")?;
        }
        Ok(())
    }
}

impl FromStr for Location {
    type Err = LocationError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Location::parse(s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn valid_addresses_parse_and_print_back() {
        for text in [
            "%IX0.0",
            "%QX2.6",
            "%IW0",
            "%QW2",
            "%MW1023",
            "%MD0",
            "%ML20",
            "%IX1023.7",
        ] {
            let loc = Location::parse(text).expect(text);
            assert_eq!(loc.to_string(), text);
        }
        let q = Location::parse("%QX2.6").expect("valid");
        assert_eq!(
            (q.area, q.size, q.index, q.bit),
            (Area::Output, Size::Bit, 2, Some(6))
        );
        assert_eq!(q.bit_number(), Some(22), "coil 22 is %QX2.6");
        assert_eq!(
            Location::parse("%qw2").expect("any case").to_string(),
            "%QW2"
        );
    }

    #[test]
    fn the_documented_invalid_examples_are_refused_with_their_reasons() {
        let cases = [
            ("%IX0.8", "the least significant index is greater than 7"),
            ("%QX0.0.1", "three part hierarchy is not permitted"),
            (
                "%IB1.1",
                "two part hierarchy is only permitted for X data size",
            ),
            ("%IX1024.0", "no more than 1023"),
            ("IX0.0", "starts with `%`"),
            ("%ZX0.0", "location prefix"),
            ("%IY0", "size prefix"),
            ("%IW", "natural number"),
            ("%IW-1", "natural number"),
            ("%IX0", "two parts"),
            ("%IX0..1", "separated by a single period"),
            ("%IX0.", "separated by a single period"),
            ("%QX.1", "separated by a single period"),
        ];
        for (text, reason) in cases {
            let err = Location::parse(text).expect_err(text).to_string();
            assert!(err.contains(reason), "{text}: {err}");
            assert!(
                err.contains(text),
                "{text}: the message names the address: {err}"
            );
        }
    }
}

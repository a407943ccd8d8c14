//! Registers and bits to typed values and back. Pure functions, no I/O.
//!
//! [`IecType`] is the IEC 61131-3 type of a field, [`Value`] a value of such a type, and
//! [`Encoding`] says how a field's value sits in Modbus registers (raw type, byte order, bit,
//! scale and offset).

mod encoding;

use std::fmt;

pub use encoding::{Encoding, Raw};

/// IEC 61131-3 elementary types supported by profiles.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum IecType {
    Bool,
    Sint,
    Int,
    Dint,
    Lint,
    Usint,
    Uint,
    Udint,
    Ulint,
    Real,
    Lreal,
    Byte,
    Word,
    Dword,
    Lword,
    String,
    Time,
}

impl IecType {
    pub const ALL: [IecType; 17] = [
        IecType::Bool,
        IecType::Sint,
        IecType::Int,
        IecType::Dint,
        IecType::Lint,
        IecType::Usint,
        IecType::Uint,
        IecType::Udint,
        IecType::Ulint,
        IecType::Real,
        IecType::Lreal,
        IecType::Byte,
        IecType::Word,
        IecType::Dword,
        IecType::Lword,
        IecType::String,
        IecType::Time,
    ];

    pub fn name(self) -> &'static str {
        match self {
            IecType::Bool => "BOOL",
            IecType::Sint => "SINT",
            IecType::Int => "INT",
            IecType::Dint => "DINT",
            IecType::Lint => "LINT",
            IecType::Usint => "USINT",
            IecType::Uint => "UINT",
            IecType::Udint => "UDINT",
            IecType::Ulint => "ULINT",
            IecType::Real => "REAL",
            IecType::Lreal => "LREAL",
            IecType::Byte => "BYTE",
            IecType::Word => "WORD",
            IecType::Dword => "DWORD",
            IecType::Lword => "LWORD",
            IecType::String => "STRING",
            IecType::Time => "TIME",
        }
    }

    /// Parses a type name, ignoring case as IEC 61131-3 does.
    pub fn parse(name: &str) -> Option<IecType> {
        IecType::ALL
            .into_iter()
            .find(|t| t.name().eq_ignore_ascii_case(name))
    }

    /// Width in bits of the integer types (TIME is a 64-bit count of milliseconds).
    pub fn int_bits(self) -> Option<(u8, bool)> {
        Some(match self {
            IecType::Sint => (8, true),
            IecType::Int => (16, true),
            IecType::Dint => (32, true),
            IecType::Lint | IecType::Time => (64, true),
            IecType::Usint | IecType::Byte => (8, false),
            IecType::Uint | IecType::Word => (16, false),
            IecType::Udint | IecType::Dword => (32, false),
            IecType::Ulint | IecType::Lword => (64, false),
            _ => return None,
        })
    }

    /// The inclusive range of an integer type.
    pub fn int_range(self) -> Option<(i128, i128)> {
        self.int_bits()
            .map(|(bits, signed)| int_range(bits, signed))
    }

    pub fn is_real(self) -> bool {
        matches!(self, IecType::Real | IecType::Lreal)
    }

    /// Types whose values are numbers that scale and offset apply to.
    pub fn is_numeric(self) -> bool {
        self.is_real() || (self.int_bits().is_some() && self != IecType::Time)
    }

    /// Registers the type takes when `word_count` is not given: the size of integer types;
    /// one for BOOL and STRING; one for REAL and LREAL, which then hold a scaled 16-bit
    /// integer (seed 000's TEMPERATURE example; IEEE-754 values say `word_count: 2` or `4`).
    pub fn default_words(self) -> u16 {
        match self {
            IecType::Bool | IecType::String | IecType::Real | IecType::Lreal => 1,
            t => t
                .int_bits()
                .map_or(1, |(bits, _)| u16::from(bits).div_ceil(16)),
        }
    }
}

impl fmt::Display for IecType {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

pub(crate) fn int_range(bits: u8, signed: bool) -> (i128, i128) {
    if signed {
        let half = 1i128 << (bits - 1);
        (-half, half - 1)
    } else {
        (0, (1i128 << bits) - 1)
    }
}

/// Byte order of multi-byte values in registers. Values are laid out most significant byte
/// first (ABCD for 32 bits, ABCDEFGH for 64 bits; the characters in order for strings), then
/// reordered:
/// - `big-endian` (ABCD, ABCDEFGH): as is; the Modbus default.
/// - `little-endian` (DCBA, HGFEDCBA): every byte reversed.
/// - `swap-bytes` (BADC, BADCFEHG): the two bytes inside each register swapped.
/// - `swap-words` (CDAB, GHEFCDAB): the registers in reverse order, bytes inside each as is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum ByteOrder {
    #[default]
    BigEndian,
    LittleEndian,
    SwapBytes,
    SwapWords,
}

impl ByteOrder {
    pub const ALL: [ByteOrder; 4] = [
        ByteOrder::BigEndian,
        ByteOrder::LittleEndian,
        ByteOrder::SwapBytes,
        ByteOrder::SwapWords,
    ];

    pub fn name(self) -> &'static str {
        match self {
            ByteOrder::BigEndian => "big-endian",
            ByteOrder::LittleEndian => "little-endian",
            ByteOrder::SwapBytes => "swap-bytes",
            ByteOrder::SwapWords => "swap-words",
        }
    }

    pub fn parse(name: &str) -> Option<ByteOrder> {
        ByteOrder::ALL.into_iter().find(|o| o.name() == name)
    }

    /// Reorders bytes between value order and register order. Every order is its own
    /// inverse, so the same call serves both directions.
    pub fn reorder(self, bytes: &mut [u8]) {
        match self {
            ByteOrder::BigEndian => {}
            ByteOrder::LittleEndian => bytes.reverse(),
            ByteOrder::SwapBytes => bytes.chunks_exact_mut(2).for_each(|pair| pair.swap(0, 1)),
            ByteOrder::SwapWords => {
                let words = bytes.len() / 2;
                for i in 0..words / 2 {
                    let j = words - 1 - i;
                    bytes.swap(2 * i, 2 * j);
                    bytes.swap(2 * i + 1, 2 * j + 1);
                }
            }
        }
    }
}

impl fmt::Display for ByteOrder {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A value of an IEC type. Which variant goes with which type is fixed: integers signed
/// (SINT..LINT) are `Int`, unsigned and bit strings (USINT..ULINT, BYTE..LWORD) are `UInt`,
/// TIME is `Time` in milliseconds.
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    Bool(bool),
    Int(i64),
    UInt(u64),
    Real(f32),
    LReal(f64),
    String(String),
    Time(i64),
}

impl Value {
    /// An integer checked against the range of `ty` (which may be any numeric type or TIME).
    pub fn from_int(ty: IecType, n: i128) -> Result<Value, CodecError> {
        if ty.is_real() {
            return Value::from_real(ty, n as f64);
        }
        let (min, max) = ty.int_range().ok_or(CodecError::WrongType {
            ty,
            found: "an integer",
        })?;
        if n < min || n > max {
            return Err(CodecError::OutOfRange {
                value: n.to_string(),
                ty,
                min: min.to_string(),
                max: max.to_string(),
            });
        }
        Ok(match ty {
            IecType::Time => Value::Time(n as i64),
            t if t.int_bits().is_some_and(|(_, signed)| signed) => Value::Int(n as i64),
            _ => Value::UInt(n as u64),
        })
    }

    /// A real number for a REAL or LREAL (an integer type accepts only whole numbers).
    pub fn from_real(ty: IecType, x: f64) -> Result<Value, CodecError> {
        if !x.is_finite() {
            return Err(CodecError::NotFinite { ty });
        }
        match ty {
            IecType::Real => {
                if x.abs() > f64::from(f32::MAX) {
                    return Err(CodecError::OutOfRange {
                        value: x.to_string(),
                        ty,
                        min: (-f32::MAX).to_string(),
                        max: f32::MAX.to_string(),
                    });
                }
                Ok(Value::Real(x as f32))
            }
            IecType::Lreal => Ok(Value::LReal(x)),
            _ if ty.int_bits().is_some() => {
                if x.fract() != 0.0 {
                    return Err(CodecError::NotWhole { value: x, ty });
                }
                Value::from_int(ty, x as i128)
            }
            _ => Err(CodecError::WrongType {
                ty,
                found: "a number",
            }),
        }
    }

    /// The value as an f64, for numbers.
    pub fn as_f64(&self) -> Option<f64> {
        match *self {
            Value::Int(i) => Some(i as f64),
            Value::UInt(u) => Some(u as f64),
            Value::Real(r) => Some(f64::from(r)),
            Value::LReal(r) => Some(r),
            Value::Time(t) => Some(t as f64),
            _ => None,
        }
    }

    /// The value as an exact integer, for integer and TIME values.
    pub fn as_i128(&self) -> Option<i128> {
        match *self {
            Value::Int(i) | Value::Time(i) => Some(i.into()),
            Value::UInt(u) => Some(u.into()),
            _ => None,
        }
    }

    /// Whether this value is of the variant that `ty` uses.
    pub fn is_of(&self, ty: IecType) -> bool {
        match self {
            Value::Bool(_) => ty == IecType::Bool,
            Value::Int(_) => ty.int_bits().is_some_and(|(_, s)| s) && ty != IecType::Time,
            Value::UInt(_) => ty.int_bits().is_some_and(|(_, s)| !s),
            Value::Real(_) => ty == IecType::Real,
            Value::LReal(_) => ty == IecType::Lreal,
            Value::String(_) => ty == IecType::String,
            Value::Time(_) => ty == IecType::Time,
        }
    }

    /// The zero value of a type: what a field holds before anything is known.
    pub fn zero(ty: IecType) -> Value {
        match ty {
            IecType::Bool => Value::Bool(false),
            IecType::Real => Value::Real(0.0),
            IecType::Lreal => Value::LReal(0.0),
            IecType::String => Value::String(String::new()),
            IecType::Time => Value::Time(0),
            t if t.int_bits().is_some_and(|(_, s)| s) => Value::Int(0),
            _ => Value::UInt(0),
        }
    }
}

impl fmt::Display for Value {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Value::Bool(b) => write!(f, "{}", if *b { "TRUE" } else { "FALSE" }),
            Value::Int(i) => write!(f, "{i}"),
            Value::UInt(u) => write!(f, "{u}"),
            Value::Real(r) => write!(f, "{r}"),
            Value::LReal(r) => write!(f, "{r}"),
            Value::String(s) => write!(f, "'{s}'"),
            Value::Time(t) => f.write_str(&crate::duration::format_iec(*t)),
        }
    }
}

/// Why a value could not be converted.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CodecError {
    #[error("{value} is out of range for {ty} ({min} to {max})")]
    OutOfRange {
        value: String,
        ty: IecType,
        min: String,
        max: String,
    },
    #[error("{value} after scaling does not fit the raw register value ({min} to {max})")]
    RawOutOfRange {
        value: String,
        min: String,
        max: String,
    },
    #[error("{ty} needs a finite number")]
    NotFinite { ty: IecType },
    #[error("{ty} needs a whole number, got {value}")]
    NotWhole { value: f64, ty: IecType },
    #[error("{ty} does not take {found}")]
    WrongType { ty: IecType, found: &'static str },
    #[error("the string is {len} bytes long; the field holds at most {max}")]
    TooLong { len: usize, max: usize },
    #[error("expected {expected} registers, got {found}")]
    WrongLength { expected: usize, found: usize },
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn type_names_parse_ignoring_case() {
        for t in IecType::ALL {
            assert_eq!(IecType::parse(t.name()), Some(t));
            assert_eq!(IecType::parse(&t.name().to_lowercase()), Some(t));
        }
        assert_eq!(IecType::parse("FLOAT"), None);
    }

    #[test]
    fn integers_out_of_their_type_are_rejected() {
        assert_eq!(Value::from_int(IecType::Usint, 255), Ok(Value::UInt(255)));
        assert!(matches!(
            Value::from_int(IecType::Usint, 256),
            Err(CodecError::OutOfRange { .. })
        ));
        assert!(Value::from_int(IecType::Sint, -129).is_err());
        assert_eq!(
            Value::from_int(IecType::Lint, i64::MIN.into()),
            Ok(Value::Int(i64::MIN))
        );
        assert_eq!(
            Value::from_int(IecType::Ulint, u64::MAX.into()),
            Ok(Value::UInt(u64::MAX))
        );
        assert!(Value::from_int(IecType::Ulint, -1).is_err());
        assert!(Value::from_int(IecType::Bool, 1).is_err());
    }

    #[test]
    fn reals_are_checked() {
        assert_eq!(Value::from_real(IecType::Real, 21.5), Ok(Value::Real(21.5)));
        assert!(Value::from_real(IecType::Real, 1e39).is_err());
        assert!(Value::from_real(IecType::Lreal, f64::NAN).is_err());
        assert!(matches!(
            Value::from_real(IecType::Int, 2.5),
            Err(CodecError::NotWhole { .. })
        ));
        assert_eq!(Value::from_real(IecType::Int, 2.0), Ok(Value::Int(2)));
    }

    #[test]
    fn every_byte_order_is_its_own_inverse() {
        for order in ByteOrder::ALL {
            for len in [2, 4, 8, 10] {
                let original: Vec<u8> = (1..=len).collect();
                let mut bytes = original.clone();
                order.reorder(&mut bytes);
                order.reorder(&mut bytes);
                assert_eq!(bytes, original, "{order} {len}");
            }
        }
    }

    #[test]
    fn byte_orders_match_their_letters() {
        let abcd = *b"ABCD";
        let cases = [
            (ByteOrder::BigEndian, *b"ABCD"),
            (ByteOrder::LittleEndian, *b"DCBA"),
            (ByteOrder::SwapBytes, *b"BADC"),
            (ByteOrder::SwapWords, *b"CDAB"),
        ];
        for (order, expected) in cases {
            let mut bytes = abcd;
            order.reorder(&mut bytes);
            assert_eq!(bytes, expected, "{order}");
        }
        let mut long = *b"ABCDEFGH";
        ByteOrder::SwapWords.reorder(&mut long);
        assert_eq!(&long, b"GHEFCDAB");
    }
}

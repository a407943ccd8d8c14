//! Registers and bits to typed values and back. Pure functions, no I/O.
//!
//! [`IecType`] is the IEC 61131-3 type of a field, [`Value`] a value of such a type, and
//! [`Encoding`] says how a field's value sits in Modbus registers (raw type, byte order, bit,
//! scale and offset).

mod encoding;

use std::fmt;

pub(crate) use encoding::{Encoding, Raw, Switch};

pub(crate) use iogate_types::{IecType, Value, ValueError, int_range};

/// Registers as bytes, each register high byte first: the one place registers are
/// unpacked (the codec, the Modbus map, raw transactions).
pub(crate) fn register_bytes(regs: &[u16]) -> Vec<u8> {
    regs.iter().flat_map(|r| r.to_be_bytes()).collect()
}

/// Bytes as registers, two by two, the first of each pair the high byte (an odd last byte
/// is left out): the one place registers are packed.
pub(crate) fn bytes_registers(bytes: &[u8]) -> Vec<u16> {
    bytes
        .chunks_exact(2)
        .map(|pair| u16::from_be_bytes([pair[0], pair[1]]))
        .collect()
}

/// Registers a type's full width takes: 32-bit types two, 64-bit types four, everything
/// else one. Without `word_count` every field takes one register (source document 000:
/// "default 1 ... use 2 for 32-bit DINT/REAL values"); this is the count to add for the
/// full width, and the size of a `raw_type`.
pub(crate) fn full_words(ty: IecType) -> u16 {
    match ty {
        IecType::Real => 2,
        IecType::Lreal => 4,
        t => t
            .int_bits()
            .map_or(1, |(bits, _)| u16::from(bits).div_ceil(16)),
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
    pub(crate) const ALL: [ByteOrder; 4] = [
        ByteOrder::BigEndian,
        ByteOrder::LittleEndian,
        ByteOrder::SwapBytes,
        ByteOrder::SwapWords,
    ];

    pub(crate) fn name(self) -> &'static str {
        match self {
            ByteOrder::BigEndian => "big-endian",
            ByteOrder::LittleEndian => "little-endian",
            ByteOrder::SwapBytes => "swap-bytes",
            ByteOrder::SwapWords => "swap-words",
        }
    }

    /// Reorders bytes between value order and register order. Every order is its own
    /// inverse, so the same call serves both directions.
    pub(crate) fn reorder(self, bytes: &mut [u8]) {
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

/// Why a value could not be converted.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CodecError {
    #[error(transparent)]
    Value(#[from] ValueError),
    #[error("{value} after scaling does not fit the raw register value ({min} to {max})")]
    RawOutOfRange {
        value: String,
        min: String,
        max: String,
    },
    #[error("{ty} needs a finite number")]
    NotFinite { ty: IecType },
    #[error("{ty} does not take {found}")]
    WrongType { ty: IecType, found: &'static str },
    #[error("the string is {len} bytes long; the field holds at most {max}")]
    TooLong { len: usize, max: usize },
    #[error("the string is {len} characters long; the field holds at most {max}")]
    TooManyCharacters { len: usize, max: usize },
    #[error("expected {expected} registers, got {found}")]
    WrongLength { expected: usize, found: usize },
    /// A client's value of the wrong kind for the type (a string for a BOOL, ...).
    #[error("{ty} needs {expected}, got {found}")]
    Expected {
        ty: IecType,
        expected: &'static str,
        found: &'static str,
    },
    /// A duration literal that does not parse.
    #[error(transparent)]
    Time(#[from] iogate_types::time::TimeError),
    /// A switch's register holding neither of its two values.
    #[error("the register holds {raw}, neither on_value {on} nor off_value {off}")]
    NotASwitchValue { raw: u16, on: u16, off: u16 },
    /// A value of another type than the field's.
    #[error("a {ty} value is needed")]
    NotOfType { ty: IecType },
    /// A value the device's protocol cannot hold where the field is (a text longer than
    /// the PLC's STRING[n], a count past a counter's 999): refused before it is sent.
    #[error("{0}")]
    Protocol(String),
}

#[cfg(test)]
mod tests {
    use super::*;

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

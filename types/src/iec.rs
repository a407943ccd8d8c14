//! The IEC 61131-3 elementary types a field can have.

use std::fmt;

use serde::Serialize;

/// IEC 61131-3 elementary types supported by profiles.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "UPPERCASE")]
pub enum IecType {
    /// TRUE/FALSE, one bit.
    Bool,
    /// 8-bit signed, -128..127.
    Sint,
    /// 16-bit signed.
    Int,
    /// 32-bit signed.
    Dint,
    /// 64-bit signed.
    Lint,
    /// 8-bit unsigned, 0..255.
    Usint,
    /// 16-bit unsigned.
    Uint,
    /// 32-bit unsigned.
    Udint,
    /// 64-bit unsigned.
    Ulint,
    /// 32-bit IEEE-754.
    Real,
    /// 64-bit IEEE-754.
    Lreal,
    /// 8-bit pattern.
    Byte,
    /// 16-bit pattern.
    Word,
    /// 32-bit pattern.
    Dword,
    /// 64-bit pattern.
    Lword,
    /// Text.
    String,
    /// A duration in milliseconds (64-bit).
    Time,
}

impl IecType {
    /// Every type, in the order of the profile format's table.
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

    /// The IEC name, e.g. `REAL`.
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

    /// REAL or LREAL.
    pub fn is_real(self) -> bool {
        matches!(self, IecType::Real | IecType::Lreal)
    }

    /// Types whose values are numbers that scale and offset apply to.
    pub fn is_numeric(self) -> bool {
        self.is_real() || (self.int_bits().is_some() && self != IecType::Time)
    }
}

impl fmt::Display for IecType {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// The inclusive range of a `bits`-wide integer.
pub fn int_range(bits: u8, signed: bool) -> (i128, i128) {
    if signed {
        let half = 1i128 << (bits - 1);
        (-half, half - 1)
    } else {
        (0, (1i128 << bits) - 1)
    }
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
}

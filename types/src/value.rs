//! A value of an IEC type, built only through checks that it fits the type.

use std::fmt;

use serde::Serialize;

use crate::IecType;
use crate::time::{self, TimeError};

/// A value of an IEC type. Which variant goes with which type is fixed: integers signed
/// (SINT..LINT) are `Int`, unsigned and bit strings (USINT..ULINT, BYTE..LWORD) are `UInt`,
/// TIME is `Time` in milliseconds (negative allowed, as IEC TIME). Serialised as the plain
/// JSON of the value.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum Value {
    /// BOOL.
    Bool(bool),
    /// SINT, INT, DINT, LINT.
    Int(i64),
    /// USINT, UINT, UDINT, ULINT, BYTE, WORD, DWORD, LWORD.
    UInt(u64),
    /// REAL.
    Real(f32),
    /// LREAL.
    LReal(f64),
    /// STRING.
    String(String),
    /// TIME, in milliseconds.
    Time(i64),
}

/// Why a value does not fit a type.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ValueError {
    /// A number outside the type's range.
    #[error("{value} is out of range for {ty} ({min} to {max})")]
    OutOfRange {
        /// The number as given.
        value: String,
        /// The type it was meant for.
        ty: IecType,
        /// The type's smallest value.
        min: String,
        /// The type's largest value.
        max: String,
    },
    /// NaN or an infinity for a real type.
    #[error("{ty} needs a finite number")]
    NotFinite {
        /// The type it was meant for.
        ty: IecType,
    },
    /// A fraction for an integer type.
    #[error("{ty} needs a whole number, got {value}")]
    NotWhole {
        /// The number as given.
        value: f64,
        /// The type it was meant for.
        ty: IecType,
    },
    /// A value of another kind (a string for a number, ...).
    #[error("{ty} does not take {found}")]
    WrongType {
        /// The type it was meant for.
        ty: IecType,
        /// What was given.
        found: &'static str,
    },
    /// A typed value whose type is not the field's.
    #[error("the field is {ty}, the value says {declared}")]
    Mislabelled {
        /// The field's type.
        ty: IecType,
        /// The type the value was labelled with.
        declared: IecType,
    },
    /// No value at all.
    #[error("{ty} needs a value; none was set")]
    Missing {
        /// The type it was meant for.
        ty: IecType,
    },
    /// A protobuf type number iogate does not know.
    #[error("{0} is not an IEC type number of iogate.v1.IecType")]
    UnknownType(i32),
    /// Text that does not parse as a value of the type.
    #[error("`{text}` is not a {ty} value")]
    NotAValue {
        /// The text as given.
        text: String,
        /// The type it was meant for.
        ty: IecType,
    },
    /// A duration literal that does not parse.
    #[error(transparent)]
    Time(#[from] TimeError),
}

impl Value {
    /// An integer checked against the range of `ty` (which may be any numeric type or TIME).
    pub fn from_int(ty: IecType, n: i128) -> Result<Value, ValueError> {
        if ty.is_real() {
            return Value::from_real(ty, n as f64);
        }
        let (min, max) = ty.int_range().ok_or(ValueError::WrongType {
            ty,
            found: "an integer",
        })?;
        if n < min || n > max {
            return Err(ValueError::OutOfRange {
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
    pub fn from_real(ty: IecType, x: f64) -> Result<Value, ValueError> {
        if !x.is_finite() {
            return Err(ValueError::NotFinite { ty });
        }
        match ty {
            IecType::Real => {
                if x.abs() > f64::from(f32::MAX) {
                    return Err(ValueError::OutOfRange {
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
                    return Err(ValueError::NotWhole { value: x, ty });
                }
                Value::from_int(ty, x as i128)
            }
            _ => Err(ValueError::WrongType {
                ty,
                found: "a number",
            }),
        }
    }

    /// Parses text as a value of `ty`, as a person types it: `true`/`false`/`1`/`0`/`on`/
    /// `off` for BOOL, numbers (`16#BEEF` or `0xBEEF` for unsigned types), any text for
    /// STRING, milliseconds or a literal such as `T#1s500ms` for TIME.
    pub fn parse(ty: IecType, text: &str) -> Result<Value, ValueError> {
        let t = text.trim();
        let bad = || ValueError::NotAValue {
            text: text.to_owned(),
            ty,
        };
        Ok(match ty {
            IecType::Bool => match t.to_ascii_lowercase().as_str() {
                "true" | "1" | "on" => Value::Bool(true),
                "false" | "0" | "off" => Value::Bool(false),
                _ => return Err(bad()),
            },
            IecType::Sint | IecType::Int | IecType::Dint | IecType::Lint => {
                Value::Int(t.parse().map_err(|_| bad())?)
            }
            IecType::Usint
            | IecType::Uint
            | IecType::Udint
            | IecType::Ulint
            | IecType::Byte
            | IecType::Word
            | IecType::Dword
            | IecType::Lword => match t.strip_prefix("16#").or_else(|| t.strip_prefix("0x")) {
                Some(hex) => {
                    Value::UInt(u64::from_str_radix(&hex.replace('_', ""), 16).map_err(|_| bad())?)
                }
                None => Value::UInt(t.parse().map_err(|_| bad())?),
            },
            IecType::Real => Value::Real(t.parse().map_err(|_| bad())?),
            IecType::Lreal => Value::LReal(t.parse().map_err(|_| bad())?),
            IecType::String => Value::String(text.to_owned()),
            IecType::Time => match t.parse::<i64>() {
                Ok(ms) => Value::Time(ms),
                Err(_) => Value::Time(time::parse_ms(t).map_err(|_| bad())?),
            },
        })
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

/// The value as ST writes it: `TRUE`, `21.5`, `'text'`, `T#1s500ms`.
impl fmt::Display for Value {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Value::Bool(b) => write!(f, "{}", if *b { "TRUE" } else { "FALSE" }),
            Value::Int(i) => write!(f, "{i}"),
            Value::UInt(u) => write!(f, "{u}"),
            Value::Real(r) => write!(f, "{r}"),
            Value::LReal(r) => write!(f, "{r}"),
            Value::String(s) => write!(f, "'{s}'"),
            Value::Time(t) => f.write_str(&time::format_iec(*t)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn integers_out_of_their_type_are_rejected() {
        assert_eq!(Value::from_int(IecType::Usint, 255), Ok(Value::UInt(255)));
        assert!(matches!(
            Value::from_int(IecType::Usint, 256),
            Err(ValueError::OutOfRange { .. })
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
            Err(ValueError::NotWhole { .. })
        ));
        assert_eq!(Value::from_real(IecType::Int, 2.0), Ok(Value::Int(2)));
    }

    #[test]
    fn values_parse_by_type() {
        assert_eq!(Value::parse(IecType::Bool, "on"), Ok(Value::Bool(true)));
        assert_eq!(Value::parse(IecType::Int, "-5"), Ok(Value::Int(-5)));
        assert_eq!(
            Value::parse(IecType::Word, "16#BEEF"),
            Ok(Value::UInt(0xBEEF))
        );
        assert_eq!(Value::parse(IecType::Real, "21.5"), Ok(Value::Real(21.5)));
        assert_eq!(
            Value::parse(IecType::Time, "T#1m30s"),
            Ok(Value::Time(90_000))
        );
        assert_eq!(Value::parse(IecType::Time, "250"), Ok(Value::Time(250)));
        assert!(Value::parse(IecType::Int, "five").is_err());
        assert_eq!(
            Value::parse(IecType::Bool, "maybe")
                .expect_err("not a BOOL")
                .to_string(),
            "`maybe` is not a BOOL value"
        );
    }

    #[test]
    fn values_serialize_as_plain_json() {
        assert_eq!(
            serde_json::to_string(&Value::Real(0.1)).ok().as_deref(),
            Some("0.1")
        );
        assert_eq!(
            serde_json::to_string(&Value::Bool(true)).ok().as_deref(),
            Some("true")
        );
        assert_eq!(
            serde_json::to_string(&Value::Time(1500)).ok().as_deref(),
            Some("1500")
        );
    }
}

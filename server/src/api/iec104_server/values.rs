//! Values both ways: a field's sample as the element of its point (its quality as the
//! descriptor: a stale value NT, a bad or unread one IV, a value its type cannot carry OV
//! at the nearest it can), and a command's element as the value written to its field.

use std::time::SystemTime;

use crate::cache::sample::Quality as FieldQuality;
use crate::codec::{IecType, Value};
use crate::drivers::iec104::element::{Element, Quality};
use crate::drivers::iec104::types::Kind;

/// The element of `kind` showing `value` with the field's `quality`.
pub(crate) fn element(kind: Kind, value: Option<&Value>, quality: FieldQuality) -> Element {
    let mut q = match quality {
        FieldQuality::Good => 0,
        FieldQuality::Stale => Quality::NT,
        FieldQuality::Bad | FieldQuality::NeverRead => Quality::IV,
    };
    if value.is_none() {
        q |= Quality::IV;
    }
    let number = value.and_then(number).unwrap_or(0.0);
    let mut clamp = |lo: f64, hi: f64| {
        if number < lo || number > hi {
            q |= Quality::OV;
        }
        number.clamp(lo, hi)
    };
    match kind {
        Kind::Single => Element::Single {
            on: number != 0.0,
            quality: Quality(q),
        },
        Kind::Double => Element::Double {
            state: if number != 0.0 { 2 } else { 1 },
            quality: Quality(q),
        },
        Kind::Bits => {
            let bits = value.and_then(Value::as_i128).unwrap_or(0) as u32;
            Element::Bits {
                bits,
                quality: Quality(q),
            }
        }
        Kind::Scaled => {
            let v = clamp(f64::from(i16::MIN), f64::from(i16::MAX)).round() as i16;
            Element::Scaled {
                value: v,
                quality: Quality(q),
            }
        }
        Kind::Normalized => {
            let v = (clamp(-1.0, 32767.0 / 32768.0) * 32768.0).round() as i16;
            Element::Normalized {
                value: v,
                quality: Quality(q),
            }
        }
        Kind::Counter => {
            let v = clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32;
            Element::Counter {
                value: v,
                sequence: 0,
                carry: false,
                adjusted: false,
                invalid: q & (Quality::IV | Quality::OV) != 0,
            }
        }
        _ => {
            let v = clamp(f64::from(f32::MIN), f64::from(f32::MAX)) as f32;
            Element::Float {
                value: v,
                quality: Quality(q),
            }
        }
    }
}

fn number(value: &Value) -> Option<f64> {
    match value {
        Value::Bool(b) => Some(f64::from(u8::from(*b))),
        v => v.as_f64(),
    }
}

/// The value a command carries for a field of `ty`, and whether it selects; or why it
/// carries none.
pub(crate) fn commanded(element: &Element, ty: IecType) -> Result<(Value, bool), String> {
    let real = |x: f64| Value::from_real(ty, x).map_err(|e| e.to_string());
    Ok(match *element {
        Element::SingleCommand { qu, .. } | Element::DoubleCommand { qu, .. }
            if !matches!(qu, 0 | 3) =>
        {
            let what = match qu {
                1 => "a short pulse",
                2 => "a long pulse",
                _ => "a qualifier the gateway does not know",
            };
            return Err(format!(
                "{what} (QU {qu}) is not executed: the gateway writes values (QU 0 or 3, persistent), it does not time pulses"
            ));
        }
        // QL 1-63 are reserved for the standard's own uses (0 is the default, 64-127 a
        // station's private ones, which this gateway has none of).
        Element::SetScaled { ql, .. }
        | Element::SetNormalized { ql, .. }
        | Element::SetFloat { ql, .. }
            if ql != 0 =>
        {
            return Err(format!(
                "a set-point of qualifier QL {ql} is not executed: the gateway takes QL 0 (default) only"
            ));
        }
        Element::SingleCommand { on, select, .. } if ty == IecType::Bool => {
            (Value::Bool(on), select)
        }
        Element::DoubleCommand { state, select, .. } if ty == IecType::Bool => match state {
            1 => (Value::Bool(false), select),
            2 => (Value::Bool(true), select),
            s => {
                return Err(format!(
                    "a double command of state {s} is neither off (1) nor on (2)"
                ));
            }
        },
        Element::SetScaled { value, select, .. } => (real(f64::from(value))?, select),
        Element::SetNormalized { value, select, .. } => (real(f64::from(value) / 32768.0)?, select),
        Element::SetFloat { value, select, .. } => (real(f64::from(value))?, select),
        Element::BitsCommand(bits) => (
            Value::from_int(ty, i128::from(bits)).map_err(|e| e.to_string())?,
            false,
        ),
        _ => return Err(format!("no command of this type sets a {}", ty.name())),
    })
}

/// Milliseconds since 1970 of `at`.
pub(crate) fn millis(at: SystemTime) -> i64 {
    at.duration_since(SystemTime::UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as i64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_value_its_type_cannot_carry_is_overflowed_at_the_nearest() {
        let e = element(Kind::Scaled, Some(&Value::UInt(40_000)), FieldQuality::Good);
        assert_eq!(
            e,
            Element::Scaled {
                value: i16::MAX,
                quality: Quality(Quality::OV)
            }
        );
        let e = element(Kind::Float, Some(&Value::Real(2.5)), FieldQuality::Stale);
        assert_eq!(
            e,
            Element::Float {
                value: 2.5,
                quality: Quality(Quality::NT)
            }
        );
        let e = element(Kind::Single, None, FieldQuality::NeverRead);
        assert_eq!(e.quality(), Some(Quality(Quality::IV)));
    }

    #[test]
    fn commands_carry_values_their_field_takes() {
        let c = Element::SetFloat {
            value: 12.5,
            select: true,
            ql: 0,
        };
        assert_eq!(commanded(&c, IecType::Real), Ok((Value::Real(12.5), true)));
        assert!(
            commanded(&c, IecType::Int)
                .expect_err("not whole")
                .contains("whole")
        );
        let c = Element::SetScaled {
            value: 300,
            select: false,
            ql: 0,
        };
        assert!(commanded(&c, IecType::Usint).is_err());
        let c = Element::DoubleCommand {
            state: 0,
            qu: 0,
            select: false,
        };
        assert!(commanded(&c, IecType::Bool).is_err());
    }
}

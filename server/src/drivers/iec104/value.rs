//! Values both ways: an element the station sent as a field's value of its IEC 61131 type,
//! its quality descriptor judged (IV: not a value; NT, SB, BL, OV, a counter's carry or
//! adjustment: the value with its doubt), and a value a client writes as the command
//! element of the field's command type.

use iogate_types::{IecType, Value};

use super::element::{Element, Quality};
use super::types::{Kind, TypeId};

/// A value of type `ty` from a number the station sent.
fn number(n: f64, ty: IecType) -> Result<Value, String> {
    if ty == IecType::Bool {
        return Err("a BOOL field takes single and double points".to_owned());
    }
    Value::from_real(ty, n).map_err(|e| format!("the station sent {n}: {e}"))
}

/// The doubt a quality descriptor casts on a value it carries, in the standard's words.
fn doubt(q: Quality) -> Option<String> {
    let names: Vec<&str> = q.names().into_iter().filter(|n| *n != "IV").collect();
    (!names.is_empty()).then(|| {
        let says: Vec<&str> = names
            .iter()
            .map(|n| match *n {
                "NT" => "not topical (NT)",
                "SB" => "substituted (SB)",
                "BL" => "blocked (BL)",
                _ => "overflow (OV)",
            })
            .collect();
        format!("the station marks the value {}", says.join(", "))
    })
}

/// A field's value of type `ty` from `element`, with the doubt its quality casts; an
/// invalid one (IV) or one the type cannot hold is an error saying so.
pub(crate) fn reading(element: &Element, ty: IecType) -> Result<(Value, Option<String>), String> {
    let value = match *element {
        Element::Single { on, .. } => Value::Bool(on),
        Element::Double { state, .. } => match state {
            1 => Value::Bool(false),
            2 => Value::Bool(true),
            s => return Err(format!("the double point is indeterminate ({s})")),
        },
        Element::Step { value, .. } => number(f64::from(value), ty)?,
        Element::Bits { bits, .. } => number(f64::from(bits), ty)?,
        Element::Normalized { value, .. } => number(f64::from(value) / 32768.0, ty)?,
        Element::Scaled { value, .. } => number(f64::from(value), ty)?,
        Element::Float { value, .. } => number(f64::from(value), ty)?,
        Element::Counter { value, .. } => number(f64::from(value), ty)?,
        _ => return Err("not a monitored value".to_owned()),
    };
    if matches!(value, Value::Bool(_)) && ty != IecType::Bool {
        return Err(format!("a point is a BOOL, not a {ty}"));
    }
    let quality = element.quality().unwrap_or_default();
    if quality.has(Quality::IV) {
        return Err(format!("the station marks its value {value} invalid (IV)"));
    }
    let mut doubt = doubt(quality);
    if let Element::Counter {
        carry, adjusted, ..
    } = *element
        && (carry || adjusted)
    {
        doubt = Some(format!(
            "the counter {}",
            if carry {
                "overflowed (CY)"
            } else {
                "was adjusted (CA)"
            }
        ));
    }
    Ok((value, doubt))
}

fn as_f64(value: &Value) -> Result<f64, String> {
    match value {
        Value::Bool(b) => Ok(f64::from(u8::from(*b))),
        v => v.as_f64().ok_or_else(|| format!("{v} is not a number")),
    }
}

/// The element a command of `command` carries for `value`, selected or executed.
pub(crate) fn command(command: TypeId, value: &Value, select: bool) -> Result<Element, String> {
    let kind = command.kind().ok_or("not a command")?;
    let n = as_f64(value)?;
    let ranged = |lo: f64, hi: f64| {
        if n.fract() != 0.0 || n < lo || n > hi {
            Err(format!(
                "{value} does not fit {} ({lo} to {hi})",
                command.name()
            ))
        } else {
            Ok(n)
        }
    };
    Ok(match kind {
        Kind::SingleCommand => Element::SingleCommand {
            on: n != 0.0,
            qu: 0,
            select,
        },
        Kind::DoubleCommand => Element::DoubleCommand {
            state: if n != 0.0 { 2 } else { 1 },
            qu: 0,
            select,
        },
        Kind::StepCommand => Element::StepCommand {
            step: if n > 0.0 {
                2
            } else if n < 0.0 {
                1
            } else {
                return Err("a step command is 1 (higher) or -1 (lower)".into());
            },
            qu: 0,
            select,
        },
        Kind::SetScaled => Element::SetScaled {
            value: ranged(-32768.0, 32767.0)? as i16,
            select,
            ql: 0,
        },
        Kind::SetNormalized => {
            if !(-1.0..1.0).contains(&n) {
                return Err(format!("{value} does not fit C_SE_NA_1 (-1 to below 1)"));
            }
            Element::SetNormalized {
                value: (n * 32768.0).round().clamp(-32768.0, 32767.0) as i16,
                select,
                ql: 0,
            }
        }
        Kind::SetFloat => {
            if !n.is_finite() || n.abs() > f64::from(f32::MAX) {
                return Err(format!("{value} does not fit C_SE_NC_1 (a 32-bit float)"));
            }
            Element::SetFloat {
                value: n as f32,
                select,
                ql: 0,
            }
        }
        Kind::BitsCommand => Element::BitsCommand(ranged(0.0, f64::from(u32::MAX))? as u32),
        _ => return Err(format!("{} is not a command", command.name())),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_are_judged_by_their_quality() {
        let q = |b| Quality(b);
        let float = |b| Element::Float {
            value: 12.5,
            quality: q(b),
        };
        assert_eq!(
            reading(&float(0), IecType::Real),
            Ok((Value::Real(12.5), None))
        );
        let (_, doubt) =
            reading(&float(Quality::NT | Quality::SB), IecType::Real).expect("a value");
        assert_eq!(
            doubt.as_deref(),
            Some("the station marks the value not topical (NT), substituted (SB)")
        );
        let e = reading(&float(Quality::IV), IecType::Real).expect_err("invalid");
        assert!(e.contains("12.5 invalid (IV)"), "{e}");
        let normalized = Element::Normalized {
            value: -16384,
            quality: q(0),
        };
        assert_eq!(
            reading(&normalized, IecType::Real),
            Ok((Value::Real(-0.5), None))
        );
        let scaled = Element::Scaled {
            value: -7,
            quality: q(0),
        };
        assert_eq!(reading(&scaled, IecType::Int), Ok((Value::Int(-7), None)));
        assert!(
            reading(&scaled, IecType::Uint)
                .expect_err("negative")
                .contains("sent -7")
        );
        let double = Element::Double {
            state: 0,
            quality: q(0),
        };
        assert!(
            reading(&double, IecType::Bool)
                .expect_err("indeterminate")
                .contains("indeterminate")
        );
    }

    #[test]
    fn commands_carry_what_was_asked_or_say_why_not() {
        use super::super::types::id;
        let c = command(TypeId(id::C_SE_NC_1), &Value::Real(2.5), true).expect("fits");
        assert_eq!(
            c,
            Element::SetFloat {
                value: 2.5,
                select: true,
                ql: 0
            }
        );
        let c = command(TypeId(id::C_SC_NA_1), &Value::Bool(true), false).expect("fits");
        assert_eq!(
            c,
            Element::SingleCommand {
                on: true,
                qu: 0,
                select: false
            }
        );
        let e = command(TypeId(id::C_SE_NB_1), &Value::Int(40000), false).expect_err("too big");
        assert!(e.contains("C_SE_NB_1"), "{e}");
        assert!(command(TypeId(id::C_SE_NA_1), &Value::Real(1.0), false).is_err());
        let c = command(TypeId(id::C_DC_NA_1), &Value::Bool(false), false).expect("fits");
        assert_eq!(
            c,
            Element::DoubleCommand {
                state: 1,
                qu: 0,
                select: false
            }
        );
    }
}

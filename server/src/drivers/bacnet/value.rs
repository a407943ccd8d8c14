//! BACnet values as the fields' IEC values and back: a property's application-tagged value
//! read as the field's type (a number that does not fit is an error naming both, never a
//! wrapped or truncated value), and a field's value written as the datatype the object's
//! property takes (REAL for analog objects, ENUMERATED inactive/active for binary ones,
//! Unsigned for multi-state ones). The status flags say whether a value is good.

use bacnet_types::enums::ObjectType;
use bacnet_types::primitives::PropertyValue;

use crate::codec::{IecType, Value};

/// A property's value as a field of type `ty`, or why not.
pub(crate) fn reading(ty: IecType, value: &PropertyValue) -> Result<Value, String> {
    let fits = |v: Result<Value, iogate_types::ValueError>| v.map_err(|e| e.to_string());
    match (ty, value) {
        (IecType::Bool, PropertyValue::Boolean(b)) => Ok(Value::Bool(*b)),
        (IecType::Bool, PropertyValue::Enumerated(n)) if *n <= 1 => Ok(Value::Bool(*n == 1)),
        (IecType::Bool, PropertyValue::Unsigned(n)) if *n <= 1 => Ok(Value::Bool(*n == 1)),
        (IecType::String, PropertyValue::CharacterString(s)) => Ok(Value::String(s.clone())),
        // A device's own NaN or infinity (a sensor fault) is its value, as for Modbus.
        (IecType::Real, PropertyValue::Real(x)) if !x.is_finite() => Ok(Value::Real(*x)),
        (IecType::Lreal, PropertyValue::Real(x)) if !x.is_finite() => {
            Ok(Value::LReal(f64::from(*x)))
        }
        (IecType::Lreal, PropertyValue::Double(x)) if !x.is_finite() => Ok(Value::LReal(*x)),
        (IecType::Real | IecType::Lreal, PropertyValue::Real(x)) => {
            fits(Value::from_real(ty, f64::from(*x)))
        }
        (IecType::Real | IecType::Lreal, PropertyValue::Double(x)) => {
            fits(Value::from_real(ty, *x))
        }
        (t, PropertyValue::Unsigned(n)) if t != IecType::Bool && t != IecType::String => {
            number(t, i128::from(*n))
        }
        (t, PropertyValue::Enumerated(n)) if t != IecType::Bool && t != IecType::String => {
            number(t, i128::from(*n))
        }
        (t, PropertyValue::Signed(n)) if t != IecType::Bool && t != IecType::String => {
            number(t, i128::from(*n))
        }
        (t, PropertyValue::Boolean(b)) if t != IecType::String => number(t, i128::from(*b)),
        (t, PropertyValue::BitString { unused_bits, data })
            if t.int_bits().is_some_and(|(_, signed)| !signed) =>
        {
            bits(t, *unused_bits, data)
        }
        (IecType::Real | IecType::Lreal, _)
        | (_, PropertyValue::Real(_) | PropertyValue::Double(_)) => {
            Err(format!("{ty} does not take the device's {}", kind(value)))
        }
        _ => Err(format!("{ty} does not take the device's {}", kind(value))),
    }
}

/// A BIT STRING as an unsigned field of type `ty`: the string's bit n (BACnet's first bit,
/// status-flags' in-alarm, is bit 0) is the number's bit n, so `status-flags` reads as
/// in-alarm 1, fault 2, overridden 4, out-of-service 8. A string longer than the type is
/// refused.
fn bits(ty: IecType, unused: u8, data: &[u8]) -> Result<Value, String> {
    let len = (data.len() * 8).saturating_sub(usize::from(unused.min(7)));
    let width = ty.int_bits().map_or(0, |(w, _)| usize::from(w));
    if len > width {
        return Err(format!(
            "{ty} does not take the device's BIT STRING of {len} bits"
        ));
    }
    let n = (0..len)
        .filter(|i| data[i / 8] & (0x80 >> (i % 8)) != 0)
        .fold(0u64, |n, i| n | 1 << i);
    number(ty, i128::from(n))
}

/// A whole number as a field of type `ty` (a real type takes it as a number).
fn number(ty: IecType, n: i128) -> Result<Value, String> {
    let v = match ty {
        IecType::Real | IecType::Lreal => Value::from_real(ty, n as f64),
        _ => Value::from_int(ty, n),
    };
    v.map_err(|e| format!("the device's {n}: {e}"))
}

/// What a value is, for messages.
pub(crate) fn kind(value: &PropertyValue) -> &'static str {
    match value {
        PropertyValue::Null => "NULL",
        PropertyValue::Boolean(_) => "BOOLEAN",
        PropertyValue::Unsigned(_) => "Unsigned",
        PropertyValue::Signed(_) => "INTEGER",
        PropertyValue::Real(_) => "REAL",
        PropertyValue::Double(_) => "Double",
        PropertyValue::OctetString(_) => "OCTET STRING",
        PropertyValue::CharacterString(_) => "CharacterString",
        PropertyValue::BitString { .. } => "BIT STRING",
        PropertyValue::Enumerated(_) => "ENUMERATED",
        PropertyValue::Date(_) => "Date",
        PropertyValue::Time(_) => "Time",
        _ => "value of another kind",
    }
}

/// A field's value as the datatype `object`'s present value takes.
pub(crate) fn writing(object: ObjectType, value: &Value) -> Result<PropertyValue, String> {
    let analog = [
        ObjectType::ANALOG_INPUT,
        ObjectType::ANALOG_OUTPUT,
        ObjectType::ANALOG_VALUE,
    ];
    let binary = [
        ObjectType::BINARY_INPUT,
        ObjectType::BINARY_OUTPUT,
        ObjectType::BINARY_VALUE,
    ];
    let multi = [
        ObjectType::MULTI_STATE_INPUT,
        ObjectType::MULTI_STATE_OUTPUT,
        ObjectType::MULTI_STATE_VALUE,
    ];
    if analog.contains(&object) {
        let x = value.as_f64().ok_or("an analog object takes a number")?;
        let r = x as f32;
        if !r.is_finite() {
            return Err(format!("{x} does not fit a REAL"));
        }
        return Ok(PropertyValue::Real(r));
    }
    if binary.contains(&object) {
        return match value {
            Value::Bool(b) => Ok(PropertyValue::Enumerated(u32::from(*b))),
            v => match v.as_i128() {
                Some(n @ 0..=1) => Ok(PropertyValue::Enumerated(n as u32)),
                _ => Err(format!(
                    "a binary object takes inactive (0) or active (1), not {v}"
                )),
            },
        };
    }
    if multi.contains(&object) {
        return match value.as_i128() {
            Some(n) if n >= 1 && n <= i128::from(u32::MAX) => Ok(PropertyValue::Unsigned(n as u64)),
            _ => Err(format!(
                "a multi-state object takes a state from 1, not {value}"
            )),
        };
    }
    if let Some(fixed) = fixed_datatype(object, value) {
        return fixed;
    }
    Ok(match value {
        Value::Bool(b) => PropertyValue::Boolean(*b),
        Value::Int(n) => match i32::try_from(*n) {
            Ok(n) => PropertyValue::Signed(n),
            Err(_) => return Err(format!("{n} does not fit a BACnet INTEGER")),
        },
        Value::UInt(n) => PropertyValue::Unsigned(*n),
        Value::Real(x) => PropertyValue::Real(*x),
        Value::LReal(x) => PropertyValue::Double(*x),
        Value::String(s) => PropertyValue::CharacterString(s.clone()),
        Value::Time(ms) => {
            PropertyValue::Unsigned(u64::try_from(*ms).map_err(|_| "a negative TIME".to_owned())?)
        }
    })
}

/// A value as the present value of an object whose datatype the standard fixes: an
/// integer value's INTEGER, a positive integer value's Unsigned, a large analog value's
/// Double, a character string value's CharacterString. `None` for other objects.
fn fixed_datatype(object: ObjectType, value: &Value) -> Option<Result<PropertyValue, String>> {
    let whole = |what: &str| format!("{what} takes a whole number, not {value}");
    Some(match object {
        ObjectType::INTEGER_VALUE => match value.as_i128().map(i32::try_from) {
            Some(Ok(n)) => Ok(PropertyValue::Signed(n)),
            Some(Err(_)) => Err(format!("{value} does not fit an integer value's INTEGER")),
            None => Err(whole("an integer value")),
        },
        ObjectType::POSITIVE_INTEGER_VALUE => match value.as_i128().map(u64::try_from) {
            Some(Ok(n)) => Ok(PropertyValue::Unsigned(n)),
            Some(Err(_)) => Err(format!(
                "a positive integer value takes 0 or more, not {value}"
            )),
            None => Err(whole("a positive integer value")),
        },
        ObjectType::LARGE_ANALOG_VALUE => match value.as_f64() {
            Some(x) if x.is_finite() => Ok(PropertyValue::Double(x)),
            _ => Err(format!(
                "a large analog value takes a finite number, not {value}"
            )),
        },
        ObjectType::CHARACTERSTRING_VALUE => match value {
            Value::String(s) => Ok(PropertyValue::CharacterString(s.clone())),
            _ => Err(format!(
                "a character string value takes a STRING, not {value}"
            )),
        },
        _ => return None,
    })
}

/// The status flags' fault and out-of-service bits (in-alarm 0, fault 1, overridden 2,
/// out-of-service 3, from the first byte's highest bit): why the value is not good, if it
/// is not.
pub(crate) fn not_good(flags: &PropertyValue) -> Option<&'static str> {
    let PropertyValue::BitString { data, unused_bits } = flags else {
        return Some("the device's status-flags are not a bit string");
    };
    if data.is_empty() || data.len() * 8 < 4 + usize::from(*unused_bits) {
        return Some("the device's status-flags hold fewer than their four bits");
    }
    let first = data.first().copied().unwrap_or(0);
    if first & 0x40 != 0 {
        return Some("the device flags it as in fault (status-flags)");
    }
    if first & 0x10 != 0 {
        return Some("the device flags it as out of service (status-flags)");
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bit_string_reads_as_its_bits_from_bit_0() {
        // status-flags: in-alarm and out-of-service set (1000 1000, 4 unused bits).
        let flags = PropertyValue::BitString {
            unused_bits: 4,
            data: vec![0b1001_0000],
        };
        assert_eq!(reading(IecType::Byte, &flags), Ok(Value::UInt(0b1001)));
        let fault = PropertyValue::BitString {
            unused_bits: 4,
            data: vec![0b0100_0000],
        };
        assert_eq!(reading(IecType::Uint, &fault), Ok(Value::UInt(2)));
        let long = PropertyValue::BitString {
            unused_bits: 0,
            data: vec![0xff, 0x01],
        };
        let why = reading(IecType::Byte, &long).expect_err("16 bits in a BYTE");
        assert!(why.contains("16 bits"), "{why}");
        assert!(
            reading(IecType::Int, &fault).is_err(),
            "a signed type is refused"
        );
    }

    #[test]
    fn a_value_that_does_not_fit_the_field_is_an_error_naming_both() {
        assert_eq!(
            reading(IecType::Real, &PropertyValue::Real(21.5)),
            Ok(Value::Real(21.5))
        );
        assert_eq!(
            reading(IecType::Bool, &PropertyValue::Enumerated(1)),
            Ok(Value::Bool(true))
        );
        assert!(reading(IecType::Bool, &PropertyValue::Enumerated(2)).is_err());
        assert_eq!(
            reading(IecType::Uint, &PropertyValue::Unsigned(3)),
            Ok(Value::UInt(3))
        );
        assert!(
            reading(IecType::Sint, &PropertyValue::Unsigned(300))
                .expect_err("refused")
                .contains("300")
        );
        let why = reading(IecType::Int, &PropertyValue::Real(1.5)).expect_err("refused");
        assert!(why.contains("INT") && why.contains("REAL"), "{why}");
    }

    #[test]
    fn values_are_written_as_the_object_takes_them() {
        assert_eq!(
            writing(ObjectType::ANALOG_OUTPUT, &Value::Real(42.0)),
            Ok(PropertyValue::Real(42.0))
        );
        assert_eq!(
            writing(ObjectType::BINARY_OUTPUT, &Value::Bool(true)),
            Ok(PropertyValue::Enumerated(1))
        );
        assert_eq!(
            writing(ObjectType::MULTI_STATE_VALUE, &Value::UInt(3)),
            Ok(PropertyValue::Unsigned(3))
        );
        assert!(writing(ObjectType::MULTI_STATE_VALUE, &Value::UInt(0)).is_err());
        assert!(writing(ObjectType::ANALOG_VALUE, &Value::LReal(1e300)).is_err());
    }

    #[test]
    fn a_devices_own_nan_is_its_value() {
        let nan = reading(IecType::Real, &PropertyValue::Real(f32::NAN)).expect("taken");
        assert!(matches!(nan, Value::Real(x) if x.is_nan()));
        assert!(reading(IecType::Int, &PropertyValue::Real(f32::NAN)).is_err());
    }

    #[test]
    fn fault_and_out_of_service_are_not_good() {
        let flags = |b: u8| PropertyValue::BitString {
            unused_bits: 4,
            data: vec![b],
        };
        assert_eq!(not_good(&flags(0x00)), None);
        assert_eq!(not_good(&flags(0x80)), None, "in alarm is still a value");
        assert!(not_good(&flags(0x40)).is_some_and(|w| w.contains("fault")));
        assert!(not_good(&flags(0x10)).is_some_and(|w| w.contains("out of service")));
        let empty = PropertyValue::BitString {
            unused_bits: 0,
            data: vec![],
        };
        assert!(not_good(&empty).is_some_and(|w| w.contains("four bits")));
        assert!(not_good(&PropertyValue::Unsigned(0)).is_some());
    }
}

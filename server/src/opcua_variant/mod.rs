//! IEC values as OPC UA variants and back, for the OPC UA server (`crate::api::opcua`) and
//! the OPC UA client driver alike: the built-in type of each IEC type, a value as its
//! field's variant, a variant as a value of a field's type (range-checked: a number that
//! does not fit is an error, never a wrapped or truncated one), and a data value's status
//! as the field's quality.

use std::time::SystemTime;

use opcua::types::{DataTypeId, DataValue, StatusCode, UAString, Variant, VariantScalarTypeId};

use crate::cache::FieldError;
use crate::codec::{IecType, Value};

/// The OPC UA built-in type of an IEC type.
pub(crate) fn data_type(ty: IecType) -> DataTypeId {
    match ty {
        IecType::Bool => DataTypeId::Boolean,
        IecType::Sint => DataTypeId::SByte,
        IecType::Int => DataTypeId::Int16,
        IecType::Dint => DataTypeId::Int32,
        IecType::Lint => DataTypeId::Int64,
        IecType::Usint | IecType::Byte => DataTypeId::Byte,
        IecType::Uint | IecType::Word => DataTypeId::UInt16,
        IecType::Udint | IecType::Dword => DataTypeId::UInt32,
        IecType::Ulint | IecType::Lword => DataTypeId::UInt64,
        IecType::Real => DataTypeId::Float,
        IecType::Lreal => DataTypeId::Double,
        IecType::String => DataTypeId::String,
        IecType::Time => DataTypeId::Duration,
    }
}

/// A value as the variant of its field's type.
pub(crate) fn variant(ty: IecType, value: &Value) -> Variant {
    match (ty, value) {
        (_, Value::Bool(b)) => Variant::Boolean(*b),
        (IecType::Sint, Value::Int(n)) => Variant::SByte(*n as i8),
        (IecType::Int, Value::Int(n)) => Variant::Int16(*n as i16),
        (IecType::Dint, Value::Int(n)) => Variant::Int32(*n as i32),
        (_, Value::Int(n)) => Variant::Int64(*n),
        (IecType::Usint | IecType::Byte, Value::UInt(n)) => Variant::Byte(*n as u8),
        (IecType::Uint | IecType::Word, Value::UInt(n)) => Variant::UInt16(*n as u16),
        (IecType::Udint | IecType::Dword, Value::UInt(n)) => Variant::UInt32(*n as u32),
        (_, Value::UInt(n)) => Variant::UInt64(*n),
        (_, Value::Real(x)) => Variant::Float(*x),
        (_, Value::LReal(x)) => Variant::Double(*x),
        (_, Value::String(s)) => Variant::String(UAString::from(s.as_str())),
        (_, Value::Time(ms)) => Variant::Double(*ms as f64),
    }
}

/// A client's variant as a value of `ty`: numbers of any numeric variant (checked against
/// the type's range by the service), booleans for BOOL, strings for STRING.
pub(crate) fn value_of(ty: IecType, v: &Variant) -> Result<Value, iogate_types::ValueError> {
    use iogate_types::ValueError;
    let wrong = |found| ValueError::WrongType { ty, found };
    match v {
        Variant::Boolean(b) if ty == IecType::Bool => Ok(Value::Bool(*b)),
        Variant::Boolean(_) => Err(wrong("a Boolean")),
        Variant::String(s) if ty == IecType::String => Ok(Value::String(s.as_ref().to_owned())),
        Variant::String(_) => Err(wrong("a String")),
        _ if ty == IecType::Bool || ty == IecType::String => Err(wrong(kind(v))),
        Variant::SByte(n) => Value::from_int(ty, i128::from(*n)),
        Variant::Byte(n) => Value::from_int(ty, i128::from(*n)),
        Variant::Int16(n) => Value::from_int(ty, i128::from(*n)),
        Variant::UInt16(n) => Value::from_int(ty, i128::from(*n)),
        Variant::Int32(n) => Value::from_int(ty, i128::from(*n)),
        Variant::UInt32(n) => Value::from_int(ty, i128::from(*n)),
        Variant::Int64(n) => Value::from_int(ty, i128::from(*n)),
        Variant::UInt64(n) => Value::from_int(ty, i128::from(*n)),
        Variant::Float(x) => Value::from_real(ty, f64::from(*x)),
        Variant::Double(x) => Value::from_real(ty, *x),
        Variant::Empty => Err(ValueError::Missing { ty }),
        _ => Err(wrong(kind(v))),
    }
}

/// What a variant is, as a refusal names it ("BOOL does not take a DateTime").
fn kind(v: &Variant) -> &'static str {
    match v {
        Variant::SByte(_)
        | Variant::Byte(_)
        | Variant::Int16(_)
        | Variant::UInt16(_)
        | Variant::Int32(_)
        | Variant::UInt32(_)
        | Variant::Int64(_)
        | Variant::UInt64(_)
        | Variant::Float(_)
        | Variant::Double(_) => "a number",
        Variant::Boolean(_) => "a Boolean",
        Variant::String(_) => "a String",
        Variant::DateTime(_) => "a DateTime",
        Variant::ByteString(_) => "a ByteString",
        Variant::Guid(_) => "a Guid",
        Variant::LocalizedText(_) => "a LocalizedText",
        Variant::QualifiedName(_) => "a QualifiedName",
        Variant::NodeId(_) | Variant::ExpandedNodeId(_) => "a NodeId",
        Variant::StatusCode(_) => "a StatusCode",
        Variant::ExtensionObject(_) => "a structure (ExtensionObject)",
        Variant::Array(_) => "an array",
        _ => "this kind of value",
    }
}

/// A variant read from a server as a value of the field's type: `value_of`, and a STRING
/// no longer than the field holds.
pub(crate) fn read_value(ty: IecType, max_len: usize, v: &Variant) -> Result<Value, String> {
    let value = match v {
        Variant::LocalizedText(t) if ty == IecType::String => {
            Ok(Value::String(t.text.as_ref().to_owned()))
        }
        _ => value_of(ty, v),
    }
    .map_err(|e| format!("the server's {} does not fit: {e}", type_name(v)))?;
    if let Value::String(s) = &value
        && s.len() > max_len
    {
        return Err(format!(
            "the server's string is {} bytes long; the field holds at most {max_len}",
            s.len()
        ));
    }
    Ok(value)
}

/// The variant's type, as OPC UA names it.
pub(crate) fn type_name(v: &Variant) -> String {
    match v.scalar_type_id() {
        Some(t) => format!("{t:?}"),
        None if matches!(v, Variant::Empty) => "empty value".to_owned(),
        None => "array".to_owned(),
    }
}

/// A data value's status and value as a field's reading: Good is the value; Uncertain the
/// value with the status as its doubt (stale, with the reason); Bad the status's name as
/// the field's error. With the server's source timestamp, where it gave one.
pub(crate) struct Reading {
    pub(crate) value: Result<Value, FieldError>,
    pub(crate) doubt: Option<FieldError>,
    pub(crate) at: Option<SystemTime>,
}

pub(crate) fn reading(ty: IecType, max_len: usize, dv: &DataValue) -> Reading {
    let status = dv.status.unwrap_or(StatusCode::Good);
    let at = dv
        .source_timestamp
        .as_ref()
        .map(|t| SystemTime::from(t.as_chrono()));
    let value = if status.is_bad() {
        Err(FieldError::Device(status.to_string()))
    } else {
        let v = dv.value.as_ref().unwrap_or(&Variant::Empty);
        read_value(ty, max_len, v).map_err(FieldError::Device)
    };
    let doubt = status
        .is_uncertain()
        .then(|| FieldError::Device(status.to_string()));
    Reading { value, doubt, at }
}

/// A value to write as the variant type the server's variable holds (learned from its
/// values), checked against that type's range; else as the field's own type's variant.
pub(crate) fn write_variant(
    ty: IecType,
    value: &Value,
    server: Option<VariantScalarTypeId>,
) -> Result<Variant, String> {
    use VariantScalarTypeId as T;
    let Some(target) = server else {
        return Ok(variant(ty, value));
    };
    let int = match value {
        Value::Int(n) => Some(i128::from(*n)),
        Value::UInt(n) => Some(i128::from(*n)),
        Value::Time(ms) => Some(i128::from(*ms)),
        _ => None,
    };
    let float = value.as_f64();
    let out_of_range = || format!("{value} does not fit the server's {target:?}");
    let fit = |n: i128| -> Result<Variant, String> {
        Ok(match target {
            T::SByte => Variant::SByte(i8::try_from(n).map_err(|_| out_of_range())?),
            T::Byte => Variant::Byte(u8::try_from(n).map_err(|_| out_of_range())?),
            T::Int16 => Variant::Int16(i16::try_from(n).map_err(|_| out_of_range())?),
            T::UInt16 => Variant::UInt16(u16::try_from(n).map_err(|_| out_of_range())?),
            T::Int32 => Variant::Int32(i32::try_from(n).map_err(|_| out_of_range())?),
            T::UInt32 => Variant::UInt32(u32::try_from(n).map_err(|_| out_of_range())?),
            T::Int64 => Variant::Int64(i64::try_from(n).map_err(|_| out_of_range())?),
            T::UInt64 => Variant::UInt64(u64::try_from(n).map_err(|_| out_of_range())?),
            T::Float => Variant::Float(n as f32),
            T::Double => Variant::Double(n as f64),
            _ => return Err(format!("the server's {target:?} does not take {value}")),
        })
    };
    match (value, target) {
        (Value::Bool(b), T::Boolean) => Ok(Variant::Boolean(*b)),
        (Value::String(s), T::String) => Ok(Variant::String(UAString::from(s.as_str()))),
        (Value::Real(x), T::Float) => Ok(Variant::Float(*x)),
        (Value::Real(_) | Value::LReal(_), T::Double) => Ok(Variant::Double(float.unwrap_or(0.0))),
        (Value::LReal(x), T::Float) if x.abs() <= f64::from(f32::MAX) => {
            Ok(Variant::Float(*x as f32))
        }
        (Value::Real(_) | Value::LReal(_), _) => match float {
            Some(x) if x.is_finite() && x.fract() == 0.0 && x.abs() < 9.0e18 => fit(x as i128),
            _ => Err(out_of_range()),
        },
        _ => match int {
            Some(n) => fit(n),
            None => Err(format!("the server's {target:?} does not take {value}")),
        },
    }
}

#[cfg(test)]
mod tests;

//! A value as a Modbus master sees it at a location: big-endian, high word first,
//! whatever the device's own byte order.

use iogate_types::Size;

use crate::codec::{ByteOrder, CodecError, Encoding, IecType, Value};

/// How a field's value sits in a location's bit or registers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Repr {
    Bit,
    Int16,
    Uint16,
    /// A REAL/LREAL on one device register: the raw register, as the device holds it.
    Raw16,
    Int32,
    Uint32,
    Real32,
    Int64,
    Uint64,
    Real64,
}

impl Repr {
    /// How a value of `ty` fits a location of `size`; `one_register` says the field is a
    /// REAL/LREAL stored on a single device register (scaled integer).
    pub(crate) fn of(ty: IecType, size: Size, one_register: bool) -> Option<Repr> {
        use IecType as T;
        Some(match (size, ty) {
            (Size::Bit, T::Bool) => Repr::Bit,
            (Size::Word, T::Int | T::Sint) => Repr::Int16,
            (Size::Word, T::Uint | T::Word | T::Usint | T::Byte) => Repr::Uint16,
            (Size::Word, T::Real | T::Lreal) if one_register => Repr::Raw16,
            (Size::Double, T::Dint | T::Time) => Repr::Int32,
            (Size::Double, T::Udint | T::Dword) => Repr::Uint32,
            (Size::Double, T::Real) => Repr::Real32,
            (Size::Long, T::Lint | T::Time) => Repr::Int64,
            (Size::Long, T::Ulint | T::Lword) => Repr::Uint64,
            (Size::Long, T::Lreal) => Repr::Real64,
            _ => return None,
        })
    }

    /// The raw register as the device holds it, for a scaled REAL on one register.
    fn raw_encoding(encoding: Option<&Encoding>) -> Option<Encoding> {
        encoding.map(|e| Encoding {
            order: ByteOrder::BigEndian,
            ..*e
        })
    }

    /// The registers showing `value` (zeros when there is none yet), or `None` when the
    /// value does not fit the location (a TIME past ±2147483647 ms at `%MD`): such a value
    /// is refused, never clamped into a different number.
    pub(crate) fn registers(
        self,
        value: Option<&Value>,
        encoding: Option<&Encoding>,
    ) -> Option<Vec<u16>> {
        let int = |min: i128, max: i128| {
            let n = value.and_then(Value::as_i128).unwrap_or(0);
            (min..=max).contains(&n).then_some(n)
        };
        let real = || value.and_then(Value::as_f64).unwrap_or(0.0);
        let bool_as_int = || i128::from(matches!(value, Some(Value::Bool(true))));
        Some(match self {
            Repr::Bit => vec![bool_as_int() as u16],
            Repr::Int16 => vec![int(i16::MIN.into(), i16::MAX.into())? as i16 as u16],
            Repr::Uint16 => vec![int(0, u16::MAX.into())? as u16],
            Repr::Raw16 => match value {
                None => vec![0],
                Some(v) => Self::raw_encoding(encoding)
                    .and_then(|e| e.encode(v).ok())
                    .filter(|r| r.len() == 1)?,
            },
            Repr::Int32 => words(&(int(i32::MIN.into(), i32::MAX.into())? as i32).to_be_bytes()),
            Repr::Uint32 => words(&(int(0, u32::MAX.into())? as u32).to_be_bytes()),
            Repr::Real32 => words(&(real() as f32).to_be_bytes()),
            Repr::Int64 => words(&(int(i64::MIN.into(), i64::MAX.into())? as i64).to_be_bytes()),
            Repr::Uint64 => words(&(int(0, u64::MAX.into())? as u64).to_be_bytes()),
            Repr::Real64 => words(&real().to_be_bytes()),
        })
    }

    /// The value of type `ty` a master's registers (or bit, as 0/1) stand for, or why they
    /// do not fit the field.
    pub(crate) fn value(
        self,
        regs: &[u16],
        ty: IecType,
        encoding: Option<&Encoding>,
    ) -> Result<Value, CodecError> {
        let bytes = crate::codec::register_bytes(regs);
        let int = |n: i128| Ok(Value::from_int(ty, n)?);
        let real = |x: f64| Ok(Value::from_real(ty, x)?);
        let get = |n: usize| -> Result<&[u8], CodecError> {
            bytes.get(..n).ok_or(CodecError::WrongLength {
                expected: n.div_ceil(2),
                found: regs.len(),
            })
        };
        match self {
            Repr::Bit => Ok(Value::Bool(regs.first().is_some_and(|&r| r != 0))),
            Repr::Int16 => int(i128::from(i16::from_be_bytes(arr(get(2)?)))),
            Repr::Uint16 => int(i128::from(u16::from_be_bytes(arr(get(2)?)))),
            Repr::Raw16 => Self::raw_encoding(encoding)
                .ok_or(CodecError::WrongType {
                    ty,
                    found: "a raw register without the field's encoding",
                })?
                .decode(&regs[..1.min(regs.len())]),
            Repr::Int32 => int(i128::from(i32::from_be_bytes(arr(get(4)?)))),
            Repr::Uint32 => int(i128::from(u32::from_be_bytes(arr(get(4)?)))),
            Repr::Real32 => real(f64::from(f32::from_be_bytes(arr(get(4)?)))),
            Repr::Int64 => int(i128::from(i64::from_be_bytes(arr(get(8)?)))),
            Repr::Uint64 => int(i128::from(u64::from_be_bytes(arr(get(8)?)))),
            Repr::Real64 => real(f64::from_be_bytes(arr(get(8)?))),
        }
    }
}

fn words(bytes: &[u8]) -> Vec<u16> {
    crate::codec::bytes_registers(bytes)
}

fn arr<const N: usize>(bytes: &[u8]) -> [u8; N] {
    let mut out = [0u8; N];
    out.copy_from_slice(&bytes[..N]);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_are_served_big_endian_high_word_first() {
        assert_eq!(
            Repr::Real32.registers(Some(&Value::Real(1.0)), None),
            Some(vec![0x3F80, 0x0000])
        );
        assert_eq!(
            Repr::Int32.registers(Some(&Value::Int(-2)), None),
            Some(vec![0xFFFF, 0xFFFE])
        );
        assert_eq!(
            Repr::Uint64.registers(Some(&Value::UInt(0x0102_0304_0506_0708)), None),
            Some(vec![0x0102, 0x0304, 0x0506, 0x0708])
        );
        assert_eq!(
            Repr::Int16.registers(Some(&Value::Int(-5)), None),
            Some(vec![0xFFFB])
        );
        assert_eq!(Repr::Int16.registers(None, None), Some(vec![0]));
    }

    #[test]
    fn a_time_that_does_not_fit_a_double_word_is_refused_not_clamped() {
        let month = Value::Time(30 * 24 * 3_600_000);
        assert_eq!(Repr::Int32.registers(Some(&month), None), None);
        assert_eq!(
            Repr::Int64.registers(Some(&month), None),
            Some(vec![0, 0, 0x9A7E, 0xC800])
        );
        assert_eq!(
            Repr::Int32.registers(Some(&Value::Time(i64::from(i32::MAX))), None),
            Some(vec![0x7FFF, 0xFFFF])
        );
    }

    #[test]
    fn written_registers_must_fit_the_field() {
        assert_eq!(
            Repr::Int16.value(&[0xFFFB], IecType::Sint, None),
            Ok(Value::Int(-5))
        );
        assert!(Repr::Uint16.value(&[300], IecType::Usint, None).is_err());
        assert_eq!(
            Repr::Real32.value(&[0x41AC, 0x0000], IecType::Real, None),
            Ok(Value::Real(21.5))
        );
        assert!(
            Repr::Real32
                .value(&[0x7FC0, 0x0000], IecType::Real, None)
                .is_err(),
            "NaN"
        );
        assert_eq!(
            Repr::Int32.value(&[0x0001, 0x0000], IecType::Time, None),
            Ok(Value::Time(65536))
        );
    }
}

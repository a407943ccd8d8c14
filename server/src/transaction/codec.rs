//! The bytes of raw transactions: values packed for the write block (source document 002)
//! and read values interpreted for the read block (source document 004).
//!
//! Choices where the documents are silent (README, "Raw transactions"):
//! - uint8 and int8 values take one register each (the low byte, the high byte 0 or the
//!   sign), so FC06 writes one and FC16 one per register; int32 and float take two.
//! - Bits read with FC01/02 are numbered as Modbus packs them, coil `address + i` in bit `i`
//!   of the response's bytes. With `LittleEndian` (the default) bit `i` of the value is coil
//!   `address + i`; the other orders reorder the response's bytes (padded to 2 or 4) the way
//!   they reorder register bytes (BigEndian: first byte most significant; SwapBytes: the
//!   bytes of each pair swapped; SwapWords: the pairs swapped), then keep `bitCount` bits.

use super::spec::{ReadPlan, ValueType, WriteType};
use crate::link::frame::{Response, pack_bits};

/// One value's bytes, most significant first, before the byte order.
pub(super) fn value_bytes(ty: WriteType, v: &serde_json::Value) -> Option<Vec<u8>> {
    let n = v.as_number()?;
    let int = || -> Option<i64> {
        n.as_i64()
            .or_else(|| n.as_f64().filter(|x| x.fract() == 0.0).map(|x| x as i64))
    };
    Some(match ty {
        WriteType::Uint8 => u16::from(u8::try_from(int()?).ok()?).to_be_bytes().to_vec(),
        WriteType::Int8 => (i16::from(i8::try_from(int()?).ok()?))
            .to_be_bytes()
            .to_vec(),
        WriteType::Uint16 => u16::try_from(int()?).ok()?.to_be_bytes().to_vec(),
        WriteType::Int16 => i16::try_from(int()?).ok()?.to_be_bytes().to_vec(),
        // int32: IEEE-754 when the value is a real number, else a 32-bit integer.
        WriteType::Int32 if n.is_f64() && n.as_f64()?.fract() != 0.0 => {
            (n.as_f64()? as f32).to_be_bytes().to_vec()
        }
        WriteType::Int32 => i32::try_from(int()?).ok()?.to_be_bytes().to_vec(),
        WriteType::Float => {
            let x = n.as_f64()?;
            if !x.is_finite() || x.abs() > f64::from(f32::MAX) {
                return None;
            }
            (x as f32).to_be_bytes().to_vec()
        }
    })
}

/// Why a response could not be read as the configured value.
#[derive(Debug, Clone, PartialEq)]
pub struct ParseFailed;

/// The read block's value: the raw number, divided by the divisor, truncated to the
/// precision.
pub fn read_value(plan: &ReadPlan, response: &Response) -> Result<f64, ParseFailed> {
    let raw = match (response, plan.bits, plan.value_type) {
        (Response::Bits(bits), Some(n), _) => {
            let bits = bits.get(..usize::from(n)).ok_or(ParseFailed)?;
            let mut bytes = pack_bits(bits);
            if n <= 8 {
                f64::from(bytes[0])
            } else {
                bytes.resize(if n <= 16 { 2 } else { 4 }, 0);
                plan.order.reorder(&mut bytes);
                let value = bytes.iter().fold(0u64, |acc, b| (acc << 8) | u64::from(*b));
                (value & ((1u64 << n) - 1)) as f64
            }
        }
        (Response::Registers(regs), _, Some(ty)) => {
            let mut bytes: Vec<u8> = regs
                .get(..usize::from(ty.registers()))
                .ok_or(ParseFailed)?
                .iter()
                .flat_map(|r| r.to_be_bytes())
                .collect();
            plan.order.reorder(&mut bytes);
            match ty {
                ValueType::Signed16 => f64::from(i16::from_be_bytes([bytes[0], bytes[1]])),
                ValueType::Unsigned16 => f64::from(u16::from_be_bytes([bytes[0], bytes[1]])),
                ValueType::Signed32 => {
                    f64::from(i32::from_be_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]))
                }
                ValueType::Unsigned32 => {
                    f64::from(u32::from_be_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]))
                }
                ValueType::Float => {
                    let x = f32::from_be_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]);
                    if !x.is_finite() {
                        return Err(ParseFailed);
                    }
                    f64::from(x)
                }
            }
        }
        _ => return Err(ParseFailed),
    };
    let divided = if plan.divisor > 1 {
        raw / f64::from(plan.divisor)
    } else {
        raw
    };
    Ok(truncate(divided, plan.precision))
}

/// Keeps `digits` decimals, dropping the rest (never rounding up a digit). The value is
/// first rounded to 1e-6 of its last kept digit, so binary floating point's 0.29 =
/// 0.28999999999999998 keeps 0.29 and 23.987 keeps 23.98.
pub fn truncate(x: f64, digits: u8) -> f64 {
    let scale = 10f64.powi(i32::from(digits));
    let scaled = ((x * scale) * 1e6).round() / 1e6;
    let kept = scaled.trunc() / scale;
    if kept == 0.0 { 0.0 } else { kept }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::ByteOrder;
    use crate::link::frame::Function;

    fn read(bits: Option<u8>, ty: Option<ValueType>, divisor: u32, precision: u8) -> ReadPlan {
        ReadPlan {
            function: Function::ReadHoldingRegisters,
            slave: 1,
            address: 0,
            bits,
            value_type: ty,
            divisor,
            precision,
            order: ByteOrder::BigEndian,
        }
    }

    #[test]
    fn the_read_blocks_examples_hold() {
        // Bits giving 13.
        let plan = ReadPlan {
            order: ByteOrder::LittleEndian,
            ..read(Some(4), None, 1, 0)
        };
        assert_eq!(
            read_value(&plan, &Response::Bits(vec![true, false, true, true])),
            Ok(13.0)
        );
        // 215 / 10 = 21.5.
        let plan = read(None, Some(ValueType::Signed16), 10, 1);
        assert_eq!(read_value(&plan, &Response::Registers(vec![215])), Ok(21.5));
        // 23.987 with precision 2 is 23.98, truncated.
        let bits = 23.987f32.to_bits();
        let plan = read(None, Some(ValueType::Float), 1, 2);
        assert_eq!(
            read_value(
                &plan,
                &Response::Registers(vec![(bits >> 16) as u16, bits as u16])
            ),
            Ok(23.98)
        );
    }

    #[test]
    fn truncation_never_rounds_and_survives_binary_fractions() {
        assert_eq!(truncate(0.29, 2), 0.29);
        assert_eq!(truncate(23.987, 2), 23.98);
        assert_eq!(truncate(-1.239, 2), -1.23);
        assert_eq!(truncate(9.999, 0), 9.0);
        assert_eq!(truncate(1.0005, 3), 1.0);
    }

    #[test]
    fn the_write_blocks_byte_orders_lay_out_0x01020304_as_documented() {
        let lay = |order| {
            let mut b = 0x0102_0304i32.to_be_bytes().to_vec();
            parse(order).reorder(&mut b);
            b
        };
        fn parse(o: &str) -> ByteOrder {
            super::super::spec::parse_byte_order(o).expect(o)
        }
        assert_eq!(lay("Little-endian"), [4, 3, 2, 1]);
        assert_eq!(lay("Big-endian"), [1, 2, 3, 4]);
        assert_eq!(lay("Big-endian (2 bytes)"), [2, 1, 4, 3]);
    }
}

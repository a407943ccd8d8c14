//! The bytes of raw transactions: values packed for the write block (source document 002)
//! and read values interpreted for the read block (source document 004).
//!
//! Choices where the documents are silent (docs/transactions.md):
//! - uint8 and int8 values take one register each (the low byte, the high byte 0 or the
//!   sign), so FC06 writes one and FC16 one per register; int32 and float take two.
//! - `int32` is always a signed 32-bit integer (a value with a fraction is refused) and
//!   `float` always IEEE-754. The document's combined `int32/float` decides by the form of
//!   the number it is given, never by its value: a JSON or YAML number written with a point
//!   or an exponent (`12.0`, `1e3`) is a float and goes out as IEEE-754, one written as an
//!   integer (`12`) as a 32-bit integer. gRPC's values are doubles: floats.
//! - Bits read with FC01/02 ([`bits_value`]): the response's bytes as Modbus packs them
//!   (the last one partial), ordered like register bytes, concatenated; with `LittleEndian`
//!   (the default) bit `i` of the value is coil `address + i`.
//! - Precision truncates the decimal digits the device meant: the exact quotient of an
//!   integer, the shortest decimal form of a FLOAT (the f32 as read, not its binary
//!   expansion widened to f64), so 0.29 with two decimals stays 0.29.

use super::spec::{ReadPlan, ValueType, WriteType};
use crate::codec::ByteOrder;
use crate::link::frame::Response;

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
        WriteType::Int32 => i32::try_from(int()?).ok()?.to_be_bytes().to_vec(),
        // The form decides, never the value: `12` an integer, `12.0` a float.
        WriteType::Int32OrFloat if !n.is_f64() => {
            i32::try_from(int()?).ok()?.to_be_bytes().to_vec()
        }
        WriteType::Float | WriteType::Int32OrFloat => {
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
pub(crate) struct ParseFailed;

/// A number as the device meant it: `digits × 10^exp`, with its sign. Integers and bit
/// patterns are exact; a FLOAT is the shortest decimal that reads back as the f32 the
/// device sent (0.29, not 0.28999999165534973), because that is the number it meant.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Decimal {
    negative: bool,
    digits: u128,
    exp: i32,
}

impl Decimal {
    fn int(n: i64) -> Decimal {
        Decimal {
            negative: n < 0,
            digits: u128::from(n.unsigned_abs()),
            exp: 0,
        }
    }

    /// The shortest decimal form of `x` (finite), as Rust's float formatting writes it
    /// (the fewest digits that parse back to the same f32).
    fn shortest(x: f32) -> Option<Decimal> {
        let text = format!("{x:e}");
        let (mantissa, exp) = text.split_once('e')?;
        let exp: i32 = exp.parse().ok()?;
        let negative = mantissa.starts_with('-');
        let mantissa = mantissa.trim_start_matches('-');
        let fraction = mantissa.split_once('.').map_or(0, |(_, f)| f.len());
        let digits: u128 = mantissa.replace('.', "").parse().ok()?;
        Some(Decimal {
            negative: negative && digits != 0,
            digits,
            exp: exp - i32::try_from(fraction).ok()?,
        })
    }

    /// This number divided by `divisor`, with `precision` decimals kept and the rest dropped
    /// (never rounded), computed on the decimal digits so no binary fraction can take a
    /// digit away.
    fn truncated(self, divisor: u32, precision: u8) -> f64 {
        let divisor = u128::from(divisor.max(1));
        let shift = self.exp + i32::from(precision);
        let pow = |n: i32| 10u128.checked_pow(n.unsigned_abs());
        let kept: Option<u128> = if shift >= 0 {
            pow(shift)
                .and_then(|p| self.digits.checked_mul(p))
                .map(|n| n / divisor)
        } else {
            // A denominator past u128 leaves nothing of the digits (at most 39 of them).
            Some(
                pow(shift)
                    .and_then(|p| p.checked_mul(divisor))
                    .map_or(0, |d| self.digits / d),
            )
        };
        let magnitude = match kept {
            // The f64 nearest to the kept decimal, so its shortest form is that decimal.
            Some(k) => format!("{k}e-{precision}").parse().unwrap_or(f64::MAX),
            // Past 10^38: no decimal is left to keep at f64's resolution.
            None => {
                let whole: f64 = format!("{}e{}", self.digits, self.exp)
                    .parse()
                    .unwrap_or(f64::MAX);
                whole / divisor as f64
            }
        };
        if self.negative && magnitude != 0.0 {
            -magnitude
        } else {
            magnitude
        }
    }
}

/// The bits of an FC01/02 read as one non-negative number (source document 004), without
/// losing or inventing a bit: the bits as bytes as Modbus packs them (coil `address + 8k + j`
/// in bit `j` of byte `k`), the last byte holding only the bits left over; then the bytes are
/// ordered as register bytes are (pairs of bytes are words; `BigEndian` keeps them in order,
/// first most significant; `LittleEndian` reverses them all; `SwapBytes` swaps the two bytes
/// of each word; `SwapWords` reverses the order of the words) and concatenated, each byte
/// giving its own number of bits. So with `LittleEndian` bit `i` of the value is coil
/// `address + i` for any count; up to 8 bits the order does not matter.
fn bits_value(bits: &[bool], order: ByteOrder) -> u64 {
    let bytes: Vec<(u64, u32)> = bits
        .chunks(8)
        .map(|chunk| {
            let byte = chunk
                .iter()
                .enumerate()
                .fold(0u64, |acc, (j, &b)| acc | (u64::from(b) << j));
            (byte, chunk.len() as u32)
        })
        .collect();
    let ordered: Vec<(u64, u32)> = match order {
        ByteOrder::BigEndian => bytes,
        ByteOrder::LittleEndian => bytes.into_iter().rev().collect(),
        ByteOrder::SwapBytes => bytes
            .chunks(2)
            .flat_map(|word| word.iter().rev().copied())
            .collect(),
        ByteOrder::SwapWords => bytes.chunks(2).rev().flatten().copied().collect(),
    };
    ordered
        .into_iter()
        .fold(0u64, |acc, (byte, width)| (acc << width) | byte)
}

/// The read block's value: the raw number, divided by the divisor, truncated to the
/// precision.
pub(crate) fn read_value(plan: &ReadPlan, response: &Response) -> Result<f64, ParseFailed> {
    let raw = match (response, plan.bits, plan.value_type) {
        (Response::Bits(bits), Some(n), _) => {
            let bits = bits.get(..usize::from(n)).ok_or(ParseFailed)?;
            let value = bits_value(bits, plan.order);
            Decimal::int(i64::try_from(value).map_err(|_| ParseFailed)?)
        }
        (Response::Registers(regs), _, Some(ty)) => {
            let mut bytes = crate::codec::register_bytes(
                regs.get(..usize::from(ty.registers())).ok_or(ParseFailed)?,
            );
            plan.order.reorder(&mut bytes);
            let four = || [bytes[0], bytes[1], bytes[2], bytes[3]];
            match ty {
                ValueType::Signed16 => {
                    Decimal::int(i16::from_be_bytes([bytes[0], bytes[1]]).into())
                }
                ValueType::Unsigned16 => {
                    Decimal::int(u16::from_be_bytes([bytes[0], bytes[1]]).into())
                }
                ValueType::Signed32 => Decimal::int(i32::from_be_bytes(four()).into()),
                ValueType::Unsigned32 => Decimal::int(u32::from_be_bytes(four()).into()),
                ValueType::Float => {
                    let x = f32::from_be_bytes(four());
                    if !x.is_finite() {
                        return Err(ParseFailed);
                    }
                    Decimal::shortest(x).ok_or(ParseFailed)?
                }
            }
        }
        _ => return Err(ParseFailed),
    };
    Ok(raw.truncated(plan.divisor, plan.precision))
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

    fn float(x: f32, divisor: u32, precision: u8) -> f64 {
        let bits = x.to_bits();
        let plan = read(None, Some(ValueType::Float), divisor, precision);
        read_value(
            &plan,
            &Response::Registers(vec![(bits >> 16) as u16, bits as u16]),
        )
        .expect("a finite float")
    }

    #[test]
    fn a_float_keeps_the_digits_the_device_meant() {
        assert_eq!(float(0.29, 1, 2), 0.29);
        assert_eq!(float(100.1, 1, 1), 100.1);
        assert_eq!(float(21.57, 1, 3), 21.57);
        assert_eq!(float(23.987, 1, 3), 23.987);
        assert_eq!(float(23.987, 1, 2), 23.98);
        assert_eq!(float(-1.239, 1, 2), -1.23);
        assert_eq!(float(9.999, 1, 0), 9.0);
        assert_eq!(float(1.0005, 1, 3), 1.0);
        assert_eq!(float(2.9, 10, 3), 0.29);
        assert_eq!(float(-0.0001, 1, 3), 0.0);
        assert_eq!(float(f32::MAX, 1, 3), 3.4028235e38);
        assert_eq!(float(f32::MIN_POSITIVE, 1, 3), 0.0);
    }

    #[test]
    fn integers_divided_keep_their_exact_decimals() {
        let plan = read(None, Some(ValueType::Unsigned16), 100, 2);
        assert_eq!(read_value(&plan, &Response::Registers(vec![29])), Ok(0.29));
        let plan = read(None, Some(ValueType::Signed32), 1000, 3);
        assert_eq!(
            read_value(&plan, &Response::Registers(vec![0xFFFF, 0xFFFF - 2_200])),
            Ok(-2.201)
        );
        let plan = read(None, Some(ValueType::Unsigned32), 3, 3);
        assert_eq!(
            read_value(&plan, &Response::Registers(vec![0, 2])),
            Ok(0.666)
        );
        let plan = read(None, Some(ValueType::Unsigned32), 4_294_967_295, 3);
        assert_eq!(
            read_value(&plan, &Response::Registers(vec![0xFFFF, 0xFFFF])),
            Ok(1.0)
        );
    }

    /// The shortest form of `x`, cut (not rounded) after `precision` decimals.
    fn cut(x: f32, precision: usize) -> f64 {
        let text = format!("{x}");
        let text = match text.split_once('.') {
            Some((int, frac)) => format!("{int}.{}", &frac[..frac.len().min(precision)]),
            None => text,
        };
        let v: f64 = text.parse().expect("a number");
        if v == 0.0 { 0.0 } else { v }
    }

    proptest::proptest! {
        #[test]
        fn every_float_with_few_enough_decimals_is_read_as_its_shortest_form(
            units in -100_000_000i64..100_000_000,
            precision in 0u8..=3,
        ) {
            let x = (units as f64 / 10f64.powi(i32::from(precision))) as f32;
            let shortest = format!("{x}");
            let decimals = shortest.split_once('.').map_or(0, |(_, f)| f.len());
            proptest::prop_assume!(decimals <= usize::from(precision));
            let expected: f64 = shortest.parse().expect("a number");
            proptest::prop_assert_eq!(float(x, 1, precision), expected);
        }

        #[test]
        fn any_float_is_its_shortest_form_cut_after_precision_decimals(
            bits in proptest::num::u32::ANY,
            precision in 0u8..=3,
        ) {
            let x = f32::from_bits(bits);
            proptest::prop_assume!(x.is_finite());
            proptest::prop_assert_eq!(float(x, 1, precision), cut(x, usize::from(precision)));
        }

        #[test]
        fn an_integer_divided_is_the_exact_quotient_cut(
            raw in proptest::num::u32::ANY,
            divisor in 1u32..=100_000,
            precision in 0u8..=3,
        ) {
            let plan = read(None, Some(ValueType::Unsigned32), divisor, precision);
            let got = read_value(&plan, &Response::Registers(vec![(raw >> 16) as u16, raw as u16]));
            let scale = 10u128.pow(u32::from(precision));
            let kept = u128::from(raw) * scale / u128::from(divisor);
            let expected: f64 = format!("{kept}e-{precision}").parse().expect("a number");
            proptest::prop_assert_eq!(got, Ok(expected));
        }
    }

    fn coils(n: u8, value: u64) -> Vec<bool> {
        (0..n).map(|i| value >> i & 1 == 1).collect()
    }

    fn bits(n: u8, order: ByteOrder, coils: Vec<bool>) -> u64 {
        let plan = ReadPlan {
            order,
            ..read(Some(n), None, 1, 0)
        };
        read_value(&plan, &Response::Bits(coils)).expect("bits") as u64
    }

    #[test]
    fn bits_keep_every_bit_the_device_sent_in_every_order() {
        // 12 coils: byte 0 = 0xD4, byte 1 = 0x3 (four bits).
        let c = coils(12, 0x3D4);
        assert_eq!(bits(12, ByteOrder::LittleEndian, c.clone()), 0x3D4);
        assert_eq!(bits(12, ByteOrder::BigEndian, c.clone()), 0xD43);
        assert_eq!(bits(12, ByteOrder::SwapBytes, c.clone()), 0x3D4);
        assert_eq!(bits(12, ByteOrder::SwapWords, c), 0xD43);
        // 20 coils: bytes 0x21, 0x43, 0x5 (four bits).
        let c = coils(20, 0x5_4321);
        assert_eq!(bits(20, ByteOrder::LittleEndian, c.clone()), 0x5_4321);
        assert_eq!(bits(20, ByteOrder::BigEndian, c.clone()), 0x2_1435);
        assert_eq!(bits(20, ByteOrder::SwapBytes, c.clone()), 0x4_3215);
        assert_eq!(bits(20, ByteOrder::SwapWords, c), 0x5_2143);
        // 32 coils: as four register bytes.
        let c = coils(32, 0x4433_2211);
        assert_eq!(bits(32, ByteOrder::BigEndian, c.clone()), 0x1122_3344);
        assert_eq!(bits(32, ByteOrder::SwapBytes, c.clone()), 0x2211_4433);
        assert_eq!(bits(32, ByteOrder::SwapWords, c), 0x3344_1122);
    }

    proptest::proptest! {
        #[test]
        fn no_bit_is_lost_or_invented_for_any_count_or_order(
            n in 1u8..=32,
            value in proptest::num::u64::ANY,
            order in proptest::sample::select(vec![
                ByteOrder::BigEndian, ByteOrder::LittleEndian,
                ByteOrder::SwapBytes, ByteOrder::SwapWords,
            ]),
        ) {
            let value = value & ((1u64 << n) - 1);
            let got = bits(n, order, coils(n, value));
            // As many bits set, none past the count, and the same bits for any order
            // when the count is at most 8.
            proptest::prop_assert_eq!(got.count_ones(), value.count_ones());
            proptest::prop_assert!(got < 1u64 << n);
            if n <= 8 || order == ByteOrder::LittleEndian {
                proptest::prop_assert_eq!(got, value);
            }
        }
    }

    fn written(ty: &str, json: &str) -> Option<Vec<u8>> {
        let v: serde_json::Value = serde_json::from_str(json).expect("json");
        value_bytes(WriteType::parse(ty).expect(ty), &v)
    }

    #[test]
    fn the_type_decides_the_encoding_never_the_value() {
        assert_eq!(written("int32", "12"), Some(vec![0, 0, 0, 12]));
        assert_eq!(written("int32", "12.0"), Some(vec![0, 0, 0, 12]));
        assert_eq!(written("int32", "-2"), Some(vec![0xFF, 0xFF, 0xFF, 0xFE]));
        assert_eq!(written("int32", "12.6"), None, "a fraction is refused");
        assert_eq!(written("int32", "2147483648"), None);
        assert_eq!(written("float", "12.6"), Some(vec![0x41, 0x49, 0x99, 0x9A]));
        assert_eq!(written("float", "12"), Some(vec![0x41, 0x40, 0, 0]));
        assert_eq!(written("float", "12.0"), Some(vec![0x41, 0x40, 0, 0]));
    }

    #[test]
    fn int32_or_float_decides_by_the_numbers_form() {
        assert_eq!(written("int32/float", "12"), Some(vec![0, 0, 0, 12]));
        assert_eq!(written("int32/float", "12.0"), Some(vec![0x41, 0x40, 0, 0]));
        assert_eq!(
            written("int32/float", "1.2e1"),
            Some(vec![0x41, 0x40, 0, 0])
        );
        assert_eq!(
            written("int32/float", "12.6"),
            Some(vec![0x41, 0x49, 0x99, 0x9A])
        );
        assert_eq!(
            written("int32/float", "-7"),
            Some(vec![0xFF, 0xFF, 0xFF, 0xF9])
        );
        assert_eq!(written("int32/float", "4294967296"), None);
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

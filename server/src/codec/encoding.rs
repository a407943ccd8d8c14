use super::{ByteOrder, CodecError, IecType, Value, int_range};

/// How a value is stored on the device.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Raw {
    /// A coil or discrete input.
    Bit,
    /// One bit (0-15) of a register.
    RegisterBit(u8),
    /// A whole register read as a flag: non-zero is TRUE; written as 1 or 0.
    RegisterFlag,
    /// A two's complement or unsigned integer of 8, 16, 32 or 64 bits (8 bits take a
    /// whole register: the low byte of the 16-bit value in its byte order).
    Int { bits: u8, signed: bool },
    /// IEEE-754 single precision in two registers.
    F32,
    /// IEEE-754 double precision in four registers.
    F64,
    /// Characters, two per register, NUL-padded.
    Str { words: u16 },
}

impl Raw {
    /// The registers the raw value takes (coils and discrete inputs: none).
    pub(crate) fn words(self) -> usize {
        match self {
            Raw::Bit => 0,
            Raw::RegisterBit(_) | Raw::RegisterFlag => 1,
            Raw::Int { bits, .. } => usize::from(bits).div_ceil(16),
            Raw::F32 => 2,
            Raw::F64 => 4,
            Raw::Str { words } => usize::from(words),
        }
    }
}

/// A field's value type together with its raw storage, byte order and scaling:
/// `value = raw * scale + offset`, and on write `raw = round((value - offset) / scale)`,
/// rejected when it does not fit the raw type (never wrapped).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Encoding {
    pub(crate) ty: IecType,
    pub(crate) raw: Raw,
    pub(crate) order: ByteOrder,
    pub(crate) scale: f64,
    pub(crate) offset: f64,
}

impl Encoding {
    /// An unscaled encoding in big-endian order.
    #[cfg(test)]
    pub(crate) fn plain(ty: IecType, raw: Raw) -> Self {
        Encoding {
            ty,
            raw,
            order: ByteOrder::BigEndian,
            scale: 1.0,
            offset: 0.0,
        }
    }

    pub(crate) fn words(&self) -> usize {
        self.raw.words()
    }

    fn is_scaled(&self) -> bool {
        self.scale != 1.0 || self.offset != 0.0
    }

    /// The value of a coil or discrete input.
    pub(crate) fn decode_bit(&self, on: bool) -> Value {
        Value::Bool(on)
    }

    /// The value held in `regs` (exactly [`Encoding::words`] registers).
    pub(crate) fn decode(&self, regs: &[u16]) -> Result<Value, CodecError> {
        if regs.len() != self.words() {
            return Err(CodecError::WrongLength {
                expected: self.words(),
                found: regs.len(),
            });
        }
        match self.raw {
            Raw::Bit => Err(CodecError::WrongLength {
                expected: 0,
                found: regs.len(),
            }),
            Raw::RegisterBit(bit) => Ok(Value::Bool(regs[0] >> bit & 1 == 1)),
            Raw::RegisterFlag => Ok(Value::Bool(regs[0] != 0)),
            Raw::Int { bits, signed } => {
                let bytes = self.value_bytes(regs);
                let raw = int_from_be(&bytes, bits, signed);
                if self.is_scaled() || self.ty.is_real() {
                    self.value_from_f64(raw as f64 * self.scale + self.offset)
                } else {
                    Ok(Value::from_int(self.ty, raw)?)
                }
            }
            Raw::F32 => {
                let bytes = self.value_bytes(regs);
                let raw = f32::from_be_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]);
                self.value_from_f64(f64::from(raw) * self.scale + self.offset)
            }
            Raw::F64 => {
                let bytes = self.value_bytes(regs);
                let mut b = [0u8; 8];
                b.copy_from_slice(&bytes);
                self.value_from_f64(f64::from_be_bytes(b) * self.scale + self.offset)
            }
            Raw::Str { .. } => {
                let bytes = self.value_bytes(regs);
                let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
                Ok(Value::String(
                    String::from_utf8_lossy(&bytes[..end]).into_owned(),
                ))
            }
        }
    }

    /// The registers that hold `value` (for a coil: one register, 1 or 0; for a bit in a
    /// register: the register with only that bit set, see [`Encoding::apply_bit`]).
    pub(crate) fn encode(&self, value: &Value) -> Result<Vec<u16>, CodecError> {
        if !value.is_of(self.ty) {
            return Err(CodecError::WrongType {
                ty: self.ty,
                found: value_kind(value),
            });
        }
        match (self.raw, value) {
            (Raw::Bit | Raw::RegisterFlag, Value::Bool(b)) => Ok(vec![u16::from(*b)]),
            (Raw::RegisterBit(bit), Value::Bool(b)) => Ok(vec![u16::from(*b) << bit]),
            (Raw::Int { bits, signed }, _) => {
                let raw = match value.as_i128() {
                    Some(n) if !self.is_scaled() => n,
                    _ => {
                        let x = self.unscale(value)?;
                        let (min, max) = int_range(bits, signed);
                        let rounded = x.round();
                        if rounded < min as f64 || rounded > max as f64 {
                            return Err(raw_range(x, min, max));
                        }
                        rounded as i128
                    }
                };
                let (min, max) = int_range(bits, signed);
                if raw < min || raw > max {
                    return Err(raw_range(raw as f64, min, max));
                }
                let width = self.words() * 2;
                let all = raw.to_be_bytes();
                Ok(self.registers(all[16 - width..].to_vec()))
            }
            (Raw::F32, _) => {
                let x = self.unscale(value)?;
                if x.abs() > f64::from(f32::MAX) {
                    return Err(raw_range(x, -f32::MAX, f32::MAX));
                }
                Ok(self.registers((x as f32).to_be_bytes().to_vec()))
            }
            (Raw::F64, _) => {
                let x = self.unscale(value)?;
                Ok(self.registers(x.to_be_bytes().to_vec()))
            }
            (Raw::Str { words }, Value::String(s)) => {
                let max = usize::from(words) * 2;
                if s.len() > max {
                    return Err(CodecError::TooLong { len: s.len(), max });
                }
                let mut bytes = s.as_bytes().to_vec();
                bytes.resize(max, 0);
                Ok(self.registers(bytes))
            }
            _ => Err(CodecError::WrongType {
                ty: self.ty,
                found: value_kind(value),
            }),
        }
    }

    /// `current` with this field's bit set to `on` and every other bit kept.
    #[cfg(test)]
    pub(crate) fn apply_bit(&self, current: u16, on: bool) -> u16 {
        match self.raw {
            Raw::RegisterBit(bit) if on => current | 1 << bit,
            Raw::RegisterBit(bit) => current & !(1 << bit),
            _ => u16::from(on),
        }
    }

    fn unscale(&self, value: &Value) -> Result<f64, CodecError> {
        let x = value.as_f64().ok_or(CodecError::WrongType {
            ty: self.ty,
            found: value_kind(value),
        })?;
        let raw = (x - self.offset) / self.scale;
        if raw.is_finite() {
            Ok(raw)
        } else {
            Err(CodecError::NotFinite { ty: self.ty })
        }
    }

    fn value_from_f64(&self, x: f64) -> Result<Value, CodecError> {
        if self.ty.is_real() {
            Ok(Value::from_real(self.ty, x)?)
        } else if x.is_finite() {
            Ok(Value::from_int(self.ty, x.round() as i128)?)
        } else {
            Err(CodecError::NotFinite { ty: self.ty })
        }
    }

    /// Register contents as bytes in value order (most significant first).
    fn value_bytes(&self, regs: &[u16]) -> Vec<u8> {
        let mut bytes = super::register_bytes(regs);
        self.order.reorder(&mut bytes);
        bytes
    }

    /// Bytes in value order to registers.
    fn registers(&self, mut bytes: Vec<u8>) -> Vec<u16> {
        self.order.reorder(&mut bytes);
        super::bytes_registers(&bytes)
    }
}

fn raw_range(value: impl ToString, min: impl ToString, max: impl ToString) -> CodecError {
    CodecError::RawOutOfRange {
        value: value.to_string(),
        min: min.to_string(),
        max: max.to_string(),
    }
}

fn value_kind(value: &Value) -> &'static str {
    match value {
        Value::Bool(_) => "a boolean",
        Value::Int(_) | Value::UInt(_) => "an integer",
        Value::Real(_) | Value::LReal(_) => "a real number",
        Value::String(_) => "a string",
        Value::Time(_) => "a duration",
    }
}

/// The integer in the low `bits` of big-endian `bytes`, sign-extended when `signed`.
fn int_from_be(bytes: &[u8], bits: u8, signed: bool) -> i128 {
    let unsigned = bytes.iter().fold(0u128, |acc, &b| acc << 8 | u128::from(b));
    let mask = (1u128 << bits) - 1;
    let value = unsigned & mask;
    if signed && value >> (bits - 1) & 1 == 1 {
        value as i128 - (1i128 << bits)
    } else {
        value as i128
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn enc(ty: IecType, raw: Raw, order: ByteOrder) -> Encoding {
        Encoding {
            order,
            ..Encoding::plain(ty, raw)
        }
    }

    #[test]
    fn cdab_real_round_trips() {
        let e = enc(IecType::Real, Raw::F32, ByteOrder::SwapWords);
        let regs = e.encode(&Value::Real(230.5)).expect("encode");
        let be = (230.5f32).to_bits();
        assert_eq!(regs, vec![(be & 0xFFFF) as u16, (be >> 16) as u16]);
        assert_eq!(e.decode(&regs), Ok(Value::Real(230.5)));
    }

    #[test]
    fn dint_in_every_byte_order_matches_the_letters() {
        let value = Value::Int(0x0102_0304);
        let cases = [
            (ByteOrder::BigEndian, [0x0102, 0x0304]),
            (ByteOrder::LittleEndian, [0x0403, 0x0201]),
            (ByteOrder::SwapBytes, [0x0201, 0x0403]),
            (ByteOrder::SwapWords, [0x0304, 0x0102]),
        ];
        for (order, regs) in cases {
            let e = enc(
                IecType::Dint,
                Raw::Int {
                    bits: 32,
                    signed: true,
                },
                order,
            );
            assert_eq!(e.encode(&value).expect("encode"), regs.to_vec(), "{order}");
            assert_eq!(e.decode(&regs), Ok(value.clone()), "{order}");
        }
    }

    #[test]
    fn lint_words_swap_as_documented() {
        let e = enc(
            IecType::Lint,
            Raw::Int {
                bits: 64,
                signed: true,
            },
            ByteOrder::SwapWords,
        );
        let regs = e
            .encode(&Value::Int(0x0102_0304_0506_0708))
            .expect("encode");
        assert_eq!(regs, vec![0x0708, 0x0506, 0x0304, 0x0102]);
    }

    #[test]
    fn write_block_uint8_example_value() {
        // Source document 002: uint8 value 3, big-endian, written with FC06 as 0x0003.
        let e = enc(
            IecType::Usint,
            Raw::Int {
                bits: 8,
                signed: false,
            },
            ByteOrder::BigEndian,
        );
        assert_eq!(e.encode(&Value::UInt(3)).expect("encode"), vec![0x0003]);
        let sint = enc(
            IecType::Sint,
            Raw::Int {
                bits: 8,
                signed: true,
            },
            ByteOrder::BigEndian,
        );
        assert_eq!(sint.encode(&Value::Int(-2)).expect("encode"), vec![0xFFFE]);
        assert_eq!(sint.decode(&[0x00FE]), Ok(Value::Int(-2)));
    }

    #[test]
    fn profile_temperature_example_scaling() {
        // Source document 000: raw 450 * 0.1 + (-40) = 5.0 degrees.
        let e = Encoding {
            scale: 0.1,
            offset: -40.0,
            ..Encoding::plain(
                IecType::Real,
                Raw::Int {
                    bits: 16,
                    signed: true,
                },
            )
        };
        assert_eq!(e.decode(&[450]), Ok(Value::Real(5.0)));
        assert_eq!(e.encode(&Value::Real(5.0)), Ok(vec![450]));
        // Negative temperatures need a signed raw register.
        assert_eq!(e.decode(&[(-50i16) as u16]), Ok(Value::Real(-45.0)));
    }

    #[test]
    fn scaled_write_out_of_raw_range_is_rejected_not_wrapped() {
        let e = Encoding {
            scale: 0.01,
            ..Encoding::plain(
                IecType::Real,
                Raw::Int {
                    bits: 16,
                    signed: false,
                },
            )
        };
        assert_eq!(e.encode(&Value::Real(655.35)), Ok(vec![65535]));
        assert!(matches!(
            e.encode(&Value::Real(655.36)),
            Err(CodecError::RawOutOfRange { .. })
        ));
        assert!(matches!(
            e.encode(&Value::Real(-0.01)),
            Err(CodecError::RawOutOfRange { .. })
        ));
    }

    #[test]
    fn writes_round_to_the_nearest_raw_integer() {
        let e = Encoding {
            scale: 0.1,
            ..Encoding::plain(
                IecType::Lreal,
                Raw::Int {
                    bits: 16,
                    signed: true,
                },
            )
        };
        assert_eq!(e.encode(&Value::LReal(12.34)), Ok(vec![123]));
        assert_eq!(e.encode(&Value::LReal(12.36)), Ok(vec![124]));
    }

    #[test]
    fn bit_in_register_keeps_the_other_bits() {
        let e = Encoding::plain(IecType::Bool, Raw::RegisterBit(3));
        assert_eq!(e.decode(&[0b1000]), Ok(Value::Bool(true)));
        assert_eq!(e.decode(&[0b0111]), Ok(Value::Bool(false)));
        assert_eq!(e.apply_bit(0b1_0000_0001, true), 0b1_0000_1001);
        assert_eq!(e.apply_bit(0xFFFF, false), 0xFFF7);
    }

    #[test]
    fn strings_are_two_characters_per_register() {
        let e = enc(IecType::String, Raw::Str { words: 3 }, ByteOrder::BigEndian);
        let regs = e.encode(&Value::String("ABC".into())).expect("encode");
        assert_eq!(regs, vec![0x4142, 0x4300, 0x0000]);
        assert_eq!(e.decode(&regs), Ok(Value::String("ABC".into())));
        assert!(matches!(
            e.encode(&Value::String("ABCDEFG".into())),
            Err(CodecError::TooLong { len: 7, max: 6 })
        ));
        let swapped = enc(IecType::String, Raw::Str { words: 2 }, ByteOrder::SwapBytes);
        assert_eq!(
            swapped.decode(&[0x4241, 0x0043]),
            Ok(Value::String("ABC".into()))
        );
    }

    #[test]
    fn wrong_register_count_is_an_error_not_a_panic() {
        let e = Encoding::plain(IecType::Real, Raw::F32);
        assert_eq!(
            e.decode(&[1]),
            Err(CodecError::WrongLength {
                expected: 2,
                found: 1
            })
        );
    }

    #[test]
    fn nan_from_the_device_is_an_error() {
        let e = Encoding::plain(IecType::Real, Raw::F32);
        let bits = f32::NAN.to_bits();
        assert!(matches!(
            e.decode(&[(bits >> 16) as u16, bits as u16]),
            Err(CodecError::Value(
                crate::codec::ValueError::NotFinite { .. }
            ))
        ));
    }

    #[test]
    fn wrong_value_type_is_rejected() {
        let e = Encoding::plain(
            IecType::Int,
            Raw::Int {
                bits: 16,
                signed: true,
            },
        );
        assert!(matches!(
            e.encode(&Value::Bool(true)),
            Err(CodecError::WrongType { .. })
        ));
    }

    fn order() -> impl Strategy<Value = ByteOrder> {
        prop::sample::select(ByteOrder::ALL.to_vec())
    }

    fn int_type() -> impl Strategy<Value = IecType> {
        prop::sample::select(
            IecType::ALL
                .into_iter()
                .filter(|t| t.int_bits().is_some())
                .collect::<Vec<_>>(),
        )
    }

    proptest! {
        #[test]
        fn integers_round_trip(ty in int_type(), order in order(), pick in any::<u64>()) {
            let (bits, signed) = ty.int_bits().expect("int");
            let (min, max) = int_range(bits, signed);
            let span = (max - min) as u128 + 1;
            let n = min + (u128::from(pick) % span) as i128;
            let value = Value::from_int(ty, n).expect("in range");
            let e = enc(ty, Raw::Int { bits, signed }, order);
            let regs = e.encode(&value).expect("encode");
            prop_assert_eq!(regs.len(), e.words());
            prop_assert_eq!(e.decode(&regs), Ok(value));
        }

        #[test]
        fn reals_round_trip(x in any::<f32>().prop_filter("finite", |x| x.is_finite()), order in order()) {
            let e = enc(IecType::Real, Raw::F32, order);
            let regs = e.encode(&Value::Real(x)).expect("encode");
            prop_assert_eq!(e.decode(&regs), Ok(Value::Real(x)));
        }

        #[test]
        fn lreals_round_trip(x in any::<f64>().prop_filter("finite", |x| x.is_finite()), order in order()) {
            let e = enc(IecType::Lreal, Raw::F64, order);
            let regs = e.encode(&Value::LReal(x)).expect("encode");
            prop_assert_eq!(e.decode(&regs), Ok(Value::LReal(x)));
        }

        #[test]
        fn strings_round_trip(s in "[ -~]{0,20}", order in order()) {
            let e = enc(IecType::String, Raw::Str { words: 10 }, order);
            let regs = e.encode(&Value::String(s.clone())).expect("encode");
            prop_assert_eq!(e.decode(&regs), Ok(Value::String(s)));
        }

        #[test]
        fn scaled_raw_registers_round_trip(
            raw in any::<i16>(),
            scale in prop::sample::select(vec![0.1, 0.01, 0.5, 2.0, 10.0, -0.1]),
            offset in -1000.0f64..1000.0,
            order in order(),
            lreal in any::<bool>(),
        ) {
            let ty = if lreal { IecType::Lreal } else { IecType::Real };
            let e = Encoding { scale, offset, order, ty, raw: Raw::Int { bits: 16, signed: true } };
            let regs = vec![raw as u16];
            let value = e.decode(&regs).expect("decode");
            prop_assert_eq!(e.encode(&value).expect("encode"), regs);
        }

        #[test]
        fn time_in_two_registers_round_trips(ms in any::<i32>(), order in order()) {
            let e = enc(IecType::Time, Raw::Int { bits: 32, signed: true }, order);
            let regs = e.encode(&Value::Time(ms.into())).expect("encode");
            prop_assert_eq!(e.decode(&regs), Ok(Value::Time(ms.into())));
        }

        #[test]
        fn any_registers_decode_without_panic(regs in prop::collection::vec(any::<u16>(), 0..6), ty in prop::sample::select(IecType::ALL.to_vec())) {
            let raw = match ty {
                IecType::Bool => Raw::RegisterBit(15),
                IecType::Real => Raw::F32,
                IecType::Lreal => Raw::F64,
                IecType::String => Raw::Str { words: 3 },
                t => { let (bits, signed) = t.int_bits().expect("int"); Raw::Int { bits, signed } }
            };
            let _ = Encoding::plain(ty, raw).decode(&regs);
        }
    }
}

//! The codec's round trips and edge cases.

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
fn an_inverted_coil_writes_zero_for_true_and_reads_zero_as_true() {
    let e = Encoding {
        switch: Some(Switch { on: 0, off: 1 }),
        ..Encoding::plain(IecType::Bool, Raw::Bit)
    };
    assert!(!e.wire_bit(true));
    assert!(e.wire_bit(false));
    assert_eq!(e.encode(&Value::Bool(true)), Ok(vec![0]));
    assert_eq!(e.decode_bit(false), Value::Bool(true));
    assert_eq!(e.decode_bit(true), Value::Bool(false));
    let bit = Encoding {
        switch: Some(Switch { on: 0, off: 1 }),
        ..Encoding::plain(IecType::Bool, Raw::RegisterBit(2))
    };
    assert_eq!(bit.decode(&[0b100]), Ok(Value::Bool(false)));
    assert_eq!(bit.apply_bit(0xFFFF, true), 0xFFFB);
    assert_eq!(bit.encode(&Value::Bool(false)), Ok(vec![0b100]));
}

#[test]
fn a_register_switch_takes_only_its_two_values() {
    let e = Encoding {
        switch: Some(Switch {
            on: 0xA5,
            off: 0x5A,
        }),
        ..Encoding::plain(IecType::Bool, Raw::RegisterFlag)
    };
    assert_eq!(e.encode(&Value::Bool(true)), Ok(vec![0xA5]));
    assert_eq!(e.encode(&Value::Bool(false)), Ok(vec![0x5A]));
    assert_eq!(e.decode(&[0xA5]), Ok(Value::Bool(true)));
    assert_eq!(e.decode(&[0x5A]), Ok(Value::Bool(false)));
    assert_eq!(
        e.decode(&[1]),
        Err(CodecError::NotASwitchValue {
            raw: 1,
            on: 0xA5,
            off: 0x5A
        })
    );
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
fn nan_and_infinities_from_the_device_are_its_values_and_never_written() {
    let e = Encoding::plain(IecType::Real, Raw::F32);
    let bits = f32::NAN.to_bits();
    assert!(matches!(
        e.decode(&[(bits >> 16) as u16, bits as u16]),
        Ok(Value::Real(x)) if x.is_nan()
    ));
    let bits = f32::NEG_INFINITY.to_bits();
    assert_eq!(
        e.decode(&[(bits >> 16) as u16, bits as u16]),
        Ok(Value::Real(f32::NEG_INFINITY))
    );
    let l = Encoding::plain(IecType::Lreal, Raw::F64);
    assert_eq!(
        l.decode(&[0x7FF0, 0, 0, 0]),
        Ok(Value::LReal(f64::INFINITY))
    );
    assert!(e.encode(&Value::Real(f32::NAN)).is_err());
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
        let e = Encoding { scale, offset, order, ..Encoding::plain(ty, Raw::Int { bits: 16, signed: true }) };
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

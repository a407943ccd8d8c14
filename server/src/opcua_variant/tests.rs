use super::*;
use opcua::types::DateTime;

#[test]
fn a_server_value_that_does_not_fit_the_field_is_an_error_never_a_wrapped_number() {
    assert_eq!(
        read_value(IecType::Int, 64, &Variant::Int32(-32768)),
        Ok(Value::Int(-32768))
    );
    for (ty, v) in [
        (IecType::Int, Variant::Int32(40_000)),
        (IecType::Usint, Variant::Int16(-1)),
        (IecType::Udint, Variant::Int64(1 << 40)),
        (IecType::Dint, Variant::Double(1.5)),
        (IecType::Real, Variant::Double(1e300)),
        (IecType::Bool, Variant::Int16(1)),
        (IecType::Int, Variant::Boolean(true)),
    ] {
        let e = read_value(ty, 64, &v).expect_err(&format!("{ty} from {v:?}"));
        assert!(e.starts_with("the server's"), "{e}");
    }
    let e = read_value(IecType::String, 4, &Variant::from("too long")).expect_err("length");
    assert!(e.contains("at most 4"), "{e}");
}

#[test]
fn status_codes_become_qualities_with_the_source_timestamp() {
    let at = DateTime::ymd_hms(2026, 1, 2, 3, 4, 5);
    let dv = |status: StatusCode| DataValue {
        value: Some(Variant::Float(2.5)),
        status: Some(status),
        source_timestamp: Some(at),
        ..Default::default()
    };
    let good = reading(IecType::Real, 64, &dv(StatusCode::Good));
    assert_eq!(good.value.expect("good"), Value::Real(2.5));
    assert!(good.doubt.is_none());
    assert_eq!(good.at, Some(SystemTime::from(at.as_chrono())));
    let uncertain = reading(IecType::Real, 64, &dv(StatusCode::UncertainLastUsableValue));
    assert_eq!(uncertain.value.expect("kept"), Value::Real(2.5));
    assert_eq!(
        uncertain.doubt.expect("doubt").to_string(),
        "UncertainLastUsableValue"
    );
    let bad = reading(IecType::Real, 64, &dv(StatusCode::BadSensorFailure));
    assert_eq!(bad.value.expect_err("bad").to_string(), "BadSensorFailure");
}

#[test]
fn writes_take_the_servers_type_and_are_refused_where_they_do_not_fit() {
    use VariantScalarTypeId as T;
    assert_eq!(
        write_variant(IecType::Int, &Value::Int(300), Some(T::Int32)),
        Ok(Variant::Int32(300))
    );
    assert_eq!(
        write_variant(IecType::Int, &Value::Int(300), None),
        Ok(Variant::Int16(300))
    );
    assert!(write_variant(IecType::Dint, &Value::Int(70_000), Some(T::Int16)).is_err());
    assert!(write_variant(IecType::Dint, &Value::Int(-1), Some(T::UInt32)).is_err());
    assert_eq!(
        write_variant(IecType::Lreal, &Value::LReal(3.0), Some(T::Int16)),
        Ok(Variant::Int16(3))
    );
    assert!(write_variant(IecType::Lreal, &Value::LReal(3.5), Some(T::Int16)).is_err());
    assert!(write_variant(IecType::Bool, &Value::Bool(true), Some(T::String)).is_err());
}

#[test]
fn a_value_of_another_kind_is_named_by_its_kind() {
    let date = Variant::DateTime(Box::new(DateTime::ymd_hms(2026, 1, 2, 3, 4, 5)));
    let e = read_value(IecType::String, 64, &date).expect_err("a DateTime");
    assert!(e.contains("STRING does not take a DateTime"), "{e}");
    let bytes = Variant::ByteString(opcua::types::ByteString::from(vec![1u8, 2]));
    let e = read_value(IecType::String, 64, &bytes).expect_err("a ByteString");
    assert!(e.contains("does not take a ByteString"), "{e}");
    let e = read_value(IecType::Bool, 64, &Variant::Int16(1)).expect_err("a number");
    assert!(e.contains("BOOL does not take a number"), "{e}");
}

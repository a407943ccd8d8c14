//! The value model to and from the protobuf messages of `iogate.v1`: the one place these
//! mappings are written, for the gateway and its client alike.

use iogate_proto::pb;

use crate::time;
use crate::{Direction, IecType, Quality, Value, ValueError};

impl IecType {
    /// The protobuf enum of the type.
    pub fn to_pb(self) -> pb::IecType {
        match self {
            IecType::Bool => pb::IecType::Bool,
            IecType::Sint => pb::IecType::Sint,
            IecType::Int => pb::IecType::Int,
            IecType::Dint => pb::IecType::Dint,
            IecType::Lint => pb::IecType::Lint,
            IecType::Usint => pb::IecType::Usint,
            IecType::Uint => pb::IecType::Uint,
            IecType::Udint => pb::IecType::Udint,
            IecType::Ulint => pb::IecType::Ulint,
            IecType::Real => pb::IecType::Real,
            IecType::Lreal => pb::IecType::Lreal,
            IecType::Byte => pb::IecType::Byte,
            IecType::Word => pb::IecType::Word,
            IecType::Dword => pb::IecType::Dword,
            IecType::Lword => pb::IecType::Lword,
            IecType::String => pb::IecType::String,
            IecType::Time => pb::IecType::Time,
        }
    }

    /// The IEC type of a protobuf type number, `None` for UNSPECIFIED or an unknown number.
    pub fn from_pb(ty: i32) -> Option<IecType> {
        let ty = pb::IecType::try_from(ty).ok()?;
        IecType::ALL.into_iter().find(|t| t.to_pb() == ty)
    }
}

impl Value {
    /// The protobuf value, labelled with `ty` when it is known.
    pub fn to_pb(&self, ty: Option<IecType>) -> pb::Value {
        use pb::value::Kind;
        let kind = match self {
            Value::Bool(b) => Kind::BoolValue(*b),
            Value::Int(i) => Kind::IntValue(*i),
            Value::UInt(u) => Kind::UintValue(*u),
            Value::Real(r) => Kind::RealValue(*r),
            Value::LReal(r) => Kind::LrealValue(*r),
            Value::String(s) => Kind::StringValue(s.clone()),
            Value::Time(t) => Kind::TimeMs(*t),
        };
        pb::Value {
            r#type: ty.map_or(0, |t| t.to_pb().into()),
            kind: Some(kind),
        }
    }

    /// The value a protobuf value carries, as it is (`None` when it carries none).
    pub fn from_pb(v: &pb::Value) -> Option<Value> {
        use pb::value::Kind;
        Some(match v.kind.as_ref()? {
            Kind::BoolValue(b) => Value::Bool(*b),
            Kind::IntValue(i) => Value::Int(*i),
            Kind::UintValue(u) => Value::UInt(*u),
            Kind::RealValue(r) => Value::Real(*r),
            Kind::LrealValue(r) => Value::LReal(*r),
            Kind::StringValue(s) => Value::String(s.clone()),
            Kind::TimeMs(t) => Value::Time(*t),
        })
    }

    /// A protobuf value as a value of `ty`. Numbers convert when they fit exactly; a string
    /// is also a TIME literal such as `T#1s500ms`.
    pub fn from_pb_as(ty: IecType, v: &pb::Value) -> Result<Value, ValueError> {
        use pb::value::Kind;
        match IecType::from_pb(v.r#type) {
            Some(declared) if declared != ty => {
                return Err(ValueError::Mislabelled { ty, declared });
            }
            None if v.r#type != 0 => return Err(ValueError::UnknownType(v.r#type)),
            _ => {}
        }
        let Some(kind) = &v.kind else {
            return Err(ValueError::Missing { ty });
        };
        let wrong = |kind: &Kind| ValueError::WrongType {
            ty,
            found: kind_name(kind),
        };
        match (ty, kind) {
            (IecType::Bool, Kind::BoolValue(b)) => Ok(Value::Bool(*b)),
            (IecType::String, Kind::StringValue(s)) => Ok(Value::String(s.clone())),
            (IecType::Time, Kind::TimeMs(ms)) => Ok(Value::Time(*ms)),
            (IecType::Time, Kind::StringValue(s)) => Ok(Value::Time(time::parse_ms(s)?)),
            (IecType::Bool | IecType::String | IecType::Time, other) => Err(wrong(other)),
            (t, Kind::IntValue(i)) => Value::from_int(t, (*i).into()),
            (t, Kind::UintValue(u)) => Value::from_int(t, (*u).into()),
            (t, Kind::RealValue(r)) => Value::from_real(t, f64::from(*r)),
            (t, Kind::LrealValue(r)) => Value::from_real(t, *r),
            (_, other) => Err(wrong(other)),
        }
    }
}

fn kind_name(kind: &pb::value::Kind) -> &'static str {
    use pb::value::Kind;
    match kind {
        Kind::BoolValue(_) => "a boolean",
        Kind::IntValue(_) | Kind::UintValue(_) => "an integer",
        Kind::RealValue(_) | Kind::LrealValue(_) => "a real number",
        Kind::StringValue(_) => "a string",
        Kind::TimeMs(_) => "a duration",
    }
}

impl Quality {
    /// The protobuf enum of the quality.
    pub fn to_pb(self) -> pb::Quality {
        match self {
            Quality::Good => pb::Quality::Good,
            Quality::Stale => pb::Quality::Stale,
            Quality::NeverRead => pb::Quality::NeverRead,
            Quality::Bad => pb::Quality::Bad,
        }
    }

    /// The quality of a protobuf quality number; an unknown one reads as never read.
    pub fn from_pb(q: i32) -> Quality {
        match pb::Quality::try_from(q) {
            Ok(pb::Quality::Good) => Quality::Good,
            Ok(pb::Quality::Stale) => Quality::Stale,
            Ok(pb::Quality::Bad) => Quality::Bad,
            _ => Quality::NeverRead,
        }
    }
}

impl Direction {
    /// The protobuf enum of the direction.
    pub fn to_pb(self) -> pb::Direction {
        match self {
            Direction::Input => pb::Direction::Input,
            Direction::Output => pb::Direction::Output,
            Direction::Inout => pb::Direction::Inout,
        }
    }

    /// The direction of a protobuf direction number; an unknown one reads as an input.
    pub fn from_pb(d: i32) -> Direction {
        match pb::Direction::try_from(d) {
            Ok(pb::Direction::Output) => Direction::Output,
            Ok(pb::Direction::Inout) => Direction::Inout,
            _ => Direction::Input,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use pb::value::Kind;

    fn pv(kind: Kind) -> pb::Value {
        pb::Value {
            r#type: 0,
            kind: Some(kind),
        }
    }

    #[test]
    fn every_type_maps_both_ways() {
        for t in IecType::ALL {
            assert_eq!(IecType::from_pb(t.to_pb().into()), Some(t));
        }
        assert_eq!(IecType::from_pb(0), None);
        assert_eq!(IecType::from_pb(99), None);
        for q in [
            Quality::Good,
            Quality::Stale,
            Quality::NeverRead,
            Quality::Bad,
        ] {
            assert_eq!(Quality::from_pb(q.to_pb().into()), q);
        }
        for d in Direction::ALL {
            assert_eq!(Direction::from_pb(d.to_pb().into()), d);
        }
    }

    #[test]
    fn numbers_convert_when_they_fit() {
        assert_eq!(
            Value::from_pb_as(IecType::Real, &pv(Kind::IntValue(3))),
            Ok(Value::Real(3.0))
        );
        assert_eq!(
            Value::from_pb_as(IecType::Int, &pv(Kind::LrealValue(3.0))),
            Ok(Value::Int(3))
        );
        assert!(Value::from_pb_as(IecType::Int, &pv(Kind::LrealValue(3.5))).is_err());
        assert!(Value::from_pb_as(IecType::Usint, &pv(Kind::IntValue(-1))).is_err());
        assert_eq!(
            Value::from_pb_as(IecType::Time, &pv(Kind::StringValue("T#2s".into()))),
            Ok(Value::Time(2000))
        );
        assert!(Value::from_pb_as(IecType::Bool, &pv(Kind::IntValue(1))).is_err());
        let mislabelled = pb::Value {
            r#type: pb::IecType::Real.into(),
            kind: Some(Kind::RealValue(1.0)),
        };
        assert_eq!(
            Value::from_pb_as(IecType::Int, &mislabelled)
                .expect_err("mislabelled")
                .to_string(),
            "the field is INT, the value says REAL"
        );
        assert!(Value::from_pb_as(IecType::Int, &pb::Value::default()).is_err());
        let unknown = pb::Value {
            r#type: 999,
            kind: Some(Kind::IntValue(1)),
        };
        assert_eq!(
            Value::from_pb_as(IecType::Int, &unknown),
            Err(ValueError::UnknownType(999))
        );
    }

    #[test]
    fn values_round_trip_through_protobuf() {
        for v in [
            Value::Bool(true),
            Value::Int(-3),
            Value::UInt(7),
            Value::Real(0.5),
            Value::LReal(1e-9),
            Value::String("x".into()),
            Value::Time(1500),
        ] {
            assert_eq!(Value::from_pb(&v.to_pb(None)), Some(v));
        }
    }
}

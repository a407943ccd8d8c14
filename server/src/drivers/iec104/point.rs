//! Where an IEC 104 field is: its information object address (`ioa: 4001`, 1 to 16777215),
//! the ASDU type it is fixed to where the station's own answers must not decide it
//! (`asdu: M_ME_NC_1` for an input; for an output the command, `asdu: C_DC_NA_1`), and
//! whether its commands are selected before they are executed (`select: true`) and
//! terminated by the station (`termination: true`: the outcome waits for ACTTERM). Where a
//! device is: its `common_address` (the link's unless it says). Checked when the profile or
//! the configuration is loaded, so a typo is a problem with its line.

use crate::codec::IecType;
use crate::profile::FieldKey;

use super::types::{Kind, TypeId};

pub(crate) const ASDU: &str = "asdu";
pub(crate) const SELECT: &str = "select";
pub(crate) const TERMINATION: &str = "termination";
pub(crate) const COMMON_ADDRESS: &str = "common_address";

pub(crate) const FIELD_KEYS: &[FieldKey] = &[
    FieldKey {
        key: ASDU,
        check: check_asdu,
    },
    FieldKey {
        key: SELECT,
        check: check_select,
    },
    FieldKey {
        key: TERMINATION,
        check: check_select,
    },
];

/// An information object address as written.
pub(crate) fn ioa(text: &str) -> Result<u32, String> {
    text.trim()
        .parse::<u32>()
        .ok()
        .filter(|a| (1..=super::asdu::MAX_IOA).contains(a))
        .ok_or_else(|| format!("`{text}` is not an information object address (1 to 16777215)"))
}

pub(crate) fn check_ioa(
    _key: &str,
    text: &str,
    ty: Option<IecType>,
    _length: Option<u16>,
) -> Result<(), String> {
    ioa(text)?;
    match ty {
        Some(IecType::String | IecType::Time) => Err(format!(
            "IEC 104 carries no {} (its values are points, counters, measured values and bitstrings)",
            ty.map(|t| t.to_string()).unwrap_or_default()
        )),
        _ => Ok(()),
    }
}

/// Whether a field of type `ty` can be carried by ASDUs of `kind`.
pub(crate) fn carries(kind: Kind, ty: IecType) -> bool {
    use IecType::*;
    let integer = matches!(ty, Sint | Int | Dint | Lint | Usint | Uint | Udint | Ulint);
    let real = matches!(ty, Real | Lreal);
    match kind {
        Kind::Single | Kind::Double | Kind::SingleCommand | Kind::DoubleCommand => ty == Bool,
        Kind::Step | Kind::Scaled | Kind::SetScaled => integer || real,
        Kind::Normalized
        | Kind::NormalizedBare
        | Kind::SetNormalized
        | Kind::Float
        | Kind::SetFloat => real,
        Kind::Counter => integer,
        Kind::Bits | Kind::BitsCommand => matches!(ty, Byte | Word | Dword | Udint | Uint | Usint),
        Kind::StepCommand => integer,
        _ => false,
    }
}

/// An `asdu:` as written: a monitor or command type that carries the field's type.
pub(crate) fn asdu(text: &str, ty: Option<IecType>) -> Result<TypeId, String> {
    let id = TypeId::named(text.trim()).ok_or_else(|| {
        format!(
            "`{text}` is not an ASDU type this gateway speaks ({})",
            TypeId::names()
                .filter(|n| n.starts_with("M_")
                    || n.starts_with("C_S")
                    || n.starts_with("C_D")
                    || n.starts_with("C_B")
                    || n.starts_with("C_R"))
                .collect::<Vec<_>>()
                .join(", ")
        )
    })?;
    let kind = id.kind().unwrap_or(Kind::Read);
    if let Some(ty) = ty
        && !carries(kind, ty)
    {
        return Err(format!("{} does not carry a {ty}", id.name()));
    }
    if !data(kind) {
        return Err(format!("{} carries no field's value", id.name()));
    }
    Ok(id)
}

/// Whether ASDUs of `kind` carry a value or a command (not a system element).
fn data(kind: Kind) -> bool {
    !matches!(
        kind,
        Kind::EndOfInit
            | Kind::Interrogation
            | Kind::CounterInterrogation
            | Kind::Read
            | Kind::ClockSync
            | Kind::ResetProcess
            | Kind::Test
    )
}

fn check_asdu(text: &str, ty: Option<IecType>) -> Result<(), String> {
    asdu(text, ty).map(drop)
}

fn check_select(text: &str, _ty: Option<IecType>) -> Result<(), String> {
    select(text).map(drop)
}

pub(crate) fn select(text: &str) -> Result<bool, String> {
    match text.trim() {
        "true" => Ok(true),
        "false" => Ok(false),
        other => Err(format!("`{other}` is not true or false")),
    }
}

/// A device's `common_address` as written.
pub(crate) fn common_address(text: &str) -> Result<u16, String> {
    text.trim()
        .parse::<u16>()
        .ok()
        .filter(|a| (1..=65534).contains(a))
        .ok_or_else(|| format!("`{text}` is not a common address (1 to 65534)"))
}

/// The command a field's output sends: its `asdu:`, else the one its type calls for.
pub(crate) fn command_for(ty: IecType, fixed: Option<TypeId>) -> Option<TypeId> {
    use super::types::id;
    if let Some(f) = fixed
        && f.kind().is_some_and(|k| {
            matches!(
                k,
                Kind::SingleCommand
                    | Kind::DoubleCommand
                    | Kind::StepCommand
                    | Kind::SetNormalized
                    | Kind::SetScaled
                    | Kind::SetFloat
                    | Kind::BitsCommand
            )
        })
    {
        return Some(f);
    }
    let default = match ty {
        IecType::Bool => id::C_SC_NA_1,
        IecType::Real | IecType::Lreal => id::C_SE_NC_1,
        IecType::Byte | IecType::Word | IecType::Dword => id::C_BO_NA_1,
        IecType::String | IecType::Time | IecType::Lword => return None,
        _ => id::C_SE_NB_1,
    };
    Some(TypeId(default))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn points_as_profiles_write_them() {
        assert_eq!(ioa("4001"), Ok(4001));
        assert!(ioa("0").is_err());
        assert!(ioa("16777216").expect_err("too big").contains("16777215"));
        assert_eq!(asdu("M_ME_NC_1", Some(IecType::Real)), Ok(TypeId(13)));
        assert!(
            asdu("M_ME_NC_1", Some(IecType::Bool))
                .expect_err("no")
                .contains("does not carry a BOOL")
        );
        assert!(
            asdu("C_IC_NA_1", None)
                .expect_err("no")
                .contains("carries no field")
        );
        assert!(asdu("M_XX", None).expect_err("no").contains("M_SP_NA_1"));
        assert_eq!(command_for(IecType::Bool, None), Some(TypeId(45)));
        assert_eq!(command_for(IecType::Int, None), Some(TypeId(49)));
        assert_eq!(command_for(IecType::Real, None), Some(TypeId(50)));
        assert_eq!(
            command_for(IecType::Bool, Some(TypeId(46))),
            Some(TypeId(46))
        );
        assert_eq!(common_address("7"), Ok(7));
        assert!(common_address("65535").is_err());
    }
}

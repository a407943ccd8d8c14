//! How an S7 field's value is stored: from its address (a bit, a width, a typed form, a
//! timer or counter) and the field's type. Checked when a profile is loaded, so an address
//! whose width does not fit its field's type (`MW2` for a REAL) is a problem with its line;
//! the driver reads and writes by the same form.

use super::address::{Address, Area, S7Type, Width, parse};
use crate::codec::IecType;

/// The longest S7 STRING, in characters.
pub(crate) const MAX_STRING: u16 = 254;

/// How a field's value is stored in the PLC.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Form {
    /// A BOOL: one bit of a byte.
    Bit(u8),
    /// The field's IEC type big-endian (TIME as DINT milliseconds).
    Number,
    /// A CHAR (one byte) or WCHAR (UTF-16), as a one-character STRING.
    Char,
    WChar,
    /// STRING[n]: its maximum and length bytes, then n characters.
    String(u16),
    /// WSTRING[n]: its maximum and length words, then n UTF-16 characters.
    WString(u16),
    /// DATE_AND_TIME (BCD) or DTL, as ISO 8601 text (a STRING field) or milliseconds since
    /// 1970 (a LINT field).
    Dt,
    Dtl,
    /// A timer (S5TIME: a time base and three BCD digits), as milliseconds or its word.
    Timer,
    /// A counter (three BCD digits), as its count or its word.
    Counter,
}

impl Form {
    /// The bytes a value takes in the PLC.
    pub(crate) fn bytes(self, ty: IecType) -> u16 {
        match self {
            Form::Bit(_) | Form::Char => 1,
            Form::WChar | Form::Timer | Form::Counter => 2,
            Form::Number => number_bytes(ty),
            Form::String(n) => n + 2,
            Form::WString(n) => 2 * n + 4,
            Form::Dt => 8,
            Form::Dtl => 12,
        }
    }
}

/// An address as one key whatever way it is written (`C3` and `Z3`, `T5` and `t5`,
/// `DB1.DBW0` and `db1.dbw0` are one place in the PLC).
pub(crate) fn point_identity(text: &str) -> String {
    match parse(text) {
        Ok(a) => format!("{a:?}"),
        Err(_) => text.to_owned(),
    }
}

/// The bytes of an IEC type's number (a STRING has none).
pub(crate) fn number_bytes(ty: IecType) -> u16 {
    match ty {
        IecType::Bool | IecType::Sint | IecType::Usint | IecType::Byte => 1,
        IecType::Int | IecType::Uint | IecType::Word => 2,
        IecType::Dint | IecType::Udint | IecType::Dword | IecType::Real | IecType::Time => 4,
        IecType::Lint | IecType::Ulint | IecType::Lword | IecType::Lreal => 8,
        IecType::String => 0,
    }
}

/// A field's form from its address, type and (for a string) its maximum length; why not,
/// naming both, when they do not fit.
pub(crate) fn form(address: &Address, ty: IecType, length: Option<u16>) -> Result<Form, String> {
    let fits_time = matches!(ty, IecType::String | IecType::Lint);
    let string = |wide: bool| match length {
        Some(n) if n <= MAX_STRING => Ok(if wide {
            Form::WString(n)
        } else {
            Form::String(n)
        }),
        Some(n) => Err(format!(
            "a string holds at most {MAX_STRING} characters, not {n}"
        )),
        None => Err(format!(
            "an S7 {} field needs its `length:` (the n of its declaration, {MAX_STRING} when it has none)",
            if wide { "WSTRING" } else { "STRING" }
        )),
    };
    match (address.width, ty) {
        (Width::Bit(b), IecType::Bool) => Ok(Form::Bit(b)),
        (Width::Bit(_), t) => Err(format!("a bit address holds a BOOL, not a {t}")),
        (_, IecType::Bool) => {
            Err("a BOOL is a bit: write the bit's address (e.g. DB1.DBX0.1)".into())
        }
        (Width::Cell, t) => cell(address.area, t),
        (Width::Typed(S7Type::Elementary(s)), t) if s == t => Ok(Form::Number),
        (Width::Typed(S7Type::Elementary(s)), t) => {
            Err(format!("the address holds a {s}; the field is a {t}"))
        }
        (Width::Typed(S7Type::Char), IecType::String) => Ok(Form::Char),
        (Width::Typed(S7Type::WChar), IecType::String) => Ok(Form::WChar),
        (Width::Typed(S7Type::String), IecType::String) => string(false),
        (Width::Typed(S7Type::WString), IecType::String) => string(true),
        (Width::Typed(S7Type::Dt), _) if fits_time => Ok(Form::Dt),
        (Width::Typed(S7Type::Dtl), _) if fits_time => Ok(Form::Dtl),
        (Width::Typed(S7Type::Dt | S7Type::Dtl), t) => Err(format!(
            "a date and time is read as a STRING (ISO 8601) or a LINT (ms since 1970), not a {t}"
        )),
        (Width::Typed(s), t) => Err(format!("the address holds a {s:?}; the field is a {t}")),
        (Width::Unsized | Width::Byte, IecType::String) => string(false),
        (w, IecType::String) => Err(format!(
            "a STRING is at a byte address (DB1.DBB10 or DB1.STRING10), not a {}-byte one",
            w.bytes().unwrap_or(0)
        )),
        (Width::Unsized, _) => Ok(Form::Number),
        (w, t) => match w.bytes() {
            Some(b) if b == number_bytes(t) => Ok(Form::Number),
            Some(b) => Err(format!(
                "the address is {b} byte(s); a {t} is {}",
                number_bytes(t)
            )),
            None => Ok(Form::Number),
        },
    }
}

/// A timer's or counter's form for a field's type.
fn cell(area: Area, ty: IecType) -> Result<Form, String> {
    let ok = matches!(
        ty,
        IecType::Word | IecType::Int | IecType::Uint | IecType::Dint | IecType::Udint
    ) || (area == Area::Timers && ty == IecType::Time);
    match (ok, area) {
        (true, Area::Timers) => Ok(Form::Timer),
        (true, _) => Ok(Form::Counter),
        (false, Area::Timers) => Err(format!(
            "a timer is read as TIME, an integer (ms) or its WORD, not a {ty}"
        )),
        (false, _) => Err(format!(
            "a counter is read as an integer or its WORD, not a {ty}"
        )),
    }
}

/// An S7 field's `address` with its type and length, checked (the profile loader's check).
pub(crate) fn check(
    _key: &str,
    text: &str,
    ty: Option<IecType>,
    length: Option<u16>,
) -> Result<(), String> {
    let address = parse(text)?;
    match ty {
        Some(ty) => form(&address, ty, length)
            .map(drop)
            .map_err(|e| format!("`{}`: {e}", text.trim())),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn of(text: &str, ty: IecType, length: Option<u16>) -> Result<Form, String> {
        form(&parse(text)?, ty, length)
    }

    #[test]
    fn an_address_and_a_type_make_a_form() {
        for (text, ty, length, want) in [
            ("DB1.DBX0.1", IecType::Bool, None, Form::Bit(1)),
            ("MW2", IecType::Int, None, Form::Number),
            ("DB1.8", IecType::Lreal, None, Form::Number),
            ("DB1.LREAL8", IecType::Lreal, None, Form::Number),
            ("DB1.DBB10", IecType::String, Some(20), Form::String(20)),
            ("DB1.WSTRING10", IecType::String, Some(8), Form::WString(8)),
            ("DB1.CHAR3", IecType::String, None, Form::Char),
            ("DB1.DT0", IecType::String, None, Form::Dt),
            ("DB1.DTL0", IecType::Lint, None, Form::Dtl),
            ("T5", IecType::Time, None, Form::Timer),
            ("C3", IecType::Int, None, Form::Counter),
        ] {
            assert_eq!(of(text, ty, length), Ok(want), "{text}");
            assert!(want.bytes(ty) > 0);
        }
        assert_eq!(Form::WString(8).bytes(IecType::String), 20);
        assert_eq!(Form::String(20).bytes(IecType::String), 22);
    }

    #[test]
    fn a_width_that_does_not_fit_the_type_names_both() {
        for (text, ty, length, says) in [
            ("MW2", IecType::Real, None, "2 byte(s); a REAL is 4"),
            ("MD2", IecType::Lreal, None, "4 byte(s); a LREAL is 8"),
            ("M0.1", IecType::Int, None, "holds a BOOL, not a INT"),
            ("MB0", IecType::Bool, None, "a BOOL is a bit"),
            (
                "DB1.REAL4",
                IecType::Dint,
                None,
                "holds a REAL; the field is a DINT",
            ),
            ("DB1.10", IecType::String, None, "needs its `length:`"),
            (
                "DB1.DT0",
                IecType::Real,
                None,
                "STRING (ISO 8601) or a LINT",
            ),
            ("C1", IecType::Real, None, "a counter"),
            ("DB1.DBW4", IecType::String, Some(4), "a byte address"),
        ] {
            let e = of(text, ty, length).expect_err(text);
            assert!(e.contains(says), "{text}: {e}");
        }
    }
}

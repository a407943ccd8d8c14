//! Durations as people write them: `50ms`, `2s`, `1m30s`, and IEC 61131-3 literals
//! (`T#50ms`, `TIME#1s500ms`, `T#-2s`), as signed milliseconds (the value of a TIME).

const UNITS: [(&str, f64); 6] = [
    ("ms", 1.0),
    ("us", 0.001),
    ("d", 86_400_000.0),
    ("h", 3_600_000.0),
    ("m", 60_000.0),
    ("s", 1_000.0),
];

/// Why a duration literal was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum TimeError {
    /// Not a duration literal.
    #[error("`{0}` is not a duration (write e.g. `50ms`, `2s`, `1m30s` or `T#1s500ms`)")]
    NotADuration(String),
    /// Past what milliseconds in 64 bits hold.
    #[error("`{0}` is too long a duration")]
    TooLong(String),
}

/// Parses a duration literal into signed milliseconds (fractions of a millisecond are rounded).
pub fn parse_ms(text: &str) -> Result<i64, TimeError> {
    let err = || TimeError::NotADuration(text.to_owned());
    let mut rest = text.trim();
    for prefix in ["TIME#", "time#", "T#", "t#"] {
        if let Some(r) = rest.strip_prefix(prefix) {
            rest = r;
            break;
        }
    }
    let negative = rest.starts_with('-');
    if negative {
        rest = &rest[1..];
    }
    if rest.is_empty() {
        return Err(err());
    }
    let mut total = 0.0f64;
    while !rest.is_empty() {
        let digits = rest
            .find(|c: char| !(c.is_ascii_digit() || c == '.' || c == '_'))
            .ok_or_else(err)?;
        if digits == 0 {
            return Err(err());
        }
        let number: f64 = rest[..digits].replace('_', "").parse().map_err(|_| err())?;
        rest = &rest[digits..];
        let (unit, factor) = UNITS
            .iter()
            .find(|(u, _)| {
                rest.get(..u.len())
                    .is_some_and(|head| head.eq_ignore_ascii_case(u))
            })
            .ok_or_else(err)?;
        total += number * factor;
        rest = &rest[unit.len()..];
    }
    if total > i64::MAX as f64 / 2.0 {
        return Err(TimeError::TooLong(text.to_owned()));
    }
    let ms = total.round() as i64;
    Ok(if negative { -ms } else { ms })
}

/// Formats milliseconds as an IEC literal, e.g. `T#1m30s`, `T#-500ms`, `T#0ms`.
pub fn format_iec(ms: i64) -> String {
    let mut out = String::from("T#");
    if ms < 0 {
        out.push('-');
    }
    let mut rest = ms.unsigned_abs();
    if rest == 0 {
        out.push_str("0ms");
        return out;
    }
    for (unit, factor) in [
        ("d", 86_400_000u64),
        ("h", 3_600_000),
        ("m", 60_000),
        ("s", 1_000),
        ("ms", 1),
    ] {
        let n = rest / factor;
        if n > 0 {
            out.push_str(&format!("{n}{unit}"));
            rest %= factor;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plain_and_iec_literals_parse() {
        assert_eq!(parse_ms("50ms"), Ok(50));
        assert_eq!(parse_ms("T#50ms"), Ok(50));
        assert_eq!(parse_ms("TIME#1s500ms"), Ok(1500));
        assert_eq!(parse_ms("1m30s"), Ok(90_000));
        assert_eq!(parse_ms("1.5s"), Ok(1500));
        assert_eq!(parse_ms("T#-2s"), Ok(-2000));
    }

    #[test]
    fn iec_format_round_trips() {
        for ms in [0, 1, 50, 1500, 90_000, 86_400_001, -500] {
            assert_eq!(parse_ms(&format_iec(ms)), Ok(ms));
        }
        assert_eq!(format_iec(90_500), "T#1m30s500ms");
    }
}

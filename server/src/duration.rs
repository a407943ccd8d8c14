//! Durations as people write them: `50ms`, `2s`, `1m30s`, and IEC 61131-3 literals
//! (`T#50ms`, `TIME#1s500ms`, `T#-2s`).

use std::time::Duration;

pub(crate) use iogate_types::time::parse_ms;

/// Why a duration does not parse.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub(crate) enum DurationError {
    #[error(transparent)]
    Literal(#[from] iogate_types::time::TimeError),
    #[error("`{0}` is negative")]
    Negative(String),
}

/// Parses a non-negative duration.
pub(crate) fn parse(text: &str) -> Result<Duration, DurationError> {
    let ms = parse_ms(text)?;
    u64::try_from(ms)
        .map(Duration::from_millis)
        .map_err(|_| DurationError::Negative(text.to_owned()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plain_and_iec_literals_parse() {
        assert_eq!(parse("50ms"), Ok(Duration::from_millis(50)));
        assert_eq!(parse("2s"), Ok(Duration::from_secs(2)));
        assert_eq!(parse("T#50ms"), Ok(Duration::from_millis(50)));
        assert_eq!(parse("TIME#1s500ms"), Ok(Duration::from_millis(1500)));
        assert_eq!(parse("1m30s"), Ok(Duration::from_secs(90)));
        assert_eq!(parse("1.5s"), Ok(Duration::from_millis(1500)));
        assert_eq!(parse("1h"), Ok(Duration::from_secs(3600)));
    }

    #[test]
    fn bad_literals_are_rejected_with_the_text() {
        for bad in ["", "50", "ms", "5 parsecs", "T#", "1.2.3s", "5x"] {
            let err = parse(bad).expect_err(bad).to_string();
            assert!(err.contains(&format!("`{bad}`")), "{err}");
        }
        assert_eq!(
            parse("T#-1s"),
            Err(DurationError::Negative("T#-1s".to_owned()))
        );
    }
}

//! What a topic level, a topic prefix and a size may be.

/// Why an MQTT identifier or topic is refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub(crate) enum TopicError {
    #[error("must not be empty")]
    Empty,
    #[error("`{0}` must not contain `+`, `#` or `/` (it is one level of a topic)")]
    Level(String),
    #[error(
        "`{0}` must not contain `+` or `#`, nor start or end with `/`, nor have an empty level"
    )]
    Prefix(String),
    #[error("`{0}` must not start with `$` (topics starting with `$` belong to the broker)")]
    Dollar(String),
    #[error("`{0}` is longer than 65,535 bytes")]
    TooLong(String),
}

/// One level of a topic (a Sparkplug group, edge node, device or host id).
pub(crate) fn check_level(text: &str) -> Result<(), TopicError> {
    if text.is_empty() {
        return Err(TopicError::Empty);
    }
    if text.contains(['+', '#', '/']) || text.contains('\0') {
        return Err(TopicError::Level(text.to_owned()));
    }
    Ok(())
}

/// A topic prefix of one or more levels.
pub(crate) fn check_prefix(text: &str) -> Result<(), TopicError> {
    if text.is_empty() {
        return Err(TopicError::Empty);
    }
    if text.len() > 65_535 {
        return Err(TopicError::TooLong(text.to_owned()));
    }
    if text.starts_with('$') {
        return Err(TopicError::Dollar(text.to_owned()));
    }
    if text.contains(['+', '#', '\0']) || text.split('/').any(str::is_empty) {
        return Err(TopicError::Prefix(text.to_owned()));
    }
    Ok(())
}

/// A size such as `256MiB`, `10MB`, `4096`.
pub(crate) fn parse_size(text: &str) -> Option<u64> {
    let t = text.trim();
    let split = t.find(|c: char| !c.is_ascii_digit()).unwrap_or(t.len());
    let (digits, unit) = t.split_at(split);
    let n: u64 = digits.parse().ok()?;
    let factor: u64 = match unit.trim() {
        "" | "B" => 1,
        "KB" | "kB" => 1_000,
        "KiB" => 1 << 10,
        "MB" => 1_000_000,
        "MiB" => 1 << 20,
        "GB" => 1_000_000_000,
        "GiB" => 1 << 30,
        _ => return None,
    };
    n.checked_mul(factor)
}

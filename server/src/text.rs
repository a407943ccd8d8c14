//! What a message may echo of a client's input: a short prefix, control characters escaped,
//! so that a 60 KB name gives a short error and a newline cannot forge a log line.

/// The longest part of a client's input an error message quotes.
pub const QUOTE_MAX: usize = 64;

/// At most [`QUOTE_MAX`] characters of `text`, with `…` when cut, control characters and
/// quotes escaped.
pub fn quote(text: &str) -> String {
    let mut out: String = text
        .chars()
        .take(QUOTE_MAX)
        .flat_map(|c| {
            let escaped: Vec<char> = if c.is_control() {
                c.escape_default().collect()
            } else {
                vec![c]
            };
            escaped
        })
        .collect();
    if text.chars().nth(QUOTE_MAX).is_some() {
        out.push('…');
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn long_or_forged_input_is_quoted_short_and_escaped() {
        assert_eq!(quote("sim"), "sim");
        assert_eq!(quote("line\nfake log"), "line\\nfake log");
        assert_eq!(quote("bell\u{7}"), "bell\\u{7}");
        let q = quote(&"x".repeat(60_000));
        assert_eq!(q.chars().count(), QUOTE_MAX + 1);
        assert!(q.ends_with('…'));
    }
}

//! What a message may echo of a client's input: a short prefix, control characters escaped,
//! so that a 60 KB name gives a short error and a newline cannot forge a log line.

/// The longest part of a client's input an error message quotes.
pub(crate) const QUOTE_MAX: usize = 64;

/// At most [`QUOTE_MAX`] characters of `text`, with `…` when cut, control characters and
/// quotes escaped.
pub(crate) fn quote(text: &str) -> String {
    let mut out: String = text
        .chars()
        .take(QUOTE_MAX)
        .flat_map(|c| {
            let escaped: Vec<char> = if c.is_control() || is_format(c) {
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

/// Whether `c` is an invisible format character that can change how a log line reads
/// (bidirectional overrides and isolates, zero-width characters, the byte order mark).
fn is_format(c: char) -> bool {
    matches!(c, '\u{200B}'..='\u{200F}' | '\u{202A}'..='\u{202E}' | '\u{2066}'..='\u{2069}' | '\u{FEFF}' | '\u{061C}')
}

/// Why a text file could not be read: the file itself, or a byte that is not UTF-8 (with
/// its line, 1-based, so the problem points where it is).
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum ReadError {
    Io(String),
    NotUtf8 { line: u64, column: usize, byte: u8 },
}

impl std::fmt::Display for ReadError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ReadError::Io(e) => write!(f, "cannot read the file: {e}"),
            ReadError::NotUtf8 { column, byte, .. } => write!(
                f,
                "the file is not UTF-8: byte 0x{byte:02X} at column {column}"
            ),
        }
    }
}

impl ReadError {
    /// The line it concerns, when it is in the text.
    pub(crate) fn line(&self) -> Option<u64> {
        match self {
            ReadError::Io(_) => None,
            ReadError::NotUtf8 { line, .. } => Some(*line),
        }
    }
}

/// The text of a file, or why not.
pub(crate) fn read_file(path: &std::path::Path) -> Result<String, ReadError> {
    let bytes = std::fs::read(path).map_err(|e| ReadError::Io(e.to_string()))?;
    String::from_utf8(bytes).map_err(|e| {
        let bytes = e.as_bytes();
        let at = e.utf8_error().valid_up_to();
        let before = &bytes[..at];
        let line = before.iter().filter(|&&b| b == b'\n').count() as u64 + 1;
        let column = at
            - before
                .iter()
                .rposition(|&b| b == b'\n')
                .map_or(0, |p| p + 1)
            + 1;
        ReadError::NotUtf8 {
            line,
            column,
            byte: bytes[at],
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn long_or_forged_input_is_quoted_short_and_escaped() {
        assert_eq!(quote("sim"), "sim");
        assert_eq!(quote("line\nfake log"), "line\\nfake log");
        assert_eq!(quote("bell\u{7}"), "bell\\u{7}");
        assert_eq!(
            quote("A\u{202E}B"),
            "A\\u{202e}B",
            "a right-to-left override"
        );
        assert_eq!(quote("é\u{200B}"), "é\\u{200b}");
        let q = quote(&"x".repeat(60_000));
        assert_eq!(q.chars().count(), QUOTE_MAX + 1);
        assert!(q.ends_with('…'));
    }

    #[test]
    fn a_byte_that_is_not_utf8_is_named_at_its_line() {
        let path = std::env::temp_dir().join(format!("iogate-utf8-{}.yaml", std::process::id()));
        std::fs::write(&path, b"name: Io\nfields:\n  - { name: A\xFFB }\n").expect("write");
        let e = read_file(&path).expect_err("not UTF-8");
        assert_eq!(e.line(), Some(3));
        assert_eq!(
            e.to_string(),
            "the file is not UTF-8: byte 0xFF at column 14"
        );
        let _ = std::fs::remove_file(&path);
        assert!(matches!(read_file(&path), Err(ReadError::Io(_))));
    }
}

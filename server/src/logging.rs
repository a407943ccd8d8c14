//! The gateway's log: text (the default) or JSON lines (`--log-format json`,
//! `IOGATE_LOG_FORMAT=json`) on stderr. Text lines escape every control character a value
//! brings (a newline in a host name cannot forge a line, an escape sequence cannot repaint
//! a terminal); JSON escapes them by its own rules.

use std::io::{self, Write};

use tracing_subscriber::EnvFilter;
use tracing_subscriber::fmt::MakeWriter;

/// How log lines are written.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum LogFormat {
    /// Human-readable lines.
    #[default]
    Text,
    /// One JSON object per line, for log collectors.
    Json,
}

/// Installs the global subscriber.
pub fn init(format: LogFormat, filter: EnvFilter) {
    let builder = tracing_subscriber::fmt().with_env_filter(filter);
    match format {
        LogFormat::Text => builder
            .with_ansi(false)
            .with_writer(Escaping(io::stderr))
            .init(),
        LogFormat::Json => builder
            .json()
            .flatten_event(true)
            .with_current_span(false)
            .with_writer(io::stderr)
            .init(),
    }
}

/// Makes writers that escape control characters.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Escaping<M>(pub M);

impl<'a, M: MakeWriter<'a>> MakeWriter<'a> for Escaping<M> {
    type Writer = EscapingWriter<M::Writer>;

    fn make_writer(&'a self) -> Self::Writer {
        EscapingWriter(self.0.make_writer())
    }
}

/// Writes a formatted line with its control characters escaped, the final newline kept.
pub(crate) struct EscapingWriter<W>(W);

/// `text` with every control character but a final newline (and tabs) as `\n`, `\r` or
/// `\u{1b}`.
pub(crate) fn escape_line(text: &str) -> std::borrow::Cow<'_, str> {
    let body = text.strip_suffix('\n').unwrap_or(text);
    if !body.chars().any(|c| c.is_control() && c != '\t') {
        return std::borrow::Cow::Borrowed(text);
    }
    let mut out = String::with_capacity(text.len() + 8);
    for c in body.chars() {
        match c {
            '\t' => out.push('\t'),
            '\n' => out.push_str("\\n"),
            '\r' => out.push_str("\\r"),
            c if c.is_control() => out.push_str(&c.escape_unicode().to_string()),
            c => out.push(c),
        }
    }
    if body.len() < text.len() {
        out.push('\n');
    }
    std::borrow::Cow::Owned(out)
}

impl<W: Write> Write for EscapingWriter<W> {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        let text = String::from_utf8_lossy(buf);
        self.0.write_all(escape_line(&text).as_bytes())?;
        Ok(buf.len())
    }

    fn flush(&mut self) -> io::Result<()> {
        self.0.flush()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::{Arc, Mutex};

    #[test]
    fn control_characters_in_values_cannot_forge_lines() {
        assert_eq!(escape_line("plain line\n"), "plain line\n");
        assert_eq!(
            escape_line("host=a\n2026-01-01 INFO forged\n"),
            "host=a\\n2026-01-01 INFO forged\n"
        );
        assert_eq!(escape_line("x\u{1b}[31mred\r"), "x\\u{1b}[31mred\\r");
    }

    #[derive(Clone, Default)]
    struct Buffer(Arc<Mutex<Vec<u8>>>);

    impl Write for Buffer {
        fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
            self.0.lock().expect("lock").extend_from_slice(buf);
            Ok(buf.len())
        }
        fn flush(&mut self) -> io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn a_logged_event_is_one_line_whatever_its_fields_hold() {
        let buffer = Buffer::default();
        let sink = buffer.clone();
        let subscriber = tracing_subscriber::fmt()
            .with_ansi(false)
            .with_writer(Escaping(move || sink.clone()))
            .finish();
        tracing::subscriber::with_default(subscriber, || {
            let host = "plc\nERROR forged line";
            tracing::warn!(host, "cannot connect");
        });
        let text = String::from_utf8(buffer.0.lock().expect("lock").clone()).expect("utf8");
        assert_eq!(text.lines().count(), 1, "{text}");
        assert!(text.contains("plc\\nERROR forged line"), "{text}");
    }
}

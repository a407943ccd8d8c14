//! `iogate profile import`: device descriptions of other gateways made into iogate profiles:
//! wb-mqtt-serial device templates (JSON, `wb`) and EdgeX device profiles (YAML, `edgex`).
//! Every field that can be mapped is (register kind, address, type, byte and word order,
//! scale, offset, unit, bits); everything else is reported with its source line. A result is
//! loaded back as `iogate check` loads it before it is given out.

mod cli;
mod edgex;
pub(crate) mod emit;
mod wb;

pub use cli::run;

use std::fmt::Write;
use std::path::Path;

use crate::codec::{ByteOrder, IecType};
use crate::profile::{Direction, RegisterKind};
use crate::yaml::{Kind, Node, Report};

/// The formats a file can be read as.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    Wb,
    Edgex,
}

impl Format {
    pub fn parse(text: &str) -> Result<Format, String> {
        match text {
            "wb" => Ok(Format::Wb),
            "edgex" => Ok(Format::Edgex),
            other => Err(format!("unknown format `{other}` (wb or edgex)")),
        }
    }

    /// By the file's name: `.json` (and `.json.jinja`) are wb-mqtt-serial templates, `.yaml`
    /// and `.yml` EdgeX profiles.
    fn of(path: &Path) -> Option<Format> {
        let name = path.file_name()?.to_string_lossy().to_ascii_lowercase();
        if name.ends_with(".json") || name.ends_with(".json.jinja") {
            Some(Format::Wb)
        } else if name.ends_with(".yaml") || name.ends_with(".yml") {
            Some(Format::Edgex)
        } else {
            None
        }
    }
}

/// A field as imported, before it is written out.
#[derive(Debug, Clone, PartialEq)]
struct Imported {
    name: String,
    ty: IecType,
    direction: Direction,
    kind: RegisterKind,
    address: u16,
    bit: Option<u8>,
    word_count: Option<u16>,
    raw_type: Option<IecType>,
    scale: f64,
    offset: f64,
    order: ByteOrder,
    unit: Option<String>,
    description: Option<String>,
    /// A BOOL's raw values where not the plain ones.
    switch: Option<crate::codec::Switch>,
    line: u64,
}

impl Imported {
    fn span(&self) -> u32 {
        if self.kind.is_bit() {
            1
        } else {
            u32::from(self.word_count.unwrap_or(1))
        }
    }
}

/// A profile as imported: its fields and what could not be mapped.
#[derive(Debug, Default)]
struct Draft {
    name: String,
    vendor: Option<String>,
    description: Option<String>,
    fields: Vec<Imported>,
    /// What was not mapped: line and why.
    unmapped: Vec<(u64, String)>,
    /// The source says it is superseded (wb-mqtt-serial's `"deprecated": true`).
    deprecated: bool,
}

impl Draft {
    fn skip(&mut self, line: u64, why: impl Into<String>) {
        self.unmapped.push((line, why.into()));
    }

    /// Adds a field: its name made an IEC identifier unique in the profile, and left out
    /// (reported) where it shares registers with a field added before.
    fn add(&mut self, mut field: Imported, source_name: &str) {
        let base = identifier(source_name);
        let mut name = base.clone();
        let mut n = 2;
        while self
            .fields
            .iter()
            .any(|f| f.name.eq_ignore_ascii_case(&name))
        {
            name = format!("{base}_{n}");
            n += 1;
        }
        if name != source_name && field.description.is_none() {
            field.description = Some(source_name.to_owned());
        }
        field.name = name;
        let (a0, a1) = (
            u32::from(field.address),
            u32::from(field.address) + field.span() - 1,
        );
        let clash = self.fields.iter().find(|g| {
            let (b0, b1) = (u32::from(g.address), u32::from(g.address) + g.span() - 1);
            let bits_apart = matches!((field.bit, g.bit), (Some(x), Some(y)) if x != y);
            g.kind == field.kind && a0 <= b1 && b0 <= a1 && !bits_apart
        });
        if let Some(g) = clash {
            let why = format!(
                "`{source_name}` shares {} {a0} with field {} (line {}): an iogate field owns its registers",
                field.kind.name(),
                g.name,
                g.line
            );
            self.skip(field.line, why);
            return;
        }
        self.fields.push(field);
    }
}

/// A source name made an IEC identifier: letters, digits and single underscores, not
/// starting with a digit, not a keyword or a name the device's block already has.
pub(crate) fn identifier(source: &str) -> String {
    let mut out = String::new();
    for c in source.chars() {
        if c.is_ascii_alphanumeric() {
            out.push(c);
        } else if !out.ends_with('_') {
            out.push('_');
        }
    }
    let mut out = out.trim_matches('_').to_owned();
    if out.is_empty() {
        out = "Field".to_owned();
    }
    if out.starts_with(|c: char| c.is_ascii_digit()) {
        out.insert_str(0, "F_");
    }
    let lower = out.to_ascii_lowercase();
    if crate::profile::keywords::is_keyword(&out)
        || super::load::RESERVED_NAMES.contains(&lower.as_str())
    {
        out.push_str("_value");
    }
    out
}

/// The type of a scaled integer: REAL holds every 16-bit raw value's digits, but not a
/// 32- or 64-bit counter's (12345.6789 kWh as REAL reads 12345.679): those are LREAL.
fn scaled_type(raw: IecType) -> IecType {
    match raw.int_bits() {
        Some((bits, _)) if bits > 16 => IecType::Lreal,
        _ => IecType::Real,
    }
}

/// A number as YAML writes it: integers without a fraction.
fn number(x: f64) -> String {
    if x.fract() == 0.0 && x.abs() < 1e15 {
        format!("{}", x as i64)
    } else {
        format!("{x}")
    }
}

/// A YAML double-quoted string.
pub(crate) fn quoted(text: &str) -> String {
    let mut out = String::from("\"");
    for c in text.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            c if c.is_control() => {
                let _ = write!(out, "\\u{:04x}", u32::from(c));
            }
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

/// The profile's YAML.
fn render(draft: &Draft, source: &str, from: &str) -> String {
    let mut out = format!("# Imported from {source} ({from}) by `iogate profile import`.\n");
    if !draft.unmapped.is_empty() {
        let _ = writeln!(
            out,
            "# Not imported ({}): see the import report.",
            draft.unmapped.len()
        );
    }
    let _ = writeln!(out, "name: {}", draft.name);
    if let Some(v) = &draft.vendor {
        let _ = writeln!(out, "vendor: {}", quoted(v));
    }
    out.push_str("protocol: modbus-rtu\n");
    if let Some(d) = &draft.description {
        let _ = writeln!(out, "description: {}", quoted(d));
    }
    out.push_str("fields:\n");
    for f in &draft.fields {
        let mut reg = format!("address: {}, kind: {}", f.address, f.kind.name());
        if let Some(bit) = f.bit {
            let _ = write!(reg, ", bit: {bit}");
        }
        if let Some(raw) = f.raw_type {
            let _ = write!(reg, ", raw_type: {}", raw.name());
        } else if let Some(w) = f.word_count {
            let _ = write!(reg, ", word_count: {w}");
        }
        if f.scale != 1.0 {
            let _ = write!(reg, ", scale: {}", number(f.scale));
        }
        if f.offset != 0.0 {
            let _ = write!(reg, ", offset: {}", number(f.offset));
        }
        if f.order != ByteOrder::BigEndian {
            let _ = write!(reg, ", byte_order: {}", f.order.name());
        }
        if let Some(u) = &f.unit {
            let _ = write!(reg, ", unit: {}", quoted(u));
        }
        if let Some(s) = f.switch {
            let _ = write!(reg, ", on_value: {}, off_value: {}", s.on, s.off);
        }
        let _ = write!(
            out,
            "  - {{ name: {}, type: {}, direction: {}, register: {{ {reg} }}",
            f.name,
            f.ty.name(),
            f.direction.name()
        );
        if let Some(d) = &f.description {
            let _ = write!(out, ", description: {}", quoted(d));
        }
        out.push_str(" }\n");
    }
    out
}

/// One file imported: the profile's file name and text, and the report of what was not
/// mapped (`file:line: why`).
#[derive(Debug)]
pub struct Converted {
    pub profile: String,
    pub file_name: String,
    pub text: String,
    pub fields: usize,
    pub unmapped: Vec<String>,
    /// The source is a deprecated template (a current one may share its name).
    pub deprecated: bool,
}

/// Imports one file (`from` as given, else by its name).
pub fn import_file(path: &Path, from: Option<Format>) -> Result<Converted, String> {
    let shown = path.display().to_string();
    let format = from.or_else(|| Format::of(path)).ok_or_else(|| {
        format!("{shown}: say --from wb or --from edgex (not a .json or .yaml name)")
    })?;
    let text = crate::text::read_file(path).map_err(|e| format!("{shown}: {e}"))?;
    import_text(&shown, &text, format)
}

/// Imports one file's text; `file` names it.
pub fn import_text(file: &str, text: &str, format: Format) -> Result<Converted, String> {
    if text.contains("{%") || text.contains("{{") {
        let line = text
            .lines()
            .position(|l| l.contains("{%") || l.contains("{{"))
            .map_or(1, |i| i + 1);
        return Err(format!(
            "{file}:{line}: a Jinja template: render it first (its expressions are not a register map)"
        ));
    }
    // wb-mqtt-serial reads JSON with `//` comments and tab indentation; YAML takes neither.
    let relaxed;
    let text = if format == Format::Wb {
        relaxed = relaxed_json(text);
        relaxed.as_str()
    } else {
        text
    };
    let mut report = Report::new(file);
    let root = crate::yaml::parse(text, &mut report).ok_or_else(|| {
        report
            .into_problems()
            .iter()
            .map(|p| p.to_string())
            .collect::<Vec<_>>()
            .join("\n")
    })?;
    let (draft, from) = match format {
        Format::Wb => (
            wb::read(&root).map_err(|e| format!("{file}: {e}"))?,
            "a wb-mqtt-serial device template",
        ),
        Format::Edgex => (
            edgex::read(&root).map_err(|e| format!("{file}: {e}"))?,
            "an EdgeX device profile",
        ),
    };
    if draft.fields.is_empty() {
        let mut why = format!("{file}: no field could be mapped");
        for (line, reason) in &draft.unmapped {
            let _ = write!(why, "\n  {file}:{line}: {reason}");
        }
        return Err(why);
    }
    let source = Path::new(file)
        .file_name()
        .map_or(file.to_owned(), |n| n.to_string_lossy().into_owned());
    let text = render(&draft, &source, from);
    let file_name = format!("{}.yaml", draft.name.to_ascii_lowercase());
    // What `iogate check` would say: nothing, or the importer has a bug to name.
    if let Err(problems) = crate::profile::load_str(&file_name, &text) {
        return Err(format!(
            "{file}: the imported profile does not load (a bug of the importer):\n{problems}"
        ));
    }
    Ok(Converted {
        profile: draft.name.clone(),
        file_name,
        fields: draft.fields.len(),
        deprecated: draft.deprecated,
        unmapped: draft
            .unmapped
            .iter()
            .map(|(line, why)| format!("{file}:{line}: {why}"))
            .collect(),
        text,
    })
}

/// JSON as wb-mqtt-serial reads it made plain JSON, line for line: `//` comments outside
/// strings removed, tabs (never inside a JSON string) made spaces.
fn relaxed_json(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let mut in_string = false;
    let mut escaped = false;
    let mut chars = text.chars().peekable();
    while let Some(c) = chars.next() {
        if in_string {
            out.push(c);
            match c {
                _ if escaped => escaped = false,
                '\\' => escaped = true,
                '"' => in_string = false,
                _ => {}
            }
            continue;
        }
        match c {
            '"' => {
                in_string = true;
                out.push(c);
            }
            '/' if chars.peek() == Some(&'/') => {
                while chars.peek().is_some_and(|&n| n != '\n') {
                    chars.next();
                }
            }
            '\t' => out.push_str("  "),
            c => out.push(c),
        }
    }
    out
}

/// A scalar as text (numbers as written), for keys that are strings in some files and
/// numbers in others.
fn scalar(node: &Node) -> Option<String> {
    match &node.kind {
        Kind::Str(s) => Some(s.clone()),
        Kind::Int(i) => Some(i.to_string()),
        Kind::Float(f) => Some(f.to_string()),
        Kind::Bool(b) => Some(b.to_string()),
        _ => None,
    }
}

/// A number: an integer, a float, or a string holding one (`"0x1A"`, `"0.1"`).
fn num(node: &Node) -> Option<f64> {
    match &node.kind {
        Kind::Int(i) => Some(*i as f64),
        Kind::Float(f) => Some(*f),
        Kind::Str(s) => num_text(s),
        _ => None,
    }
}

/// A number written as text: decimal, or hexadecimal with `0x`.
fn num_text(text: &str) -> Option<f64> {
    let text = text.trim();
    match text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
        Some(hex) => i64::from_str_radix(hex, 16).ok().map(|i| i as f64),
        None => text.parse().ok(),
    }
}

/// The entries of a mapping, or none.
fn entries(node: &Node) -> &[(crate::yaml::Key, Node)] {
    match &node.kind {
        Kind::Map(entries) => entries,
        _ => &[],
    }
}

fn get<'a>(node: &'a Node, key: &str) -> Option<&'a Node> {
    entries(node)
        .iter()
        .find(|(k, _)| k.name == key)
        .map(|(_, v)| v)
        .filter(|v| v.kind != Kind::Null)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_become_identifiers() {
        assert_eq!(identifier("Active Power"), "Active_Power");
        assert_eq!(identifier("L1-N voltage, V"), "L1_N_voltage_V");
        assert_eq!(identifier("1st input"), "F_1st_input");
        assert_eq!(identifier("Time"), "Time_value");
        assert_eq!(identifier("connected"), "connected_value");
        assert_eq!(identifier("---"), "Field");
    }

    #[test]
    fn relaxed_json_loses_comments_and_tabs_but_no_line_or_string() {
        let text = "{\n\t\"a\": \"x // y\", // note\n\t\"b\": \"q\\\"//\" }";
        let plain = relaxed_json(text);
        assert_eq!(plain, "{\n  \"a\": \"x // y\", \n  \"b\": \"q\\\"//\" }");
    }
}

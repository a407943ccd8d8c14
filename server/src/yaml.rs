//! The one place that parses YAML.
//!
//! Profiles and the gateway config are parsed into a small tree that keeps the line of every
//! key and value, then validated by hand. Deserializing straight into structs would stop at the
//! first unknown key or wrong type; walking the tree lets validation report every problem of a
//! file at once, each with its line.

mod de;

use std::fmt;

/// One problem found in a YAML file: where it is, what it concerns, what is wrong.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Problem {
    pub file: String,
    pub line: u64,
    /// What the problem concerns, e.g. `field DO_0: register.bit`.
    pub(crate) context: String,
    pub(crate) message: String,
}

impl Problem {
    /// What is wrong, with what it concerns (`context: message`), without file and line.
    pub(crate) fn what(&self) -> String {
        if self.context.is_empty() {
            self.message.clone()
        } else {
            format!("{}: {}", self.context, self.message)
        }
    }
}

impl fmt::Display for Problem {
    /// `file:line: context: message`; a message's further lines (iogate's detail after a
    /// source document's own words) are indented under it.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let message = self.message.replace('\n', "\n    ");
        if self.context.is_empty() {
            write!(f, "{}:{}: {message}", self.file, self.line)
        } else {
            write!(
                f,
                "{}:{}: {}: {message}",
                self.file, self.line, self.context
            )
        }
    }
}

/// Every problem found in one or more files.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Problems(pub Vec<Problem>);

impl Problems {
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    pub fn len(&self) -> usize {
        self.0.len()
    }

    pub fn iter(&self) -> impl Iterator<Item = &Problem> {
        self.0.iter()
    }

    pub(crate) fn extend_all(&mut self, others: impl IntoIterator<Item = Problems>) {
        for other in others {
            self.extend(other);
        }
    }

    pub(crate) fn extend(&mut self, other: Problems) {
        self.0.extend(other.0);
    }
}

impl fmt::Display for Problems {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, p) in self.0.iter().enumerate() {
            if i > 0 {
                writeln!(f)?;
            }
            write!(f, "{p}")?;
        }
        Ok(())
    }
}

impl std::error::Error for Problems {}

/// Collects the problems of one file.
#[derive(Debug)]
pub(crate) struct Report {
    file: String,
    problems: Vec<Problem>,
}

impl Report {
    pub(crate) fn new(file: impl Into<String>) -> Self {
        Self {
            file: file.into(),
            problems: Vec::new(),
        }
    }

    pub(crate) fn file(&self) -> &str {
        &self.file
    }

    pub(crate) fn push(
        &mut self,
        line: u64,
        context: impl Into<String>,
        message: impl std::fmt::Display,
    ) {
        self.problems.push(Problem {
            file: self.file.clone(),
            line,
            context: context.into(),
            message: message.to_string(),
        });
    }

    pub(crate) fn has_problems(&self) -> bool {
        !self.problems.is_empty()
    }

    /// The problems, in line order.
    pub(crate) fn into_problems(mut self) -> Problems {
        self.problems.sort_by_key(|p| p.line);
        Problems(self.problems)
    }
}

/// A YAML value with the line it starts on.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Node {
    pub(crate) line: u64,
    pub(crate) kind: Kind,
}

#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Kind {
    Null,
    Bool(bool),
    Int(i128),
    Float(f64),
    Str(String),
    Seq(Vec<Node>),
    Map(Vec<(Key, Node)>),
}

#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Key {
    pub(crate) name: String,
    pub(crate) line: u64,
}

/// The most values (keys, scalars, lists and mappings) one YAML file may hold.
const MAX_VALUES: usize = 1_500_000;

/// Parses YAML text into a [`Node`] tree; a syntax error is one problem with its line.
/// An empty document is `Null`.
pub(crate) fn parse(text: &str, report: &mut Report) -> Option<Node> {
    // YAML 1.2 booleans only: `parity: N` is the letter N, not false. The reader's bounds
    // hold a profile of 50,000 fields of about ten keys each, and no more.
    let mut budget = serde_saphyr::Budget::default();
    budget.max_nodes = MAX_VALUES;
    budget.max_events = 2 * MAX_VALUES;
    let options =
        serde_saphyr::options! { with_snippet: false, strict_booleans: true, budget: Some(budget) };
    match serde_saphyr::from_str_with_options::<Option<Node>>(text, options) {
        Ok(node) => Some(node.unwrap_or(Node {
            line: 1,
            kind: Kind::Null,
        })),
        Err(e) => {
            let line = e.location().map(|l| l.line()).unwrap_or(1).max(1);
            let message = match &e {
                serde_saphyr::Error::DuplicateMappingKey { key: Some(key), .. } => {
                    format!("duplicate key `{key}`: a key may appear once in a mapping (keep one)")
                }
                serde_saphyr::Error::DuplicateMappingKey { key: None, .. } => {
                    "duplicate key: a key may appear once in a mapping (keep one)".to_owned()
                }
                serde_saphyr::Error::Budget {
                    breach:
                        serde_saphyr::budget::BudgetBreach::Nodes { .. }
                        | serde_saphyr::budget::BudgetBreach::Events { .. },
                    ..
                } => format!(
                    "the file holds more than {MAX_VALUES} values, the most one file may hold (a profile of about 50,000 fields): split it into several profiles"
                ),
                _ => format!("invalid YAML: {}", strip_location(&e.to_string())),
            };
            report.push(line, "", message);
            None
        }
    }
}

/// The YAML crate's messages start with `error: line N column M: `; the line is reported
/// separately, so keep only the message.
fn strip_location(msg: &str) -> &str {
    let msg = msg.strip_prefix("error: ").unwrap_or(msg);
    if msg.starts_with("line ")
        && let Some((_, rest)) = msg.split_once(": ")
    {
        return rest;
    }
    msg
}

impl Node {
    /// A `null` value on `line`.
    pub(crate) fn null(line: u64) -> Node {
        Node {
            line,
            kind: Kind::Null,
        }
    }

    pub(crate) fn describe(&self) -> &'static str {
        match self.kind {
            Kind::Null => "nothing",
            Kind::Bool(_) => "a boolean",
            Kind::Int(_) => "an integer",
            Kind::Float(_) => "a number",
            Kind::Str(_) => "a string",
            Kind::Seq(_) => "a list",
            Kind::Map(_) => "a mapping",
        }
    }

    /// A string scalar. Numbers and booleans are not silently turned into strings.
    pub(crate) fn str(&self, report: &mut Report, ctx: &str) -> Option<&str> {
        match &self.kind {
            Kind::Str(s) => Some(s),
            _ => {
                report.push(
                    self.line,
                    ctx,
                    format!("expected a string, found {}", self.describe()),
                );
                None
            }
        }
    }

    /// A string, or a scalar number written without quotes (host names, port paths, addresses).
    pub(crate) fn scalar_text(&self, report: &mut Report, ctx: &str) -> Option<String> {
        match &self.kind {
            Kind::Str(s) => Some(s.clone()),
            Kind::Int(i) => Some(i.to_string()),
            Kind::Float(f) => Some(f.to_string()),
            _ => {
                report.push(
                    self.line,
                    ctx,
                    format!("expected a string, found {}", self.describe()),
                );
                None
            }
        }
    }

    /// An integer within `min..=max`.
    pub(crate) fn int_in(
        &self,
        report: &mut Report,
        ctx: &str,
        min: i128,
        max: i128,
    ) -> Option<i128> {
        match self.kind {
            Kind::Int(i) if (min..=max).contains(&i) => Some(i),
            Kind::Int(i) => {
                report.push(
                    self.line,
                    ctx,
                    format!("{i} is outside the allowed range {min}-{max}"),
                );
                None
            }
            _ => {
                report.push(
                    self.line,
                    ctx,
                    format!("expected an integer, found {}", self.describe()),
                );
                None
            }
        }
    }

    /// A finite number (integers are accepted as numbers).
    pub(crate) fn number(&self, report: &mut Report, ctx: &str) -> Option<f64> {
        let value = match self.kind {
            Kind::Int(i) => i as f64,
            Kind::Float(f) => f,
            _ => {
                report.push(
                    self.line,
                    ctx,
                    format!("expected a number, found {}", self.describe()),
                );
                return None;
            }
        };
        if value.is_finite() {
            Some(value)
        } else {
            report.push(self.line, ctx, "the number must be finite");
            None
        }
    }

    pub(crate) fn seq(&self, report: &mut Report, ctx: &str) -> Option<&[Node]> {
        match &self.kind {
            Kind::Seq(items) => Some(items),
            _ => {
                report.push(
                    self.line,
                    ctx,
                    format!("expected a list, found {}", self.describe()),
                );
                None
            }
        }
    }

    /// Opens a mapping for reading its keys; anything else is reported.
    pub(crate) fn map<'a>(&'a self, report: &mut Report, ctx: &str) -> Option<MapReader<'a>> {
        match &self.kind {
            Kind::Map(entries) => Some(MapReader {
                line: self.line,
                entries,
                used: vec![false; entries.len()],
            }),
            _ => {
                report.push(
                    self.line,
                    ctx,
                    format!("expected a mapping, found {}", self.describe()),
                );
                None
            }
        }
    }
}

/// A YAML boolean, or the problem reported.
pub(crate) fn boolean(node: &Node, report: &mut Report, ctx: &str) -> Option<bool> {
    match node.kind {
        Kind::Bool(b) => Some(b),
        _ => {
            report.push(
                node.line,
                ctx,
                format!("expected true or false, found {}", node.describe()),
            );
            None
        }
    }
}

/// Reads the keys of a mapping; [`MapReader::finish`] reports every key nobody asked for.
pub(crate) struct MapReader<'a> {
    pub(crate) line: u64,
    entries: &'a [(Key, Node)],
    used: Vec<bool>,
}

impl<'a> MapReader<'a> {
    /// The value of `key`, if present (a `null` value counts as absent).
    pub(crate) fn get(&mut self, key: &str) -> Option<&'a Node> {
        let idx = self.entries.iter().position(|(k, _)| k.name == key)?;
        self.used[idx] = true;
        let node = &self.entries[idx].1;
        (node.kind != Kind::Null).then_some(node)
    }

    /// The value of a key that must be present.
    pub(crate) fn require(
        &mut self,
        key: &str,
        report: &mut Report,
        ctx: &str,
    ) -> Option<&'a Node> {
        let node = self.get(key);
        if node.is_none() {
            report.push(self.line, ctx, format!("missing required key `{key}`"));
        }
        node
    }

    /// Every key not read yet, with its value (`null` ones included), marked as read.
    pub(crate) fn rest(&mut self) -> Vec<(&'a Key, &'a Node)> {
        let mut rest = Vec::new();
        for ((key, node), used) in self.entries.iter().zip(self.used.iter_mut()) {
            if !*used {
                *used = true;
                rest.push((key, node));
            }
        }
        rest
    }

    /// Reports every key that was not read, naming the keys that are allowed.
    pub(crate) fn finish(self, report: &mut Report, ctx: &str, allowed: &[&str]) {
        for ((key, _), used) in self.entries.iter().zip(&self.used) {
            if !used {
                report.push(
                    key.line,
                    ctx,
                    format!(
                        "unknown key `{}` (expected one of: {})",
                        key.name,
                        allowed.join(", ")
                    ),
                );
            }
        }
    }
}

/// Replaces `cut` characters at `at` of `text` with `insert`: the mutation the loaders'
/// never-panic properties apply to valid files.
#[cfg(test)]
pub(crate) fn mutate(text: &str, at: proptest::sample::Index, insert: &str, cut: usize) -> String {
    let mut chars: Vec<char> = text.chars().collect();
    let i = at.index(chars.len());
    let end = (i + cut).min(chars.len());
    chars.splice(i..end, insert.chars());
    chars.into_iter().collect()
}

#[cfg(test)]
#[path = "yaml_tests.rs"]
mod tests;

//! How a declaration is refused: the rules it breaks, the names it cannot find, or how it
//! contradicts what exists, each worded as the source documents word it.

use std::fmt;
use std::time::Duration;

use crate::cache::{AccessError, Refusal};
use crate::config::Framing;
use crate::config::rules::{Mismatch, RuleError};

/// Where a declaration contradicts what exists.
#[derive(Debug, Clone, PartialEq)]
pub enum Conflict {
    /// The serial port runs with other settings (the "configuration mismatch" of source
    /// document 004).
    Serial {
        port: String,
        mismatch: Mismatch,
    },
    Framing {
        have: Framing,
        want: Framing,
    },
    /// The endpoint is another link's.
    LinkName {
        is: String,
        declared: String,
    },
    Profile {
        have: String,
        want: String,
    },
    Link {
        have: Option<String>,
        want: Option<String>,
    },
    SlaveId {
        have: u8,
        want: u8,
    },
    RefreshRate {
        have: Duration,
        want: Duration,
    },
    Timeout {
        have: Duration,
        want: Duration,
    },
}

impl fmt::Display for Conflict {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let none = |n: &Option<String>| n.clone().unwrap_or_else(|| "none".to_owned());
        match self {
            Conflict::Serial { port, mismatch: m } => write!(
                f,
                "{} configuration mismatch.\n{port}: {} declared, {} in use",
                m.setting, m.want, m.have
            ),
            Conflict::Framing { have, want } => write!(
                f,
                "framing {} declared, {} in use",
                want.name(),
                have.name()
            ),
            Conflict::LinkName { is, declared } => {
                write!(f, "it is link `{is}`, not `{declared}`")
            }
            Conflict::Profile { have, want } => write!(f, "profile {have} (declared {want})"),
            Conflict::Link { have, want } => {
                write!(f, "link {} (declared {})", none(have), none(want))
            }
            Conflict::SlaveId { have, want } => write!(f, "slave_id {have} (declared {want})"),
            Conflict::RefreshRate { have, want } => write!(
                f,
                "refresh_rate {} ms (declared {} ms)",
                have.as_millis(),
                want.as_millis()
            ),
            Conflict::Timeout { have, want } => write!(
                f,
                "timeout {} ms (declared {} ms)",
                have.as_millis(),
                want.as_millis()
            ),
        }
    }
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DeclareError {
    #[error("{}", rule_list(.0))]
    Rules(Vec<RuleError>),
    #[error(
        "`{name}` cannot name a {what}: 1-64 letters, digits, `_`, `-` or `.`, starting with a letter, digit or `_`"
    )]
    BadName { what: &'static str, name: String },
    #[error(transparent)]
    UnknownProfile(AccessError),
    #[error("no link `{0}`; declare it with EnsureLink first")]
    UnknownLink(String),
    #[error("link {link} conflicts with its declaration: {}", join(.conflicts, "; "))]
    LinkConflict {
        link: String,
        conflicts: Vec<Conflict>,
    },
    #[error("link name `{name}` is already used by another endpoint ({endpoint})")]
    NameTaken { name: String, endpoint: String },
    /// The security policy does not allow the endpoint.
    #[error("{0}")]
    NotAllowed(String),
    #[error("{0}")]
    OutOfBounds(String),
    #[error("no more {0} can be declared (at most {1})")]
    TooMany(&'static str, usize),
    #[error("`{name}` clashes with {what} `{other}` (names ignore case)")]
    NameClash {
        what: &'static str,
        name: String,
        other: String,
    },
    #[error("device {device} exists with {}", join(.conflicts, ", "))]
    DeviceConflict {
        device: String,
        conflicts: Vec<Conflict>,
    },
    #[error(transparent)]
    NotFound(AccessError),
    /// Only what was declared at run time can be removed at run time.
    #[error("{what} {name} comes from the config file; remove it there")]
    FromConfig { what: &'static str, name: String },
    #[error("link {link} is still used by {}; remove {} first", .by.join(", "), if .by.len() == 1 { "it" } else { "them" })]
    InUse { link: String, by: Vec<String> },
}

impl DeclareError {
    pub(crate) fn refusal(&self) -> Refusal {
        match self {
            DeclareError::Rules(_)
            | DeclareError::BadName { .. }
            | DeclareError::OutOfBounds(_) => Refusal::Invalid,
            DeclareError::NotAllowed(_) => Refusal::Forbidden,
            DeclareError::TooMany(..) => Refusal::TooMany,
            DeclareError::UnknownProfile(_)
            | DeclareError::UnknownLink(_)
            | DeclareError::NotFound(_) => Refusal::NotFound,
            DeclareError::LinkConflict { .. }
            | DeclareError::NameTaken { .. }
            | DeclareError::NameClash { .. }
            | DeclareError::DeviceConflict { .. }
            | DeclareError::FromConfig { .. }
            | DeclareError::InUse { .. } => Refusal::Conflict,
        }
    }
}

fn rule_list(errors: &[RuleError]) -> String {
    errors
        .iter()
        .map(|e| format!("{}: {e}", e.key()))
        .collect::<Vec<_>>()
        .join("; ")
}

fn join(conflicts: &[Conflict], separator: &str) -> String {
    conflicts
        .iter()
        .map(ToString::to_string)
        .collect::<Vec<_>>()
        .join(separator)
}

//! Configuration reloads as the front-ends see them: a reload is asked for (by SIGHUP, the
//! REST call, gRPC `ReloadConfig` or the file watch), and answers with a [`Report`] of what
//! changed or with every problem found. The loading, checking, comparing and applying is
//! done by the gateway's composition root (`crate::reload`), installed here as a
//! [`Reloading`]; the front-ends only call [`Service::reload`] and render the answer.

use std::sync::Arc;

use futures_util::future::BoxFuture;
use serde::{Deserialize, Serialize};

use super::Service;
use crate::yaml::Problems;

/// What asked for a reload.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum Trigger {
    Sighup,
    Api,
    Grpc,
    Watch,
    /// `iogate check --diff --against`: two files compared, nothing running.
    Check,
}

impl Trigger {
    pub(crate) fn name(self) -> &'static str {
        match self {
            Trigger::Sighup => "sighup",
            Trigger::Api => "api",
            Trigger::Grpc => "grpc",
            Trigger::Watch => "watch",
            Trigger::Check => "check",
        }
    }
}

/// What kind of thing a reload changed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    Listener,
    Security,
    Profile,
    Link,
    Device,
    Field,
    Map,
    Transaction,
    /// A front-end's own section, by its key (`api::front_end`).
    Section(&'static str),
    Reload,
}

impl Kind {
    /// The kinds the core reports; sections' kinds are their keys.
    pub(crate) const CORE: [Kind; 9] = [
        Kind::Listener,
        Kind::Security,
        Kind::Profile,
        Kind::Link,
        Kind::Device,
        Kind::Field,
        Kind::Map,
        Kind::Transaction,
        Kind::Reload,
    ];

    pub(crate) fn name(self) -> &'static str {
        match self {
            Kind::Listener => "listener",
            Kind::Security => "security",
            Kind::Profile => "profile",
            Kind::Link => "link",
            Kind::Device => "device",
            Kind::Field => "field",
            Kind::Map => "map",
            Kind::Transaction => "transaction",
            Kind::Section(key) => key,
            Kind::Reload => "reload",
        }
    }

    /// Where it comes in a report: the core's kinds in their order, the sections by key
    /// before the reload's own settings.
    fn rank(self) -> (usize, &'static str) {
        match self {
            Kind::Section(key) => (Kind::CORE.len() - 1, key),
            Kind::Reload => (Kind::CORE.len(), ""),
            core => (Kind::CORE.iter().position(|k| *k == core).unwrap_or(0), ""),
        }
    }
}

impl Ord for Kind {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.rank().cmp(&other.rank())
    }
}

impl PartialOrd for Kind {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

impl Serialize for Kind {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.name())
    }
}

/// A core kind by its name; any other name is a section's (a gateway asked by
/// `iogate check --diff` may have front-ends this program has not). Each section name is
/// kept once for the life of the process.
impl<'de> Deserialize<'de> for Kind {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        static KEYS: std::sync::Mutex<Vec<&'static str>> = std::sync::Mutex::new(Vec::new());
        let name = String::deserialize(d)?;
        if let Some(core) = Kind::CORE.iter().find(|k| k.name() == name) {
            return Ok(*core);
        }
        let mut keys = KEYS.lock().unwrap_or_else(|e| e.into_inner());
        let key = match keys.iter().find(|k| **k == name) {
            Some(key) => key,
            None => {
                let key: &'static str = Box::leak(name.into_boxed_str());
                keys.push(key);
                key
            }
        };
        Ok(Kind::Section(key))
    }
}

/// A string, one of the core's kinds or a front-end's section key; the OpenAPI document
/// lists the sections' keys beside the core's kinds.
impl utoipa::PartialSchema for Kind {
    fn schema() -> utoipa::openapi::RefOr<utoipa::openapi::schema::Schema> {
        use utoipa::openapi::schema::{ObjectBuilder, Type};
        ObjectBuilder::new()
            .schema_type(Type::String)
            .description(Some("What kind of thing a reload changed."))
            .enum_values(Some(Kind::CORE.iter().map(|k| k.name())))
            .into()
    }
}

impl utoipa::ToSchema for Kind {}

/// What happened to it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum Action {
    Added,
    Removed,
    Changed,
}

impl Action {
    pub(crate) fn name(self) -> &'static str {
        match self {
            Action::Added => "added",
            Action::Removed => "removed",
            Action::Changed => "changed",
        }
    }
}

/// One change: a link, device, field (`device.field`), profile, map entry (its located
/// address), standing transaction, security setting, listener or section.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Item {
    pub kind: Kind,
    pub name: String,
    pub action: Action,
    /// What changed, `key: before -> after`, and what was done about it.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub details: Vec<String>,
}

/// What a reload changed (or would change, in a dry run).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Report {
    pub trigger: Trigger,
    /// Whether it was only compared (`iogate check --diff`, `dry_run`).
    pub dry_run: bool,
    pub changes: Vec<Item>,
    /// Links whose settings changed: their port or socket was closed and opened again.
    pub reopened: Vec<String>,
    /// How long loading, checking and applying took.
    pub took_ms: f64,
    /// The hash of the configuration now in force (or, in a dry run, of the one compared).
    pub config_hash: String,
    /// When, in milliseconds since the Unix epoch.
    pub at_unix_ms: i64,
}

impl Report {
    /// One line per change, for the log and the terminal.
    pub fn lines(&self) -> Vec<String> {
        self.changes
            .iter()
            .map(|c| {
                let mut line = format!("{} {} {}", c.kind.name(), c.name, c.action.name());
                if !c.details.is_empty() {
                    line.push_str(": ");
                    line.push_str(&c.details.join("; "));
                }
                line
            })
            .collect()
    }
}

/// `key: before -> after` when they differ (a reload report's words for a setting).
pub(crate) fn changed<T: PartialEq + std::fmt::Debug>(
    key: &str,
    before: &T,
    after: &T,
) -> Option<String> {
    (before != after).then(|| format!("{key}: {before:?} -> {after:?}"))
}

/// `key: before -> after` when their texts differ.
pub(crate) fn changed_text(
    key: &str,
    before: impl ToString,
    after: impl ToString,
) -> Option<String> {
    let (b, a) = (before.to_string(), after.to_string());
    (b != a).then(|| format!("{key}: {b} -> {a}"))
}

/// A duration as a reload's report writes it.
pub(crate) fn duration(d: std::time::Duration) -> String {
    format!("{d:?}")
}

/// A front-end's section that differs (its front-end is started, stopped or restarted):
/// the action, and the keys that changed followed by what the restart does.
pub(crate) fn restarted_section<T>(
    old: &Option<T>,
    new: &Option<T>,
    what: &str,
    keys: impl Fn(&T, &T) -> Vec<Option<String>>,
    stopped: &str,
    restart: &str,
) -> (Action, Vec<String>) {
    match (old, new) {
        (Some(x), Some(y)) => {
            let mut details: Vec<String> = keys(x, y).into_iter().flatten().collect();
            details.push(restart.to_owned());
            (Action::Changed, details)
        }
        (Some(_), None) => (
            Action::Removed,
            vec![format!("{what} is stopped {stopped}")],
        ),
        (None, _) => (Action::Added, vec![format!("{what} is started")]),
    }
}

/// The configuration in force, for `GET /api/v1/config`.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct ConfigStatus {
    /// The config file, or `built-in demo`.
    pub file: String,
    /// The profiles directory, if one is used.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub profiles: Option<String>,
    /// SHA-256 of the config file and of every profile file, in hex.
    pub hash: String,
    /// When the configuration in force was loaded, in milliseconds since the Unix epoch.
    pub loaded_at_unix_ms: i64,
    /// Whether changed files are applied by themselves (`reload.watch`).
    pub watch: bool,
    /// The report of the last reload that was applied, if any.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub last_report: Option<Report>,
    /// The problems of the last reload that was refused, if it came after the last applied.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub last_problems: Vec<String>,
    /// The servers listening now, each with what a client connects to.
    pub listening: Vec<super::listening::Listener>,
}

/// Why a reload changed nothing.
#[derive(Debug, Clone, thiserror::Error)]
pub enum ReloadError {
    /// The new configuration or a profile has problems: every one, with file and line.
    #[error("{0}")]
    Invalid(Problems),
    /// The gateway runs its built-in demo: there is no file to load again.
    #[error("the gateway runs its built-in demo: there is no configuration file to reload")]
    NoFile,
    /// Checked and valid, but applying it failed (a listener could not be bound): nothing
    /// was changed.
    #[error("{0}")]
    Failed(String),
}

/// Loads, checks, compares and applies a configuration (`crate::reload::Reloader`).
pub(crate) trait Reloading: Send + Sync + std::fmt::Debug {
    fn reload(
        self: Arc<Self>,
        service: Arc<Service>,
        trigger: Trigger,
        dry_run: bool,
    ) -> BoxFuture<'static, Result<Report, ReloadError>>;

    fn status(&self) -> ConfigStatus;
}

impl Service {
    /// Installs what reloads the configuration (once, at start).
    pub(crate) fn attach_reloader(&self, reloader: Arc<dyn Reloading>) {
        let _ = self.reloader.set(reloader);
    }

    /// Loads the configuration and profiles again and applies what changed (or, with
    /// `dry_run`, only reports it).
    pub(crate) async fn reload(
        self: &Arc<Self>,
        trigger: Trigger,
        dry_run: bool,
    ) -> Result<Report, ReloadError> {
        let Some(reloader) = self.reloader.get().cloned() else {
            return Err(ReloadError::NoFile);
        };
        reloader.reload(self.clone(), trigger, dry_run).await
    }

    /// The configuration in force and the last reload's report.
    pub(crate) fn config_status(&self) -> Option<ConfigStatus> {
        self.reloader.get().map(|r| r.status())
    }
}

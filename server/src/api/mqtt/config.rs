//! The `mqtt:` section of `iogate.yaml`: one broker the gateway publishes into, as a
//! Sparkplug B edge node and/or on plain JSON topics, with a store-and-forward buffer on
//! disk. Read here as written; files (password, TLS) are read when the gateway starts, and
//! checked by `iogate check`.

use std::path::PathBuf;
use std::time::Duration;

use crate::duration;
use crate::yaml::boolean;
use crate::yaml::{Kind, Node, Report};

mod sections;
mod topics;

pub use crate::profile::deadband::Deadband;
pub(crate) use crate::profile::deadband::read_deadband;
use sections::{read_buffer, read_json, read_report, read_sparkplug, read_tls};
pub(crate) use topics::{check_level, check_prefix, parse_size};

const KEYS: &[&str] = &[
    "url",
    "client_id",
    "username",
    "password_file",
    "password_env",
    "tls",
    "version",
    "keep_alive",
    "clean_start",
    "reconnect_max",
    "sparkplug",
    "json",
    "report",
    "buffer",
    "writes",
];
const TLS_KEYS: &[&str] = &["ca", "cert", "key"];
const SPARKPLUG_KEYS: &[&str] = &["group_id", "edge_node_id", "primary_host"];
const JSON_KEYS: &[&str] = &["prefix", "qos", "retain"];
const REPORT_KEYS: &[&str] = &["deadband", "min_interval", "max_interval"];
const BUFFER_KEYS: &[&str] = &["dir", "max_bytes", "max_age", "replay_rate", "fsync"];

pub(crate) const DEFAULT_KEEP_ALIVE: Duration = Duration::from_secs(30);
/// The longest wait between attempts to reach the broker (the waits double up to it, each
/// with a quarter of jitter): short, so a host sees the node born soon after an outage.
pub(crate) const DEFAULT_RECONNECT_MAX: Duration = Duration::from_secs(5);
pub(crate) const DEFAULT_MIN_INTERVAL: Duration = Duration::ZERO;
pub(crate) const DEFAULT_MAX_INTERVAL: Duration = Duration::ZERO;
pub(crate) const DEFAULT_MAX_BYTES: u64 = 256 << 20;
pub(crate) const DEFAULT_MAX_AGE: Duration = Duration::from_secs(7 * 86_400);
pub(crate) const DEFAULT_REPLAY_RATE: u32 = 500;

/// The MQTT protocol version the gateway connects with.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum MqttVersion {
    #[default]
    V311,
    V5,
}

/// Where the broker is.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BrokerUrl {
    pub(crate) tls: bool,
    pub(crate) host: String,
    pub(crate) port: u16,
}

impl std::fmt::Display for BrokerUrl {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let scheme = if self.tls { "mqtts" } else { "mqtt" };
        if self.host.contains(':') {
            write!(f, "{scheme}://[{}]:{}", self.host, self.port)
        } else {
            write!(f, "{scheme}://{}:{}", self.host, self.port)
        }
    }
}

/// Why a broker URL is refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub(crate) enum UrlError {
    #[error("`{0}` is not an MQTT URL (write mqtt://host:port or mqtts://host:port)")]
    Scheme(String),
    #[error("`{0}` has no host")]
    NoHost(String),
    #[error("`{0}` has a port that is not a number 1-65535")]
    Port(String),
    #[error("`{0}` has a path, query or user part; write the user in `username`")]
    Extra(String),
}

impl BrokerUrl {
    pub(crate) fn parse(text: &str) -> Result<BrokerUrl, UrlError> {
        let (tls, rest) = if let Some(rest) = text.strip_prefix("mqtts://") {
            (true, rest)
        } else if let Some(rest) = text.strip_prefix("mqtt://") {
            (false, rest)
        } else {
            return Err(UrlError::Scheme(text.to_owned()));
        };
        let rest = rest.strip_suffix('/').unwrap_or(rest);
        if rest.contains(['/', '?', '#', '@']) {
            return Err(UrlError::Extra(text.to_owned()));
        }
        let default_port = if tls { 8883 } else { 1883 };
        let (host, port) = if let Some(bracketed) = rest.strip_prefix('[') {
            let (host, after) = bracketed
                .split_once(']')
                .ok_or_else(|| UrlError::NoHost(text.to_owned()))?;
            match after.strip_prefix(':') {
                Some(p) => (host, Some(p)),
                None if after.is_empty() => (host, None),
                None => return Err(UrlError::Port(text.to_owned())),
            }
        } else {
            match rest.rsplit_once(':') {
                Some((h, p)) => (h, Some(p)),
                None => (rest, None),
            }
        };
        if host.is_empty() {
            return Err(UrlError::NoHost(text.to_owned()));
        }
        let port = match port {
            None => default_port,
            Some(p) => p
                .parse::<u16>()
                .ok()
                .filter(|&p| p != 0)
                .ok_or_else(|| UrlError::Port(text.to_owned()))?,
        };
        Ok(BrokerUrl {
            tls,
            host: host.to_owned(),
            port,
        })
    }
}

/// TLS files for `mqtts://`: the CA to trust (else the system's roots) and an optional
/// client certificate and key.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct MqttTls {
    pub(crate) ca: Option<PathBuf>,
    pub(crate) cert: Option<PathBuf>,
    pub(crate) key: Option<PathBuf>,
}

/// The Sparkplug B identity of the gateway.
#[derive(Debug, Clone, PartialEq)]
pub struct SparkplugConfig {
    pub(crate) group_id: String,
    pub(crate) edge_node_id: String,
    /// Publish only while this primary host application says it is online.
    pub(crate) primary_host: Option<String>,
}

/// The plain JSON topics.
#[derive(Debug, Clone, PartialEq)]
pub struct JsonConfig {
    pub(crate) prefix: String,
    pub(crate) qos: u8,
    pub(crate) retain: bool,
}

/// Report by exception.
#[derive(Debug, Clone, PartialEq)]
pub struct ReportConfig {
    pub(crate) deadband: Deadband,
    /// At most one report per field this often (0: no limit).
    pub(crate) min_interval: Duration,
    /// At least one report per field this often, changed or not (0: only on change).
    pub(crate) max_interval: Duration,
}

impl Default for ReportConfig {
    fn default() -> Self {
        ReportConfig {
            deadband: Deadband::None,
            min_interval: DEFAULT_MIN_INTERVAL,
            max_interval: DEFAULT_MAX_INTERVAL,
        }
    }
}

/// When the buffer forces its writes to disk.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Fsync {
    /// After every message: a crash loses nothing that was buffered.
    Always,
    /// Once a second: a crash loses at most the last second.
    #[default]
    Second,
    /// Never explicitly (the operating system's choice).
    Never,
}

/// The store-and-forward buffer.
#[derive(Debug, Clone, PartialEq)]
pub struct BufferConfig {
    pub(crate) dir: Option<PathBuf>,
    pub(crate) max_bytes: u64,
    pub(crate) max_age: Duration,
    /// Messages per second replayed after a reconnect.
    pub(crate) replay_rate: u32,
    pub(crate) fsync: Fsync,
}

impl Default for BufferConfig {
    fn default() -> Self {
        BufferConfig {
            dir: None,
            max_bytes: DEFAULT_MAX_BYTES,
            max_age: DEFAULT_MAX_AGE,
            replay_rate: DEFAULT_REPLAY_RATE,
            fsync: Fsync::default(),
        }
    }
}

/// Where the password comes from; it is never logged.
#[derive(Debug, Clone, PartialEq)]
pub enum Password {
    File(PathBuf),
    Env(String),
}

#[derive(Debug, Clone, PartialEq)]
pub struct MqttConfig {
    pub(crate) url: BrokerUrl,
    pub(crate) client_id: String,
    pub(crate) username: Option<String>,
    pub(crate) password: Option<Password>,
    pub(crate) tls: MqttTls,
    pub(crate) version: MqttVersion,
    pub(crate) keep_alive: Duration,
    pub(crate) clean_start: bool,
    /// The longest wait between attempts to connect.
    pub(crate) reconnect_max: Duration,
    pub(crate) sparkplug: Option<SparkplugConfig>,
    pub(crate) json: Option<JsonConfig>,
    pub(crate) report: ReportConfig,
    pub(crate) buffer: BufferConfig,
    pub(crate) writes: bool,
    pub(crate) line: u64,
}

fn duration_at(node: &Node, report: &mut Report, ctx: &str) -> Option<Duration> {
    let text = node.scalar_text(report, ctx)?;
    duration::parse(&text)
        .map_err(|e| report.push(node.line, ctx, e))
        .ok()
}

fn path_at(node: &Node, report: &mut Report, ctx: &str) -> Option<PathBuf> {
    let text = node.scalar_text(report, ctx)?;
    if text.is_empty() {
        report.push(node.line, ctx, "must not be empty");
        return None;
    }
    Some(PathBuf::from(text))
}

fn level_at(node: &Node, report: &mut Report, ctx: &str) -> Option<String> {
    let text = node.scalar_text(report, ctx)?;
    check_level(&text)
        .map_err(|e| report.push(node.line, ctx, e))
        .ok()?;
    Some(text)
}

/// Reads the section; `None` after reporting its problems.
pub(super) fn read(node: &Node, report: &mut Report) -> Option<MqttConfig> {
    let ctx = "mqtt";
    let mut map = node.map(report, ctx)?;
    let at = |k: &str| format!("{ctx}.{k}");
    let url = map
        .require("url", report, ctx)
        .and_then(|n| broker_url(n, report));
    let client_id = match map.get("client_id") {
        None => Some(String::new()),
        Some(n) => client_id(n, report),
    };
    let username = map
        .get("username")
        .and_then(|n| n.scalar_text(report, &at("username")));
    let password = password(&mut map, node.line, report);
    let tls = match map.get("tls") {
        None => MqttTls::default(),
        Some(n) => read_tls(n, report).unwrap_or_default(),
    };
    let version = match map.get("version") {
        None => Some(MqttVersion::V311),
        Some(n) => version(&n.scalar_text(report, &at("version"))?, n.line, report),
    };
    let keep_alive = match map.get("keep_alive") {
        None => Some(DEFAULT_KEEP_ALIVE),
        Some(n) => keep_alive(n, report),
    };
    let clean_line = map.get("clean_start").map_or(node.line, |n| n.line);
    let clean_start = match map.get("clean_start") {
        None => Some(true),
        Some(n) => boolean(n, report, &at("clean_start")),
    };
    let reconnect_max = match map.get("reconnect_max") {
        None => Some(DEFAULT_RECONNECT_MAX),
        Some(n) => reconnect_max(n, report),
    };
    let sparkplug_node = map.get("sparkplug");
    let json_node = map.get("json");
    let sparkplug = sparkplug_node.and_then(|n| read_sparkplug(n, report));
    let json = json_node.and_then(|n| read_json(n, report));
    let report_config = map.get("report").and_then(|n| read_report(n, report));
    let buffer = map.get("buffer").and_then(|n| read_buffer(n, report));
    let writes = match map.get("writes") {
        None => Some(false),
        Some(n) => boolean(n, report, &at("writes")),
    };
    map.finish(report, ctx, KEYS);
    let together = Together {
        url: url.as_ref(),
        tls: &tls,
        sparkplug: sparkplug_node.is_some(),
        json: json_node.is_some(),
        client_id: client_id.as_deref(),
        clean_start,
        clean_line,
    };
    together.check(node.line, report);
    Some(MqttConfig {
        url: url?,
        client_id: client_id.unwrap_or_default(),
        username,
        password,
        tls,
        version: version.unwrap_or_default(),
        keep_alive: keep_alive.unwrap_or(DEFAULT_KEEP_ALIVE),
        clean_start: clean_start.unwrap_or(true),
        reconnect_max: reconnect_max.unwrap_or(DEFAULT_RECONNECT_MAX),
        sparkplug,
        json,
        report: report_config.unwrap_or_default(),
        buffer: buffer.unwrap_or_default(),
        writes: writes.unwrap_or(false),
        line: node.line,
    })
}

/// What the section's keys must agree on together.
struct Together<'a> {
    url: Option<&'a BrokerUrl>,
    tls: &'a MqttTls,
    sparkplug: bool,
    json: bool,
    client_id: Option<&'a str>,
    clean_start: Option<bool>,
    clean_line: u64,
}

impl Together<'_> {
    fn check(&self, line: u64, report: &mut Report) {
        if !self.sparkplug && !self.json {
            report.push(
                line,
                "mqtt",
                "publishes nothing: give `sparkplug:`, `json:` or both",
            );
        }
        if self.url.is_some_and(|u| !u.tls) && *self.tls != MqttTls::default() {
            report.push(
                line,
                "mqtt.tls",
                "TLS files are given but the URL is mqtt://; write mqtts://",
            );
        }
        if self.tls.cert.is_some() != self.tls.key.is_some() {
            report.push(
                line,
                "mqtt.tls",
                "a client certificate needs its key, and a key its certificate",
            );
        }
        if self.sparkplug && self.clean_start == Some(false) {
            report.push(
                self.clean_line,
                "mqtt.clean_start",
                "a Sparkplug B edge node connects with a clean session (Sparkplug 3.0: Clean Session, with MQTT 5 Clean Start and no session expiry): remove clean_start: false",
            );
        }
        if self.client_id == Some("") && self.clean_start == Some(false) {
            report.push(
                line,
                "mqtt.clean_start",
                "a session kept across connections (clean_start: false) needs a client_id",
            );
        }
    }
}

/// `url`: `mqtt://` or `mqtts://` with a host.
fn broker_url(n: &Node, report: &mut Report) -> Option<BrokerUrl> {
    let text = n.scalar_text(report, "mqtt.url")?;
    BrokerUrl::parse(&text)
        .map_err(|e| report.push(n.line, "mqtt.url", e))
        .ok()
}

/// `client_id`: at most 65,535 bytes, no NUL.
fn client_id(n: &Node, report: &mut Report) -> Option<String> {
    let t = n.scalar_text(report, "mqtt.client_id")?;
    if t.len() > 65_535 || t.contains('\0') {
        report.push(n.line, "mqtt.client_id", "is not a valid MQTT client id");
        return None;
    }
    Some(t)
}

/// `password_file` or `password_env`, not both.
fn password(
    map: &mut crate::yaml::MapReader<'_>,
    line: u64,
    report: &mut Report,
) -> Option<Password> {
    let password_file = map
        .get("password_file")
        .and_then(|n| path_at(n, report, "mqtt.password_file"));
    let password_env = map.get("password_env").and_then(|n| {
        let name = n.scalar_text(report, "mqtt.password_env")?;
        if name.is_empty() || name.contains(['=', '\0']) {
            report.push(
                n.line,
                "mqtt.password_env",
                "is not an environment variable name",
            );
            return None;
        }
        Some(name)
    });
    match (password_file, password_env) {
        (Some(_), Some(_)) => {
            report.push(
                line,
                "mqtt",
                "give the password in password_file or password_env, not both",
            );
            None
        }
        (Some(f), None) => Some(Password::File(f)),
        (None, Some(e)) => Some(Password::Env(e)),
        (None, None) => None,
    }
}

/// `version`: 3.1.1 (or 4) or 5.
fn version(text: &str, line: u64, report: &mut Report) -> Option<MqttVersion> {
    match text {
        "3.1.1" | "4" => Some(MqttVersion::V311),
        "5" | "5.0" => Some(MqttVersion::V5),
        other => {
            report.push(
                line,
                "mqtt.version",
                format!("unknown MQTT version `{other}` (expected 3.1.1 or 5)"),
            );
            None
        }
    }
}

/// `keep_alive`: 0 (off) or whole seconds up to 65535.
fn keep_alive(n: &Node, report: &mut Report) -> Option<Duration> {
    let d = duration_at(n, report, "mqtt.keep_alive")?;
    if d.as_secs() > u64::from(u16::MAX) || (d > Duration::ZERO && d.as_secs() == 0) {
        report.push(
            n.line,
            "mqtt.keep_alive",
            "must be 0 (off) or whole seconds from 1s to 65535s",
        );
        return None;
    }
    Some(d)
}

/// `reconnect_max`: from 500 ms to an hour.
fn reconnect_max(n: &Node, report: &mut Report) -> Option<Duration> {
    let d = duration_at(n, report, "mqtt.reconnect_max")?;
    if !(Duration::from_millis(500)..=Duration::from_secs(3600)).contains(&d) {
        report.push(n.line, "mqtt.reconnect_max", "must be from 500ms to 1h");
        return None;
    }
    Some(d)
}

#[cfg(test)]
mod tests;

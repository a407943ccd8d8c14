//! A link's `opcua:` settings: the endpoint URL, the security policy and mode, the
//! application certificate (given, or made in the PKI directory), the server certificates
//! to trust, and who the gateway is to the server (anonymous, a user name with a password
//! file, or a user certificate). Read at `check` (every problem with its line) and again
//! when the link opens.

use std::path::{Path, PathBuf};

use crate::config::DriverLink;
use crate::yaml::{Kind, MapReader, Node, Report};

const KEYS: &[&str] = &[
    "url",
    "security_policy",
    "security_mode",
    "certificate",
    "private_key",
    "pki_dir",
    "trusted",
    "user",
    "subscribe",
    "accept_host_mismatch",
    "max_message_size",
    "max_string_length",
    "max_array_length",
];

/// What the client decodes of a server's answers, at most: a larger message, string or
/// array ends the connection, so the defaults are what servers send (FreeOpcUa's first
/// publish of a 2,000-field device, a long string) and the settings raise them, bounded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Limits {
    /// Bytes of one message (all its chunks).
    pub(crate) message: usize,
    /// Bytes of one string or byte string.
    pub(crate) string: usize,
    /// Elements of one array (a publish answer's notifications among them).
    pub(crate) array: usize,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            message: 16 << 20,
            string: 1 << 20,
            array: 100_000,
        }
    }
}

/// The bounds of each limit: (key, least, most).
const LIMIT_BOUNDS: [(&str, i128, i128); 3] = [
    ("max_message_size", 65_535, 256 << 20),
    ("max_string_length", 65_535, 64 << 20),
    ("max_array_length", 1_000, 10_000_000),
];
const USER_KEYS: &[&str] = &["username", "password_file", "certificate", "private_key"];

/// The security policies, as the profile of OPC UA Part 7 names them, and the names the
/// OPC UA library knows them by.
pub(crate) const POLICIES: &[(&str, &str)] = &[
    ("None", "None"),
    ("Basic256Sha256", "Basic256Sha256"),
    ("Aes128_Sha256_RsaOaep", "Aes128-Sha256-RsaOaep"),
    ("Aes256_Sha256_RsaPss", "Aes256-Sha256-RsaPss"),
];
const MODES: &[&str] = &["None", "Sign", "SignAndEncrypt"];

/// The PKI directory when the settings name none, beside the config file.
pub(crate) const DEFAULT_PKI_DIR: &str = "pki/client";

/// Who the gateway is to the server.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum User {
    Anonymous,
    Password { username: String, file: PathBuf },
    Certificate { certificate: PathBuf, key: PathBuf },
}

#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Settings {
    pub(crate) url: String,
    /// The library's name of the policy.
    pub(crate) policy: &'static str,
    pub(crate) mode: &'static str,
    pub(crate) certificate: Option<PathBuf>,
    pub(crate) private_key: Option<PathBuf>,
    pub(crate) pki_dir: PathBuf,
    /// Server certificates (DER or PEM files) trusted besides those in `pki_dir/trusted`.
    pub(crate) trusted: Vec<PathBuf>,
    pub(crate) user: User,
    /// Monitored items where the server has subscriptions (`false`: read every refresh).
    pub(crate) subscribe: bool,
    /// A trusted server certificate is accepted although the host name the URL names is
    /// not among its DNS and IP names (a server reached through another name).
    pub(crate) accept_host_mismatch: bool,
    pub(crate) limits: Limits,
}

/// Reads a link's settings; `None` after reporting every problem.
pub(crate) fn read(link: &str, d: &DriverLink, report: &mut Report) -> Option<Settings> {
    let ctx = format!("link {link}: opcua");
    let at = |k: &str| format!("{ctx}.{k}");
    let mut map = d.settings.map(report, &ctx)?;
    let base = &d.base;
    let url = map.get("url").and_then(|n| endpoint(n, report, &at("url")));
    let policy = word(
        &mut map,
        "security_policy",
        &at("security_policy"),
        report,
        POLICIES.iter().map(|p| p.0),
    )
    .map(|p| {
        p.map_or("None", |p| {
            POLICIES
                .iter()
                .find(|(n, _)| *n == p)
                .map_or("None", |x| x.1)
        })
    });
    let mode = word(
        &mut map,
        "security_mode",
        &at("security_mode"),
        report,
        MODES.iter().copied(),
    );
    let certificate = map
        .get("certificate")
        .and_then(|n| path(n, base, report, &at("certificate")));
    let private_key = map
        .get("private_key")
        .and_then(|n| path(n, base, report, &at("private_key")));
    let pki_dir = match map.get("pki_dir") {
        None => Some(base.join(DEFAULT_PKI_DIR)),
        Some(n) => path(n, base, report, &at("pki_dir")),
    };
    let trusted = map
        .get("trusted")
        .map_or(Some(Vec::new()), |n| paths(n, base, report, &at("trusted")));
    let user = match map.get("user") {
        None => Some(User::Anonymous),
        Some(n) => user(n, base, report, &at("user")),
    };
    let subscribe = match map.get("subscribe") {
        None => Some(true),
        Some(n) => crate::yaml::boolean(n, report, &at("subscribe")),
    };
    let accept_host_mismatch = match map.get("accept_host_mismatch") {
        None => Some(false),
        Some(n) => crate::yaml::boolean(n, report, &at("accept_host_mismatch")),
    };
    let limits = read_limits(&mut map, report, &ctx);
    map.finish(report, &ctx, KEYS);
    let (policy, mode) = (policy?, mode?);
    let mode = secured(policy, mode, d.settings.line, &ctx, report)?;
    if certificate.is_some() != private_key.is_some() {
        report.push(
            d.settings.line,
            &ctx,
            "an application certificate needs its private_key, and a key its certificate",
        );
        return None;
    }
    Some(Settings {
        url: url?,
        policy,
        mode,
        certificate,
        private_key,
        pki_dir: pki_dir?,
        trusted: trusted?,
        user: user?,
        subscribe: subscribe?,
        accept_host_mismatch: accept_host_mismatch?,
        limits: limits?,
    })
}

/// The message, string and array limits the settings raise or lower.
fn read_limits(
    map: &mut crate::yaml::MapReader<'_>,
    report: &mut Report,
    ctx: &str,
) -> Option<Limits> {
    let mut limits = Some(Limits::default());
    for (key, least, most) in LIMIT_BOUNDS {
        let Some(n) = map.get(key) else { continue };
        let value = n
            .int_in(report, &format!("{ctx}.{key}"), least, most)
            .map(|v| v as usize);
        match (value, limits.as_mut()) {
            (Some(v), Some(l)) => match key {
                "max_message_size" => l.message = v,
                "max_string_length" => l.string = v,
                _ => l.array = v,
            },
            _ => limits = None,
        }
    }
    limits
}

/// An endpoint URL: `opc.tcp://` and where.
fn endpoint(n: &Node, report: &mut Report, ctx: &str) -> Option<String> {
    let text = n.scalar_text(report, ctx)?;
    if text.starts_with("opc.tcp://") && text.len() > "opc.tcp://".len() {
        return Some(text);
    }
    report.push(
        n.line,
        ctx,
        format!(
            "`{}` is not an OPC UA endpoint (write opc.tcp://HOST:PORT[/PATH])",
            crate::text::quote(&text)
        ),
    );
    None
}

/// The security mode a policy goes with: none without one, SignAndEncrypt unless said.
fn secured(
    policy: &'static str,
    mode: Option<&'static str>,
    line: u64,
    ctx: &str,
    report: &mut Report,
) -> Option<&'static str> {
    Some(match (policy, mode) {
        ("None", None | Some("None")) => "None",
        ("None", Some(m)) => {
            report.push(
                line,
                ctx,
                format!("security_mode {m} needs a security_policy other than None"),
            );
            return None;
        }
        (_, None) => "SignAndEncrypt",
        (_, Some("None")) => {
            report.push(
                line,
                ctx,
                format!("security_policy {policy} needs security_mode Sign or SignAndEncrypt"),
            );
            return None;
        }
        (_, Some(m)) => m,
    })
}

/// One of `allowed`, or nothing written (`Some(None)`).
fn word<'w>(
    map: &mut MapReader<'_>,
    key: &str,
    ctx: &str,
    report: &mut Report,
    allowed: impl Iterator<Item = &'w str> + Clone,
) -> Option<Option<&'w str>> {
    let Some(n) = map.get(key) else {
        return Some(None);
    };
    let text = n.scalar_text(report, ctx)?;
    match allowed.clone().find(|w| *w == text) {
        Some(w) => Some(Some(w)),
        None => {
            let all: Vec<&str> = allowed.collect();
            report.push(
                n.line,
                ctx,
                format!(
                    "unknown `{}` (expected one of: {})",
                    crate::text::quote(&text),
                    all.join(", ")
                ),
            );
            None
        }
    }
}

fn path(node: &Node, base: &Path, report: &mut Report, ctx: &str) -> Option<PathBuf> {
    let text = node.scalar_text(report, ctx)?;
    if text.is_empty() || text.contains('\0') {
        report.push(node.line, ctx, "is not a path");
        return None;
    }
    Some(base.join(text))
}

fn paths(node: &Node, base: &Path, report: &mut Report, ctx: &str) -> Option<Vec<PathBuf>> {
    match &node.kind {
        Kind::Seq(items) => items.iter().map(|n| path(n, base, report, ctx)).collect(),
        _ => path(node, base, report, ctx).map(|p| vec![p]),
    }
}

/// `anonymous`, `{ username, password_file }` or `{ certificate, private_key }`.
fn user(node: &Node, base: &Path, report: &mut Report, ctx: &str) -> Option<User> {
    if let Kind::Str(s) = &node.kind {
        if s == "anonymous" {
            return Some(User::Anonymous);
        }
        report.push(node.line, ctx, format!("`{}`: write `anonymous`, `{{ username, password_file }}` or `{{ certificate, private_key }}`", crate::text::quote(s)));
        return None;
    }
    let mut map = node.map(report, ctx)?;
    let at = |k: &str| format!("{ctx}.{k}");
    let username = map
        .get("username")
        .and_then(|n| n.scalar_text(report, &at("username")));
    let file = map
        .get("password_file")
        .and_then(|n| path(n, base, report, &at("password_file")));
    let certificate = map
        .get("certificate")
        .and_then(|n| path(n, base, report, &at("certificate")));
    let key = map
        .get("private_key")
        .and_then(|n| path(n, base, report, &at("private_key")));
    map.finish(report, ctx, USER_KEYS);
    match (username, file, certificate, key) {
        (Some(username), Some(file), None, None) => Some(User::Password { username, file }),
        (None, None, Some(certificate), Some(key)) => Some(User::Certificate { certificate, key }),
        _ => {
            report.push(
                node.line,
                ctx,
                "a user is `{ username, password_file }` or `{ certificate, private_key }`",
            );
            None
        }
    }
}

/// The password in a user's password file: its first line.
pub(crate) fn password(file: &Path) -> Result<String, String> {
    let text = std::fs::read_to_string(file)
        .map_err(|e| format!("password_file {}: {e}", file.display()))?;
    Ok(text.lines().next().unwrap_or_default().to_owned())
}

/// Every file the settings name, read as `check` reads them: what cannot be read is named.
pub(crate) fn check_files(link: &str, s: &Settings) -> Vec<String> {
    let mut files: Vec<(&str, &Path)> = Vec::new();
    if let (Some(c), Some(k)) = (&s.certificate, &s.private_key) {
        files.push(("certificate", c));
        files.push(("private_key", k));
    }
    for t in &s.trusted {
        files.push(("trusted", t));
    }
    match &s.user {
        User::Anonymous => {}
        User::Password { file, .. } => files.push(("user.password_file", file)),
        User::Certificate { certificate, key } => {
            files.push(("user.certificate", certificate));
            files.push(("user.private_key", key));
        }
    }
    files
        .into_iter()
        .filter_map(|(key, p)| {
            std::fs::metadata(p)
                .err()
                .map(|e| format!("link {link}: opcua.{key} {}: {e}", p.display()))
        })
        .collect()
}

#[cfg(test)]
#[path = "config_tests.rs"]
mod tests;

//! The `opcua:` section of `iogate.yaml`: the OPC UA server, its endpoints' security, its
//! certificates and who may connect. Read here as written; the certificate files and the
//! PKI directory are made or read when the gateway starts.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use crate::yaml::boolean;
use crate::yaml::{Kind, Node, Report};

const KEYS: &[&str] = &[
    "listen",
    "application_uri",
    "security",
    "pki_dir",
    "certificate",
    "private_key",
    "trust_client_certs",
    "users",
    "anonymous",
    "max_sessions",
    "max_subscriptions_per_session",
    "max_monitored_items_per_subscription",
    "max_monitored_items",
    "max_connections",
    "max_connections_per_client",
    "max_notifications_per_publish",
    "subscription_lifetime",
];

pub(crate) const DEFAULT_LISTEN: &str = "127.0.0.1:4840";
pub(crate) const DEFAULT_APPLICATION_URI: &str = "urn:iogate";
pub(crate) const DEFAULT_PKI_DIR: &str = "pki";
pub(crate) const DEFAULT_MAX_SESSIONS: usize = 100;
pub(crate) const DEFAULT_MAX_SUBSCRIPTIONS: usize = 10;
pub(crate) const DEFAULT_MAX_MONITORED_ITEMS: usize = 20_000;
/// Monitored items of all sessions together, by default: what 10,000 fields watched by five
/// clients need, bounding the memory every client together can make the server hold.
pub(crate) const DEFAULT_MAX_MONITORED_ITEMS_TOTAL: usize = 50_000;
/// TCP connections open at once, by default, and from one address: room for every session
/// and for short discovery connections beside them.
pub(crate) const DEFAULT_MAX_CONNECTIONS: usize = 256;
pub(crate) const DEFAULT_MAX_CONNECTIONS_PER_CLIENT: usize = 64;
/// Notifications in one publish answer, at most, by default (a client may ask for fewer):
/// async-opcua's clients decode arrays of at most 1,000 by default, and a longer answer
/// would end their session. An answer is also closed at about 160 KiB of notifications.
pub(crate) const DEFAULT_MAX_NOTIFICATIONS_PER_PUBLISH: usize = 1000;
const MAX_NOTIFICATIONS_PER_PUBLISH: usize = 100_000;
/// How long a subscription outlives its client's last publish request, by default: a
/// vanished client's subscriptions and items go about when its session does.
pub(crate) const DEFAULT_SUBSCRIPTION_LIFETIME: Duration = Duration::from_secs(60);
/// The most sessions, subscriptions per session and items per subscription configurable.
const MAX_SESSIONS: usize = 10_000;
const MAX_SUBSCRIPTIONS: usize = 1_000;
const MAX_MONITORED_ITEMS: usize = 1_000_000;

/// One endpoint's security: a policy and a message security mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub(crate) enum Endpoint {
    None,
    Basic256Sha256Sign,
    Basic256Sha256SignEncrypt,
    Aes256Sha256RsaPssSign,
    Aes256Sha256RsaPssSignEncrypt,
}

impl Endpoint {
    pub(crate) const ALL: [Endpoint; 5] = [
        Endpoint::None,
        Endpoint::Basic256Sha256Sign,
        Endpoint::Basic256Sha256SignEncrypt,
        Endpoint::Aes256Sha256RsaPssSign,
        Endpoint::Aes256Sha256RsaPssSignEncrypt,
    ];

    /// The name in `opcua.security`.
    pub(crate) fn name(self) -> &'static str {
        match self {
            Endpoint::None => "none",
            Endpoint::Basic256Sha256Sign => "basic256sha256_sign",
            Endpoint::Basic256Sha256SignEncrypt => "basic256sha256_sign_encrypt",
            Endpoint::Aes256Sha256RsaPssSign => "aes256_sha256_rsapss_sign",
            Endpoint::Aes256Sha256RsaPssSignEncrypt => "aes256_sha256_rsapss_sign_encrypt",
        }
    }

    fn parse(text: &str) -> Option<Endpoint> {
        Endpoint::ALL.into_iter().find(|e| e.name() == text)
    }
}

/// Who a client is, beyond its certificate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(crate) enum Users {
    /// User name `token` with one of the gateway's bearer tokens as password: its role.
    #[default]
    Tokens,
}

/// What an anonymous session may do.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Anonymous {
    /// Refused.
    Refused,
    /// The role given.
    Role(crate::auth::Role),
}

#[derive(Debug, Clone, PartialEq)]
pub struct OpcUaConfig {
    pub listen: SocketAddr,
    pub(crate) application_uri: String,
    /// The endpoints offered, in order.
    pub(crate) security: Vec<Endpoint>,
    /// Trusted, rejected and own certificates (relative to the config's directory).
    pub(crate) pki_dir: PathBuf,
    /// The application certificate (DER) and key (PEM) when given; else made on first
    /// start in the PKI directory.
    pub(crate) certificate: Option<PathBuf>,
    pub(crate) private_key: Option<PathBuf>,
    /// Trust every client certificate (tests and commissioning only).
    pub(crate) trust_client_certs: bool,
    pub(crate) users: Users,
    /// `None`: as the tokens decide (no tokens configured: anonymous may do everything, as
    /// REST; tokens configured: refused).
    pub(crate) anonymous: Option<Anonymous>,
    pub(crate) max_sessions: usize,
    pub(crate) max_subscriptions_per_session: usize,
    pub(crate) max_monitored_items_per_subscription: usize,
    /// Monitored items of every session together.
    pub(crate) max_monitored_items: usize,
    /// Notifications in one publish answer, at most.
    pub(crate) max_notifications_per_publish: usize,
    /// How long a subscription outlives its client's last publish request, at most (its
    /// lifetime and keep-alive counts are revised to keep within it).
    pub(crate) subscription_lifetime: Duration,
    /// TCP connections open at once, and from one IP address.
    pub(crate) max_connections: usize,
    pub(crate) max_connections_per_client: usize,
    pub(crate) line: u64,
}

fn count(node: &Node, report: &mut Report, ctx: &str, max: usize) -> Option<usize> {
    node.int_in(report, ctx, 1, max as i128).map(|n| n as usize)
}

fn path(node: &Node, report: &mut Report, ctx: &str) -> Option<PathBuf> {
    let text = node.scalar_text(report, ctx)?;
    if text.is_empty() || text.contains('\0') {
        report.push(node.line, ctx, "is not a path");
        return None;
    }
    Some(PathBuf::from(text))
}

/// Reads the section; `None` after reporting its problems.
pub(super) fn read(node: &Node, report: &mut Report) -> Option<OpcUaConfig> {
    let ctx = "opcua";
    let mut map = node.map(report, ctx)?;
    let at = |k: &str| format!("{ctx}.{k}");
    let listen = match map.get("listen") {
        None => DEFAULT_LISTEN.parse().ok(),
        Some(n) => address(&n.scalar_text(report, &at("listen"))?, n.line, report),
    };
    let application_uri = match map.get("application_uri") {
        None => Some(DEFAULT_APPLICATION_URI.to_owned()),
        Some(n) => uri(n, report),
    };
    let security = match map.get("security") {
        None => None,
        Some(n) => read_security(n, report),
    };
    let pki_dir = match map.get("pki_dir") {
        None => Some(PathBuf::from(DEFAULT_PKI_DIR)),
        Some(n) => path(n, report, &at("pki_dir")),
    };
    let certificate = map
        .get("certificate")
        .and_then(|n| path(n, report, &at("certificate")));
    let private_key = map
        .get("private_key")
        .and_then(|n| path(n, report, &at("private_key")));
    let trust_client_certs = match map.get("trust_client_certs") {
        None => Some(false),
        Some(n) => boolean(n, report, &at("trust_client_certs")),
    };
    let (users, anonymous) = who(&mut map, report);
    let [
        max_sessions,
        max_subscriptions,
        max_items,
        max_items_total,
        max_connections,
        max_per_client,
        max_notifications,
    ] = limits(&mut map, report);
    let subscription_lifetime = lifetime(&mut map, report);
    map.finish(report, ctx, KEYS);
    if certificate.is_some() != private_key.is_some() {
        report.push(
            node.line,
            ctx,
            "an application certificate needs its private_key, and a key its certificate",
        );
    }
    let listen = listen?;
    let security = security.unwrap_or_else(|| default_security(listen));
    Some(OpcUaConfig {
        listen,
        application_uri: application_uri?,
        security,
        pki_dir: pki_dir?,
        certificate,
        private_key,
        trust_client_certs: trust_client_certs?,
        users: users?,
        anonymous: anonymous?,
        max_sessions: max_sessions?,
        max_subscriptions_per_session: max_subscriptions?,
        max_monitored_items_per_subscription: max_items?,
        max_monitored_items: max_items_total?,
        max_connections: max_connections?,
        max_connections_per_client: max_per_client?,
        max_notifications_per_publish: max_notifications?,
        subscription_lifetime: subscription_lifetime?,
        line: node.line,
    })
}

/// `listen`: host:port.
fn address(text: &str, line: u64, report: &mut Report) -> Option<SocketAddr> {
    text.parse::<SocketAddr>()
        .map_err(|_| {
            report.push(
                line,
                "opcua.listen",
                format!("`{text}` is not an address (host:port, e.g. 0.0.0.0:4840)"),
            )
        })
        .ok()
}

/// `application_uri`: a URI (a scheme, no spaces).
fn uri(n: &Node, report: &mut Report) -> Option<String> {
    let t = n.scalar_text(report, "opcua.application_uri")?;
    let scheme = t.split_once(':').map(|(s, _)| s);
    let valid = scheme.is_some_and(|s| {
        !s.is_empty()
            && s.chars()
                .all(|c| c.is_ascii_alphanumeric() || matches!(c, '+' | '-' | '.'))
    }) && !t.chars().any(|c| c.is_whitespace() || c.is_control());
    if !valid {
        report.push(
            n.line,
            "opcua.application_uri",
            format!("`{t}` is not a URI (e.g. urn:iogate:line1)"),
        );
        return None;
    }
    Some(t)
}

/// `users` and `anonymous`: where users come from, and what anonymous sessions may do.
fn who(
    map: &mut crate::yaml::MapReader<'_>,
    report: &mut Report,
) -> (Option<Users>, Option<Option<Anonymous>>) {
    let users = match map.get("users") {
        None => Some(Users::Tokens),
        Some(n) => n
            .scalar_text(report, "opcua.users")
            .and_then(|t| users(&t, n.line, report)),
    };
    let anonymous = match map.get("anonymous") {
        None => Some(None),
        Some(n) => match n.kind {
            Kind::Bool(false) => Some(Some(Anonymous::Refused)),
            _ => n
                .scalar_text(report, "opcua.anonymous")
                .and_then(|t| anonymous(&t, n.line, report))
                .map(Some),
        },
    };
    (users, anonymous)
}

/// `subscription_lifetime`: at least a second.
fn lifetime(map: &mut crate::yaml::MapReader<'_>, report: &mut Report) -> Option<Duration> {
    map.get("subscription_lifetime")
        .map_or(Some(DEFAULT_SUBSCRIPTION_LIFETIME), |n| {
            let ctx = "opcua.subscription_lifetime";
            crate::config::duration_value(n, report, ctx, Duration::from_secs(1))
        })
}

/// `users`: where users come from (`tokens`).
fn users(text: &str, line: u64, report: &mut Report) -> Option<Users> {
    match text {
        "tokens" => Some(Users::Tokens),
        other => {
            report.push(
                line,
                "opcua.users",
                format!("unknown user source `{other}` (expected tokens)"),
            );
            None
        }
    }
}

/// `anonymous`: the role anonymous sessions have.
fn anonymous(text: &str, line: u64, report: &mut Report) -> Option<Anonymous> {
    match crate::auth::Role::parse(text) {
        Some(role) => Some(Anonymous::Role(role)),
        None => {
            report.push(
                line,
                "opcua.anonymous",
                format!(
                    "`{text}` is not a role (read, write or admin; false refuses anonymous sessions)"
                ),
            );
            None
        }
    }
}

/// The sessions', subscriptions', monitored items' and connections' bounds and the
/// notifications in a publish answer, in that order.
fn limits(map: &mut crate::yaml::MapReader<'_>, report: &mut Report) -> [Option<usize>; 7] {
    [
        ("max_sessions", DEFAULT_MAX_SESSIONS, MAX_SESSIONS),
        (
            "max_subscriptions_per_session",
            DEFAULT_MAX_SUBSCRIPTIONS,
            MAX_SUBSCRIPTIONS,
        ),
        (
            "max_monitored_items_per_subscription",
            DEFAULT_MAX_MONITORED_ITEMS,
            MAX_MONITORED_ITEMS,
        ),
        (
            "max_monitored_items",
            DEFAULT_MAX_MONITORED_ITEMS_TOTAL,
            MAX_MONITORED_ITEMS,
        ),
        ("max_connections", DEFAULT_MAX_CONNECTIONS, 4 * MAX_SESSIONS),
        (
            "max_connections_per_client",
            DEFAULT_MAX_CONNECTIONS_PER_CLIENT,
            4 * MAX_SESSIONS,
        ),
        (
            "max_notifications_per_publish",
            DEFAULT_MAX_NOTIFICATIONS_PER_PUBLISH,
            MAX_NOTIFICATIONS_PER_PUBLISH,
        ),
    ]
    .map(|(key, default, max)| match map.get(key) {
        None => Some(default),
        Some(n) => count(n, report, &format!("opcua.{key}"), max),
    })
}

/// Every secure endpoint, and `none` on a loopback listener.
fn default_security(listen: SocketAddr) -> Vec<Endpoint> {
    Endpoint::ALL
        .into_iter()
        .filter(|e| *e != Endpoint::None || listen.ip().is_loopback())
        .collect()
}

fn read_security(node: &Node, report: &mut Report) -> Option<Vec<Endpoint>> {
    let ctx = "opcua.security";
    let items = node.seq(report, ctx)?;
    let mut out = Vec::new();
    let mut ok = true;
    for item in items {
        let Some(text) = item.scalar_text(report, ctx) else {
            ok = false;
            continue;
        };
        match Endpoint::parse(&text) {
            Some(e) if out.contains(&e) => {
                report.push(item.line, ctx, format!("`{text}` is listed twice"));
                ok = false;
            }
            Some(e) => out.push(e),
            None => {
                report.push(
                    item.line,
                    ctx,
                    format!(
                        "unknown endpoint `{text}` (expected {})",
                        Endpoint::ALL.map(Endpoint::name).join(", ")
                    ),
                );
                ok = false;
            }
        }
    }
    if ok && out.is_empty() {
        report.push(node.line, ctx, "lists no endpoint");
        ok = false;
    }
    ok.then_some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read_text(text: &str) -> (Option<OpcUaConfig>, Vec<String>) {
        crate::config::read_section(text, "opcua", read)
    }

    #[test]
    fn the_interface_section_reads_and_defaults_are_documented_ones() {
        let (config, problems) = read_text(
            "opcua:
  listen: 127.0.0.1:4840
  application_uri: urn:iogate:line1
  security: [none, basic256sha256_sign_encrypt]
  pki_dir: /var/lib/iogate/pki
  users: tokens
  max_sessions: 100
",
        );
        assert_eq!(problems, Vec::<String>::new());
        let config = config.expect("read");
        assert_eq!(
            config.security,
            vec![Endpoint::None, Endpoint::Basic256Sha256SignEncrypt]
        );
        assert_eq!(config.application_uri, "urn:iogate:line1");
        assert_eq!(config.max_sessions, 100);
        // Defaults: every secure endpoint, `none` only on loopback.
        let (loopback, _) = read_text("opcua: {}\n");
        let loopback = loopback.expect("read");
        assert_eq!(loopback.listen.to_string(), DEFAULT_LISTEN);
        assert_eq!(loopback.security, Endpoint::ALL.to_vec());
        assert_eq!(loopback.max_monitored_items_per_subscription, 20_000);
        assert_eq!(loopback.subscription_lifetime, Duration::from_secs(60));
        let (wide, _) = read_text("opcua: { listen: 0.0.0.0:4840 }\n");
        assert!(!wide.expect("read").security.contains(&Endpoint::None));
    }

    #[test]
    fn every_bad_key_is_named_with_its_line() {
        let (config, problems) = read_text(
            "opcua:
  listen: somewhere
  application_uri: not a uri
  security: [none, none, basic128]
  users: ldap
  anonymous: root
  max_sessions: 0
  certificate: own.der
  colour: red
  subscription_lifetime: 500ms
",
        );
        assert!(config.is_none());
        let text = problems.join("\n");
        for expected in [
            "2: opcua.listen: `somewhere` is not an address",
            "3: opcua.application_uri: `not a uri` is not a URI",
            "4: opcua.security: `none` is listed twice",
            "4: opcua.security: unknown endpoint `basic128`",
            "5: opcua.users: unknown user source `ldap`",
            "6: opcua.anonymous: `root` is not a role",
            "7: opcua.max_sessions: 0 is outside the allowed range 1-10000",
            "opcua: an application certificate needs its private_key",
            "opcua: unknown key `colour`",
            "10: opcua.subscription_lifetime: must be at least 1000ms",
        ] {
            assert!(text.contains(expected), "{expected}\n{text}");
        }
    }
}

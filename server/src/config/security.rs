//! The `security:` section: who may do what (`tokens_file`, `read_only`, `insecure`), TLS
//! for the listeners (`tls: {cert, key, client_ca}`) and what run-time declarations may
//! reach (`declare.serial_ports`, `declare.tcp_hosts`).

use std::net::IpAddr;
use std::path::PathBuf;

use crate::yaml::{Kind, Node, Report};

const KEYS: &[&str] = &["tokens_file", "read_only", "insecure", "tls", "declare"];
const TLS_KEYS: &[&str] = &["cert", "key", "client_ca"];
const DECLARE_KEYS: &[&str] = &["serial_ports", "tcp_hosts"];

/// Serial ports a run-time declaration may open when none are configured.
pub(crate) const DEFAULT_SERIAL_PORTS: &[&str] = &[
    "/dev/ttyS*",
    "/dev/ttyUSB*",
    "/dev/ttyACM*",
    "/dev/ttyAMA*",
    "/dev/serial/by-id/*",
];

/// A TCP endpoint run-time declarations may connect to.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum HostRule {
    /// An address range, `192.0.2.0/24` (a single address is a /32 or /128).
    Network { addr: IpAddr, prefix: u8 },
    /// A host name or address, with a port or any port.
    Host { host: String, port: Option<u16> },
}

impl HostRule {
    pub fn parse(text: &str) -> Option<HostRule> {
        if let Some((addr, prefix)) = text.split_once('/') {
            let addr: IpAddr = addr.parse().ok()?;
            let max = if addr.is_ipv4() { 32 } else { 128 };
            let prefix: u8 = prefix.parse().ok().filter(|p| *p <= max)?;
            return Some(HostRule::Network { addr, prefix });
        }
        if let Ok(addr) = text.parse::<IpAddr>() {
            let prefix = if addr.is_ipv4() { 32 } else { 128 };
            return Some(HostRule::Network { addr, prefix });
        }
        match text.rsplit_once(':') {
            Some((host, port)) if !host.is_empty() => Some(HostRule::Host {
                host: host.to_ascii_lowercase(),
                port: Some(port.parse().ok()?),
            }),
            _ if !text.is_empty() && !text.contains(char::is_whitespace) => Some(HostRule::Host {
                host: text.to_ascii_lowercase(),
                port: None,
            }),
            _ => None,
        }
    }

    /// Whether `host:port` is allowed by this rule.
    pub(crate) fn allows(&self, host: &str, port: u16) -> bool {
        match self {
            HostRule::Network { addr, prefix } => {
                let Ok(ip) = host.parse::<IpAddr>() else {
                    return false;
                };
                match (addr, ip) {
                    (IpAddr::V4(a), IpAddr::V4(b)) => {
                        let mask = u32::MAX.checked_shl(32 - u32::from(*prefix)).unwrap_or(0);
                        u32::from(*a) & mask == u32::from(b) & mask
                    }
                    (IpAddr::V6(a), IpAddr::V6(b)) => {
                        let mask = u128::MAX.checked_shl(128 - u32::from(*prefix)).unwrap_or(0);
                        u128::from(*a) & mask == u128::from(b) & mask
                    }
                    _ => false,
                }
            }
            HostRule::Host { host: h, port: p } => {
                h.eq_ignore_ascii_case(host) && p.is_none_or(|p| p == port)
            }
        }
    }
}

/// What run-time declarations may reach.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DeclarePolicy {
    /// Glob patterns (`*` any characters) of serial port paths.
    pub serial_ports: Vec<String>,
    /// TCP endpoints; none by default.
    pub tcp_hosts: Vec<HostRule>,
}

impl Default for DeclarePolicy {
    fn default() -> Self {
        DeclarePolicy {
            serial_ports: DEFAULT_SERIAL_PORTS
                .iter()
                .map(|s| (*s).to_owned())
                .collect(),
            tcp_hosts: Vec::new(),
        }
    }
}

/// `*` matches any run of characters (also `/`); everything else itself.
pub(crate) fn glob(pattern: &str, text: &str) -> bool {
    match pattern.split_once('*') {
        None => pattern == text,
        Some((head, rest)) => {
            let Some(tail) = text.strip_prefix(head) else {
                return false;
            };
            (0..=tail.len())
                .filter(|&i| tail.is_char_boundary(i))
                .any(|i| glob(rest, &tail[i..]))
        }
    }
}

impl DeclarePolicy {
    pub(crate) fn allows_serial(&self, port: &str) -> bool {
        self.serial_ports.iter().any(|p| glob(p, port))
    }

    pub(crate) fn allows_tcp(&self, host: &str, port: u16) -> bool {
        self.tcp_hosts.iter().any(|r| r.allows(host, port))
    }
}

#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct SecurityConfig {
    pub(crate) tokens_file: Option<PathBuf>,
    pub(crate) read_only: bool,
    pub(crate) insecure: bool,
    pub(crate) tls: Option<crate::tls::TlsFiles>,
    pub declare: DeclarePolicy,
    /// The lines of `tokens_file` and `tls` (0: not written), for problems found when their
    /// files are loaded.
    pub(crate) tokens_file_line: u64,
    pub(crate) tls_line: u64,
}

impl SecurityConfig {
    /// Makes the relative paths relative to `base`, the config file's directory.
    pub(crate) fn resolve(&mut self, base: &std::path::Path) {
        let paths = [self.tokens_file.as_mut()].into_iter().chain(
            self.tls
                .iter_mut()
                .flat_map(|t| [Some(&mut t.cert), Some(&mut t.key), t.client_ca.as_mut()]),
        );
        for path in paths.flatten() {
            if path.is_relative() {
                *path = base.join(&*path);
            }
        }
    }
}

fn read_tls(node: &Node, report: &mut Report) -> Option<crate::tls::TlsFiles> {
    let mut map = node.map(report, "security.tls")?;
    let mut path = |key: &str, report: &mut Report| {
        map.get(key)
            .and_then(|n| n.scalar_text(report, &format!("security.tls.{key}")))
            .map(PathBuf::from)
    };
    let cert = path("cert", report);
    let key = path("key", report);
    let client_ca = path("client_ca", report);
    map.finish(report, "security.tls", TLS_KEYS);
    match (cert, key) {
        (Some(cert), Some(key)) => Some(crate::tls::TlsFiles {
            cert,
            key,
            client_ca,
        }),
        _ => {
            report.push(
                node.line,
                "security.tls",
                "needs both `cert` (PEM certificate chain) and `key` (PEM private key)",
            );
            None
        }
    }
}

fn strings(node: &Node, report: &mut Report, ctx: &str) -> Vec<(String, u64)> {
    node.seq(report, ctx)
        .map(|items| {
            items
                .iter()
                .filter_map(|n| n.scalar_text(report, ctx).map(|t| (t, n.line)))
                .collect()
        })
        .unwrap_or_default()
}

/// Why a `declare.serial_ports` entry is no pattern of serial device paths, if it is not:
/// serial ports are device files, so a pattern is an absolute path under `/dev/`.
fn serial_pattern_problem(pattern: &str) -> Option<String> {
    let shown = crate::text::quote(pattern);
    if !pattern.starts_with("/dev/") || pattern.len() == "/dev/".len() {
        return Some(format!(
            "`{shown}` is not a pattern of serial device paths: write an absolute path under /dev/, `*` for any characters (e.g. /dev/ttyUSB*)"
        ));
    }
    if pattern.split('/').any(|part| part == "..") {
        return Some(format!(
            "`{shown}`: `..` may not appear in a serial port pattern"
        ));
    }
    None
}

fn flag(node: &Node, report: &mut Report, ctx: &str) -> bool {
    match node.kind {
        Kind::Bool(b) => b,
        _ => {
            report.push(node.line, ctx, "expected true or false");
            false
        }
    }
}

pub(super) fn read(node: &Node, report: &mut Report) -> SecurityConfig {
    let mut out = SecurityConfig::default();
    let Some(mut map) = node.map(report, "security") else {
        return out;
    };
    if let Some(n) = map.get("tokens_file") {
        out.tokens_file_line = n.line;
        out.tokens_file = n
            .scalar_text(report, "security.tokens_file")
            .map(PathBuf::from);
    }
    if let Some(n) = map.get("read_only") {
        out.read_only = flag(n, report, "security.read_only");
    }
    if let Some(n) = map.get("insecure") {
        out.insecure = flag(n, report, "security.insecure");
    }
    if let Some(n) = map.get("tls") {
        out.tls_line = n.line;
        out.tls = read_tls(n, report);
    }
    if let Some(declare) = map.get("declare")
        && let Some(mut d) = declare.map(report, "security.declare")
    {
        if let Some(n) = d.get("serial_ports") {
            out.declare.serial_ports = strings(n, report, "security.declare.serial_ports")
                .into_iter()
                .filter(|(text, line)| {
                    let problem = serial_pattern_problem(text);
                    if let Some(problem) = &problem {
                        report.push(*line, "security.declare.serial_ports", problem.clone());
                    }
                    problem.is_none()
                })
                .map(|(s, _)| s)
                .collect();
        }
        if let Some(n) = d.get("tcp_hosts") {
            out.declare.tcp_hosts = strings(n, report, "security.declare.tcp_hosts")
                .into_iter()
                .filter_map(|(text, line)| {
                    let rule = HostRule::parse(&text);
                    if rule.is_none() {
                        report.push(
                            line,
                            "security.declare.tcp_hosts",
                            format!(
                                "`{text}` is not a network (192.0.2.0/24), an address, or host[:port]"
                            ),
                        );
                    }
                    rule
                })
                .collect();
        }
        d.finish(report, "security.declare", DECLARE_KEYS);
    }
    map.finish(report, "security", KEYS);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn patterns_and_host_rules_match_what_they_say() {
        let policy = DeclarePolicy::default();
        assert!(policy.allows_serial("/dev/ttyUSB0"));
        assert!(policy.allows_serial("/dev/serial/by-id/usb-FTDI_1234-if00-port0"));
        assert!(!policy.allows_serial("/etc/passwd"));
        assert!(!policy.allows_serial("/dev/pts/3"));
        assert!(!policy.allows_tcp("127.0.0.1", 502), "no TCP by default");
        let rules = ["192.0.2.0/24", "plc7.example:502", "10.0.0.5"];
        let policy = DeclarePolicy {
            tcp_hosts: rules.iter().filter_map(|r| HostRule::parse(r)).collect(),
            ..DeclarePolicy::default()
        };
        assert!(policy.allows_tcp("192.0.2.77", 1502));
        assert!(!policy.allows_tcp("192.0.3.1", 502));
        assert!(policy.allows_tcp("PLC7.example", 502));
        assert!(!policy.allows_tcp("plc7.example", 8080));
        assert!(policy.allows_tcp("10.0.0.5", 9));
        assert!(!policy.allows_tcp("10.0.0.6", 9));
        assert!(HostRule::parse("300.1.1.1/8").is_none());
    }
}

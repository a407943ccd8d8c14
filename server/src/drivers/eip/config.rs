//! A link's `eip:` settings: `host`, `port` (44818), `path` (the route to the controller
//! as Logix users write it: `1,0` is the backplane, slot 0; `""` for a controller that
//! answers itself, such as a Micro800) and the timeout of a request.

use std::time::Duration;

use crate::config::DriverLink;
use crate::yaml::Report;

const KEYS: &[&str] = &["host", "port", "path", "timeout", "connected"];

/// The longest `timeout`.
const MAX_TIMEOUT: Duration = Duration::from_secs(10);

#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Settings {
    pub(crate) host: String,
    pub(crate) port: u16,
    /// The route as CIP port segments.
    pub(crate) route: Vec<u8>,
    pub(crate) timeout: Duration,
    /// Whether a class 3 connection is asked for (Forward Open); without one every request
    /// goes unconnected (`connected: false`: a controller with few connections to spare).
    pub(crate) connected: bool,
}

/// A route as Logix writes it (`1,0`; `1,0,2,192.168.1.20,1,0`) as port segments.
pub(crate) fn route(text: &str) -> Result<Vec<u8>, String> {
    let text = text.trim();
    if text.is_empty() {
        return Ok(Vec::new());
    }
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    if parts.len() % 2 == 1 {
        return Err(format!(
            "`{text}` is not a route: pairs of port and address (`1,0`: backplane, slot 0)"
        ));
    }
    let mut out = Vec::new();
    for pair in parts.chunks(2) {
        let port: u8 = pair[0]
            .parse()
            .ok()
            .filter(|p| (1..=14).contains(p))
            .ok_or_else(|| format!("`{}` in `{text}` is not a port (1-14)", pair[0]))?;
        match pair[1].parse::<u8>() {
            Ok(address) => out.extend_from_slice(&[port, address]),
            Err(_) if pair[1].parse::<std::net::Ipv4Addr>().is_ok() => {
                let address = pair[1].as_bytes();
                out.push(0x10 | port);
                out.push(address.len() as u8);
                out.extend_from_slice(address);
                if address.len() % 2 == 1 {
                    out.push(0);
                }
            }
            Err(_) => {
                return Err(format!(
                    "`{}` in `{text}` is not an address (a slot 0-255 or an IP address)",
                    pair[1]
                ));
            }
        }
    }
    Ok(out)
}

/// Reads a link's settings; `None` after reporting every problem.
pub(crate) fn read(link: &str, d: &DriverLink, report: &mut Report) -> Option<Settings> {
    let ctx = format!("link {link}: eip");
    let at = |k: &str| format!("{ctx}.{k}");
    let mut map = d.settings.map(report, &ctx)?;
    let host = map
        .get("host")
        .and_then(|n| n.scalar_text(report, &at("host")));
    let port = map
        .get("port")
        .map_or(Some(44818), |n| n.int_in(report, &at("port"), 1, 65535));
    let route = match map.get("path") {
        None => Some(vec![1, 0]),
        Some(n) => {
            let text = n.scalar_text(report, &at("path"));
            text.and_then(|t| match route(&t) {
                Ok(r) => Some(r),
                Err(e) => {
                    report.push(n.line, at("path"), e);
                    None
                }
            })
        }
    };
    let timeout = map
        .get("timeout")
        .map_or(Some(Duration::from_secs(2)), |n| {
            let text = n.scalar_text(report, &at("timeout"))?;
            match crate::duration::parse(&text) {
                Ok(t) if t > MAX_TIMEOUT || t.is_zero() => {
                    report.push(n.line, at("timeout"), "more than 0 and at most 10s");
                    None
                }
                Ok(t) => Some(t),
                Err(e) => {
                    report.push(n.line, at("timeout"), e.to_string());
                    None
                }
            }
        });
    let connected = map.get("connected").map_or(Some(true), |n| {
        crate::yaml::boolean(n, report, &at("connected"))
    });
    map.finish(report, &ctx, KEYS);
    Some(Settings {
        host: host?,
        port: u16::try_from(port?).ok()?,
        route: route?,
        timeout: timeout?,
        connected: connected?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn routes_as_logix_writes_them() {
        assert_eq!(route("1,0"), Ok(vec![1, 0]));
        assert_eq!(route(""), Ok(vec![]));
        assert_eq!(route(" 1, 3 "), Ok(vec![1, 3]));
        assert_eq!(
            route("1,0,2,10.0.0.1"),
            Ok([&[1u8, 0, 0x12, 8][..], b"10.0.0.1"].concat())
        );
        for bad in ["1", "0,1", "15,0", "1,x", "1,256"] {
            assert!(route(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn a_link_is_connected_unless_it_says_not() {
        let settings = |text: &str| {
            let (config, problems) = crate::config::read_section(text, "eip", |n, report| {
                let link = DriverLink {
                    protocol: "eip",
                    endpoint: String::new(),
                    settings: n.clone(),
                    base: std::path::PathBuf::new(),
                };
                read("plc", &link, report)
            });
            (config.map(|s| s.connected), problems)
        };
        assert_eq!(settings("eip: { host: plc }\n"), (Some(true), vec![]));
        assert_eq!(
            settings("eip: { host: plc, connected: false }\n"),
            (Some(false), vec![])
        );
        let (none, problems) = settings("eip: { host: plc, connected: maybe }\n");
        assert_eq!(none, None);
        assert!(
            problems.iter().any(|p| p.contains("eip.connected")),
            "{problems:?}"
        );
    }
}

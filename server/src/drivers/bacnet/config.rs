//! A link's `bacnet:` settings: where the gateway's BACnet/IP port is bound (`bind`, the
//! standard port 47808 unless it says), the broadcast address its Who-Is goes to, the BBMD
//! it registers with as a foreign device (`bbmd`, with `foreign_ttl`), and the timeout and
//! retries of a confirmed request (the standard's APDU_Timeout and Number_Of_APDU_Retries).

use std::net::{Ipv4Addr, SocketAddrV4};
use std::time::Duration;

use crate::config::DriverLink;
use crate::yaml::{Node, Report};

const KEYS: &[&str] = &[
    "bind",
    "broadcast",
    "bbmd",
    "foreign_ttl",
    "timeout",
    "retries",
];

/// BACnet/IP's port (0xBAC0).
pub(crate) const STANDARD_PORT: u16 = 47808;

/// The longest `timeout` of a confirmed request.
const MAX_TIMEOUT: Duration = Duration::from_secs(30);

#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Settings {
    pub(crate) bind: SocketAddrV4,
    pub(crate) broadcast: Ipv4Addr,
    /// The BBMD to register with as a foreign device, and the registration's lifetime.
    pub(crate) bbmd: Option<(SocketAddrV4, Duration)>,
    pub(crate) timeout: Duration,
    pub(crate) retries: u8,
}

/// `HOST[:PORT]` as an IPv4 socket address (the standard port unless it says).
pub(crate) fn address(text: &str) -> Result<SocketAddrV4, String> {
    let (host, port) = match text.rsplit_once(':') {
        Some((h, p)) => (
            h,
            p.parse::<u16>()
                .map_err(|_| format!("`{p}` in `{text}` is not a port (0-65535)"))?,
        ),
        None => (text, STANDARD_PORT),
    };
    let ip = host.parse::<Ipv4Addr>().map_err(|_| {
        format!("`{host}` is not an IPv4 address (BACnet/IP devices are reached by address)")
    })?;
    Ok(SocketAddrV4::new(ip, port))
}

fn address_at(n: &Node, report: &mut Report, ctx: &str) -> Option<SocketAddrV4> {
    let text = n.scalar_text(report, ctx)?;
    address(&text)
        .map_err(|why| report.push(n.line, ctx, why))
        .ok()
}

fn duration_at(n: &Node, report: &mut Report, ctx: &str, most: Duration) -> Option<Duration> {
    let text = n.scalar_text(report, ctx)?;
    match crate::duration::parse(&text) {
        Ok(d) if d.is_zero() || d > most => {
            report.push(n.line, ctx, format!("more than 0 and at most {most:?}"));
            None
        }
        Ok(d) => Some(d),
        Err(e) => {
            report.push(n.line, ctx, e.to_string());
            None
        }
    }
}

/// Reads a link's settings; `None` after reporting every problem.
pub(crate) fn read(link: &str, d: &DriverLink, report: &mut Report) -> Option<Settings> {
    let ctx = format!("link {link}: bacnet");
    let at = |k: &str| format!("{ctx}.{k}");
    let mut map = d.settings.map(report, &ctx)?;
    let bind = map
        .get("bind")
        .and_then(|n| address_at(n, report, &at("bind")));
    let broadcast = match map.get("broadcast") {
        None => Some(Ipv4Addr::BROADCAST),
        Some(n) => n.scalar_text(report, &at("broadcast")).and_then(|t| {
            t.parse::<Ipv4Addr>()
                .map_err(|_| {
                    report.push(
                        n.line,
                        at("broadcast"),
                        format!("`{t}` is not an IPv4 address"),
                    )
                })
                .ok()
        }),
    };
    let bbmd = map.get("bbmd").map(|n| address_at(n, report, &at("bbmd")));
    let ttl = map
        .get("foreign_ttl")
        .map_or(Some(Duration::from_secs(60)), |n| {
            duration_at(n, report, &at("foreign_ttl"), Duration::from_secs(65535))
        });
    let timeout = map
        .get("timeout")
        .map_or(Some(Duration::from_secs(3)), |n| {
            duration_at(n, report, &at("timeout"), MAX_TIMEOUT)
        });
    let retries = map.get("retries").map_or(Some(3), |n| {
        n.int_in(report, &at("retries"), 0, 10).map(|r| r as u8)
    });
    map.finish(report, &ctx, KEYS);
    let bbmd = match bbmd {
        None => None,
        Some(b) => Some((b?, ttl?)),
    };
    Some(Settings {
        bind: bind?,
        broadcast: broadcast?,
        bbmd,
        timeout: timeout?,
        retries: retries?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_address_without_a_port_is_on_the_standard_port() {
        assert_eq!(
            address("10.0.0.5"),
            Ok("10.0.0.5:47808".parse().expect("addr"))
        );
        assert_eq!(
            address("10.0.0.5:47809"),
            Ok("10.0.0.5:47809".parse().expect("addr"))
        );
        assert!(
            address("plant.local:47808")
                .expect_err("refused")
                .contains("not an IPv4 address")
        );
        assert!(
            address("10.0.0.5:x")
                .expect_err("refused")
                .contains("not a port")
        );
    }
}

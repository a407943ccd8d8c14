//! A link's `iec104:` settings: the station's `host` and `port` (2404), the `common_address`
//! its devices have unless they say, the originator address of the gateway's commands, the
//! standard's timers and windows (`t0` connect, `t1` an answer or acknowledgement, `t2` the
//! gateway's acknowledgements, `t3` a test frame on a quiet connection; `k` frames sent
//! unacknowledged, `w` received before the gateway acknowledges), how often the station is
//! interrogated (general `interrogation`, `counter_interrogation`), whether its clock is set,
//! and a `backup` address of the same station for a redundant connection.

use std::time::Duration;

use crate::config::DriverLink;
use crate::yaml::{Node, Report};

const KEYS: &[&str] = &[
    "host",
    "port",
    "backup",
    "common_address",
    "originator",
    "t0",
    "t1",
    "t2",
    "t3",
    "k",
    "w",
    "interrogation",
    "counter_interrogation",
    "clock_sync",
];

/// IEC 60870-5-104's port.
pub(crate) const STANDARD_PORT: u16 = 2404;

#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Settings {
    pub(crate) host: String,
    pub(crate) port: u16,
    /// Another address of the same station, tried when the first does not connect.
    pub(crate) backup: Option<(String, u16)>,
    pub(crate) common_address: u16,
    pub(crate) originator: u8,
    pub(crate) t0: Duration,
    pub(crate) t1: Duration,
    pub(crate) t2: Duration,
    pub(crate) t3: Duration,
    pub(crate) k: u16,
    pub(crate) w: u16,
    /// How often a general interrogation is sent after the one at connect (`None`: only
    /// at connect).
    pub(crate) interrogation: Option<Duration>,
    pub(crate) counter_interrogation: Option<Duration>,
    pub(crate) clock_sync: bool,
}

/// `HOST[:PORT]` (the standard port unless it says).
pub(crate) fn address(text: &str) -> Result<(String, u16), String> {
    match text.rsplit_once(':') {
        Some((h, p)) if !h.is_empty() && !h.ends_with(':') => p
            .parse::<u16>()
            .ok()
            .filter(|p| *p > 0)
            .map(|p| (h.trim_matches(['[', ']']).to_owned(), p))
            .ok_or_else(|| format!("`{p}` in `{text}` is not a port (1-65535)")),
        _ if text.trim().is_empty() => Err("an empty address".to_owned()),
        _ => Ok((text.trim().to_owned(), STANDARD_PORT)),
    }
}

/// A duration of at least 100 ms and at most `most` (the 104 timers, both sides).
pub(crate) fn duration(
    n: &Node,
    report: &mut Report,
    ctx: &str,
    most: Duration,
) -> Option<Duration> {
    let text = n.scalar_text(report, ctx)?;
    match crate::duration::parse(&text) {
        Ok(d) if d < Duration::from_millis(100) || d > most => {
            report.push(n.line, ctx, format!("at least 100ms and at most {most:?}"));
            None
        }
        Ok(d) => Some(d),
        Err(e) => {
            report.push(n.line, ctx, e.to_string());
            None
        }
    }
}

/// A period that may be `off`.
pub(crate) fn period(n: &Node, report: &mut Report, ctx: &str) -> Option<Option<Duration>> {
    let text = n.scalar_text(report, ctx)?;
    if matches!(text.trim(), "off" | "0" | "false") {
        return Some(None);
    }
    match crate::duration::parse(&text) {
        Ok(d) if d < Duration::from_secs(1) || d > Duration::from_secs(86_400) => {
            report.push(n.line, ctx, "at least 1s and at most 24h, or off");
            None
        }
        Ok(d) => Some(Some(d)),
        Err(e) => {
            report.push(n.line, ctx, e.to_string());
            None
        }
    }
}

/// `backup`: another address of the station than `own`.
fn backup(
    n: &Node,
    own: Option<&(String, u16)>,
    report: &mut Report,
    ctx: &str,
) -> Option<(String, u16)> {
    let text = n.scalar_text(report, ctx)?;
    match address(&text) {
        Ok(b) if Some(&b) == own => {
            let why =
                format!("`{text}` is the station's own address: a backup is its other address");
            report.push(n.line, ctx, why);
            None
        }
        Ok(b) => Some(b),
        Err(e) => {
            report.push(n.line, ctx, e);
            None
        }
    }
}

/// Reads a link's settings; `None` after reporting every problem.
pub(crate) fn read(link: &str, d: &DriverLink, report: &mut Report) -> Option<Settings> {
    let ctx = format!("link {link}: iec104");
    let at = |k: &str| format!("{ctx}.{k}");
    let mut map = d.settings.map(report, &ctx)?;
    let host = map
        .require("host", report, &ctx)
        .and_then(|n| n.scalar_text(report, &at("host")));
    let port = map
        .get("port")
        .map_or(Some(i128::from(STANDARD_PORT)), |n| {
            n.int_in(report, &at("port"), 1, 65535)
        });
    let own = host
        .as_ref()
        .zip(port)
        .map(|(h, p)| (h.clone(), u16::try_from(p).unwrap_or_default()));
    let backup = map
        .get("backup")
        .map(|n| backup(n, own.as_ref(), report, &at("backup")));
    let mut int = |key: &str, default: i128, lo: i128, hi: i128, report: &mut Report| {
        map.get(key)
            .map_or(Some(default), |n| n.int_in(report, &at(key), lo, hi))
    };
    let common_address = int("common_address", 1, 1, 65534, report);
    let originator = int("originator", 0, 0, 255, report);
    let k = int("k", 12, 1, 32767, report);
    let w = int("w", 8, 1, 32767, report);
    let mut time = |key: &str, default: u64, most: u64, report: &mut Report| {
        map.get(key)
            .map_or(Some(Duration::from_secs(default)), |n| {
                duration(n, report, &at(key), Duration::from_secs(most))
            })
    };
    let t0 = time("t0", 30, 255, report);
    let t1 = time("t1", 15, 255, report);
    let t2 = time("t2", 10, 255, report);
    let t3 = time("t3", 20, 172_800, report);
    let interrogation = map
        .get("interrogation")
        .map_or(Some(None), |n| period(n, report, &at("interrogation")));
    let counter = map.get("counter_interrogation").map_or(Some(None), |n| {
        period(n, report, &at("counter_interrogation"))
    });
    let clock_sync = map.get("clock_sync").map_or(Some(false), |n| {
        crate::yaml::boolean(n, report, &at("clock_sync"))
    });
    let line = d.settings.line;
    if let (Some(t1), Some(t2)) = (t1, t2)
        && t2 >= t1
    {
        report.push(line, at("t2"), format!("t2 ({t2:?}) must be shorter than t1 ({t1:?}): the station waits t1 for the gateway's acknowledgement"));
    }
    if let (Some(k), Some(w)) = (k, w)
        && w > k
    {
        report.push(
            line,
            at("w"),
            format!("w ({w}) must be at most k ({k}); the standard recommends two thirds of k"),
        );
    }
    map.finish(report, &ctx, KEYS);
    Some(Settings {
        host: host?,
        port: u16::try_from(port?).ok()?,
        backup: match backup {
            Some(b) => Some(b?),
            None => None,
        },
        common_address: u16::try_from(common_address?).ok()?,
        originator: u8::try_from(originator?).ok()?,
        t0: t0?,
        t1: t1?,
        t2: t2?,
        t3: t3?,
        k: u16::try_from(k?).ok()?,
        w: u16::try_from(w?).ok()?,
        interrogation: interrogation?,
        counter_interrogation: counter?,
        clock_sync: clock_sync?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_address_without_a_port_is_on_the_standard_port() {
        assert_eq!(address("10.0.0.5"), Ok(("10.0.0.5".into(), 2404)));
        assert_eq!(address("rtu-7:2405"), Ok(("rtu-7".into(), 2405)));
        assert!(
            address("rtu-7:x")
                .expect_err("refused")
                .contains("not a port")
        );
        assert!(address(" ").is_err());
    }
}

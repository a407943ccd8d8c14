//! A link's `s7:` settings: `host`, `port` (102), `rack` and `slot`, or the TSAPs outright
//! (`local_tsap`, `remote_tsap`, for S7-200 and LOGO!), the connection type (`pg`, `op`,
//! `s7`), the PDU size asked for and the timeout of a job.

use std::time::Duration;

use super::plan::{DEFAULT_GAP, MAX_GAP};
use crate::config::DriverLink;
use crate::yaml::{Kind, Node, Report};

const KEYS: &[&str] = &[
    "host",
    "port",
    "rack",
    "slot",
    "local_tsap",
    "remote_tsap",
    "connection_type",
    "pdu_size",
    "timeout",
    "max_gap",
];

/// The longest `timeout`: the open's three exchanges fit the driver's open timeout.
const MAX_TIMEOUT: Duration = Duration::from_secs(4);

#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Settings {
    pub(crate) host: String,
    pub(crate) port: u16,
    pub(crate) local_tsap: u16,
    pub(crate) remote_tsap: u16,
    pub(crate) pdu: u16,
    pub(crate) timeout: Duration,
    /// The most bytes between two fields of one block read with them (not asked for).
    pub(crate) max_gap: u32,
}

fn int(n: &Node, report: &mut Report, ctx: &str, max: i128) -> Option<i128> {
    match &n.kind {
        Kind::Str(s) if s.starts_with("0x") || s.starts_with("0X") => {
            match i128::from_str_radix(&s[2..], 16) {
                Ok(v) if (0..=max).contains(&v) => Some(v),
                _ => {
                    report.push(n.line, ctx, format!("`{s}` is not a number 0-{max}"));
                    None
                }
            }
        }
        _ => n.int_in(report, ctx, 0, max),
    }
}

/// The remote TSAP of rack and slot for a connection type (1 PG, 2 OP, 3 S7 basic).
pub(crate) fn remote_tsap(kind: i128, rack: i128, slot: i128) -> i128 {
    (kind << 8) | (rack * 0x20 + slot)
}

/// Reads a link's settings; `None` after reporting every problem.
/// A job's `timeout`: at most [`MAX_TIMEOUT`].
fn job_timeout(n: &crate::yaml::Node, report: &mut Report, ctx: &str) -> Option<Duration> {
    let text = n.scalar_text(report, ctx)?;
    match crate::duration::parse(&text) {
        Ok(t) if t > MAX_TIMEOUT => {
            report.push(
                n.line,
                ctx,
                "at most 4s (a job a PLC has not answered in 4 s is lost)",
            );
            None
        }
        Ok(t) => Some(t),
        Err(e) => {
            report.push(n.line, ctx, e.to_string());
            None
        }
    }
}

pub(crate) fn read(link: &str, d: &DriverLink, report: &mut Report) -> Option<Settings> {
    let ctx = format!("link {link}: s7");
    let at = |k: &str| format!("{ctx}.{k}");
    let mut map = d.settings.map(report, &ctx)?;
    let host = map
        .get("host")
        .and_then(|n| n.scalar_text(report, &at("host")));
    let port = map
        .get("port")
        .map_or(Some(102), |n| int(n, report, &at("port"), 65535));
    let rack = map
        .get("rack")
        .map_or(Some(0), |n| int(n, report, &at("rack"), 7));
    let slot = map
        .get("slot")
        .map_or(Some(1), |n| int(n, report, &at("slot"), 31));
    let local = map
        .get("local_tsap")
        .map(|n| int(n, report, &at("local_tsap"), 0xFFFF));
    let remote = map
        .get("remote_tsap")
        .map(|n| int(n, report, &at("remote_tsap"), 0xFFFF));
    let kind = match map.get("connection_type") {
        None => Some(1),
        Some(n) => match n.scalar_text(report, &at("connection_type")).as_deref() {
            Some("pg") => Some(1),
            Some("op") => Some(2),
            Some("s7") => Some(3),
            Some(other) => {
                report.push(
                    n.line,
                    at("connection_type"),
                    format!("unknown `{other}` (expected pg, op or s7)"),
                );
                None
            }
            None => None,
        },
    };
    let pdu = map
        .get("pdu_size")
        .map_or(Some(960), |n| n.int_in(report, &at("pdu_size"), 240, 960));
    let timeout = map
        .get("timeout")
        .map_or(Some(Duration::from_secs(2)), |n| {
            job_timeout(n, report, &at("timeout"))
        });
    let max_gap = map.get("max_gap").map_or(Some(DEFAULT_GAP), |n| {
        n.int_in(report, &at("max_gap"), 0, i128::from(MAX_GAP))
            .map(|v| v as u32)
    });
    map.finish(report, &ctx, KEYS);
    let (rack, slot, kind) = (rack?, slot?, kind?);
    let remote = match remote {
        Some(r) => r?,
        None => remote_tsap(kind, rack, slot),
    };
    let local = match local {
        Some(l) => l?,
        None => 0x0100,
    };
    Some(Settings {
        host: host?,
        port: u16::try_from(port?).ok()?,
        local_tsap: u16::try_from(local).ok()?,
        remote_tsap: u16::try_from(remote).ok()?,
        pdu: u16::try_from(pdu?).ok()?,
        timeout: timeout?,
        max_gap: max_gap?,
    })
}

//! The `modbus_server:` section of `iogate.yaml`: the Modbus server that serves cached
//! fields at IEC located addresses (source documents 001 and 003), over TCP (`listen`) and
//! as a slave on serial lines (`serial`, RTU or ASCII). Read here as written; the bindings
//! are resolved against the devices and profiles in `crate::map`.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use iogate_types::Location;

use crate::duration;
use crate::yaml::{Kind, Node, Report, boolean};

const KEYS: &[&str] = &[
    "listen",
    "address_space",
    "unit_id",
    "map",
    "auto",
    "forward",
    "read_only",
    "max_connections",
    "max_connections_per_client",
    "idle_timeout",
    "memory_file",
    "on_bad_quality",
    "serial",
];
/// A `serial` entry's own keys, beside a line's ([`super::line::KEYS`]).
const SERIAL_KEYS: &[&str] = &["unit_id", "turnaround_delay"];
/// The longest turnaround delay: a master waits about a second for an answer.
pub(crate) const MAX_TURNAROUND: Duration = Duration::from_millis(500);
const MAP_KEYS: &[&str] = &["at", "field"];
const FORWARD_KEYS: &[&str] = &["unit_ids", "link"];

pub(crate) const DEFAULT_MAX_CONNECTIONS: usize = 16;
/// Connections from one master's address, by default (at most `max_connections`).
pub(crate) const DEFAULT_MAX_CONNECTIONS_PER_CLIENT: usize = 8;
pub(crate) const DEFAULT_IDLE_TIMEOUT: Duration = Duration::from_secs(60);

/// The three address maps of source document 001.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum AddressSpace {
    /// The OpenPLC runtime for Linux and Windows.
    #[default]
    Linux,
    /// ESP32, STM32, RP2040 and similar.
    Esp32,
    /// ATmega 328P and similar.
    Atmega,
}

impl AddressSpace {
    pub(crate) fn name(self) -> &'static str {
        match self {
            AddressSpace::Linux => "linux",
            AddressSpace::Esp32 => "esp32",
            AddressSpace::Atmega => "atmega",
        }
    }
}

/// What a master reads from a bound field whose value is not good.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum OnBadQuality {
    /// The last good value (0 before the first), as if nothing were wrong: bind the
    /// device's `connected` or `error_code` to see it.
    #[default]
    LastValue,
    /// Exception 0x0B (gateway target device failed to respond).
    Exception,
}

/// One `map` entry as written.
#[derive(Debug, Clone, PartialEq)]
pub struct MapEntry {
    pub(crate) at: Location,
    /// `device.field` (a field, or a diagnostic such as `connected`).
    pub(crate) device: String,
    pub(crate) field: String,
    pub(crate) line: u64,
}

/// Unit ids forwarded as they are to the slaves on a link.
#[derive(Debug, Clone, PartialEq)]
pub struct Forward {
    pub(crate) first: u8,
    pub(crate) last: u8,
    pub(crate) link: String,
    pub(crate) line: u64,
}

/// One `serial` entry: a port on which the server is a slave.
#[derive(Debug, Clone, PartialEq)]
pub struct SerialServer {
    pub(crate) line: crate::config::SerialSettings,
    /// The unit id this port answers (broadcasts, 0, are applied without an answer).
    pub(crate) unit_id: u8,
    /// Waited after a request's end (its 3.5-character silence) before the answer, for
    /// masters and RS-485 adapters slow to turn the line around.
    pub(crate) turnaround_delay: Duration,
    pub(crate) at: u64,
}

impl SerialServer {
    /// Whether both serve the same port the same way (where they are written aside).
    pub(crate) fn same_as(&self, other: &SerialServer) -> bool {
        (&self.line, self.unit_id, self.turnaround_delay)
            == (&other.line, other.unit_id, other.turnaround_delay)
    }
}

#[derive(Debug, Clone, PartialEq)]
pub struct ModbusServerConfig {
    /// The Modbus TCP listener; `None` when the server is on serial ports only.
    pub listen: Option<SocketAddr>,
    pub(crate) serial: Vec<SerialServer>,
    pub(crate) address_space: AddressSpace,
    pub(crate) unit_id: u8,
    pub(crate) map: Vec<MapEntry>,
    pub(crate) auto: bool,
    pub(crate) forward: Vec<Forward>,
    pub(crate) read_only: bool,
    pub(crate) max_connections: usize,
    /// Connections from one address (`max_connections_per_client`; never more than
    /// `max_connections` in effect).
    pub(crate) max_connections_per_client: usize,
    pub(crate) idle_timeout: Duration,
    pub(crate) memory_file: Option<PathBuf>,
    /// Where `memory_file` is written (0 when it is not).
    pub(crate) memory_file_line: u64,
    pub(crate) on_bad_quality: OnBadQuality,
    pub(crate) line: u64,
}

/// Reads the section; `None` after reporting its problems.
pub(super) fn read(node: &Node, report: &mut Report) -> Option<ModbusServerConfig> {
    let ctx = "modbus_server";
    let mut map = node.map(report, ctx)?;
    let at = |k: &str| format!("{ctx}.{k}");
    let listen = map.get("listen").and_then(|n| address(n, report));
    let address_space = match map.get("address_space") {
        None => Some(AddressSpace::Linux),
        Some(n) => address_space(n, report),
    };
    let unit_id = match map.get("unit_id") {
        None => Some(1),
        Some(n) => n.int_in(report, &at("unit_id"), 1, 247).map(|u| u as u8),
    };
    let mut flag = |key: &str, report: &mut Report| match map.get(key) {
        None => Some(false),
        Some(n) => boolean(n, report, &at(key)),
    };
    let auto = flag("auto", report);
    let read_only = flag("read_only", report);
    let mut count = |key: &str, default: usize, report: &mut Report| match map.get(key) {
        None => Some(default),
        Some(n) => n.int_in(report, &at(key), 1, 10_000).map(|m| m as usize),
    };
    let max_connections = count("max_connections", DEFAULT_MAX_CONNECTIONS, report);
    let per_client = count(
        "max_connections_per_client",
        DEFAULT_MAX_CONNECTIONS_PER_CLIENT,
        report,
    );
    let idle_timeout = match map.get("idle_timeout") {
        None => Some(DEFAULT_IDLE_TIMEOUT),
        Some(n) => n.scalar_text(report, &at("idle_timeout")).and_then(|t| {
            duration::parse(&t)
                .map_err(|e| report.push(n.line, at("idle_timeout"), e))
                .ok()
        }),
    };
    let memory_file_line = map.get("memory_file").map_or(0, |n| n.line);
    let memory_file = map
        .get("memory_file")
        .and_then(|n| n.scalar_text(report, &at("memory_file")))
        .map(PathBuf::from);
    let on_bad_quality = match map.get("on_bad_quality") {
        None => Some(OnBadQuality::LastValue),
        Some(n) => on_bad_quality(n, report),
    };
    let entries = list(map.get("map"), report, "map", read_entry);
    let forward: Vec<Forward> = list(map.get("forward"), report, "forward", read_forward);
    forward_overlaps(&forward, report);
    let serial: Vec<SerialServer> = list(map.get("serial"), report, "serial", read_serial);
    if map.get("listen").is_none() && map.get("serial").is_none() {
        report.push(
            node.line,
            ctx,
            "missing `listen` (the Modbus TCP address) or `serial` (ports to serve as a slave): give one or both",
        );
    }
    served_once(&serial, report);
    map.finish(report, ctx, KEYS);
    // A setting that was refused (and reported) takes its default, so that the map is
    // still checked against the devices.
    Some(ModbusServerConfig {
        listen,
        serial,
        address_space: address_space.unwrap_or(AddressSpace::Linux),
        unit_id: unit_id.unwrap_or(1),
        map: entries,
        auto: auto.unwrap_or(false),
        forward,
        read_only: read_only.unwrap_or(false),
        max_connections: max_connections.unwrap_or(DEFAULT_MAX_CONNECTIONS),
        max_connections_per_client: per_client.unwrap_or(DEFAULT_MAX_CONNECTIONS_PER_CLIENT),
        idle_timeout: idle_timeout.unwrap_or(DEFAULT_IDLE_TIMEOUT),
        memory_file,
        memory_file_line,
        on_bad_quality: on_bad_quality.unwrap_or_default(),
        line: node.line,
    })
}

/// A list of the section (`key`), each entry read by `read`.
fn list<T>(
    node: Option<&Node>,
    report: &mut Report,
    key: &str,
    read: fn(&Node, usize, &mut Report) -> Option<T>,
) -> Vec<T> {
    node.and_then(|n| n.seq(report, &format!("modbus_server.{key}")))
        .map(|items| {
            items
                .iter()
                .enumerate()
                .filter_map(|(i, n)| read(n, i, report))
                .collect()
        })
        .unwrap_or_default()
}

/// `listen`: IP:port.
fn address(n: &Node, report: &mut Report) -> Option<SocketAddr> {
    let text = n.scalar_text(report, "modbus_server.listen")?;
    text.parse::<SocketAddr>()
        .map_err(|_| {
            report.push(
                n.line,
                "modbus_server.listen",
                format!("`{text}` is not an address (write IP:port, e.g. 127.0.0.1:5020)"),
            )
        })
        .ok()
}

/// `address_space`: linux, esp32 or atmega.
fn address_space(n: &Node, report: &mut Report) -> Option<AddressSpace> {
    let t = n.scalar_text(report, "modbus_server.address_space")?;
    match t.as_str() {
        "linux" => Some(AddressSpace::Linux),
        "esp32" => Some(AddressSpace::Esp32),
        "atmega" => Some(AddressSpace::Atmega),
        other => {
            report.push(
                n.line,
                "modbus_server.address_space",
                format!("unknown address space `{other}` (expected linux, esp32 or atmega)"),
            );
            None
        }
    }
}

/// `on_bad_quality`: last_value or exception.
fn on_bad_quality(n: &Node, report: &mut Report) -> Option<OnBadQuality> {
    let t = n.scalar_text(report, "modbus_server.on_bad_quality")?;
    match t.as_str() {
        "last_value" => Some(OnBadQuality::LastValue),
        "exception" => Some(OnBadQuality::Exception),
        other => {
            report.push(
                n.line,
                "modbus_server.on_bad_quality",
                format!("unknown choice `{other}` (expected last_value or exception)"),
            );
            None
        }
    }
}

/// A serial port is served once.
fn served_once(serial: &[SerialServer], report: &mut Report) {
    for (i, s) in serial.iter().enumerate() {
        if let Some(j) = serial[..i].iter().position(|e| e.line.port == s.line.port) {
            report.push(
                s.at,
                format!("modbus_server.serial[{i}].port"),
                format!(
                    "{} is served by modbus_server.serial[{j}] already (line {}): a port is served once",
                    crate::text::quote(&s.line.port),
                    serial[j].at
                ),
            );
        }
    }
}

fn read_serial(node: &Node, index: usize, report: &mut Report) -> Option<SerialServer> {
    let ctx = format!("modbus_server.serial[{index}]");
    let mut map = node.map(report, &ctx)?;
    let line = super::line::read_line(&mut map, &ctx, report);
    let unit_id = match map.get("unit_id") {
        None => Some(1),
        Some(n) => n
            .int_in(report, &format!("{ctx}.unit_id"), 1, 247)
            .map(|u| u as u8),
    };
    let turnaround_delay = match map.get("turnaround_delay") {
        None => Some(Duration::ZERO),
        Some(n) => n
            .scalar_text(report, &format!("{ctx}.turnaround_delay"))
            .and_then(|t| {
                let checked = duration::parse(&t).map_err(|e| e.to_string()).and_then(|d| {
                    if d > MAX_TURNAROUND {
                        Err(format!(
                            "{} ms is longer than the {} ms allowed (a master waits about a second for its answer)",
                            d.as_millis(),
                            MAX_TURNAROUND.as_millis()
                        ))
                    } else {
                        Ok(d)
                    }
                });
                checked
                    .map_err(|e| report.push(n.line, format!("{ctx}.turnaround_delay"), e))
                    .ok()
            }),
    };
    map.finish(report, &ctx, &[super::line::KEYS, SERIAL_KEYS].concat());
    Some(SerialServer {
        line: line?,
        unit_id: unit_id?,
        turnaround_delay: turnaround_delay?,
        at: node.line,
    })
}

fn read_entry(node: &Node, index: usize, report: &mut Report) -> Option<MapEntry> {
    let ctx = format!("modbus_server.map[{index}]");
    let mut map = node.map(report, &ctx)?;
    let at = map.require("at", report, &ctx).and_then(|n| {
        let text = n.scalar_text(report, &format!("{ctx}.at"))?;
        Location::parse(&text)
            .map_err(|e| report.push(n.line, format!("{ctx}.at"), e.to_string()))
            .ok()
    });
    let field = map.require("field", report, &ctx).and_then(|n| {
        let text = n.scalar_text(report, &format!("{ctx}.field"))?;
        match text.split_once('.') {
            Some((d, f)) if !d.is_empty() && !f.is_empty() => Some((d.to_owned(), f.to_owned())),
            _ => {
                report.push(
                    n.line,
                    format!("{ctx}.field"),
                    format!("`{text}` is not `device.field`"),
                );
                None
            }
        }
    });
    map.finish(report, &ctx, MAP_KEYS);
    let (device, field) = field?;
    Some(MapEntry {
        at: at?,
        device,
        field,
        line: node.line,
    })
}

/// Each unit id goes one way: a forwarded range may not take ids of an earlier range (to
/// any link); the first would silently win.
fn forward_overlaps(forward: &[Forward], report: &mut Report) {
    let shown = |f: &Forward| {
        if f.first == f.last {
            format!("{}", f.first)
        } else {
            format!("{}-{}", f.first, f.last)
        }
    };
    for (i, f) in forward.iter().enumerate() {
        if let Some((j, earlier)) = forward[..i]
            .iter()
            .enumerate()
            .find(|(_, e)| e.first <= f.last && f.first <= e.last)
        {
            report.push(
                f.line,
                format!("modbus_server.forward[{i}].unit_ids"),
                format!(
                    "{} overlaps modbus_server.forward[{j}] ({} to link {}, line {}): a unit id is forwarded to one link",
                    shown(f),
                    shown(earlier),
                    crate::text::quote(&earlier.link),
                    earlier.line
                ),
            );
        }
    }
}

fn read_forward(node: &Node, index: usize, report: &mut Report) -> Option<Forward> {
    let ctx = format!("modbus_server.forward[{index}]");
    let mut map = node.map(report, &ctx)?;
    let ids = map.require("unit_ids", report, &ctx).and_then(|n| {
        let text = match &n.kind {
            Kind::Int(i) => i.to_string(),
            _ => n.scalar_text(report, &format!("{ctx}.unit_ids"))?,
        };
        let parse = |t: &str| {
            t.trim()
                .parse::<u8>()
                .ok()
                .filter(|u| (1..=247).contains(u))
        };
        let range = match text.split_once('-') {
            Some((a, b)) => parse(a).zip(parse(b)).filter(|(a, b)| a <= b),
            None => parse(&text).map(|u| (u, u)),
        };
        if range.is_none() {
            report.push(
                n.line,
                format!("{ctx}.unit_ids"),
                format!("`{text}` is not a unit id or a range such as 2-247 (ids 1-247)"),
            );
        }
        range
    });
    let link = map
        .require("link", report, &ctx)
        .and_then(|n| n.scalar_text(report, &format!("{ctx}.link")));
    map.finish(report, &ctx, FORWARD_KEYS);
    let (first, last) = ids?;
    Some(Forward {
        first,
        last,
        link: link?,
        line: node.line,
    })
}

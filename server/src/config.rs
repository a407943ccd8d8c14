//! `iogate.yaml`: listeners, links and devices, validated like profiles (every problem at
//! once, with file and line). Cross-checks against the loaded profiles are in [`check_devices`].

use std::collections::HashMap;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::time::Duration;

use crate::duration;
use crate::profile::{Catalog, Protocol};
use crate::yaml::{self, Node, Problems, Report};

pub const DEFAULT_HTTP: &str = "127.0.0.1:8080";
pub const DEFAULT_GRPC: &str = "127.0.0.1:50051";
pub const DEFAULT_REFRESH: Duration = Duration::from_millis(100);
pub const DEFAULT_TIMEOUT: Duration = Duration::from_millis(200);
pub const DEFAULT_RETRIES: u32 = 1;
/// Registers per read transaction (the Modbus limit; coils are limited separately to 2000).
pub const MAX_READ_REGISTERS: u16 = 125;

const TOP_KEYS: &[&str] = &["listen", "profiles", "links", "devices"];
const LISTEN_KEYS: &[&str] = &["http", "grpc"];
const LINK_KEYS: &[&str] = &["name", "serial", "tcp", "guard_time"];
const SERIAL_KEYS: &[&str] = &["port", "baud", "parity", "data_bits", "stop_bits"];
const TCP_KEYS: &[&str] = &["host", "port", "framing"];
const DEVICE_KEYS: &[&str] = &[
    "name",
    "profile",
    "link",
    "slave_id",
    "refresh_rate",
    "timeout",
    "retries",
    "max_batch",
    "max_gap",
];

#[derive(Debug, Clone, PartialEq)]
pub struct Config {
    pub http: SocketAddr,
    pub grpc: SocketAddr,
    /// The `profiles` directory as configured, relative to the config file's directory.
    pub profiles: Option<PathBuf>,
    pub links: Vec<LinkConfig>,
    pub devices: Vec<DeviceConfig>,
    /// The file the config came from.
    pub source: String,
}

#[derive(Debug, Clone, PartialEq)]
pub struct LinkConfig {
    pub name: String,
    pub transport: Transport,
    /// Extra silence kept between frames, on top of the 3.5 characters.
    pub guard_time: Duration,
    pub line: u64,
}

#[derive(Debug, Clone, PartialEq)]
pub enum Transport {
    Serial(SerialSettings),
    Tcp {
        host: String,
        port: u16,
        framing: Framing,
    },
}

/// How Modbus frames travel over a TCP link.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Framing {
    /// Modbus TCP (MBAP header).
    Mbap,
    /// RTU frames with CRC over a raw socket (serial device servers).
    Rtu,
}

impl Framing {
    pub fn name(self) -> &'static str {
        match self {
            Framing::Mbap => "mbap",
            Framing::Rtu => "rtu",
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Parity {
    None,
    Even,
    Odd,
}

impl Parity {
    pub fn letter(self) -> char {
        match self {
            Parity::None => 'N',
            Parity::Even => 'E',
            Parity::Odd => 'O',
        }
    }
}

#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SerialSettings {
    pub port: String,
    pub baud: u32,
    pub parity: Parity,
    pub data_bits: u8,
    pub stop_bits: u8,
}

#[derive(Debug, Clone, PartialEq)]
pub struct DeviceConfig {
    pub name: String,
    pub profile: String,
    pub link: Option<String>,
    pub slave_id: Option<u8>,
    pub refresh_rate: Duration,
    pub timeout: Duration,
    pub retries: u32,
    pub max_batch: u16,
    pub max_gap: u16,
    pub line: u64,
}

impl Config {
    /// A config with default listeners and nothing else.
    pub fn empty(source: &str) -> Self {
        Config {
            http: DEFAULT_HTTP
                .parse()
                .unwrap_or(SocketAddr::from(([127, 0, 0, 1], 8080))),
            grpc: DEFAULT_GRPC
                .parse()
                .unwrap_or(SocketAddr::from(([127, 0, 0, 1], 50051))),
            profiles: None,
            links: Vec::new(),
            devices: Vec::new(),
            source: source.to_owned(),
        }
    }

    /// Reads and parses a config file.
    pub fn load(path: &Path) -> Result<Config, Problems> {
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| {
            let mut report = Report::new(&file);
            report.push(0, "", format!("cannot read the config file: {e}"));
            report.into_problems()
        })?;
        let mut config = parse(&file, &text)?;
        if let Some(dir) = &config.profiles
            && dir.is_relative()
        {
            let base = path.parent().unwrap_or(Path::new("."));
            config.profiles = Some(base.join(dir));
        }
        Ok(config)
    }
}

/// Parses config text; `file` names it in problems.
pub fn parse(file: &str, text: &str) -> Result<Config, Problems> {
    let mut report = Report::new(file);
    let config = yaml::parse(text, &mut report).and_then(|root| read_config(&root, &mut report));
    match config {
        Some(c) if !report.has_problems() => Ok(c),
        _ => Err(report.into_problems()),
    }
}

fn read_config(root: &Node, report: &mut Report) -> Option<Config> {
    let mut config = Config::empty(report.file());
    if root.kind == yaml::Kind::Null {
        return Some(config);
    }
    let mut map = root.map(report, "config")?;
    if let Some(listen) = map.get("listen").and_then(|n| n.map(report, "listen")) {
        let mut listen = listen;
        for (key, slot) in [("http", &mut config.http), ("grpc", &mut config.grpc)] {
            if let Some(node) = listen.get(key) {
                let ctx = format!("listen.{key}");
                if let Some(text) = node.scalar_text(report, &ctx) {
                    match text.parse::<SocketAddr>() {
                        Ok(addr) => *slot = addr,
                        Err(_) => report.push(
                            node.line,
                            &ctx,
                            format!(
                                "`{text}` is not an address (write IP:port, e.g. 127.0.0.1:8080)"
                            ),
                        ),
                    }
                }
            }
        }
        listen.finish(report, "listen", LISTEN_KEYS);
    }
    config.profiles = map
        .get("profiles")
        .and_then(|n| n.scalar_text(report, "profiles"))
        .map(PathBuf::from);
    if let Some(links) = map.get("links").and_then(|n| n.seq(report, "links")) {
        check_unique(&entry_names(links), "link", report);
        config.links = links
            .iter()
            .enumerate()
            .filter_map(|(i, n)| read_link(n, i, report))
            .collect();
    }
    if let Some(devices) = map.get("devices").and_then(|n| n.seq(report, "devices")) {
        check_unique(&entry_names(devices), "device", report);
        config.devices = devices
            .iter()
            .enumerate()
            .filter_map(|(i, n)| read_device(n, i, report))
            .collect();
    }
    map.finish(report, "config", TOP_KEYS);
    check_ports(&config.links, report);
    Some(config)
}

fn name_of(
    map: &mut yaml::MapReader<'_>,
    report: &mut Report,
    what: &str,
    index: usize,
) -> (Option<String>, String) {
    let fallback = format!("{what}s[{index}]");
    let name = map
        .require("name", report, &fallback)
        .and_then(|n| n.scalar_text(report, &format!("{fallback}: name")));
    let ctx = name.as_ref().map_or(fallback, |n| format!("{what} {n}"));
    (name, ctx)
}

fn read_link(node: &Node, index: usize, report: &mut Report) -> Option<LinkConfig> {
    let mut map = node.map(report, &format!("links[{index}]"))?;
    let (name, ctx) = name_of(&mut map, report, "link", index);
    let serial = map.get("serial");
    let tcp = map.get("tcp");
    let guard_time = map.get("guard_time").map_or(Some(Duration::ZERO), |n| {
        duration_value(n, report, &format!("{ctx}: guard_time"), Duration::ZERO)
    });
    map.finish(report, &ctx, LINK_KEYS);
    let transport = match (serial, tcp) {
        (Some(s), None) => read_serial(s, &ctx, report).map(Transport::Serial),
        (None, Some(t)) => read_tcp(t, &ctx, report),
        (Some(_), Some(t)) => {
            report.push(t.line, &ctx, "a link is either `serial` or `tcp`, not both");
            None
        }
        (None, None) => {
            report.push(node.line, &ctx, "a link needs `serial` or `tcp` settings");
            None
        }
    };
    Some(LinkConfig {
        name: name?,
        transport: transport?,
        guard_time: guard_time?,
        line: node.line,
    })
}

fn read_serial(node: &Node, link: &str, report: &mut Report) -> Option<SerialSettings> {
    let ctx = format!("{link}: serial");
    let mut map = node.map(report, &ctx)?;
    let at = |k: &str| format!("{ctx}.{k}");
    let port = map
        .require("port", report, &ctx)
        .and_then(|n| n.scalar_text(report, &at("port")));
    if let (Some(p), Some(n)) = (&port, map.get("port"))
        && p.trim().is_empty()
    {
        report.push(n.line, at("port"), "no port configured (the port is empty)");
    }
    let baud = map
        .require("baud", report, &ctx)
        .and_then(|n| n.int_in(report, &at("baud"), 300, 4_000_000))
        .map(|b| b as u32);
    let parity = match map.get("parity") {
        None => Some(Parity::None),
        Some(n) => n.scalar_text(report, &at("parity")).and_then(|text| {
            let parity = match text.to_ascii_uppercase().as_str() {
                "N" | "NONE" => Some(Parity::None),
                "E" | "EVEN" => Some(Parity::Even),
                "O" | "ODD" => Some(Parity::Odd),
                _ => None,
            };
            if parity.is_none() {
                report.push(
                    n.line,
                    at("parity"),
                    format!("invalid parity `{text}` (expected N, E or O)"),
                );
            }
            parity
        }),
    };
    let data_bits = match map.get("data_bits") {
        None => Some(8),
        Some(n) => bits_of(n, report, &at("data_bits"), &[7, 8]),
    };
    let stop_bits = match map.get("stop_bits") {
        None => Some(1),
        Some(n) => bits_of(n, report, &at("stop_bits"), &[1, 2]),
    };
    map.finish(report, &ctx, SERIAL_KEYS);
    Some(SerialSettings {
        port: port?,
        baud: baud?,
        parity: parity?,
        data_bits: data_bits?,
        stop_bits: stop_bits?,
    })
}

fn bits_of(node: &Node, report: &mut Report, ctx: &str, allowed: &[u8]) -> Option<u8> {
    let n = node.int_in(report, ctx, 0, 255)? as u8;
    if allowed.contains(&n) {
        Some(n)
    } else {
        let list: Vec<_> = allowed.iter().map(u8::to_string).collect();
        report.push(
            node.line,
            ctx,
            format!("{n} is not allowed (expected {})", list.join(" or ")),
        );
        None
    }
}

fn read_tcp(node: &Node, link: &str, report: &mut Report) -> Option<Transport> {
    let ctx = format!("{link}: tcp");
    let mut map = node.map(report, &ctx)?;
    let host = map
        .require("host", report, &ctx)
        .and_then(|n| n.scalar_text(report, &format!("{ctx}.host")));
    let port = match map.get("port") {
        None => Some(502),
        Some(n) => n
            .int_in(report, &format!("{ctx}.port"), 1, 65535)
            .map(|p| p as u16),
    };
    let framing = match map.get("framing") {
        None => Some(Framing::Mbap),
        Some(n) => match n.scalar_text(report, &format!("{ctx}.framing")).as_deref() {
            Some("mbap") => Some(Framing::Mbap),
            Some("rtu") => Some(Framing::Rtu),
            Some(other) => {
                report.push(
                    n.line,
                    format!("{ctx}.framing"),
                    format!("unknown framing `{other}` (expected mbap or rtu)"),
                );
                None
            }
            None => None,
        },
    };
    map.finish(report, &ctx, TCP_KEYS);
    Some(Transport::Tcp {
        host: host?,
        port: port?,
        framing: framing?,
    })
}

/// A duration such as `50ms` or `T#1s`, at least `min`.
fn duration_value(node: &Node, report: &mut Report, ctx: &str, min: Duration) -> Option<Duration> {
    let text = match &node.kind {
        yaml::Kind::Str(s) => s.clone(),
        yaml::Kind::Int(i) => {
            report.push(
                node.line,
                ctx,
                format!("`{i}` has no unit (write e.g. `{i}ms`)"),
            );
            return None;
        }
        _ => {
            report.push(
                node.line,
                ctx,
                format!("expected a duration, found {}", node.describe()),
            );
            return None;
        }
    };
    match duration::parse(&text) {
        Ok(d) if d >= min => Some(d),
        Ok(_) => {
            report.push(
                node.line,
                ctx,
                format!("must be at least {}ms", min.as_millis()),
            );
            None
        }
        Err(e) => {
            report.push(node.line, ctx, e);
            None
        }
    }
}

fn read_device(node: &Node, index: usize, report: &mut Report) -> Option<DeviceConfig> {
    let mut map = node.map(report, &format!("devices[{index}]"))?;
    let (name, ctx) = name_of(&mut map, report, "device", index);
    let at = |k: &str| format!("{ctx}: {k}");
    let profile = map
        .require("profile", report, &ctx)
        .and_then(|n| n.scalar_text(report, &at("profile")));
    let link = map
        .get("link")
        .and_then(|n| n.scalar_text(report, &at("link")));
    let slave_id = map
        .get("slave_id")
        .and_then(|n| n.int_in(report, &at("slave_id"), 1, 247))
        .map(|s| s as u8);
    let mut duration_of = |key: &str, default: Duration, min: Duration| -> Option<Duration> {
        map.get(key).map_or(Some(default), |node| {
            duration_value(node, report, &at(key), min)
        })
    };
    let refresh_rate = duration_of("refresh_rate", DEFAULT_REFRESH, Duration::from_millis(1));
    let timeout = duration_of("timeout", DEFAULT_TIMEOUT, Duration::from_millis(1));
    let retries = match map.get("retries") {
        None => Some(DEFAULT_RETRIES),
        Some(n) => n.int_in(report, &at("retries"), 0, 10).map(|r| r as u32),
    };
    let max_batch = match map.get("max_batch") {
        None => Some(MAX_READ_REGISTERS),
        Some(n) => n
            .int_in(report, &at("max_batch"), 1, i128::from(MAX_READ_REGISTERS))
            .map(|m| m as u16),
    };
    let max_gap = match map.get("max_gap") {
        None => Some(0),
        Some(n) => n
            .int_in(report, &at("max_gap"), 0, i128::from(MAX_READ_REGISTERS))
            .map(|m| m as u16),
    };
    map.finish(report, &ctx, DEVICE_KEYS);
    Some(DeviceConfig {
        name: name?,
        profile: profile?,
        link,
        slave_id,
        refresh_rate: refresh_rate?,
        timeout: timeout?,
        retries: retries?,
        max_batch: max_batch?,
        max_gap: max_gap?,
        line: node.line,
    })
}

/// The `name` of every entry that has one, with its line, whatever else is wrong with it.
fn entry_names(entries: &[Node]) -> Vec<(String, u64)> {
    entries
        .iter()
        .filter_map(|entry| match &entry.kind {
            yaml::Kind::Map(keys) => keys.iter().find_map(|(k, v)| match &v.kind {
                yaml::Kind::Str(name) if k.name == "name" => Some((name.clone(), entry.line)),
                _ => None,
            }),
            _ => None,
        })
        .collect()
}

fn check_unique(items: &[(String, u64)], what: &str, report: &mut Report) {
    let mut seen: HashMap<&str, u64> = HashMap::new();
    for (name, line) in items {
        let (name, line) = (name.as_str(), *line);
        if let Some(first) = seen.get(name) {
            report.push(
                line,
                format!("{what} {name}"),
                format!("duplicate {what} name (first defined on line {first})"),
            );
        } else {
            seen.insert(name, line);
        }
    }
}

/// One serial port is one link: two links on one port with different settings are the
/// seed's "configuration mismatch".
fn check_ports(links: &[LinkConfig], report: &mut Report) {
    let mut by_port: HashMap<&str, (&LinkConfig, &SerialSettings)> = HashMap::new();
    for link in links {
        let Transport::Serial(s) = &link.transport else {
            continue;
        };
        let Some((first, fs)) = by_port.get(s.port.as_str()) else {
            by_port.insert(&s.port, (link, s));
            continue;
        };
        let ctx = format!("link {}", link.name);
        let mut mismatch = |what: &str, a: String, b: String| {
            report.push(
                link.line,
                &ctx,
                format!(
                    "{what} configuration mismatch on {}: {b} here, {a} in link {} (line {})",
                    s.port, first.name, first.line
                ),
            );
        };
        let mut any = false;
        if fs.baud != s.baud {
            mismatch("Baudrate", fs.baud.to_string(), s.baud.to_string());
            any = true;
        }
        if fs.parity != s.parity {
            mismatch(
                "Parity",
                fs.parity.letter().into(),
                s.parity.letter().into(),
            );
            any = true;
        }
        if fs.stop_bits != s.stop_bits {
            mismatch(
                "Stop bits",
                fs.stop_bits.to_string(),
                s.stop_bits.to_string(),
            );
            any = true;
        }
        if fs.data_bits != s.data_bits {
            mismatch(
                "Data bits",
                fs.data_bits.to_string(),
                s.data_bits.to_string(),
            );
            any = true;
        }
        if !any {
            report.push(
                link.line,
                &ctx,
                format!(
                    "port {} is already link {} (line {}); let the devices share that link",
                    s.port, first.name, first.line
                ),
            );
        }
    }
}

/// Checks devices against the profiles and links: profile exists, simulated devices have no
/// link and slave id, Modbus devices have both.
pub fn check_devices(config: &Config, catalog: &Catalog) -> Result<(), Problems> {
    let mut report = Report::new(&config.source);
    for d in &config.devices {
        let ctx = format!("device {}", d.name);
        let Some(profile) = catalog.get(&d.profile) else {
            let known: Vec<_> = catalog.iter().map(|p| p.name.as_str()).collect();
            report.push(
                d.line,
                &ctx,
                format!(
                    "unknown profile `{}` (known: {})",
                    d.profile,
                    if known.is_empty() {
                        "none".to_owned()
                    } else {
                        known.join(", ")
                    }
                ),
            );
            continue;
        };
        if profile.protocol == Protocol::Simulated {
            if let Some(link) = &d.link {
                report.push(
                    d.line,
                    &ctx,
                    format!("a simulated device has no link (remove `link: {link}`)"),
                );
            }
            if d.slave_id.is_some() {
                report.push(d.line, &ctx, "a simulated device has no slave_id");
            }
            continue;
        }
        match &d.link {
            None => report.push(
                d.line,
                &ctx,
                format!(
                    "profile {} is {}: the device needs a `link`",
                    profile.name,
                    profile.protocol.name()
                ),
            ),
            Some(link) if !config.links.iter().any(|l| &l.name == link) => {
                let known: Vec<_> = config.links.iter().map(|l| l.name.as_str()).collect();
                report.push(
                    d.line,
                    &ctx,
                    format!(
                        "unknown link `{link}` (known: {})",
                        if known.is_empty() {
                            "none".to_owned()
                        } else {
                            known.join(", ")
                        }
                    ),
                );
            }
            Some(_) => {}
        }
        if d.slave_id.is_none() {
            report.push(d.line, &ctx, "no slave configured: set slave_id (1-247)");
        }
    }
    let problems = report.into_problems();
    if problems.is_empty() {
        Ok(())
    } else {
        Err(problems)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = "listen:\n  http: 127.0.0.1:0\nlinks:\n  - name: rs485\n    serial: { port: /dev/ttyUSB0, baud: 9600, parity: N, data_bits: 8, stop_bits: 1 }\n  - name: plant\n    tcp: { host: 192.0.2.10, port: 502 }\ndevices:\n  - { name: io_rack, profile: MyIoModule, link: rs485, slave_id: 1, refresh_rate: 50ms }\n  - { name: pump_vfd, profile: MyVfd, link: rs485, slave_id: 2, refresh_rate: 100ms, timeout: 200ms }\n  - { name: sim, profile: SimIo, refresh_rate: T#100ms }\n";

    #[test]
    fn the_spec_example_parses() {
        let c = parse("iogate.yaml", GOOD).expect("parses");
        assert_eq!(c.http.port(), 0);
        assert_eq!(c.grpc.to_string(), DEFAULT_GRPC);
        assert_eq!(c.links.len(), 2);
        assert_eq!(c.devices[0].refresh_rate, Duration::from_millis(50));
        assert_eq!(c.devices[1].timeout, Duration::from_millis(200));
        assert_eq!(c.devices[2].refresh_rate, Duration::from_millis(100));
        assert_eq!(c.devices[2].link, None);
        assert_eq!(c.devices[2].line, 11);
    }

    fn problems(text: &str) -> String {
        parse("c.yaml", text).expect_err("should fail").to_string()
    }

    #[test]
    fn serial_settings_mismatch_on_one_port_is_an_error() {
        let text = "links:\n  - { name: a, serial: { port: /dev/ttyS0, baud: 9600 } }\n  - { name: b, serial: { port: /dev/ttyS0, baud: 19200, parity: E } }\n";
        let all = problems(text);
        assert!(all.contains("c.yaml:3: link b: Baudrate configuration mismatch on /dev/ttyS0: 19200 here, 9600 in link a (line 2)"), "{all}");
        assert!(all.contains("Parity configuration mismatch"), "{all}");
    }

    #[test]
    fn every_config_problem_is_reported() {
        let text = "listen: { http: localhost }\nlinks:\n  - { name: a, serial: { port: /dev/x, baud: 9600, parity: X, stop_bits: 3 } }\ndevices:\n  - { name: d, profile: P, slave_id: 300, refresh_rate: 50 }\n  - { name: d, profile: P, refresh_rate: soon, colour: red }\n";
        let all = problems(text);
        for needle in [
            "c.yaml:1: listen.http: `localhost` is not an address",
            "c.yaml:3: link a: serial.parity: invalid parity `X`",
            "c.yaml:3: link a: serial.stop_bits: 3 is not allowed",
            "c.yaml:5: device d: slave_id: 300 is outside",
            "c.yaml:5: device d: refresh_rate: `50` has no unit",
            "c.yaml:6: device d: refresh_rate: `soon` is not a duration",
            "c.yaml:6: device d: unknown key `colour`",
            "c.yaml:6: device d: duplicate device name (first defined on line 5)",
        ] {
            assert!(all.contains(needle), "missing {needle:?} in\n{all}");
        }
    }

    #[test]
    fn devices_are_checked_against_profiles_and_links() {
        let config = parse("c.yaml", "links:\n  - { name: bus, tcp: { host: 127.0.0.1 } }\ndevices:\n  - { name: a, profile: Sim, link: bus }\n  - { name: b, profile: Real }\n  - { name: c, profile: Nope }\n  - { name: e, profile: Real, link: other, slave_id: 1 }\n").expect("parses");
        let sim = crate::profile::load_str("s.yaml", "name: Sim\nprotocol: simulated\nfields:\n  - { name: X, type: BOOL, direction: input, register: { address: 0, kind: virtual } }\n").expect("sim");
        let real = crate::profile::load_str("r.yaml", "name: Real\nfields:\n  - { name: X, type: BOOL, direction: input, register: { address: 0, kind: coil } }\n").expect("real");
        let catalog = Catalog::new([sim, real]);
        let all = check_devices(&config, &catalog)
            .expect_err("fails")
            .to_string();
        for needle in [
            "c.yaml:4: device a: a simulated device has no link",
            "c.yaml:5: device b: profile Real is modbus-rtu: the device needs a `link`",
            "c.yaml:5: device b: no slave configured",
            "c.yaml:6: device c: unknown profile `Nope` (known: Real, Sim)",
            "c.yaml:7: device e: unknown link `other` (known: bus)",
        ] {
            assert!(all.contains(needle), "missing {needle:?} in\n{all}");
        }
    }

    proptest::proptest! {
        #[test]
        fn arbitrary_text_never_panics(text in "\\PC{0,300}") {
            let _ = parse("fuzz.yaml", &text);
        }

        #[test]
        fn mutated_configs_never_panic(
            at in proptest::prelude::any::<proptest::sample::Index>(),
            insert in "[ \\-:{}\\[\\],#'\"a-z0-9\n]{0,4}",
            cut in 0usize..6,
        ) {
            let _ = parse("fuzz.yaml", &crate::yaml::mutate(GOOD, at, &insert, cut));
        }
    }

    #[test]
    fn empty_config_is_valid() {
        let c = parse("c.yaml", "").expect("empty is fine");
        assert!(c.devices.is_empty());
    }
}

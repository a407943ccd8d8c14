//! Reading `iogate.yaml` from its YAML tree: shapes, keys and values, every problem with
//! its line. The rules a link or device obeys are applied through [`super::rules`].

use std::collections::HashMap;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

mod device;

use super::line::ruled;
use super::rules;
use super::{Config, DeviceConfig, Framing, LinkConfig, SerialSettings, Transport};
use crate::duration;
use crate::yaml::{self, Node, Report};
use device::read_device;

/// The top-level keys the config reader reads; every other one is kept for the
/// front-ends, which name the keys they read.
pub(crate) const CORE_KEYS: &[&str] = &[
    "listen",
    "profiles",
    "links",
    "devices",
    "modbus_server",
    "transactions",
    "security",
    "reload",
    "ha",
];
const RELOAD_KEYS: &[&str] = &["watch", "debounce"];
const LISTEN_KEYS: &[&str] = &[
    "http",
    "grpc",
    "header_timeout",
    "body_timeout",
    "max_streams",
    "max_connections",
    "max_connections_per_client",
    "max_streams_per_client",
];
const LINK_KEYS: &[&str] = &["name", "serial", "tcp", "guard_time"];
const TCP_KEYS: &[&str] = &["host", "port", "framing"];
pub(super) const DEVICE_KEYS: &[&str] = &[
    "name",
    "profile",
    "link",
    "slave_id",
    "refresh_rate",
    "timeout",
    "retries",
    "max_batch",
    "max_gap",
    "write_mode",
    "rewrite_outputs",
    "on_client_loss",
];

pub(super) fn read_config(root: &Node, report: &mut Report) -> Option<Config> {
    let mut config = Config::empty(report.file());
    if root.kind == yaml::Kind::Null {
        return Some(config);
    }
    let mut map = root.map(report, "config")?;
    if let Some(listen) = map.get("listen").and_then(|n| n.map(report, "listen")) {
        read_listen(&mut config, listen, report);
    }
    if let Some(n) = map.get("profiles") {
        config.lines.profiles = n.line;
        config.profiles = n.scalar_text(report, "profiles").map(PathBuf::from);
    }
    if let Some(links) = map.get("links").and_then(|n| n.seq(report, "links")) {
        read_links(&mut config, links, report);
    }
    if let Some(devices) = map.get("devices").and_then(|n| n.seq(report, "devices")) {
        read_devices(&mut config, devices, report);
    }
    config.modbus_server = map
        .get("modbus_server")
        .and_then(|n| super::modbus_server::read(n, report));
    if let Some(n) = map.get("security") {
        config.security = super::security::read(n, report);
    }
    config.transactions = map
        .get("transactions")
        .map(|n| super::transactions::read(n, report))
        .unwrap_or_default();
    if let Some(reload) = map.get("reload").and_then(|n| n.map(report, "reload")) {
        read_reload(&mut config.reload, reload, report);
    }
    config.ha = map.get("ha").and_then(|n| super::ha::read(n, report));
    for (key, node) in map.rest() {
        config.sections.keep(&key.name, key.line, node);
    }
    super::check::check_ports(&config.links, report);
    super::check::check_server_ports(&config, report);
    Some(config)
}

/// `listen:`: the HTTP and gRPC addresses, the request timeouts, the streams' bound.
fn read_listen(config: &mut Config, mut listen: yaml::MapReader<'_>, report: &mut Report) {
    for (key, slot, line) in [
        ("http", &mut config.http, &mut config.lines.http),
        ("grpc", &mut config.grpc, &mut config.lines.grpc),
    ] {
        if let Some(node) = listen.get(key) {
            *line = node.line;
            let ctx = format!("listen.{key}");
            if let Some(text) = node.scalar_text(report, &ctx) {
                match text.parse::<SocketAddr>() {
                    Ok(addr) => *slot = addr,
                    Err(_) => report.push(
                        node.line,
                        &ctx,
                        format!("`{text}` is not an address (write IP:port, e.g. 127.0.0.1:8080)"),
                    ),
                }
            }
        }
    }
    if let Some(node) = listen.get("header_timeout")
        && let Some(d) = duration_value(
            node,
            report,
            "listen.header_timeout",
            Duration::from_millis(10),
        )
    {
        config.header_timeout = d;
    }
    if let Some(node) = listen.get("body_timeout")
        && let Some(d) = duration_value(
            node,
            report,
            "listen.body_timeout",
            Duration::from_millis(10),
        )
    {
        config.body_timeout = d;
    }
    if let Some(n) = listen.get("max_streams").and_then(|node| {
        node.int_in(
            report,
            "listen.max_streams",
            1,
            super::MAX_STREAMS_LIMIT as i128,
        )
    }) {
        config.max_streams = usize::try_from(n).unwrap_or(super::DEFAULT_MAX_STREAMS);
    }
    if let Some(n) = listen.get("max_connections").and_then(|node| {
        let most = super::MAX_STREAMS_LIMIT as i128;
        node.int_in(report, "listen.max_connections", 1, most)
    }) {
        config.max_connections = usize::try_from(n).unwrap_or(super::DEFAULT_MAX_CONNECTIONS);
    }
    if let Some(n) = listen.get("max_connections_per_client").and_then(|node| {
        let most = super::MAX_STREAMS_LIMIT as i128;
        node.int_in(report, "listen.max_connections_per_client", 1, most)
    }) {
        config.max_connections_per_client = usize::try_from(n).unwrap_or(1);
    }
    if let Some(n) = listen.get("max_streams_per_client").and_then(|node| {
        let most = super::MAX_STREAMS_LIMIT as i128;
        node.int_in(report, "listen.max_streams_per_client", 1, most)
    }) {
        config.max_streams_per_client = usize::try_from(n).unwrap_or(1);
    }
    listen.finish(report, "listen", LISTEN_KEYS);
}

/// `links:`, each checked; one that cannot be read is named as unreadable.
fn read_links(config: &mut Config, links: &[Node], report: &mut Report) {
    check_unique(&entry_names(links), "link", report);
    for (i, n) in links.iter().enumerate() {
        match read_link(n, i, report) {
            Some(link) => config.links.push(link),
            None => config.unreadable.links.extend(
                entry_names(std::slice::from_ref(n))
                    .into_iter()
                    .map(|(name, _)| name),
            ),
        }
    }
}

/// `devices:`, each checked; one that cannot be read is named as unreadable.
fn read_devices(config: &mut Config, devices: &[Node], report: &mut Report) {
    check_unique(&entry_names(devices), "device", report);
    for (i, n) in devices.iter().enumerate() {
        match read_device(n, i, report) {
            Some((device, slave_refused)) => {
                if slave_refused {
                    config.unreadable.slave_ids.push(device.name.clone());
                }
                config.devices.push(device);
            }
            None => config.unreadable.devices.extend(
                entry_names(std::slice::from_ref(n))
                    .into_iter()
                    .map(|(name, _)| name),
            ),
        }
    }
}

/// `reload: { watch, debounce }`.
fn read_reload(
    config: &mut super::ReloadConfig,
    mut reload: yaml::MapReader<'_>,
    report: &mut Report,
) {
    if let Some(node) = reload.get("watch")
        && let Some(watch) = yaml::boolean(node, report, "reload.watch")
    {
        config.watch = watch;
    }
    if let Some(node) = reload.get("debounce")
        && let Some(d) = duration_value(node, report, "reload.debounce", Duration::ZERO)
    {
        if d > super::MAX_DEBOUNCE {
            report.push(
                node.line,
                "reload.debounce",
                format!(
                    "{d:?} is longer than {} s: changes would wait too long",
                    super::MAX_DEBOUNCE.as_secs()
                ),
            );
        } else {
            config.debounce = d;
        }
    }
    reload.finish(report, "reload", RELOAD_KEYS);
}

pub(super) fn name_of(
    map: &mut yaml::MapReader<'_>,
    report: &mut Report,
    what: &str,
    index: usize,
) -> (Option<String>, String) {
    let fallback = format!("{what}s[{index}]");
    let name = map.require("name", report, &fallback).and_then(|n| {
        let text = n.scalar_text(report, &format!("{fallback}: name"))?;
        rules::name(&text)
            .map_err(|e| report.push(n.line, format!("{fallback}: name"), e.to_string()))
            .ok()
            .map(|()| text)
    });
    let ctx = name.as_ref().map_or(fallback, |n| format!("{what} {n}"));
    (name, ctx)
}

fn read_link(node: &Node, index: usize, report: &mut Report) -> Option<LinkConfig> {
    let mut map = node.map(report, &format!("links[{index}]"))?;
    let (name, ctx) = name_of(&mut map, report, "link", index);
    let serial = map.get("serial");
    let tcp = map.get("tcp");
    let driver = crate::profile::drivers()
        .iter()
        .find_map(|w| map.get(w.link_key).map(|n| (w.link_key, w.link_at, n)));
    let guard_time = map.get("guard_time").map_or(Some(Duration::ZERO), |n| {
        let at = format!("{ctx}: guard_time");
        duration_value(n, report, &at, Duration::ZERO)
            .and_then(|d| ruled(rules::guard_time(d), n.line, &at, report))
    });
    let keys: Vec<&str> = LINK_KEYS
        .iter()
        .copied()
        .chain(crate::profile::drivers().iter().map(|w| w.link_key))
        .collect();
    map.finish(report, &ctx, &keys);
    let transport = match (serial, tcp, driver) {
        (Some(s), None, None) => read_serial(s, &ctx, report).map(Transport::Serial),
        (None, Some(t), None) => read_tcp(t, &ctx, report),
        (None, None, Some((key, at, n))) => read_driver(key, at, n, &ctx, report),
        (Some(_), Some(t), None) => {
            report.push(t.line, &ctx, "a link is either `serial` or `tcp`, not both");
            None
        }
        (None, None, None) => {
            report.push(
                node.line,
                &ctx,
                format!(
                    "a link needs `serial` or `tcp` settings (or {})",
                    crate::profile::drivers()
                        .iter()
                        .map(|w| format!("`{}` for a {} device", w.link_key, w.protocol))
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            );
            None
        }
        (_, _, Some((key, _, n))) => {
            report.push(
                n.line,
                &ctx,
                format!("a link is `serial`, `tcp` or `{key}`, not several"),
            );
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

/// The settings of a link of another protocol, kept for its driver: they must say where
/// the link goes (`at`: `url`).
fn read_driver(
    protocol: &'static str,
    at: &str,
    node: &Node,
    link: &str,
    report: &mut Report,
) -> Option<Transport> {
    let ctx = format!("{link}: {protocol}");
    let yaml::Kind::Map(entries) = &node.kind else {
        report.push(
            node.line,
            &ctx,
            format!("expected a mapping, found {}", node.describe()),
        );
        return None;
    };
    let Some((_, value)) = entries.iter().find(|(k, _)| k.name == at) else {
        report.push(node.line, &ctx, format!("missing required key `{at}`"));
        return None;
    };
    let mut endpoint = value.scalar_text(report, &format!("{ctx}.{at}"))?;
    // Where the link goes, with the port its settings give (an S7 PLC or a Logix controller
    // on another port than the protocol's).
    if let Some((_, port)) = entries.iter().find(|(k, _)| k.name == "port")
        && let yaml::Kind::Int(p) = &port.kind
    {
        endpoint = format!("{endpoint}:{p}");
    }
    let base = std::path::Path::new(report.file())
        .parent()
        .map(std::path::Path::to_path_buf)
        .unwrap_or_default();
    Some(Transport::Driver(super::DriverLink {
        protocol,
        endpoint,
        settings: node.clone(),
        base,
    }))
}

fn read_serial(node: &Node, link: &str, report: &mut Report) -> Option<SerialSettings> {
    let ctx = format!("{link}: serial");
    let mut map = node.map(report, &ctx)?;
    let settings = super::line::read_line(&mut map, &ctx, report);
    map.finish(report, &ctx, super::line::KEYS);
    settings
}

fn read_tcp(node: &Node, link: &str, report: &mut Report) -> Option<Transport> {
    let ctx = format!("{link}: tcp");
    let mut map = node.map(report, &ctx)?;
    let host = map
        .require("host", report, &ctx)
        .and_then(|n| n.scalar_text(report, &format!("{ctx}.host")));
    let port = match map.get("port") {
        None => Some((i128::from(rules::DEFAULT_TCP_PORT), node.line)),
        Some(n) => n
            .int_in(report, &format!("{ctx}.port"), 0, i128::from(u32::MAX))
            .map(|p| (p, n.line)),
    };
    let framing = match map.get("framing") {
        None => Some(Framing::Mbap),
        Some(n) => {
            let at = format!("{ctx}.framing");
            n.scalar_text(report, &at)
                .and_then(|text| ruled(rules::parse_framing(&text), n.line, &at, report))
        }
    };
    map.finish(report, &ctx, TCP_KEYS);
    let host = host?;
    let (port, line) = port?;
    let port = rules::tcp_endpoint(&host, port as u64)
        .map_err(|errors| {
            for e in errors {
                report.push(line, format!("{ctx}.{}", e.key()), e.to_string());
            }
        })
        .ok()?;
    Some(Transport::Tcp {
        host,
        port,
        framing: framing?,
    })
}

/// A duration such as `50ms` or `T#1s`, at least `min`.
pub(crate) fn duration_value(
    node: &Node,
    report: &mut Report,
    ctx: &str,
    min: Duration,
) -> Option<Duration> {
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

/// Names are unique ignoring case (`Sim` and `sim` are one name, as IEC identifiers).
fn check_unique(items: &[(String, u64)], what: &str, report: &mut Report) {
    let mut seen: HashMap<String, u64> = HashMap::new();
    for (name, line) in items {
        let (name, line) = (name.as_str(), *line);
        if let Some(first) = seen.get(&name.to_ascii_lowercase()) {
            report.push(
                line,
                format!("{what} {name}"),
                format!("duplicate {what} name (first defined on line {first})"),
            );
        } else {
            seen.insert(name.to_ascii_lowercase(), line);
        }
    }
}

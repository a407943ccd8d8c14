//! Comparing the configuration in force with a new one: what was added, removed and
//! changed, by link, device, field, profile, map entry, standing transaction, security
//! setting and listener. Pure: the same comparison makes a reload's report, what the reload
//! applies, and `iogate check --diff`. Lines in the files are not compared (a comment added
//! above a device changes nothing).

use std::fmt::Debug;

use crate::auth::Tokens;
use crate::config::{DeviceConfig, LinkConfig, Transport};
use crate::profile::{Field, Profile};
use crate::service::{Action, Item, Kind};
use crate::setup::Setup;

mod details;

pub(crate) use details::same_profile;
use details::*;

/// Names added, removed and changed, in the new file's order (removed: the old one's).
#[derive(Debug, Default, Clone, PartialEq)]
pub(crate) struct Names {
    pub(crate) added: Vec<String>,
    pub(crate) removed: Vec<String>,
    pub(crate) changed: Vec<String>,
}

impl Names {
    fn is_empty(&self) -> bool {
        self.added.is_empty() && self.removed.is_empty() && self.changed.is_empty()
    }
}

/// Everything that differs, as report items and as what to apply.
#[derive(Debug, Default)]
pub(crate) struct Diff {
    pub(crate) items: Vec<Item>,
    /// Links whose settings changed (reopened).
    pub(crate) links: Names,
    /// Devices re-planned (config or profile changed).
    pub(crate) devices: Names,
    pub(crate) transactions: Names,
    /// Any profile file changed (the catalog is replaced).
    pub(crate) profiles: bool,
    /// Tokens, `read_only` or the declaration policy.
    pub(crate) access: bool,
    /// The TLS files or their contents.
    pub(crate) tls: bool,
    /// The Modbus server's section (other than its listener) or its map.
    pub(crate) modbus: bool,
    pub(crate) modbus_listen: bool,
    pub(crate) http_listen: bool,
    pub(crate) grpc_listen: bool,
    /// `listen.max_streams`: in force for the streams opened from now on.
    pub(crate) max_streams: bool,
    /// The front-ends with a section of their own whose section changed (restarted).
    pub(crate) front_ends: Vec<&'static str>,
}

impl Diff {
    pub(crate) fn is_empty(&self) -> bool {
        self.items.is_empty()
    }

    fn push(&mut self, kind: Kind, name: impl Into<String>, action: Action, details: Vec<String>) {
        self.items.push(Item {
            kind,
            name: name.into(),
            action,
            details,
        });
    }
}

/// Compares the configuration in force (`old`, with its tokens) with `new`.
pub(crate) fn diff(old: &Setup, old_tokens: &Tokens, new: &Setup, new_tokens: &Tokens) -> Diff {
    let mut d = Diff::default();
    listeners(&mut d, old, new);
    security(&mut d, old, old_tokens, new, new_tokens);
    profiles(&mut d, old, new);
    links(&mut d, old, new);
    devices(&mut d, old, new);
    modbus_server(&mut d, old, new);
    transactions(&mut d, old, new);
    front_ends(&mut d, old, new);
    d
}

/// The HTTP and gRPC listeners, their limits and the streams' bound.
fn listeners(d: &mut Diff, old: &Setup, new: &Setup) {
    let (a, b) = (&old.config, &new.config);
    for (key, before, after, flag) in [
        ("listen.http", a.http, b.http, &mut d.http_listen),
        ("listen.grpc", a.grpc, b.grpc, &mut d.grpc_listen),
    ] {
        if before != after {
            *flag = true;
            d.items.push(Item {
                kind: Kind::Listener,
                name: key.to_owned(),
                action: Action::Changed,
                details: vec![format!("{before} -> {after}: rebound")],
            });
        }
    }
    let limits: Vec<String> = [
        changed_text(
            "header_timeout",
            duration(a.header_timeout),
            duration(b.header_timeout),
        ),
        changed_text(
            "body_timeout",
            duration(a.body_timeout),
            duration(b.body_timeout),
        ),
        changed_text("max_connections", a.max_connections, b.max_connections),
        changed_text(
            "max_connections_per_client",
            a.max_connections_per_client,
            b.max_connections_per_client,
        ),
    ]
    .into_iter()
    .flatten()
    .collect();
    let mut listen = limits;
    let per_client = changed_text(
        "max_streams_per_client",
        a.max_streams_per_client,
        b.max_streams_per_client,
    );
    if let Some(change) = per_client {
        d.max_streams = true;
        listen.push(format!("{change} (streams already open stay)"));
    }
    if let Some(change) = changed_text("max_streams", a.max_streams, b.max_streams) {
        d.max_streams = true;
        listen.push(format!(
            "{change} (streams already open stay; new ones count against it)"
        ));
    }
    if !listen.is_empty() {
        d.push(Kind::Listener, "listen", Action::Changed, listen);
    }
}

/// Tokens, read-only, what declarations may reach, TLS.
fn security(d: &mut Diff, old: &Setup, old_tokens: &Tokens, new: &Setup, new_tokens: &Tokens) {
    let (a, b) = (&old.config, &new.config);
    let mut security = old_tokens.changes_to(new_tokens);
    security.extend(changed_text(
        "read_only",
        a.security.read_only,
        b.security.read_only,
    ));
    security.extend(changed("declare", &a.security.declare, &b.security.declare));
    if !security.is_empty() {
        d.access = true;
        d.push(Kind::Security, "security", Action::Changed, security);
    }
    if a.security.tls != b.security.tls {
        d.tls = true;
        let what = match (&a.security.tls, &b.security.tls) {
            (None, Some(_)) => "TLS turned on: HTTP and gRPC listeners rebound",
            (Some(_), None) => "TLS turned off: HTTP and gRPC listeners rebound",
            _ => "TLS files changed: new connections get the new ones",
        };
        d.push(
            Kind::Security,
            "tls",
            Action::Changed,
            vec![what.to_owned()],
        );
    }
}

/// Profiles added, changed (field by field) and removed.
fn profiles(d: &mut Diff, old: &Setup, new: &Setup) {
    for p in new.catalog.iter() {
        match old.catalog.get(&p.name) {
            None => {
                d.profiles = true;
                d.push(Kind::Profile, &p.name, Action::Added, Vec::new());
            }
            Some(o) if !same_profile(o, p) => {
                d.profiles = true;
                let details = field_items("", o, p)
                    .into_iter()
                    .map(|i| format!("field {} {}", &i.name[1..], i.action.name()))
                    .collect();
                d.push(Kind::Profile, &p.name, Action::Changed, details);
            }
            Some(_) => {}
        }
    }
    for p in old.catalog.iter() {
        if new.catalog.get(&p.name).is_none() {
            d.profiles = true;
            d.push(Kind::Profile, &p.name, Action::Removed, Vec::new());
        }
    }
}

/// Links added, changed and removed.
fn links(d: &mut Diff, old: &Setup, new: &Setup) {
    let (a, b) = (&old.config, &new.config);
    for l in &b.links {
        match a.links.iter().find(|o| o.name == l.name) {
            None => {
                d.links.added.push(l.name.clone());
                d.push(
                    Kind::Link,
                    &l.name,
                    Action::Added,
                    vec![l.transport.to_string()],
                );
            }
            Some(o) => {
                let details = link_details(o, l);
                if !details.is_empty() {
                    d.links.changed.push(l.name.clone());
                    let mut details = details;
                    details.push("reopened".to_owned());
                    d.push(Kind::Link, &l.name, Action::Changed, details);
                }
            }
        }
    }
    for o in &a.links {
        if !b.links.iter().any(|l| l.name == o.name) {
            d.links.removed.push(o.name.clone());
            d.push(
                Kind::Link,
                &o.name,
                Action::Removed,
                vec!["port closed".to_owned()],
            );
        }
    }
}

/// Devices and their fields.
fn devices(d: &mut Diff, old: &Setup, new: &Setup) {
    let (a, b) = (&old.config, &new.config);
    for n in &b.devices {
        let Some(new_profile) = new.catalog.get(&n.profile) else {
            continue;
        };
        match a.devices.iter().find(|o| o.name == n.name) {
            None => {
                d.devices.added.push(n.name.clone());
                d.push(
                    Kind::Device,
                    &n.name,
                    Action::Added,
                    vec![format!("profile {}", n.profile)],
                );
            }
            Some(o) => {
                let Some(old_profile) = old.catalog.get(&o.profile) else {
                    continue;
                };
                let mut details = device_details(o, n);
                let fields = field_items(&n.name, old_profile, new_profile);
                if o.profile == n.profile && !same_profile(old_profile, new_profile) {
                    details.push(format!("profile {} changed", n.profile));
                }
                if !details.is_empty() || !fields.is_empty() {
                    details.push("re-planned".to_owned());
                    d.devices.changed.push(n.name.clone());
                    d.push(Kind::Device, &n.name, Action::Changed, details);
                    d.items.extend(fields);
                }
            }
        }
    }
    for o in &a.devices {
        if !b.devices.iter().any(|n| n.name == o.name) {
            d.devices.removed.push(o.name.clone());
            d.push(Kind::Device, &o.name, Action::Removed, Vec::new());
        }
    }
}

/// The Modbus server: its listener, map, memory and serial ports.
fn modbus_server(d: &mut Diff, old: &Setup, new: &Setup) {
    let (a, b) = (&old.config, &new.config);
    match (&a.modbus_server, &b.modbus_server) {
        (None, None) => {}
        (None, Some(s)) => {
            d.modbus = true;
            d.modbus_listen = true;
            d.push(
                Kind::Listener,
                "modbus_server",
                Action::Added,
                vec![listened(s)],
            );
        }
        (Some(_), None) => {
            d.modbus = true;
            d.modbus_listen = true;
            d.push(Kind::Listener, "modbus_server", Action::Removed, Vec::new());
        }
        (Some(x), Some(y)) => {
            if x.listen != y.listen {
                d.modbus_listen = true;
                d.push(
                    Kind::Listener,
                    "modbus_server.listen",
                    Action::Changed,
                    vec![format!("{} -> {}: rebound", listened(x), listened(y))],
                );
            }
            let ports = |s: &crate::config::modbus_server::ModbusServerConfig| -> Vec<String> {
                s.serial
                    .iter()
                    .map(|e| {
                        format!(
                            "{} {} {}{}{} {} unit {}",
                            e.line.port,
                            e.line.baud,
                            e.line.data_bits,
                            e.line.parity.letter(),
                            e.line.stop_bits,
                            e.line.framing.name(),
                            e.unit_id
                        )
                    })
                    .collect()
            };
            let same_serial = x.serial.len() == y.serial.len()
                && x.serial.iter().zip(&y.serial).all(|(a, b)| a.same_as(b));
            if !same_serial {
                d.push(
                    Kind::Listener,
                    "modbus_server.serial",
                    Action::Changed,
                    vec![format!(
                        "[{}] -> [{}]: changed ports restarted",
                        ports(x).join(", "),
                        ports(y).join(", ")
                    )],
                );
            }
            let mut x = x.clone();
            x.listen = y.listen;
            x.serial.iter_mut().for_each(|e| e.at = 0);
            x.line = y.line;
            x.map.iter_mut().for_each(|e| e.line = 0);
            x.forward.iter_mut().for_each(|f| f.line = 0);
            let mut y = y.clone();
            y.map.iter_mut().for_each(|e| e.line = 0);
            y.forward.iter_mut().for_each(|f| f.line = 0);
            y.serial.iter_mut().for_each(|e| e.at = 0);
            if x != y {
                d.modbus = true;
            }
        }
    }
    map(d, old, new);
}

/// The Modbus server's map: bindings added, moved and removed, and the devices they touch.
fn map(d: &mut Diff, old: &Setup, new: &Setup) {
    if let (Some(pa), Some(pb)) = (&old.map, &new.map) {
        if pa.space != pb.space {
            d.modbus = true;
            d.push(
                Kind::Map,
                "memory",
                Action::Changed,
                vec![format!("{:?} -> {:?}", pa.space, pb.space)],
            );
        }
        for binding in &pb.bindings {
            let at = binding.at.to_string();
            let what = format!("{}.{}", binding.device, binding.name);
            match pa.bindings.iter().find(|o| o.at == binding.at) {
                None => d.push(Kind::Map, at, Action::Added, vec![what]),
                Some(o) if o != binding => {
                    let before = format!("{}.{}", o.device, o.name);
                    let mut details: Vec<String> = changed_text("bound to", &before, &what)
                        .into_iter()
                        .collect();
                    details.extend(changed_text("type", o.ty, binding.ty));
                    details.extend(changed_text("writable", o.writable, binding.writable));
                    if details.is_empty() {
                        details.push(format!("{what}: its registers"));
                    }
                    d.push(Kind::Map, at, Action::Changed, details);
                }
                Some(_) => {}
            }
        }
        for o in &pa.bindings {
            if !pb.bindings.iter().any(|b| b.at == o.at) {
                let mut details = vec![format!("{}.{}", o.device, o.name)];
                if pb.reserved.iter().any(|(at, _)| *at == o.at) {
                    details.push("kept empty until a restart numbers the auto map afresh".into());
                }
                d.push(Kind::Map, o.at.to_string(), Action::Removed, details);
            }
        }
    }
    if d.items.iter().any(|i| i.kind == Kind::Map) || !d.devices.is_empty() {
        d.modbus |= new.config.modbus_server.is_some();
    }
}

/// Standing transactions.
fn transactions(d: &mut Diff, old: &Setup, new: &Setup) {
    let (a, b) = (&old.config, &new.config);
    for t in &b.transactions {
        match a.transactions.iter().find(|o| o.name == t.name) {
            None => {
                d.transactions.added.push(t.name.clone());
                d.push(Kind::Transaction, &t.name, Action::Added, Vec::new());
            }
            Some(o) => {
                let mut o = o.clone();
                o.line = t.line;
                if o != *t {
                    let details = [
                        changed_text("link", &o.link, &t.link),
                        changed_text("period", duration(o.period), duration(t.period)),
                        changed_text("enabled", o.enabled, t.enabled),
                        changed("spec", &o.spec, &t.spec),
                    ]
                    .into_iter()
                    .flatten()
                    .collect();
                    d.transactions.changed.push(t.name.clone());
                    d.push(Kind::Transaction, &t.name, Action::Changed, details);
                }
            }
        }
    }
    for o in &a.transactions {
        if !b.transactions.iter().any(|t| t.name == o.name) {
            d.transactions.removed.push(o.name.clone());
            d.push(Kind::Transaction, &o.name, Action::Removed, Vec::new());
        }
    }
}

/// The front-ends restarted when their section changes, and the reload section.
fn front_ends(d: &mut Diff, old: &Setup, new: &Setup) {
    let (a, b) = (&old.config, &new.config);
    for front_end in crate::front_ends::all() {
        if let Some((action, details)) = front_end.changed(a, b) {
            d.front_ends.push(front_end.name());
            d.push(
                Kind::Section(front_end.name()),
                front_end.name(),
                action,
                details,
            );
        }
    }
    if a.reload != b.reload {
        let details = [
            changed_text("watch", a.reload.watch, b.reload.watch),
            changed_text(
                "debounce",
                duration(a.reload.debounce),
                duration(b.reload.debounce),
            ),
        ]
        .into_iter()
        .flatten()
        .collect();
        d.push(Kind::Reload, "reload", Action::Changed, details);
    }
}

#[cfg(test)]
#[path = "diff/tests.rs"]
mod tests;

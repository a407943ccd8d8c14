//! The `ha:` section of `iogate.yaml`: this gateway as one node of an active/standby pair,
//! the arbiter that grants the lease, and the lease's length. Read here as written; `ha/`
//! runs it.

use std::time::Duration;

use super::ha_arbiters::{EtcdConfig, KubernetesConfig};
use crate::yaml::{Node, Report};

const KEYS: &[&str] = &[
    "node",
    "arbiter",
    "lease",
    "group",
    "advertise",
    "etcd",
    "kubernetes",
];

/// The lease by default, and its bounds: an MQTT keep-alive counts whole seconds (and
/// brokers round them, so a lease of one second could be dropped at once), and a lease of
/// minutes would leave the plant without a master for minutes.
pub(crate) const DEFAULT_LEASE: Duration = Duration::from_secs(3);
pub(crate) const MIN_LEASE: Duration = Duration::from_secs(2);
pub(crate) const MAX_LEASE: Duration = Duration::from_secs(60);
/// The pair's name on the arbiter by default.
pub(crate) const DEFAULT_GROUP: &str = "iogate";

/// Where a replica's own node name comes from when one config serves both (a
/// StatefulSet's pod name): it stands for `ha.node`.
pub(crate) const NODE_ENV: &str = "IOGATE_HA_NODE";
/// And the host it is reached at (the pod's IP), for `ha.advertise`.
pub(crate) const ADVERTISE_ENV: &str = "IOGATE_HA_ADVERTISE";

/// `name`, or the node name `var` gives when it is set.
fn from_env(var: &str, name: String, line: u64, report: &mut Report) -> Option<String> {
    let Ok(given) = std::env::var(var) else {
        return Some(name);
    };
    match super::rules::name(&given) {
        Ok(()) => Some(given),
        Err(e) => {
            report.push(line, var, e.to_string());
            None
        }
    }
}

/// Who grants the lease.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Arbiter {
    /// The broker of the `mqtt:` section: a connection with a client id both nodes share,
    /// a Will, and a retained claim carrying the epoch.
    Mqtt,
    /// A `coordination.k8s.io/v1` Lease.
    Kubernetes,
    /// An etcd lease and key.
    Etcd,
}

impl Arbiter {
    pub(crate) fn name(self) -> &'static str {
        match self {
            Arbiter::Mqtt => "mqtt",
            Arbiter::Kubernetes => "kubernetes",
            Arbiter::Etcd => "etcd",
        }
    }
}

#[derive(Debug, Clone, PartialEq)]
pub(crate) struct HaConfig {
    /// This node's name in the pair.
    pub(crate) node: String,
    pub(crate) arbiter: Arbiter,
    /// How long a granted lease holds without a renewal.
    pub(crate) lease: Duration,
    /// The pair's name on the arbiter (two pairs on one broker need two names).
    pub(crate) group: String,
    /// The host clients reach this node at, for the addresses it announces (default: the
    /// address each server is bound to, or this machine's host name when that is a
    /// wildcard).
    pub(crate) advertise: Option<String>,
    /// Where etcd is (`arbiter: etcd`).
    pub(crate) etcd: Option<EtcdConfig>,
    /// Where the Kubernetes Lease is (`arbiter: kubernetes`; in-cluster by default).
    pub(crate) kubernetes: Option<KubernetesConfig>,
    /// The line of the `ha` key.
    pub(crate) line: u64,
}

/// Reads `ha:`; `None` (with the problems reported) when it cannot be.
pub(crate) fn read(node: &Node, report: &mut Report) -> Option<HaConfig> {
    let mut map = node.map(report, "ha")?;
    let node_name = map
        .require("node", report, "ha")
        .and_then(|n| name(n, "ha.node", report))
        .and_then(|n| from_env(NODE_ENV, n, node.line, report));
    let arbiter = map
        .require("arbiter", report, "ha")
        .and_then(|n| arbiter(n, report));
    let lease = match map.get("lease") {
        Some(n) => lease(n, report),
        None => Some(DEFAULT_LEASE),
    };
    let group = match map.get("group") {
        Some(n) => name(n, "ha.group", report),
        None => Some(DEFAULT_GROUP.to_owned()),
    };
    let advertise = map.get("advertise").and_then(|n| advertise(n, report));
    let advertise = match std::env::var(ADVERTISE_ENV) {
        Ok(host) => Some(host).filter(|h| advertised(h, node.line, ADVERTISE_ENV, report)),
        Err(_) => advertise,
    };
    let etcd = map.get("etcd").map(|n| super::ha_arbiters::etcd(n, report));
    let kubernetes = map
        .get("kubernetes")
        .map(|n| super::ha_arbiters::kubernetes(n, report));
    map.finish(report, "ha", KEYS);
    if arbiter == Some(Arbiter::Etcd) && etcd.is_none() {
        report.push(
            node.line,
            "ha.etcd",
            "arbiter: etcd needs `etcd: {endpoints: [http://host:2379]}`",
        );
        return None;
    }
    Some(HaConfig {
        node: node_name?,
        arbiter: arbiter?,
        lease: lease?,
        group: group?,
        advertise,
        etcd: etcd.flatten(),
        kubernetes: kubernetes.map(|k| k.unwrap_or_default()),
        line: node.line,
    })
}

fn name(node: &Node, ctx: &str, report: &mut Report) -> Option<String> {
    let text = node.scalar_text(report, ctx)?;
    match super::rules::name(&text) {
        Ok(()) => Some(text),
        Err(e) => {
            report.push(node.line, ctx, e.to_string());
            None
        }
    }
}

fn arbiter(node: &Node, report: &mut Report) -> Option<Arbiter> {
    let text = node.scalar_text(report, "ha.arbiter")?;
    match text.as_str() {
        "mqtt" => Some(Arbiter::Mqtt),
        "kubernetes" => Some(Arbiter::Kubernetes),
        "etcd" => Some(Arbiter::Etcd),
        other => {
            report.push(
                node.line,
                "ha.arbiter",
                format!(
                    "{} is no arbiter: mqtt, kubernetes or etcd",
                    crate::text::quote(other)
                ),
            );
            None
        }
    }
}

fn lease(node: &Node, report: &mut Report) -> Option<Duration> {
    let text = node.scalar_text(report, "ha.lease")?;
    let d = match crate::duration::parse(&text) {
        Ok(d) => d,
        Err(e) => {
            report.push(node.line, "ha.lease", e);
            return None;
        }
    };
    if !(MIN_LEASE..=MAX_LEASE).contains(&d) || d.subsec_nanos() != 0 {
        report.push(
            node.line,
            "ha.lease",
            format!(
                "{d:?}: a lease is whole seconds, from {} s to {} s",
                MIN_LEASE.as_secs(),
                MAX_LEASE.as_secs()
            ),
        );
        return None;
    }
    Some(d)
}

fn advertise(node: &Node, report: &mut Report) -> Option<String> {
    let text = node.scalar_text(report, "ha.advertise")?;
    advertised(&text, node.line, "ha.advertise", report).then_some(text)
}

/// Whether `text` is a host name or an IP address (else reported under `ctx`).
fn advertised(text: &str, line: u64, ctx: &str, report: &mut Report) -> bool {
    let ok = !text.is_empty()
        && text.len() <= 253
        && text
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'.' | b'-' | b':' | b'[' | b']'));
    if !ok {
        report.push(
            line,
            ctx,
            format!(
                "{} is not a host name or IP address",
                crate::text::quote(text)
            ),
        );
    }
    ok
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::read_section;

    #[test]
    fn a_pair_node_is_read_with_its_defaults() {
        let (ha, problems) = read_section("ha: {node: a, arbiter: mqtt}\n", "ha", read);
        assert_eq!(problems, Vec::<String>::new());
        let ha = ha.expect("read");
        assert_eq!(
            (ha.node.as_str(), ha.arbiter, ha.lease, ha.group.as_str()),
            ("a", Arbiter::Mqtt, DEFAULT_LEASE, DEFAULT_GROUP)
        );
    }

    #[test]
    fn every_problem_is_named_at_its_line() {
        let text = "ha:\n  node: 'a b'\n  arbiter: zookeeper\n  lease: 500ms\n  advertise: 'x/y'\n  master: yes\n";
        let (ha, problems) = read_section(text, "ha", read);
        assert!(ha.is_none());
        let joined = problems.join("\n");
        for expected in [
            "2: ha.node",
            "3: ha.arbiter: zookeeper is no arbiter",
            "4: ha.lease: 500ms: a lease is whole seconds",
            "5: ha.advertise",
            "master",
        ] {
            assert!(joined.contains(expected), "{expected} in {joined}");
        }
    }

    #[test]
    fn node_and_arbiter_are_required() {
        let (ha, problems) = read_section("ha: {lease: 3s}\n", "ha", read);
        assert!(ha.is_none());
        let joined = problems.join("\n");
        assert!(
            joined.contains("node") && joined.contains("arbiter"),
            "{joined}"
        );
    }
}

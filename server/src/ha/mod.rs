//! This gateway as one node of an active/standby pair (`ha:`): its role made from the
//! section, the arbiter that grants the lease started, and what the node announces of
//! itself (how clients reach its servers). The role itself, and the fence every write
//! passes, are `crate::role`'s; the link tasks open the field only while the node is
//! active, the service refuses writes on a standby, each front-end says what it is.

use std::collections::BTreeMap;
use std::sync::Arc;

use crate::config::Config;
use crate::config::ha::{Arbiter, HaConfig};
use crate::role::{Peer, Role};
use crate::service::Service;
use crate::yaml::{Problems, Report};

mod etcd;
mod kube;
mod store;

use etcd::Etcd;
use kube::Kube;

/// The role of a gateway configured with `config`: standby until its arbiter says more,
/// or alone.
pub(crate) fn role(config: &Config) -> Arc<Role> {
    Arc::new(match &config.ha {
        Some(ha) => Role::paired(&ha.node, ha.arbiter.name(), ha.lease),
        None => Role::alone(),
    })
}

/// What `check` finds wrong with `ha:` beside the section itself: an arbiter this
/// configuration cannot reach.
pub(crate) fn check(config: &Config, base: &std::path::Path) -> Problems {
    let mut report = Report::new(&config.source);
    if let Some(ha) = &config.ha {
        let mqtt = crate::api::mqtt::section(config).is_some();
        let problem = match ha.arbiter {
            Arbiter::Mqtt if !mqtt => Some(
                "mqtt: the lease is held on the broker of the `mqtt:` section, and there is none"
                    .to_owned(),
            ),
            Arbiter::Mqtt => None,
            Arbiter::Etcd => ha
                .etcd
                .as_ref()
                .and_then(|e| Etcd::new(e, &ha.group, ha.lease, base).err()),
            Arbiter::Kubernetes => {
                let k = ha.kubernetes.clone().unwrap_or_default();
                Kube::new(&k, &ha.group, ha.lease, base).err()
            }
        };
        if let Some(problem) = problem {
            report.push(ha.line, "ha.arbiter", problem);
        }
    }
    report.into_problems()
}

/// Starts the lease of a node of a pair (nothing for a gateway alone), and the handover
/// over the `mqtt:` broker when there is one. Its servers listen already, so what it
/// announces is where they are.
pub(crate) fn start(service: &Arc<Service>, config: &Config, base: &std::path::Path) {
    let Some(ha) = config.ha.clone() else {
        return;
    };
    let token = service.tasks().token().clone();
    let role = service.tasks().role().clone();
    let me = {
        let (service, ha) = (service.clone(), ha.clone());
        Arc::new(move || announced(&service, &ha)) as Arc<dyn Fn() -> Peer + Send + Sync>
    };
    let entering = {
        let service = service.clone();
        Arc::new(move |epoch| service.take_over(epoch)) as Arc<dyn Fn(u64) + Send + Sync>
    };
    tracing::info!(node = %ha.node, arbiter = ha.arbiter.name(), lease = ?ha.lease, "HA: standby, watching the lease");
    let setup = store::StoreSetup {
        node: ha.node.clone(),
        lease: ha.lease,
        role: role.clone(),
        me: me.clone(),
        entering: entering.clone(),
    };
    let stored = match stored_lease(&ha, setup, base, token.clone()) {
        Ok(s) => s,
        Err(e) => {
            tracing::error!(error = %e, arbiter = ha.arbiter.name(), "HA: the arbiter cannot be reached: this node stays standby");
            return;
        }
    };
    let Some(mqtt) = crate::api::mqtt::section(config) else {
        if let Some(lease) = stored {
            tracing::warn!(
                "HA: no `mqtt:` broker: the lease fences writes, but nothing is handed over (write outcomes, desired values, declarations)"
            );
            service.tasks().spawn(lease);
        }
        return;
    };
    let prepared = match crate::api::mqtt::prepare(mqtt, base) {
        Ok(p) => p,
        Err(e) => {
            tracing::error!(error = %e, "HA: the MQTT broker's settings cannot be used: this node stays standby");
            return;
        }
    };
    let adopt = {
        let service = service.clone();
        Arc::new(move |epoch, records| service.adopt_writes(epoch, records))
            as Arc<dyn Fn(u64, Vec<crate::write_log::WriteRecord>) + Send + Sync>
    };
    service.cache.writes.start_journal();
    let setup = crate::api::mqtt::lease::LeaseSetup {
        prepared,
        group: ha.group.clone(),
        node: ha.node.clone(),
        lease: ha.lease,
        role,
        me,
        entering,
        log: service.cache.writes.clone(),
        adopt,
        service: service.clone(),
    };
    match stored {
        None => service
            .tasks()
            .spawn(crate::api::mqtt::lease::run(setup, token)),
        Some(lease) => {
            service.tasks().spawn(lease);
            service
                .tasks()
                .spawn(crate::api::mqtt::lease::handover(setup, token));
        }
    }
}

/// The lease held on etcd or a Kubernetes Lease, as a task; none for the MQTT arbiter
/// (whose lease is the handover connection's own).
fn stored_lease(
    ha: &HaConfig,
    setup: store::StoreSetup,
    base: &std::path::Path,
    token: tokio_util::sync::CancellationToken,
) -> Result<Option<Lease>, String> {
    match ha.arbiter {
        Arbiter::Mqtt => Ok(None),
        Arbiter::Etcd => match &ha.etcd {
            Some(e) => Etcd::new(e, &ha.group, ha.lease, base)
                .map(|e| Some(Box::pin(store::run(e, setup, token)) as Lease)),
            None => Err("no `etcd:` section".to_owned()),
        },
        Arbiter::Kubernetes => {
            let k = ha.kubernetes.clone().unwrap_or_default();
            Kube::new(&k, &ha.group, ha.lease, base)
                .map(|k| Some(Box::pin(store::run(k, setup, token)) as Lease))
        }
    }
}

/// A lease held on a store, as a task.
type Lease = std::pin::Pin<Box<dyn std::future::Future<Output = ()> + Send>>;

/// This node as clients reach it: each server's address with its host `ha.advertise`
/// where that is set, else with a wildcard host replaced by this machine's host name.
fn announced(service: &Service, ha: &HaConfig) -> Peer {
    let addresses: BTreeMap<String, String> = service
        .listening
        .list()
        .into_iter()
        .map(|l| {
            let address = match &ha.advertise {
                Some(host) => advertised(&l.address, host),
                None => reachable(&l.address, &host_name()),
            };
            (l.server, address)
        })
        .collect();
    Peer {
        node: ha.node.clone(),
        addresses,
    }
}

/// `address` with a wildcard host (`0.0.0.0`, `[::]`) replaced by `host`.
fn reachable(address: &str, host: &str) -> String {
    for wildcard in ["0.0.0.0", "[::]"] {
        if let Some(at) = address.find(wildcard) {
            let before = &address[..at];
            if before.is_empty() || before.ends_with("://") {
                return format!("{before}{host}{}", &address[at + wildcard.len()..]);
            }
        }
    }
    address.to_owned()
}

/// `address` (`[scheme://]host:port[/path]`) with its host replaced by `host`.
fn advertised(address: &str, host: &str) -> String {
    let (scheme, rest) = match address.find("://") {
        Some(at) => address.split_at(at + 3),
        None => ("", address),
    };
    let (authority, path) = rest.split_at(rest.find('/').unwrap_or(rest.len()));
    let port = match authority.rfind(':') {
        Some(at) if !authority[at..].contains(']') => &authority[at..],
        _ => "",
    };
    format!("{scheme}{host}{port}{path}")
}

fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .or_else(|_| std::fs::read_to_string("/etc/hostname"))
        .map(|s| s.trim().to_owned())
        .ok()
        .filter(|s| !s.is_empty())
        .unwrap_or_else(|| "localhost".into())
}

#[cfg(test)]
mod tests {
    use super::{advertised, reachable};

    #[test]
    fn the_advertised_host_replaces_any_host() {
        assert_eq!(
            advertised("opc.tcp://127.0.0.1:4840/", "gw-a"),
            "opc.tcp://gw-a:4840/"
        );
        assert_eq!(advertised("[::1]:502", "10.0.0.7"), "10.0.0.7:502");
        assert_eq!(
            advertised("http://0.0.0.0:8080", "gw-a"),
            "http://gw-a:8080"
        );
    }

    #[test]
    fn a_wildcard_host_is_replaced_by_the_advertised_one() {
        assert_eq!(reachable("http://0.0.0.0:8080", "gw-a"), "http://gw-a:8080");
        assert_eq!(reachable("[::]:502", "10.0.0.7"), "10.0.0.7:502");
        assert_eq!(
            reachable("opc.tcp://127.0.0.1:4840/", "gw-a"),
            "opc.tcp://127.0.0.1:4840/"
        );
    }
}

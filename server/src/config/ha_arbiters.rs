//! The arbiters of `ha:` that are stores (`etcd:`, `kubernetes:`): where each is reached.
//! Read here as written; `ha/` runs them.

use std::path::PathBuf;

use crate::yaml::{Node, Report};

const ETCD_KEYS: &[&str] = &["endpoints", "prefix", "ca"];
const KUBERNETES_KEYS: &[&str] = &["api", "namespace", "name", "token_file", "ca"];
/// The most endpoints an etcd cluster is given (a cluster has 3, 5 or 7 members).
const MAX_ENDPOINTS: usize = 9;
/// Where the lease's keys are in etcd by default (under it, the pair's group).
pub(crate) const DEFAULT_ETCD_PREFIX: &str = "iogate/ha";

/// `ha.etcd`: the cluster's client URLs (tried in turn) and the keys' prefix.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct EtcdConfig {
    pub(crate) endpoints: Vec<String>,
    pub(crate) prefix: String,
    /// The CA that signs an `https` endpoint's certificate.
    pub(crate) ca: Option<PathBuf>,
}

/// `ha.kubernetes`: the API server and the Lease. Every key has the in-cluster default
/// (the service account's token, CA and namespace; `KUBERNETES_SERVICE_HOST`).
#[derive(Debug, Clone, PartialEq, Default)]
pub(crate) struct KubernetesConfig {
    pub(crate) api: Option<String>,
    pub(crate) namespace: Option<String>,
    /// The Lease's name (default `iogate-<group>`).
    pub(crate) name: Option<String>,
    pub(crate) token_file: Option<PathBuf>,
    pub(crate) ca: Option<PathBuf>,
}

pub(crate) fn etcd(node: &Node, report: &mut Report) -> Option<EtcdConfig> {
    let mut map = node.map(report, "ha.etcd")?;
    let endpoints = map
        .require("endpoints", report, "ha.etcd")
        .and_then(|n| endpoints(n, report));
    let prefix = match map.get("prefix") {
        Some(n) => n.scalar_text(report, "ha.etcd.prefix").and_then(|p| {
            let ok = !p.is_empty() && p.len() <= 200 && !p.ends_with('/');
            if !ok {
                report.push(
                    n.line,
                    "ha.etcd.prefix",
                    "a key prefix is 1 to 200 characters and does not end with '/'",
                );
            }
            ok.then_some(p)
        }),
        None => Some(DEFAULT_ETCD_PREFIX.to_owned()),
    };
    let ca = map
        .get("ca")
        .and_then(|n| n.scalar_text(report, "ha.etcd.ca"))
        .map(PathBuf::from);
    map.finish(report, "ha.etcd", ETCD_KEYS);
    Some(EtcdConfig {
        endpoints: endpoints?,
        prefix: prefix?,
        ca,
    })
}

fn endpoints(node: &Node, report: &mut Report) -> Option<Vec<String>> {
    let items = node.seq(report, "ha.etcd.endpoints")?;
    let mut out = Vec::new();
    for item in items {
        let url = item.scalar_text(report, "ha.etcd.endpoints")?;
        match url_problem(&url) {
            None => out.push(url.trim_end_matches('/').to_owned()),
            Some(why) => {
                report.push(item.line, "ha.etcd.endpoints", why);
                return None;
            }
        }
    }
    if out.is_empty() || out.len() > MAX_ENDPOINTS {
        report.push(
            node.line,
            "ha.etcd.endpoints",
            format!("from 1 to {MAX_ENDPOINTS} client URLs (http:// or https://)"),
        );
        return None;
    }
    Some(out)
}

/// What is wrong with an arbiter's URL (`http://host:port` or `https://…`), if anything.
pub(crate) fn url_problem(url: &str) -> Option<String> {
    match url.parse::<hyper::Uri>() {
        Ok(u) if matches!(u.scheme_str(), Some("http" | "https")) && u.host().is_some() => None,
        _ => Some(format!(
            "{} is not an http:// or https:// URL with a host",
            crate::text::quote(url)
        )),
    }
}

pub(crate) fn kubernetes(node: &Node, report: &mut Report) -> Option<KubernetesConfig> {
    let mut map = node.map(report, "ha.kubernetes")?;
    let mut text = |key: &str, report: &mut Report| {
        map.get(key).and_then(|n| {
            n.scalar_text(report, &format!("ha.kubernetes.{key}"))
                .map(|t| (n.line, t))
        })
    };
    let api = text("api", report);
    let namespace = text("namespace", report);
    let name = text("name", report);
    let token_file = text("token_file", report).map(|(_, t)| PathBuf::from(t));
    let ca = text("ca", report).map(|(_, t)| PathBuf::from(t));
    let mut ok = true;
    if let Some((line, why)) = api
        .as_ref()
        .and_then(|(l, u)| url_problem(u).map(|w| (*l, w)))
    {
        report.push(line, "ha.kubernetes.api", why);
        ok = false;
    }
    for (key, value) in [("namespace", &namespace), ("name", &name)] {
        if let Some((line, v)) = value
            && !dns_label(v)
        {
            report.push(
                *line,
                format!("ha.kubernetes.{key}"),
                format!(
                    "{} is not a Kubernetes name (lower-case letters, digits and '-', at most 63)",
                    crate::text::quote(v)
                ),
            );
            ok = false;
        }
    }
    map.finish(report, "ha.kubernetes", KUBERNETES_KEYS);
    ok.then(|| KubernetesConfig {
        api: api.map(|(_, u)| u.trim_end_matches('/').to_owned()),
        namespace: namespace.map(|(_, n)| n),
        name: name.map(|(_, n)| n),
        token_file,
        ca,
    })
}

/// Whether `s` is a DNS label, as Kubernetes names a namespace or a Lease.
pub(crate) fn dns_label(s: &str) -> bool {
    !s.is_empty()
        && s.len() <= 63
        && s.bytes()
            .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'-')
        && !s.starts_with('-')
        && !s.ends_with('-')
}

#[cfg(test)]
mod tests {
    use crate::config::ha::{Arbiter, read};
    use crate::config::read_section;

    #[test]
    fn an_etcd_and_a_kubernetes_arbiter_are_read_with_their_defaults() {
        let text = "ha: {node: a, arbiter: etcd, etcd: {endpoints: [\"http://10.0.0.5:2379/\", \"https://e2:2379\"]}}\n";
        let (ha, problems) = read_section(text, "ha", read);
        assert_eq!(problems, Vec::<String>::new());
        let ha = ha.expect("read");
        let etcd = ha.etcd.expect("etcd");
        assert_eq!(ha.arbiter, Arbiter::Etcd);
        assert_eq!(etcd.endpoints, ["http://10.0.0.5:2379", "https://e2:2379"]);
        assert_eq!(etcd.prefix, super::DEFAULT_ETCD_PREFIX);
        let (ha, problems) = read_section("ha: {node: b, arbiter: kubernetes}\n", "ha", read);
        assert_eq!(problems, Vec::<String>::new());
        let ha = ha.expect("read");
        assert_eq!(ha.arbiter, Arbiter::Kubernetes);
        assert_eq!(ha.kubernetes, None, "in-cluster defaults");
    }

    #[test]
    fn every_problem_of_an_arbiter_is_named() {
        for (text, expected) in [
            (
                "ha: {node: a, arbiter: etcd}\n",
                "ha.etcd: arbiter: etcd needs",
            ),
            (
                "ha: {node: a, arbiter: etcd, etcd: {endpoints: [\"tcp://x:1\"]}}\n",
                "ha.etcd.endpoints: tcp://x:1 is not an http:// or https:// URL",
            ),
            (
                "ha: {node: a, arbiter: etcd, etcd: {endpoints: []}}\n",
                "ha.etcd.endpoints: from 1 to 9 client URLs",
            ),
            (
                "ha: {node: a, arbiter: etcd, etcd: {endpoints: [\"http://x:1\"], prefix: \"a/\"}}\n",
                "ha.etcd.prefix",
            ),
            (
                "ha: {node: a, arbiter: kubernetes, kubernetes: {namespace: Plant_1}}\n",
                "ha.kubernetes.namespace: Plant_1 is not a Kubernetes name",
            ),
            (
                "ha: {node: a, arbiter: kubernetes, kubernetes: {api: \"kube:6443\"}}\n",
                "ha.kubernetes.api",
            ),
            (
                "ha: {node: a, arbiter: kubernetes, kubernetes: {lease: x}}\n",
                "lease",
            ),
        ] {
            let (ha, problems) = read_section(text, "ha", read);
            let joined = problems.join("\n");
            assert!(joined.contains(expected), "{expected} in {joined}");
            assert!(ha.is_none() || !problems.is_empty(), "{text}");
        }
    }
}

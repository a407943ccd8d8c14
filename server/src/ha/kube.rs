//! The lease on a Kubernetes `coordination.k8s.io/v1` Lease (`arbiter: kubernetes`), as
//! client-go's leader election holds one:
//!
//! - `spec.holderIdentity` is the holder's node, `spec.leaseDurationSeconds` the pair's
//!   lease, `spec.renewTime` its last renewal, `spec.leaseTransitions` the epoch.
//!   `metadata.annotations` carry how clients reach the holder and its Sparkplug session.
//! - Every change is a PUT with the `resourceVersion` read: the API server refuses a stale
//!   one (409), so two nodes cannot both take it.
//! - Kubernetes does not expire a Lease: a standby takes it when it has seen the same
//!   `resourceVersion` for the lease's duration on its own clock (no clocks compared).

use std::path::{Path, PathBuf};
use std::time::SystemTime;

use hyper::Method;
use hyper::header::{ACCEPT, AUTHORIZATION, HeaderName};
use serde_json::{Value, json};
use tokio::time::Instant;

use super::store::{Holder, Observed, Store};
use crate::config::ha_arbiters::KubernetesConfig;
use crate::http_client::HttpClient;

/// Where a pod finds its service account.
const ACCOUNT: &str = "/var/run/secrets/kubernetes.io/serviceaccount";
const ADDRESSES: &str = "iogate.io/addresses";
const BD_SEQ: &str = "iogate.io/bd-seq";
/// The epoch a holder gave the Lease back in: an empty holder without it was emptied by
/// someone else, and its holder may still be active.
const RELEASED: &str = "iogate.io/released";

/// The longest `leaseDurationSeconds` taken from a Lease (the longest `ha.lease`).
const LONGEST: u64 = 60;

pub(crate) struct Kube {
    client: HttpClient,
    token_file: Option<PathBuf>,
    /// The Lease's path, and its collection's.
    path: String,
    collection: String,
    name: String,
    lease_s: u64,
    /// The Lease as last read or written (`None`: there is none).
    last: Option<Value>,
    /// When its `resourceVersion` was first seen.
    seen_at: Instant,
}

impl Kube {
    pub(crate) fn new(
        config: &KubernetesConfig,
        group: &str,
        lease: std::time::Duration,
        base: &Path,
    ) -> Result<Kube, String> {
        let account = Path::new(ACCOUNT);
        let api = match &config.api {
            Some(api) => api.clone(),
            None => in_cluster_api()?,
        };
        let ca = match &config.ca {
            Some(ca) => Some(base.join(ca)),
            None => Some(account.join("ca.crt")).filter(|p| p.exists()),
        };
        let namespace = match &config.namespace {
            Some(n) => n.clone(),
            None => std::fs::read_to_string(account.join("namespace"))
                .map(|s| s.trim().to_owned())
                .unwrap_or_else(|_| "default".to_owned()),
        };
        let token_file = match &config.token_file {
            Some(t) => Some(base.join(t)),
            None => Some(account.join("token")).filter(|p| p.exists()),
        };
        let name = config
            .name
            .clone()
            .unwrap_or_else(|| format!("iogate-{group}"));
        let collection = format!("/apis/coordination.k8s.io/v1/namespaces/{namespace}/leases");
        Ok(Kube {
            client: HttpClient::new(&api, ca.as_deref())?,
            token_file,
            path: format!("{collection}/{name}"),
            collection,
            name,
            lease_s: lease.as_secs(),
            last: None,
            seen_at: Instant::now(),
        })
    }

    /// One request with the service account's token (read each time: it rotates).
    async fn call(
        &mut self,
        method: Method,
        path: &str,
        body: Option<&Value>,
    ) -> Result<(u16, Value), String> {
        let mut headers: Vec<(HeaderName, String)> = vec![(ACCEPT, "application/json".into())];
        if let Some(file) = &self.token_file {
            let token = std::fs::read_to_string(file)
                .map_err(|e| format!("the service account token {}: {e}", file.display()))?;
            headers.push((AUTHORIZATION, format!("Bearer {}", token.trim())));
        }
        let body = body.map(|b| b.to_string().into_bytes()).unwrap_or_default();
        let (status, answer) = self.client.call(method, path, &headers, body).await?;
        let parsed: Result<Value, _> = serde_json::from_slice(&answer);
        if matches!(status, 200 | 201) && !parsed.as_ref().is_ok_and(|v| v["kind"] == "Lease") {
            return Err(format!(
                "{}{path} answered {status} with no Lease (a proxy's page?)",
                self.client.url()
            ));
        }
        let answer = parsed.unwrap_or(Value::Null);
        match status {
            200 | 201 | 404 | 409 => Ok((status, answer)),
            _ => Err(format!(
                "{}{path} answered {status}: {}",
                self.client.url(),
                answer["message"].as_str().unwrap_or("no message")
            )),
        }
    }

    /// Keeps `lease` as the last seen, restarting the clock when it changed.
    fn saw(&mut self, lease: Option<Value>) {
        let version =
            |l: &Option<Value>| l.as_ref().map(|l| l["metadata"]["resourceVersion"].clone());
        if version(&lease) != version(&self.last) {
            self.seen_at = Instant::now();
        }
        self.last = lease;
    }

    /// The Lease as `me` holds it, on what was last seen.
    fn lease_of(&self, me: &Holder, taking: bool) -> Value {
        let now = micro_time();
        let mut lease = self.last.clone().unwrap_or_else(|| {
            json!({
                "apiVersion": "coordination.k8s.io/v1",
                "kind": "Lease",
                "metadata": { "name": self.name },
                "spec": {},
            })
        });
        let spec = &mut lease["spec"];
        spec["holderIdentity"] = json!(me.node);
        spec["leaseDurationSeconds"] = json!(self.lease_s);
        spec["renewTime"] = json!(now);
        if taking {
            spec["acquireTime"] = json!(now);
            spec["leaseTransitions"] = json!(me.epoch);
        }
        let annotations = &mut lease["metadata"]["annotations"];
        annotations[ADDRESSES] = json!(serde_json::to_string(&me.addresses).unwrap_or_default());
        if let Some(a) = annotations.as_object_mut() {
            a.remove(RELEASED);
        }
        match me.bd_seq {
            Some(b) => annotations[BD_SEQ] = json!(b.to_string()),
            None => {
                if let Some(a) = annotations.as_object_mut() {
                    a.remove(BD_SEQ);
                }
            }
        }
        lease
    }

    /// PUTs (or POSTs, when there is none) `lease`: whether the API server took it.
    async fn write(&mut self, lease: Value) -> Result<bool, String> {
        let (method, path) = if self.last.is_some() {
            (Method::PUT, self.path.clone())
        } else {
            (Method::POST, self.collection.clone())
        };
        let (status, answer) = self.call(method, &path, Some(&lease)).await?;
        match status {
            200 | 201 => {
                let version = &answer["metadata"]["resourceVersion"];
                let sent = &lease["metadata"]["resourceVersion"];
                if answer["spec"]["holderIdentity"] != lease["spec"]["holderIdentity"]
                    || !version.is_string()
                    || version == sent
                {
                    return Err(format!(
                        "{}{path} answered {status} with a Lease that is not the one sent",
                        self.client.url()
                    ));
                }
                self.saw(Some(answer));
                Ok(true)
            }
            _ => Ok(false),
        }
    }

    fn ours(&self, me: &Holder) -> bool {
        self.last.as_ref().is_some_and(|l| {
            l["spec"]["holderIdentity"] == me.node
                && l["spec"]["leaseTransitions"].as_u64() == Some(me.epoch)
        })
    }
}

impl Store for Kube {
    fn name(&self) -> String {
        format!("Kubernetes Lease {}{}", self.client.url(), self.path)
    }

    async fn observe(&mut self) -> Result<Observed, String> {
        let path = self.path.clone();
        let (status, lease) = self.call(Method::GET, &path, None).await?;
        if status == 404 {
            self.saw(None);
            return Ok(Observed::Free(0));
        }
        if status != 200 {
            return Err(format!("{path} answered {status}"));
        }
        self.saw(Some(lease.clone()));
        let spec = &lease["spec"];
        let epoch = spec["leaseTransitions"].as_u64().unwrap_or(0);
        let node = spec["holderIdentity"].as_str().unwrap_or_default();
        let duration = spec["leaseDurationSeconds"]
            .as_u64()
            .unwrap_or(self.lease_s)
            .clamp(1, LONGEST);
        let expired = self.seen_at.elapsed().as_secs_f64() >= duration as f64;
        let released =
            lease["metadata"]["annotations"][RELEASED].as_str() == Some(&epoch.to_string());
        if (node.is_empty() && released) || expired {
            return Ok(Observed::Free(epoch));
        }
        if node.is_empty() {
            // Emptied by someone else: the holder may still be active until the Lease has
            // stood unchanged for its duration.
            return Ok(Observed::Held(Holder {
                node: String::new(),
                epoch,
                addresses: Default::default(),
                bd_seq: None,
            }));
        }
        let annotations = &lease["metadata"]["annotations"];
        Ok(Observed::Held(Holder {
            node: node.to_owned(),
            epoch,
            addresses: annotations[ADDRESSES]
                .as_str()
                .and_then(|a| serde_json::from_str(a).ok())
                .unwrap_or_default(),
            bd_seq: annotations[BD_SEQ].as_str().and_then(|b| b.parse().ok()),
        }))
    }

    async fn acquire(&mut self, me: &Holder) -> Result<Option<u64>, String> {
        let lease = self.lease_of(me, true);
        Ok(self.write(lease).await?.then_some(me.epoch))
    }

    async fn renew(&mut self, me: &Holder) -> Result<bool, String> {
        let lease = self.lease_of(me, false);
        if self.write(lease).await? {
            return Ok(true);
        }
        // Refused: a renewal whose answer was lost may have changed the version. Still
        // this node's in this epoch, it renews on what is there now.
        let path = self.path.clone();
        let (status, now) = self.call(Method::GET, &path, None).await?;
        self.saw((status == 200).then_some(now));
        if !self.ours(me) {
            return Ok(false);
        }
        let lease = self.lease_of(me, false);
        self.write(lease).await
    }

    async fn release(&mut self, me: &Holder) -> Result<(), String> {
        if !self.ours(me) {
            return Ok(());
        }
        let mut lease = self.lease_of(me, false);
        lease["spec"]["holderIdentity"] = Value::Null;
        lease["metadata"]["annotations"][RELEASED] = json!(me.epoch.to_string());
        self.write(lease).await.map(|_| ())
    }
}

fn in_cluster_api() -> Result<String, String> {
    let host = std::env::var("KUBERNETES_SERVICE_HOST").map_err(|_| {
        "arbiter: kubernetes outside a cluster needs `kubernetes: {api: https://…}`".to_owned()
    })?;
    let port = std::env::var("KUBERNETES_SERVICE_PORT").unwrap_or_else(|_| "443".into());
    let host = if host.contains(':') {
        format!("[{host}]")
    } else {
        host
    };
    Ok(format!("https://{host}:{port}"))
}

/// Now as a Kubernetes MicroTime (RFC 3339, microseconds, UTC).
fn micro_time() -> String {
    humantime::format_rfc3339_micros(SystemTime::now()).to_string()
}

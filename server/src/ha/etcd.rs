//! The lease on etcd (`arbiter: etcd`), through its v3 JSON API (`/v3/kv/…`,
//! `/v3/lease/…`, as etcd 3.4 and later serve it):
//!
//! - `<prefix>/<group>/holder` is the holder (a JSON [`Holder`]), put under an etcd lease
//!   of the pair's length: etcd deletes it when the holder stops renewing.
//! - `<prefix>/<group>/epoch` is the newest epoch, a decimal, never deleted.
//! - Taking is one transaction: the holder key absent and the epoch key as read, then both
//!   put. Two nodes cannot both succeed; the epoch only grows.

use base64::Engine;
use base64::engine::general_purpose::STANDARD as B64;
use hyper::Method;
use serde_json::{Value, json};

use super::store::{Holder, Observed, Store};
use crate::config::ha_arbiters::EtcdConfig;
use crate::http_client::HttpClient;

pub(crate) struct Etcd {
    clients: Vec<HttpClient>,
    /// The endpoint that answered last (tried first).
    at: usize,
    holder_key: String,
    epoch_key: String,
    ttl: u64,
    /// The epoch key's revision when last read (0: absent).
    epoch_revision: i64,
    /// The etcd lease that keeps this node's holder key, while it holds it.
    lease_id: Option<i64>,
    /// The holder key's revision when this node put it.
    holder_revision: i64,
    /// The session the holder key says (put again when it changes).
    put_bd_seq: Option<u8>,
    /// The holder last seen, and the etcd lease that keeps its key: a holder key gone while
    /// that lease lives was deleted by someone else, and its holder may still be active.
    seen: Option<(Holder, i64)>,
}

impl Etcd {
    pub(crate) fn new(
        config: &EtcdConfig,
        group: &str,
        lease: std::time::Duration,
        base: &std::path::Path,
    ) -> Result<Etcd, String> {
        let ca = config.ca.as_ref().map(|c| base.join(c));
        let clients = config
            .endpoints
            .iter()
            .map(|url| HttpClient::new(url, ca.as_deref()))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Etcd {
            clients,
            at: 0,
            holder_key: format!("{}/{group}/holder", config.prefix),
            epoch_key: format!("{}/{group}/epoch", config.prefix),
            ttl: lease.as_secs(),
            epoch_revision: 0,
            lease_id: None,
            holder_revision: 0,
            put_bd_seq: None,
            seen: None,
        })
    }

    /// POSTs `body` to `path` on the endpoints in turn, from the one that answered last.
    async fn post(&mut self, path: &str, body: Value) -> Result<Value, String> {
        let body = body.to_string().into_bytes();
        let mut failures = Vec::new();
        for i in 0..self.clients.len() {
            let at = (self.at + i) % self.clients.len();
            let client = &mut self.clients[at];
            match client.call(Method::POST, path, &[], body.clone()).await {
                Ok((200, answer)) => {
                    self.at = at;
                    return serde_json::from_slice(&answer)
                        .map_err(|e| format!("{}{path}: not JSON: {e}", client.url()));
                }
                Ok((status, answer)) => {
                    let answer: Value = serde_json::from_slice(&answer).unwrap_or(Value::Null);
                    let message = answer["message"].as_str().unwrap_or("no message");
                    return Err(format!(
                        "{}{path} answered {status}: {message}",
                        client.url()
                    ));
                }
                Err(e) => failures.push(format!("{}: {e}", client.url())),
            }
        }
        Err(failures.join("; "))
    }

    async fn revoke(&mut self, id: i64) -> Result<(), String> {
        self.post("/v3/lease/revoke", json!({ "ID": id.to_string() }))
            .await
            .map(|_| ())
    }
}

fn key(k: &str) -> String {
    B64.encode(k)
}

/// An int64 of etcd's JSON (a string, or a number).
fn int(v: &Value) -> i64 {
    match v {
        Value::String(s) => s.parse().unwrap_or(0),
        other => other.as_i64().unwrap_or(0),
    }
}

fn value_of(kv: &Value) -> Vec<u8> {
    kv["value"]
        .as_str()
        .and_then(|v| B64.decode(v).ok())
        .unwrap_or_default()
}

impl Store for Etcd {
    fn name(&self) -> String {
        let url = self.clients.get(self.at).map(HttpClient::url).unwrap_or("");
        format!("etcd {url}")
    }

    async fn observe(&mut self) -> Result<Observed, String> {
        let (holder_key, epoch_key) = (self.holder_key.clone(), self.epoch_key.clone());
        let txn = json!({
            "success": [
                { "request_range": { "key": key(&holder_key) } },
                { "request_range": { "key": key(&epoch_key) } },
            ],
        });
        let answer = self.post("/v3/kv/txn", txn).await?;
        let kv = |i: usize| answer["responses"][i]["response_range"]["kvs"][0].clone();
        let (holder, epoch) = (kv(0), kv(1));
        self.epoch_revision = int(&epoch["mod_revision"]);
        let last = std::str::from_utf8(&value_of(&epoch))
            .ok()
            .and_then(|s| s.trim().parse::<u64>().ok())
            .unwrap_or(0);
        if holder.is_null() {
            // Deleted with its holder's lease still alive: not given back, and not expired.
            if let Some((h, id)) = self.seen.clone()
                && self.lease_alive(id).await?
            {
                return Ok(Observed::Held(h));
            }
            self.seen = None;
            return Ok(Observed::Free(last));
        }
        match serde_json::from_slice::<Holder>(&value_of(&holder)) {
            Ok(h) => {
                self.seen = Some((h.clone(), int(&holder["lease"])));
                Ok(Observed::Held(h))
            }
            Err(e) => Err(format!("{holder_key} is not a holder: {e}")),
        }
    }

    async fn acquire(&mut self, me: &Holder) -> Result<Option<u64>, String> {
        let granted = self
            .post("/v3/lease/grant", json!({ "TTL": self.ttl.to_string() }))
            .await?;
        let id = int(&granted["ID"]);
        if id == 0 {
            return Err(format!("etcd granted no lease: {granted}"));
        }
        let holder = serde_json::to_vec(me).unwrap_or_default();
        let txn = json!({
            "compare": [
                { "key": key(&self.holder_key), "target": "CREATE", "result": "EQUAL", "create_revision": "0" },
                { "key": key(&self.epoch_key), "target": "MOD", "result": "EQUAL", "mod_revision": self.epoch_revision.to_string() },
            ],
            "success": [
                { "request_put": { "key": key(&self.holder_key), "value": B64.encode(&holder), "lease": id.to_string() } },
                { "request_put": { "key": key(&self.epoch_key), "value": B64.encode(me.epoch.to_string()) } },
            ],
        });
        let answer = match self.post("/v3/kv/txn", txn).await {
            Ok(a) => a,
            Err(e) => {
                let _ = self.revoke(id).await;
                return Err(e);
            }
        };
        if answer["succeeded"].as_bool() != Some(true) {
            let _ = self.revoke(id).await;
            return Ok(None);
        }
        self.lease_id = Some(id);
        self.holder_revision = int(&answer["header"]["revision"]);
        self.put_bd_seq = me.bd_seq;
        Ok(Some(me.epoch))
    }

    async fn renew(&mut self, me: &Holder) -> Result<bool, String> {
        let Some(id) = self.lease_id else {
            return Ok(false);
        };
        let answer = self
            .post("/v3/lease/keepalive", json!({ "ID": id.to_string() }))
            .await?;
        // An expired or revoked lease is answered without a TTL.
        if int(&answer["result"]["TTL"]) <= 0 {
            self.lease_id = None;
            return Ok(false);
        }
        // The key must still be the one this node put: someone may have deleted or
        // replaced it, and a standby may be taking the lease.
        self.put_holder(me, id).await
    }

    async fn release(&mut self, _me: &Holder) -> Result<(), String> {
        match self.lease_id.take() {
            Some(id) => self.revoke(id).await,
            None => Ok(()),
        }
    }
}

impl Etcd {
    /// Whether the holder key is still the one this node put (under its lease), putting
    /// it again when its session changed.
    async fn put_holder(&mut self, me: &Holder, id: i64) -> Result<bool, String> {
        let holder = serde_json::to_vec(me).unwrap_or_default();
        let ours = [
            json!({ "key": key(&self.holder_key), "target": "CREATE", "result": "EQUAL", "create_revision": self.holder_revision.to_string() }),
            json!({ "key": key(&self.holder_key), "target": "LEASE", "result": "EQUAL", "lease": id.to_string() }),
        ];
        let success = if me.bd_seq == self.put_bd_seq {
            json!([{ "request_range": { "key": key(&self.holder_key) } }])
        } else {
            json!([{ "request_put": { "key": key(&self.holder_key), "value": B64.encode(&holder), "lease": id.to_string() } }])
        };
        let txn = json!({ "compare": ours, "success": success });
        let answer = self.post("/v3/kv/txn", txn).await?;
        if answer["succeeded"].as_bool() != Some(true) {
            return Ok(false);
        }
        self.put_bd_seq = me.bd_seq;
        Ok(true)
    }

    /// Whether etcd lease `id` is still alive.
    async fn lease_alive(&mut self, id: i64) -> Result<bool, String> {
        if id == 0 {
            return Ok(false);
        }
        let answer = self
            .post("/v3/lease/timetolive", json!({ "ID": id.to_string() }))
            .await?;
        Ok(int(&answer["TTL"]) > 0)
    }
}

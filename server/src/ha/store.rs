//! The lease held on a store that compares and swaps (etcd, a Kubernetes Lease): the
//! standby reads the record every quarter lease and takes it, by a compare-and-swap, when
//! nobody holds it; the holder renews it three times within its own lease. The store
//! keeps the epoch, which each taking raises by one.
//!
//! The holder's own lease ([`valid`]) is three quarters of the store's, counted from when
//! a renewal was *sent*: the store counts from when it received it (etcd), or the standby
//! from when it saw it (Kubernetes), both later. A holder cut off from the store stops
//! writing before the standby can take the lease.

use std::collections::BTreeMap;
use std::future::Future;
use std::sync::Arc;
use std::time::Duration;

use tokio::time::{Instant, sleep, sleep_until, timeout};
use tokio_util::sync::CancellationToken;

use crate::role::{Peer, Role};

/// The longest wait between attempts to reach the store.
const RETRY_MAX: Duration = Duration::from_secs(1);

/// The newest epoch this node takes: a write's generation carries the epoch in 32 bits,
/// and a Lease's `leaseTransitions` is an int32.
pub(crate) const LAST_EPOCH: u64 = i32::MAX as u64;

/// The holder as the store keeps it.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub(crate) struct Holder {
    pub(crate) node: String,
    pub(crate) epoch: u64,
    #[serde(default)]
    pub(crate) addresses: BTreeMap<String, String>,
    /// The Sparkplug `bdSeq` of the holder's edge node session.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub(crate) bd_seq: Option<u8>,
}

/// What the store says of the lease.
#[derive(Debug, PartialEq)]
pub(crate) enum Observed {
    /// Nobody holds it; the newest epoch it was held in.
    Free(u64),
    Held(Holder),
}

/// A store that grants the lease.
pub(crate) trait Store: Send {
    /// Where the store is, for the log.
    fn name(&self) -> String;
    /// What the store says of the lease now.
    fn observe(&mut self) -> impl Future<Output = Result<Observed, String>> + Send;
    /// Takes the lease as `me` if it is still as last observed (its epoch is the next):
    /// the epoch, or `None` when another node took it first.
    fn acquire(&mut self, me: &Holder) -> impl Future<Output = Result<Option<u64>, String>> + Send;
    /// Renews the held lease (with `me`'s newest session); `false` when it is not this
    /// node's any more.
    fn renew(&mut self, me: &Holder) -> impl Future<Output = Result<bool, String>> + Send;
    /// Gives the held lease back.
    fn release(&mut self, me: &Holder) -> impl Future<Output = Result<(), String>> + Send;
}

/// What the lease task is given.
pub(crate) struct StoreSetup {
    pub(crate) node: String,
    pub(crate) lease: Duration,
    pub(crate) role: Arc<Role>,
    /// This node as clients reach it.
    pub(crate) me: Arc<dyn Fn() -> Peer + Send + Sync>,
    /// Called with the epoch before this node becomes active in it.
    pub(crate) entering: Arc<dyn Fn(u64) + Send + Sync>,
}

/// How long a renewal sent now holds the lease here.
pub(crate) fn valid(lease: Duration) -> Duration {
    lease * 3 / 4
}

/// Runs the lease on `store` until `token` is cancelled.
pub(crate) async fn run<S: Store>(mut store: S, setup: StoreSetup, token: CancellationToken) {
    let mut epoch = 0;
    let mut wait = Duration::ZERO;
    let mut told = false;
    loop {
        tokio::select! {
            _ = token.cancelled() => return,
            _ = sleep(wait) => {}
        }
        let observed = match ask(&setup, store.observe()).await {
            Ok(o) => o,
            Err(e) => {
                setup.role.stand_by(epoch, None);
                wait = retry(wait, setup.lease);
                tracing::warn!(store = %store.name(), error = %e, retry_in = ?wait, "HA: cannot read the lease");
                continue;
            }
        };
        wait = setup.lease / 4;
        match observed {
            Observed::Held(holder) => {
                epoch = epoch.max(holder.epoch);
                if let Some(bd_seq) = holder.bd_seq {
                    setup.role.heard_edge_session(bd_seq);
                }
                if holder.node == setup.node && !std::mem::replace(&mut told, true) {
                    tracing::error!(node = %setup.node, store = %store.name(), "HA: the lease is held by another gateway under this node's name: each node of a pair needs its own ha.node");
                }
                let active = (!holder.node.is_empty()).then_some(Peer {
                    node: holder.node,
                    addresses: holder.addresses,
                });
                setup.role.stand_by(epoch, active);
            }
            Observed::Free(last) => {
                epoch = epoch.max(last);
                setup.role.stand_by(epoch, None);
                if epoch >= LAST_EPOCH {
                    if !std::mem::replace(&mut told, true) {
                        tracing::error!(epoch, store = %store.name(), "HA: the arbiter's epoch is the last a write can carry: this node does not take the lease; with both nodes stopped, reset the epoch (etcd: the epoch key; Kubernetes: the Lease)");
                    }
                    continue;
                }
                let me = holder(&setup, epoch + 1);
                let sent = Instant::now();
                match ask(&setup, store.acquire(&me)).await {
                    Ok(Some(granted)) => {
                        epoch = granted;
                        if hold(&mut store, &setup, granted, sent, &token).await {
                            return;
                        }
                        wait = Duration::ZERO;
                    }
                    Ok(None) => wait = Duration::ZERO,
                    Err(e) => {
                        wait = retry(wait, setup.lease);
                        tracing::warn!(store = %store.name(), error = %e, "HA: cannot take the lease");
                    }
                }
            }
        }
    }
}

/// `call`, given at most a lease.
async fn ask<T>(
    setup: &StoreSetup,
    call: impl Future<Output = Result<T, String>>,
) -> Result<T, String> {
    timeout(setup.lease, call)
        .await
        .unwrap_or_else(|_| Err(format!("no answer within {:?}", setup.lease)))
}

fn retry(wait: Duration, lease: Duration) -> Duration {
    (wait * 2).clamp(Duration::from_millis(100), RETRY_MAX.min(lease / 3))
}

fn holder(setup: &StoreSetup, epoch: u64) -> Holder {
    Holder {
        node: setup.node.clone(),
        epoch,
        addresses: (setup.me)().addresses,
        bd_seq: setup.role.edge_session(),
    }
}

/// Active in `epoch`: renews until the lease is lost (false) or the gateway stops (true).
async fn hold<S: Store>(
    store: &mut S,
    setup: &StoreSetup,
    epoch: u64,
    sent: Instant,
    token: &CancellationToken,
) -> bool {
    let valid = valid(setup.lease);
    (setup.entering)(epoch);
    setup.role.activate(epoch, sent + valid, (setup.me)());
    tracing::info!(epoch, node = %setup.node, store = %store.name(), "HA: this node is active");
    let every = valid / 3;
    let mut next = Instant::now() + every;
    let why = loop {
        let until = setup.role.until().unwrap_or_else(Instant::now);
        tokio::select! {
            _ = token.cancelled() => {
                setup.role.stand_by(epoch, None);
                if let Err(e) = ask(setup, store.release(&holder(setup, epoch))).await {
                    tracing::warn!(error = %e, "HA: the lease was not given back: it ends by itself");
                }
                return true;
            }
            _ = sleep_until(until) => break "the lease was not renewed in time".to_owned(),
            _ = sleep_until(next) => {
                next += every;
                let sent = Instant::now();
                let me = holder(setup, epoch);
                tokio::select! {
                    _ = sleep_until(until) => break "the lease was not renewed in time".to_owned(),
                    renewed = store.renew(&me) => match renewed {
                        Ok(true) => setup.role.renew(sent + valid),
                        Ok(false) => break "the store no longer names this node its holder".to_owned(),
                        Err(e) => tracing::warn!(error = %e, "HA: a renewal failed"),
                    },
                }
            }
        }
    };
    setup.role.stand_by(epoch, None);
    tracing::warn!(why = %why, "HA: the lease is lost: standing by");
    // Stood down: what this node still holds on the store (an etcd lease) is given back.
    if let Err(e) = ask(setup, store.release(&holder(setup, epoch))).await {
        tracing::debug!(error = %e, "HA: the lease was not given back: it ends by itself");
    }
    false
}

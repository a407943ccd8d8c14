//! The OPC UA server's counts as the metrics show them, through its [`Door`]. The front-end counts what passes
//! through it (monitored items, values set, writes); what only the OPC UA library knows
//! (sessions, subscriptions, security rejections) and the certificates waiting for review
//! are read when asked, through the probe the front-end installs.

use std::sync::atomic::{AtomicI64, AtomicU64, Ordering};

use std::sync::Arc;

use tokio::sync::Notify;

use super::metrics::{OpcUaMetrics, OpcUaStatus};
use crate::service::doors::Door;

/// What the library knows, read at a scrape.
pub(crate) type Probe = Box<dyn Fn(&mut OpcUaStatus) + Send + Sync>;

/// The front-end's shared counts.
pub(crate) struct OpcUaState {
    monitored_items: AtomicI64,
    /// Sessions at once, at most.
    max_sessions: usize,
    /// Subscriptions of every session together, at most (sessions times each one's).
    max_subscriptions: usize,
    /// Monitored items of every session together, at most.
    max_items: i64,
    /// TCP connections at once, and from one address, at most.
    max_connections: [usize; 2],
    /// The refusals already counted into the gateway's bounds: sessions, monitored items,
    /// connections, connections from one address.
    counted: [AtomicU64; 4],
    /// Told when the first monitored item is made: the feed then follows changes again.
    watched: Notify,
    items_refused: AtomicU64,
    value_updates: AtomicU64,
    writes_accepted: AtomicU64,
    writes_refused: AtomicU64,
    probe: Probe,
    /// Its metric families, kept by the gateway's metrics across restarts.
    metrics: Arc<OpcUaMetrics>,
}

impl Door for OpcUaState {
    fn name(&self) -> &'static str {
        "opcua"
    }

    fn encode_metrics(&self, out: &mut String) -> std::fmt::Result {
        self.metrics.encode(&self.status(), out)
    }

    fn count_bounds(&self, metrics: &crate::metrics::Metrics) {
        let status = self.status();
        let max_items = usize::try_from(self.max_items).unwrap_or(usize::MAX);
        let bounds = [
            (
                "opcua_sessions",
                self.max_sessions,
                status.sessions,
                status.sessions_refused,
            ),
            (
                "opcua_monitored_items",
                max_items,
                status.monitored_items,
                status.monitored_items_refused,
            ),
            (
                "opcua_connections",
                self.max_connections[0],
                status.connections,
                status.connections_refused,
            ),
            (
                "opcua_connections_per_client",
                self.max_connections[1],
                status.connections_most_from_one,
                status.connections_refused_per_client,
            ),
        ];
        for ((name, limit, used, refused), counted) in bounds.into_iter().zip(&self.counted) {
            let bound = metrics.bound(name, limit);
            bound.set_used(usize::try_from(used).unwrap_or(usize::MAX));
            let before = counted.swap(refused, Ordering::AcqRel);
            bound.refused_by(refused.saturating_sub(before));
        }
        // Refused subscriptions are the library's to count (each session's own bound).
        let subscriptions = metrics.bound("opcua_subscriptions", self.max_subscriptions);
        subscriptions.set_used(usize::try_from(status.subscriptions).unwrap_or(usize::MAX));
    }
}

impl std::fmt::Debug for OpcUaState {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OpcUaState").finish_non_exhaustive()
    }
}

impl OpcUaState {
    /// The state of a server with `max_sessions`, `max_subscriptions`, `max_items`
    /// monitored items in all, and its connections' bounds.
    pub(crate) fn new(
        probe: Probe,
        [
            max_sessions,
            max_subscriptions,
            max_items,
            connections,
            per_client,
        ]: [usize; 5],
        metrics: Arc<OpcUaMetrics>,
    ) -> Self {
        OpcUaState {
            monitored_items: AtomicI64::new(0),
            max_sessions,
            max_subscriptions,
            max_items: i64::try_from(max_items).unwrap_or(i64::MAX),
            max_connections: [connections, per_client],
            counted: Default::default(),
            watched: Notify::new(),
            items_refused: AtomicU64::new(0),
            value_updates: AtomicU64::new(0),
            writes_accepted: AtomicU64::new(0),
            writes_refused: AtomicU64::new(0),
            probe,
            metrics,
        }
    }

    /// Takes up to `n` of the places left for monitored items; answers how many were taken
    /// (the rest are refused, Bad_TooManyMonitoredItems, and counted).
    pub(crate) fn reserve_items(&self, n: usize) -> usize {
        let n = i64::try_from(n).unwrap_or(i64::MAX);
        let mut taken = 0;
        let _ = self
            .monitored_items
            .fetch_update(Ordering::AcqRel, Ordering::Acquire, |now| {
                taken = n.min((self.max_items - now).max(0));
                Some(now + taken)
            });
        let refused = n - taken;
        if refused > 0 {
            self.items_refused
                .fetch_add(refused as u64, Ordering::Relaxed);
        }
        if taken > 0 {
            self.watched.notify_one();
        }
        taken as usize
    }

    /// Whether any monitored item exists: while none does, changes cost nothing here.
    pub(crate) fn watching(&self) -> bool {
        self.monitored_items.load(Ordering::Acquire) > 0
    }

    /// Waits until a monitored item is made.
    pub(crate) async fn watched(&self) {
        self.watched.notified().await;
    }

    pub(crate) fn items_deleted(&self, n: usize) {
        self.monitored_items.fetch_sub(n as i64, Ordering::Relaxed);
    }

    pub(crate) fn values_set(&self, n: usize) {
        self.value_updates.fetch_add(n as u64, Ordering::Relaxed);
    }

    pub(crate) fn write(&self, accepted: bool) {
        let counter = if accepted {
            &self.writes_accepted
        } else {
            &self.writes_refused
        };
        counter.fetch_add(1, Ordering::Relaxed);
    }

    pub(crate) fn status(&self) -> OpcUaStatus {
        let mut status = OpcUaStatus {
            monitored_items: self.monitored_items.load(Ordering::Relaxed).max(0) as u64,
            monitored_items_refused: self.items_refused.load(Ordering::Relaxed),
            value_updates: self.value_updates.load(Ordering::Relaxed),
            writes_accepted: self.writes_accepted.load(Ordering::Relaxed),
            writes_refused: self.writes_refused.load(Ordering::Relaxed),
            ..OpcUaStatus::default()
        };
        (self.probe)(&mut status);
        status
    }
}

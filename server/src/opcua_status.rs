//! The OPC UA server's counts as the metrics show them. The front-end counts what passes
//! through it (monitored items, values set, writes); what only the OPC UA library knows
//! (sessions, subscriptions, security rejections) and the certificates waiting for review
//! are read when asked, through the probe the front-end installs.

use std::sync::atomic::{AtomicI64, AtomicU64, Ordering};

/// A copy of the counts.
#[derive(Debug, Clone, Default, PartialEq)]
pub(crate) struct OpcUaStatus {
    pub(crate) sessions: u64,
    pub(crate) sessions_created: u64,
    pub(crate) subscriptions: u64,
    pub(crate) monitored_items: u64,
    pub(crate) value_updates: u64,
    pub(crate) writes_accepted: u64,
    pub(crate) writes_refused: u64,
    /// Sessions and requests refused for their security (certificate, signature, user).
    pub(crate) security_rejected: u64,
    /// Client certificates refused and kept in the PKI directory's `rejected/`.
    pub(crate) rejected_certificates: u64,
}

/// What the library knows, read at a scrape.
pub(crate) type Probe = Box<dyn Fn(&mut OpcUaStatus) + Send + Sync>;

/// The front-end's shared counts.
pub(crate) struct OpcUaState {
    monitored_items: AtomicI64,
    value_updates: AtomicU64,
    writes_accepted: AtomicU64,
    writes_refused: AtomicU64,
    probe: Probe,
}

impl std::fmt::Debug for OpcUaState {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OpcUaState").finish_non_exhaustive()
    }
}

impl OpcUaState {
    pub(crate) fn new(probe: Probe) -> Self {
        OpcUaState {
            monitored_items: AtomicI64::new(0),
            value_updates: AtomicU64::new(0),
            writes_accepted: AtomicU64::new(0),
            writes_refused: AtomicU64::new(0),
            probe,
        }
    }

    pub(crate) fn items_created(&self, n: usize) {
        self.monitored_items.fetch_add(n as i64, Ordering::Relaxed);
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
            value_updates: self.value_updates.load(Ordering::Relaxed),
            writes_accepted: self.writes_accepted.load(Ordering::Relaxed),
            writes_refused: self.writes_refused.load(Ordering::Relaxed),
            ..OpcUaStatus::default()
        };
        (self.probe)(&mut status);
        status
    }
}

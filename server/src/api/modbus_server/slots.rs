//! The Modbus TCP server's connections: at most `max_connections`, and at most
//! `max_connections_per_client` from one address; when a new master finds them taken, the
//! connection that has waited longest on its master (its own address's first) is closed.

use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use tokio_util::sync::CancellationToken;

/// Orders the moments connections begin to wait for their masters.
static WAITS: AtomicU64 = AtomicU64::new(0);

/// The open connections, and which one a new master closes when they are all taken (or
/// when its own address holds all of its).
pub(super) struct Slots {
    max: usize,
    max_per_client: usize,
    open: Mutex<Vec<Arc<Slot>>>,
}

/// One connection as the listener sees it.
pub(super) struct Slot {
    peer: SocketAddr,
    /// Waiting for its master: for a request, or for it to take an answer.
    pub(super) on_master: AtomicBool,
    /// Whether it has sent a whole request yet.
    pub(super) served: AtomicBool,
    /// When it last began to wait for its master, as a tick of [`WAITS`] (strictly
    /// ordered, unlike a clock's readings that may be equal).
    since: AtomicU64,
    /// Cancelled to close it for a new master.
    pub(super) evict: CancellationToken,
}

pub(super) enum Taken {
    Free(Arc<Slot>),
    Evicted {
        slot: Arc<Slot>,
        evicted: SocketAddr,
        /// Its own address held all its places (else the server was full).
        own: bool,
    },
    Full,
    /// Its address holds all its places, every one being answered.
    ClientFull,
}

impl Slots {
    pub(super) fn new(max: usize, max_per_client: usize) -> Self {
        Slots {
            max,
            max_per_client,
            open: Mutex::new(Vec::new()),
        }
    }

    /// A slot for `peer`'s connection: a free one, or the one of the connection that has
    /// waited longest on its master (never served first), which is closed: one of its own
    /// address's when that holds `max_per_client`, else anyone's when all are taken.
    pub(super) fn take(&self, peer: SocketAddr) -> Taken {
        let mut open = self.open.lock().unwrap_or_else(|e| e.into_inner());
        let mine = |s: &Slot| s.peer.ip() == peer.ip();
        // Its own limit, where it is below the server's.
        let own = self.max_per_client < self.max
            && open.iter().filter(|s| mine(s)).count() >= self.max_per_client;
        let mut evicted = None;
        if own || open.len() >= self.max {
            let victim = longest_waiting(&open, |s| !own || mine(s));
            let Some(victim) = victim.map(|i| open.swap_remove(i)) else {
                return if own { Taken::ClientFull } else { Taken::Full };
            };
            victim.evict.cancel();
            evicted = Some(victim.peer);
        }
        let slot = Arc::new(Slot {
            peer,
            on_master: AtomicBool::new(true),
            served: AtomicBool::new(false),
            since: AtomicU64::new(WAITS.fetch_add(1, Ordering::Relaxed)),
            evict: CancellationToken::new(),
        });
        open.push(slot.clone());
        match evicted {
            None => Taken::Free(slot),
            Some(evicted) => Taken::Evicted { slot, evicted, own },
        }
    }

    /// The most connections one address holds.
    pub(super) fn most_of_one_client(&self) -> usize {
        let open = self.open.lock().unwrap_or_else(|e| e.into_inner());
        let mut counts = std::collections::HashMap::new();
        for s in open.iter() {
            *counts.entry(s.peer.ip()).or_insert(0usize) += 1;
        }
        counts.into_values().max().unwrap_or(0)
    }

    pub(super) fn release(&self, slot: &Arc<Slot>) {
        let mut open = self.open.lock().unwrap_or_else(|e| e.into_inner());
        open.retain(|s| !Arc::ptr_eq(s, slot));
    }
}

/// Among the connections `among` picks, the one that has waited longest on its master
/// (never served first).
fn longest_waiting(open: &[Arc<Slot>], among: impl Fn(&Slot) -> bool) -> Option<usize> {
    open.iter()
        .enumerate()
        .filter(|(_, s)| among(s) && s.on_master.load(Ordering::Acquire))
        .min_by_key(|(_, s)| {
            (
                s.served.load(Ordering::Relaxed),
                s.since.load(Ordering::Relaxed),
            )
        })
        .map(|(i, _)| i)
}

impl Slot {
    /// From now on it waits for its master.
    pub(super) fn wait_on_master(&self) {
        self.since
            .store(WAITS.fetch_add(1, Ordering::Relaxed), Ordering::Relaxed);
        self.on_master.store(true, Ordering::Release);
    }
}

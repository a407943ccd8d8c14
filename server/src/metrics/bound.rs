//! Bounds on what clients can make the gateway hold, each counted for `/metrics`: its limit
//! (`iogate_bound_limit`), how much of it is held (`iogate_bound_used`) and how many times a
//! client was refused at it (`iogate_bound_refused_total`), by `bound` (the names in the
//! README's table of bounds).

use std::collections::HashMap;
use std::net::IpAddr;
use std::sync::{Arc, Mutex};

use prometheus_client::encoding::EncodeLabelSet;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::gauge::Gauge;

use super::Metrics;

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub(crate) struct BoundLabels {
    pub(crate) bound: &'static str,
}

/// One bound: a limit, what is held of it, the refusals. Clones share their counts.
#[derive(Clone, Debug)]
pub(crate) struct Bound {
    limit: Gauge,
    used: Gauge,
    refused: Counter,
}

/// A place held within a [`Bound`]; dropping it frees the place.
#[derive(Debug)]
pub(crate) struct Held(Gauge);

impl Drop for Held {
    fn drop(&mut self) {
        self.0.dec();
    }
}

impl Bound {
    /// Takes a place, or counts a refusal and answers `None` when all are held.
    pub(crate) fn take(&self) -> Option<Held> {
        let limit = self.limit.get();
        let before = self.used.inc();
        let held = Held(self.used.clone());
        if before >= limit {
            drop(held);
            self.refused.inc();
            return None;
        }
        Some(held)
    }

    /// Holds a place that was granted elsewhere (where the bound's owner decides, such as a
    /// server that closes an idle connection to make room).
    pub(crate) fn hold(&self) -> Held {
        self.used.inc();
        Held(self.used.clone())
    }

    /// Counts a refusal decided elsewhere (a place evicted, a connection closed at once).
    pub(crate) fn refused(&self) {
        self.refused.inc();
    }

    /// Counts `n` refusals decided elsewhere.
    pub(crate) fn refused_by(&self, n: u64) {
        self.refused.inc_by(n);
    }

    /// Sets what is held, for bounds whose places are counted elsewhere.
    pub(crate) fn set_used(&self, used: usize) {
        self.used.set(to_i64(used));
    }

    /// Puts a new limit in force; places already held stay held.
    pub(crate) fn set_limit(&self, limit: usize) {
        self.limit.set(to_i64(limit));
    }

    pub(crate) fn limit(&self) -> usize {
        usize::try_from(self.limit.get()).unwrap_or(0)
    }

    #[cfg(test)]
    pub(crate) fn used(&self) -> usize {
        usize::try_from(self.used.get()).unwrap_or(0)
    }
}

/// Places within a bound for each client (by its address): no one client holds more than
/// the limit. `used` is what the client holding the most holds.
#[derive(Clone, Debug)]
pub(crate) struct PerClient {
    bound: Bound,
    held: Arc<Mutex<HashMap<IpAddr, usize>>>,
}

/// A client's place within a [`PerClient`]; dropping it frees the place.
#[derive(Debug)]
pub(crate) struct ClientHeld {
    of: PerClient,
    client: IpAddr,
}

impl PerClient {
    /// Takes a place for `client`, or counts a refusal and answers `None` when it holds
    /// all its places.
    pub(crate) fn take(&self, client: IpAddr) -> Option<ClientHeld> {
        let limit = self.bound.limit();
        let mut held = self.held.lock().unwrap_or_else(|e| e.into_inner());
        let n = held.entry(client).or_default();
        if *n >= limit {
            self.bound.refused();
            return None;
        }
        *n += 1;
        self.count(&held);
        Some(ClientHeld {
            of: self.clone(),
            client,
        })
    }

    /// Places for each client from now on; places held stay held.
    pub(crate) fn set_limit(&self, limit: usize) {
        self.bound.set_limit(limit);
    }

    pub(crate) fn limit(&self) -> usize {
        self.bound.limit()
    }

    fn count(&self, held: &HashMap<IpAddr, usize>) {
        self.bound
            .set_used(held.values().copied().max().unwrap_or(0));
    }
}

impl Drop for ClientHeld {
    fn drop(&mut self) {
        let mut held = self.of.held.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(n) = held.get_mut(&self.client) {
            *n = n.saturating_sub(1);
            if *n == 0 {
                held.remove(&self.client);
            }
        }
        self.of.count(&held);
    }
}

fn to_i64(n: usize) -> i64 {
    i64::try_from(n).unwrap_or(i64::MAX)
}

impl Metrics {
    /// The bound named `name`, with `limit` in force (the same counts for every caller that
    /// names it: a front-end restarted by a reload keeps its refusals).
    pub(crate) fn bound(&self, name: &'static str, limit: usize) -> Bound {
        let labels = BoundLabels { bound: name };
        let bound = Bound {
            limit: self.bound_limit.get_or_create(&labels).clone(),
            used: self.bound_used.get_or_create(&labels).clone(),
            refused: self.bound_refused.get_or_create(&labels).clone(),
        };
        bound.set_limit(limit);
        bound
    }

    /// The bound named `name` for each client, `limit` places each; the clients' places are
    /// this caller's own (each listener keeps its own), the counts are the name's.
    pub(crate) fn per_client(&self, name: &'static str, limit: usize) -> PerClient {
        PerClient {
            bound: self.bound(name, limit),
            held: Arc::default(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn places_are_taken_up_to_the_limit_and_freed_when_dropped() {
        let metrics = Metrics::new();
        let bound = metrics.bound("streams", 2);
        let a = bound.take().expect("first");
        let _b = bound.take().expect("second");
        assert!(bound.take().is_none(), "a third is refused");
        assert_eq!((bound.used(), bound.refused.get()), (2, 1));
        drop(a);
        assert!(bound.take().is_some(), "a freed place is taken again");
        let again = metrics.bound("streams", 3);
        assert_eq!((again.used(), again.limit()), (1, 3), "one count per name");
        let mut text = String::new();
        prometheus_client::encoding::text::encode_registry(&mut text, &metrics.registry)
            .expect("encoded");
        assert!(
            text.contains("iogate_bound_limit{bound=\"streams\"} 3"),
            "{text}"
        );
        assert!(
            text.contains("iogate_bound_refused_total{bound=\"streams\"} 1"),
            "{text}"
        );
    }

    #[test]
    fn each_client_holds_at_most_its_places() {
        let metrics = Metrics::new();
        let per = metrics.per_client("connections_per_client", 2);
        let (a, b): (IpAddr, IpAddr) = ([10, 0, 0, 1].into(), [10, 0, 0, 2].into());
        let first = per.take(a).expect("a's first");
        let _second = per.take(a).expect("a's second");
        assert!(per.take(a).is_none(), "a's third is refused");
        let _other = per.take(b).expect("b is not held back by a");
        assert_eq!((per.bound.used(), per.bound.refused.get()), (2, 1));
        drop(first);
        assert!(per.take(a).is_some(), "a freed place is a's again");
        assert_eq!(per.held.lock().expect("held").len(), 2);
    }
}

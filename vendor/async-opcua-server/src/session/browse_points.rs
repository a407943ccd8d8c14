//! The browse continuation points of every session, in one store: each session keeps at
//! most its bound (past it a browse that needs one is answered Bad_NoContinuationPoints),
//! and every session together at most the server's bound, the oldest point released first
//! when a new one needs its place, so that sessions that never release theirs cannot keep
//! other clients from browsing nor grow the server's memory.

use std::collections::{BTreeMap, HashMap};

use opcua_types::ByteString;
use parking_lot::Mutex;

use crate::node_manager::BrowseContinuationPoint;

/// Every session's browse continuation points.
pub(crate) struct BrowsePoints {
    inner: Mutex<Inner>,
    /// A session's bound and the whole server's (0: no bound).
    per_session: usize,
    total: usize,
}

#[derive(Default)]
struct Inner {
    /// By session (its numeric id) and point id: the point and when it was kept.
    points: HashMap<(u32, ByteString), (u64, BrowseContinuationPoint)>,
    /// Oldest first.
    order: BTreeMap<u64, (u32, ByteString)>,
    /// Points each session holds.
    held: HashMap<u32, usize>,
    next: u64,
}

impl Inner {
    fn remove(&mut self, key: &(u32, ByteString)) -> Option<BrowseContinuationPoint> {
        let (seq, point) = self.points.remove(key)?;
        self.order.remove(&seq);
        if let Some(n) = self.held.get_mut(&key.0) {
            *n -= 1;
            if *n == 0 {
                self.held.remove(&key.0);
            }
        }
        Some(point)
    }
}

impl BrowsePoints {
    pub(crate) fn new(per_session: usize, total: usize) -> Self {
        BrowsePoints {
            inner: Mutex::new(Inner::default()),
            per_session,
            total,
        }
    }

    /// Keeps `point` for `session`: `Err` past the session's bound; at the server's bound
    /// the oldest point of any session is released first.
    pub(crate) fn add(&self, session: u32, point: BrowseContinuationPoint) -> Result<(), ()> {
        let mut inner = self.inner.lock();
        let held = inner.held.get(&session).copied().unwrap_or(0);
        if self.per_session > 0 && held >= self.per_session {
            return Err(());
        }
        if self.total > 0 && inner.points.len() >= self.total {
            if let Some((_, oldest)) = inner.order.pop_first() {
                inner.remove(&oldest);
            }
        }
        let key = (session, point.id.clone());
        inner.remove(&key);
        let seq = inner.next;
        inner.next += 1;
        inner.order.insert(seq, key.clone());
        *inner.held.entry(session).or_default() += 1;
        inner.points.insert(key, (seq, point));
        Ok(())
    }

    /// Takes `session`'s point `id` out of the store.
    pub(crate) fn take(&self, session: u32, id: &ByteString) -> Option<BrowseContinuationPoint> {
        self.inner.lock().remove(&(session, id.clone()))
    }

    /// Releases every point of `session` (it ended).
    pub(crate) fn release_session(&self, session: u32) {
        let mut inner = self.inner.lock();
        if !inner.held.contains_key(&session) {
            return;
        }
        let keys: Vec<_> = inner
            .points
            .keys()
            .filter(|(s, _)| *s == session)
            .cloned()
            .collect();
        for key in keys {
            inner.remove(&key);
        }
    }
}

//! The outcome of every write, by generation: a client's, and the gateway's own (a replay of
//! the requested value after a reconnect, a reconcile of a device that holds another value,
//! a safe value after a client was lost), each with its origin.
//!
//! Generations are handed out in increasing order across the whole gateway. Each field keeps
//! its newest [`FIELD_HISTORY`] writes, so a burst on other fields (or from one `Write` call
//! with thousands of items) cannot erase a write someone is waiting on; a generation older
//! than its field's history is reported as expired.

use std::collections::{BTreeMap, HashMap, VecDeque};
use std::sync::Mutex;
use std::time::SystemTime;

use crate::codec::Value;

/// Writes kept per field.
pub(crate) const FIELD_HISTORY: usize = 128;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum WriteStatus {
    /// Accepted; waiting for the device's link (or on the bus now).
    Pending,
    /// The device acknowledged the value.
    Written,
    /// A newer write to the same field replaced it before it reached the bus.
    Superseded,
    /// The bus write failed; `error` says why.
    Failed,
}

impl WriteStatus {
    pub(crate) fn name(self) -> &'static str {
        match self {
            WriteStatus::Pending => "pending",
            WriteStatus::Written => "written",
            WriteStatus::Superseded => "superseded",
            WriteStatus::Failed => "failed",
        }
    }
}

/// Who asked for a write.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Origin {
    /// A client: REST, gRPC, a scan cycle, a Modbus master.
    Client,
    /// The gateway wrote the requested value again after the link or device came back.
    Replay,
    /// The gateway wrote the requested value again because the device held another
    /// (`write_mode: reconcile`).
    Reconcile,
    /// The gateway wrote a field's safe value after the client that wrote it was lost
    /// (`on_client_loss`).
    Safety,
}

impl Origin {
    pub(crate) fn name(self) -> &'static str {
        match self {
            Origin::Client => "client",
            Origin::Replay => "replay",
            Origin::Reconcile => "reconcile",
            Origin::Safety => "safety",
        }
    }
}

#[derive(Debug, Clone, PartialEq)]
pub(crate) struct WriteRecord {
    pub(crate) generation: u64,
    pub(crate) device: String,
    pub(crate) field: String,
    /// The value asked for; `None` for a relinquish (the device's own value, or a lower
    /// priority's, takes over).
    pub(crate) value: Option<Value>,
    pub(crate) status: WriteStatus,
    pub(crate) origin: Origin,
    /// Transactions sent for it (retries included); 0 until it reached the bus.
    pub(crate) attempts: u32,
    pub(crate) error: Option<String>,
    pub(crate) requested: SystemTime,
    pub(crate) finished: Option<SystemTime>,
}

#[derive(Debug)]
pub struct WriteLog {
    inner: Mutex<Inner>,
}

#[derive(Debug)]
struct Inner {
    next: u64,
    /// Per device and field, its newest writes in generation order.
    fields: HashMap<(String, String), VecDeque<WriteRecord>>,
    /// Where each kept generation is.
    index: BTreeMap<u64, (String, String)>,
    /// Final outcomes per device and status, for metrics.
    outcomes: BTreeMap<(String, &'static str), u64>,
    /// Generations never handed out here: the gaps an epoch's start jumped over (the other
    /// node of a pair handed them out), the newest [`MAX_GAPS`].
    gaps: std::collections::VecDeque<std::ops::Range<u64>>,
}

/// Epoch starts remembered, at most (one per takeover).
const MAX_GAPS: usize = 1024;

/// What the log knows of a generation.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Lookup {
    Found(WriteRecord),
    /// Older than what its field's history keeps.
    Expired,
    /// Not handed out yet.
    Unknown,
}

impl Default for WriteLog {
    fn default() -> Self {
        WriteLog {
            inner: Mutex::new(Inner {
                next: 1,
                fields: HashMap::new(),
                index: BTreeMap::new(),
                outcomes: BTreeMap::new(),
                gaps: std::collections::VecDeque::new(),
            }),
        }
    }
}

impl Inner {
    fn record(&mut self, generation: u64) -> Option<&mut WriteRecord> {
        let key = self.index.get(&generation)?;
        let history = self.fields.get_mut(key)?;
        let idx = history
            .binary_search_by_key(&generation, |r| r.generation)
            .ok()?;
        history.get_mut(idx)
    }
}

impl WriteLog {
    fn lock(&self) -> std::sync::MutexGuard<'_, Inner> {
        // A panic while holding this lock cannot leave the log inconsistent: every update
        // is a single push or field assignment.
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Writes from now on carry `epoch` (an active/standby pair's lease, [`crate::role`]):
    /// their generations start at the epoch's first, so they are above every earlier one,
    /// the other node's included.
    pub(crate) fn enter_epoch(&self, epoch: u64) {
        let mut inner = self.lock();
        let first = crate::role::first_generation(epoch);
        if first > inner.next {
            let gap = inner.next..first;
            inner.gaps.push_back(gap);
            if inner.gaps.len() > MAX_GAPS {
                inner.gaps.pop_front();
            }
            inner.next = first;
        }
    }

    /// Writes kept, every field's together.
    pub(crate) fn kept(&self) -> usize {
        self.lock().index.len()
    }

    /// Records a new pending write from a client and returns its generation.
    #[cfg(test)]
    pub(crate) fn begin(&self, device: &str, field: &str, value: Value) -> u64 {
        self.begin_from(device, field, Some(value), Origin::Client)
    }

    /// Records a new pending write from `origin` and returns its generation.
    pub(crate) fn begin_from(
        &self,
        device: &str,
        field: &str,
        value: Option<Value>,
        origin: Origin,
    ) -> u64 {
        let mut inner = self.lock();
        let generation = inner.next;
        inner.next += 1;
        let key = (device.to_owned(), field.to_owned());
        let history = inner.fields.entry(key.clone()).or_default();
        let dropped = if history.len() >= FIELD_HISTORY {
            history.pop_front().map(|r| r.generation)
        } else {
            None
        };
        history.push_back(WriteRecord {
            generation,
            device: key.0.clone(),
            field: key.1.clone(),
            value,
            status: WriteStatus::Pending,
            origin,
            attempts: 0,
            error: None,
            requested: SystemTime::now(),
            finished: None,
        });
        if let Some(old) = dropped {
            inner.index.remove(&old);
        }
        inner.index.insert(generation, key);
        generation
    }

    /// Sets the final status of a generation.
    pub(crate) fn finish(&self, generation: u64, status: WriteStatus, error: Option<String>) {
        self.finish_after(generation, status, error, 0);
    }

    /// Sets the final status of a generation that took `attempts` transactions.
    pub(crate) fn finish_after(
        &self,
        generation: u64,
        status: WriteStatus,
        error: Option<String>,
        attempts: u32,
    ) {
        let mut inner = self.lock();
        let Some(record) = inner.record(generation) else {
            return;
        };
        record.status = status;
        record.error = error;
        record.attempts = attempts;
        record.finished = Some(SystemTime::now());
        let key = (record.device.clone(), status.name());
        *inner.outcomes.entry(key).or_default() += 1;
    }

    /// How many writes ended with each status, per device.
    pub(crate) fn outcome_counts(&self) -> Vec<(String, &'static str, u64)> {
        self.lock()
            .outcomes
            .iter()
            .map(|((device, status), n)| (device.clone(), *status, *n))
            .collect()
    }

    pub(crate) fn get(&self, generation: u64) -> Lookup {
        let mut inner = self.lock();
        if generation == 0
            || generation >= inner.next
            || inner.gaps.iter().any(|g| g.contains(&generation))
        {
            return Lookup::Unknown;
        }
        match inner.record(generation) {
            Some(record) => Lookup::Found(record.clone()),
            None => Lookup::Expired,
        }
    }

    /// The writes kept for one field, oldest first.
    #[cfg(test)]
    pub(crate) fn history(&self, device: &str, field: &str) -> Vec<WriteRecord> {
        self.lock()
            .fields
            .get(&(device.to_owned(), field.to_owned()))
            .map(|h| h.iter().cloned().collect())
            .unwrap_or_default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_generation_the_other_node_of_a_pair_handed_out_is_unknown_here_not_expired() {
        let log = WriteLog::default();
        let mine = log.begin("d", "f", Value::Bool(true));
        log.enter_epoch(2);
        let next = log.begin("d", "f", Value::Bool(false));
        assert_eq!(crate::role::epoch_of(next), 2);
        assert!(matches!(log.get(mine), Lookup::Found(_)));
        // Epoch 1 was the other node's: its generations were never handed out here.
        assert_eq!(log.get(crate::role::first_generation(1)), Lookup::Unknown);
        assert_eq!(log.get(mine + 1), Lookup::Unknown);
    }

    #[test]
    fn generations_increase_and_keep_their_outcome() {
        let log = WriteLog::default();
        let a = log.begin("d", "f", Value::Bool(true));
        let b = log.begin("d", "f", Value::Bool(false));
        assert!(b > a);
        log.finish(a, WriteStatus::Superseded, None);
        log.finish(b, WriteStatus::Failed, Some("timeout".into()));
        let Lookup::Found(ra) = log.get(a) else {
            panic!("a not found")
        };
        assert_eq!(ra.status, WriteStatus::Superseded);
        let Lookup::Found(rb) = log.get(b) else {
            panic!("b not found")
        };
        assert_eq!(rb.error.as_deref(), Some("timeout"));
        assert_eq!(log.get(b + 1), Lookup::Unknown);
        assert_eq!(log.get(0), Lookup::Unknown);
    }

    #[test]
    fn old_generations_of_a_field_expire_and_a_burst_elsewhere_erases_none() {
        let log = WriteLog::default();
        let first = log.begin("d", "f", Value::Int(0));
        let waiting = log.begin("d", "g", Value::Int(7));
        for i in 0..FIELD_HISTORY {
            log.begin("d", "f", Value::Int(i as i64));
        }
        assert_eq!(log.get(first), Lookup::Expired);
        assert!(matches!(log.get(first + 2), Lookup::Found(_)));
        // Ten thousand writes to other fields leave field g's write in place.
        for i in 0..10_000 {
            log.begin("other", &format!("f{}", i % 500), Value::Int(i));
        }
        assert!(matches!(log.get(waiting), Lookup::Found(r) if r.value == Some(Value::Int(7))));
        assert_eq!(log.history("d", "f").len(), FIELD_HISTORY);
    }

    #[test]
    fn the_gateways_own_writes_say_where_they_came_from() {
        let log = WriteLog::default();
        let g = log.begin_from("d", "f", Some(Value::Bool(true)), Origin::Replay);
        log.finish_after(g, WriteStatus::Written, None, 3);
        let Lookup::Found(r) = log.get(g) else {
            panic!("not found")
        };
        assert_eq!((r.origin, r.attempts), (Origin::Replay, 3));
    }
}

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
    /// The outcome made the gateway forget the value asked for (the device refused it, or
    /// the link was lost with it sent too often): it is not the output's desired value any
    /// more. Carried to the other node of a pair with the record.
    pub(crate) forgets: bool,
}

#[derive(Debug)]
pub struct WriteLog {
    inner: Mutex<Inner>,
    /// Woken when the journal has records.
    journaled: tokio::sync::Notify,
}

/// Records as they change, kept for the other node of a pair ([`WriteLog::start_journal`]).
#[derive(Debug, Default)]
struct Journal {
    records: VecDeque<WriteRecord>,
    /// Records dropped because the journal was full, since it was last drained.
    dropped: u64,
}

/// Records the journal holds at most: about 20 MiB, a few seconds of the fastest writes.
const JOURNAL_MAX: usize = 65_536;

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
    /// The journal, in a pair.
    journal: Option<Journal>,
    /// Generations adopted from the other node of the pair still pending there.
    adopted_pending: std::collections::BTreeSet<u64>,
    /// When a standby's hello last made a snapshot of the journal.
    snapshot_at: Option<std::time::Instant>,
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
                journal: None,
                adopted_pending: Default::default(),
                snapshot_at: None,
            }),
            journaled: tokio::sync::Notify::new(),
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

    /// Puts a copy of `generation`'s record in the journal, when there is one.
    fn journal(&mut self, generation: u64) -> bool {
        if self.journal.is_none() {
            return false;
        }
        let Some(record) = self.record(generation).cloned() else {
            return false;
        };
        let journal = self.journal.get_or_insert_with(Journal::default);
        if journal.records.len() >= JOURNAL_MAX {
            journal.records.pop_front();
            journal.dropped += 1;
        }
        journal.records.push_back(record);
        true
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
            forgets: false,
        });
        if let Some(old) = dropped {
            inner.index.remove(&old);
        }
        inner.index.insert(generation, key);
        let journaled = inner.journal(generation);
        drop(inner);
        if journaled {
            self.journaled.notify_one();
        }
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
        self.finish_forgetting(generation, (status, error, attempts), false);
    }

    /// Sets the final status, error and attempts of a generation, and whether the outcome
    /// made the gateway forget the value asked for ([`WriteRecord::forgets`]).
    pub(crate) fn finish_forgetting(
        &self,
        generation: u64,
        (status, error, attempts): (WriteStatus, Option<String>, u32),
        forgets: bool,
    ) {
        let mut inner = self.lock();
        let Some(record) = inner.record(generation) else {
            return;
        };
        record.status = status;
        record.error = error;
        record.attempts = attempts;
        record.forgets = forgets;
        record.finished = Some(SystemTime::now());
        let key = (record.device.clone(), status.name());
        *inner.outcomes.entry(key).or_default() += 1;
        if inner.journal(generation) {
            drop(inner);
            self.journaled.notify_one();
        }
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
        // A record adopted from the other node of a pair is above this node's own.
        if let Some(record) = inner.record(generation) {
            return Lookup::Found(record.clone());
        }
        if generation == 0
            || generation >= inner.next
            || inner.gaps.iter().any(|g| g.contains(&generation))
        {
            return Lookup::Unknown;
        }
        Lookup::Expired
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

#[path = "write_log_pair.rs"]
mod pair;

#[cfg(test)]
#[path = "write_log_tests.rs"]
mod tests;

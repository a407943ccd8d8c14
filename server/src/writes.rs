//! The outcome of every accepted write, by generation.
//!
//! Generations are handed out in increasing order across the whole gateway. The log keeps the
//! most recent [`WRITE_LOG_CAPACITY`] writes; an older generation is reported as expired.

use std::collections::{BTreeMap, VecDeque};
use std::sync::Mutex;
use std::time::SystemTime;

use crate::codec::Value;

pub const WRITE_LOG_CAPACITY: usize = 4096;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WriteStatus {
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
    pub fn name(self) -> &'static str {
        match self {
            WriteStatus::Pending => "pending",
            WriteStatus::Written => "written",
            WriteStatus::Superseded => "superseded",
            WriteStatus::Failed => "failed",
        }
    }
}

#[derive(Debug, Clone, PartialEq)]
pub struct WriteRecord {
    pub generation: u64,
    pub device: String,
    pub field: String,
    pub value: Value,
    pub status: WriteStatus,
    pub error: Option<String>,
    pub requested: SystemTime,
    pub finished: Option<SystemTime>,
}

#[derive(Debug)]
pub struct WriteLog {
    inner: Mutex<Inner>,
}

#[derive(Debug)]
struct Inner {
    next: u64,
    records: VecDeque<WriteRecord>,
    /// Final outcomes per device and status, for metrics.
    outcomes: BTreeMap<(String, &'static str), u64>,
}

/// What the log knows of a generation.
#[derive(Debug, Clone, PartialEq)]
pub enum Lookup {
    Found(WriteRecord),
    /// Older than what the log keeps.
    Expired,
    /// Not handed out yet.
    Unknown,
}

impl Default for WriteLog {
    fn default() -> Self {
        WriteLog {
            inner: Mutex::new(Inner {
                next: 1,
                records: VecDeque::with_capacity(WRITE_LOG_CAPACITY),
                outcomes: BTreeMap::new(),
            }),
        }
    }
}

impl WriteLog {
    fn lock(&self) -> std::sync::MutexGuard<'_, Inner> {
        // A panic while holding this lock cannot leave the log inconsistent: every update
        // is a single push or field assignment.
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Records a new pending write and returns its generation.
    pub fn begin(&self, device: &str, field: &str, value: Value) -> u64 {
        let mut inner = self.lock();
        let generation = inner.next;
        inner.next += 1;
        if inner.records.len() == WRITE_LOG_CAPACITY {
            inner.records.pop_front();
        }
        inner.records.push_back(WriteRecord {
            generation,
            device: device.to_owned(),
            field: field.to_owned(),
            value,
            status: WriteStatus::Pending,
            error: None,
            requested: SystemTime::now(),
            finished: None,
        });
        generation
    }

    /// Sets the final status of a generation.
    pub fn finish(&self, generation: u64, status: WriteStatus, error: Option<String>) {
        let mut inner = self.lock();
        if let Some(idx) = position(&inner.records, generation) {
            let record = &mut inner.records[idx];
            record.status = status;
            record.error = error;
            record.finished = Some(SystemTime::now());
            let key = (record.device.clone(), status.name());
            *inner.outcomes.entry(key).or_default() += 1;
        }
    }

    /// How many writes ended with each status, per device.
    pub fn outcome_counts(&self) -> Vec<(String, &'static str, u64)> {
        self.lock()
            .outcomes
            .iter()
            .map(|((device, status), n)| (device.clone(), *status, *n))
            .collect()
    }

    pub fn get(&self, generation: u64) -> Lookup {
        let inner = self.lock();
        if generation == 0 || generation >= inner.next {
            return Lookup::Unknown;
        }
        match position(&inner.records, generation) {
            Some(idx) => Lookup::Found(inner.records[idx].clone()),
            None => Lookup::Expired,
        }
    }
}

/// Generations are pushed in increasing order, so the log is sorted.
fn position(records: &VecDeque<WriteRecord>, generation: u64) -> Option<usize> {
    records
        .binary_search_by_key(&generation, |r| r.generation)
        .ok()
}

#[cfg(test)]
mod tests {
    use super::*;

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
    fn old_generations_expire() {
        let log = WriteLog::default();
        let first = log.begin("d", "f", Value::Int(0));
        for i in 0..WRITE_LOG_CAPACITY {
            log.begin("d", "f", Value::Int(i as i64));
        }
        assert_eq!(log.get(first), Lookup::Expired);
        assert!(matches!(log.get(first + 1), Lookup::Found(_)));
    }
}

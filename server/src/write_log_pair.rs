//! The write log in an active/standby pair: the active journals every record as it
//! changes, for its link to the standby to ship; the standby adopts what it is shipped, so
//! a client following a write on the old active finds its outcome on the new one; a write
//! still pending on the old active when it was lost ends `failed` here when this node
//! takes over (its outcome never came).

use super::{FIELD_HISTORY, Inner, Journal, WriteLog, WriteRecord, WriteStatus};

impl WriteLog {
    /// Journals every record from now on, as it begins and as it ends.
    pub(crate) fn start_journal(&self) {
        let mut inner = self.lock();
        inner.journal.get_or_insert_with(Journal::default);
    }

    /// Resolves when the journal has records (at once if it had some already).
    pub(crate) async fn journaled(&self) {
        let notified = self.journaled.notified();
        if self
            .lock()
            .journal
            .as_ref()
            .is_some_and(|j| !j.records.is_empty())
        {
            return;
        }
        notified.await;
    }

    /// Takes at most `max` records from the journal, oldest first, and how many it dropped
    /// (full) since the last drain.
    pub(crate) fn drain_journal(&self, max: usize) -> (Vec<WriteRecord>, u64) {
        let mut inner = self.lock();
        let Some(journal) = inner.journal.as_mut() else {
            return (Vec::new(), 0);
        };
        let n = journal.records.len().min(max);
        let dropped = std::mem::take(&mut journal.dropped);
        (journal.records.drain(..n).collect(), dropped)
    }

    /// As [`WriteLog::journal_snapshot`], unless one was taken less than `every` ago.
    pub(crate) fn journal_snapshot_at_most(&self, every: std::time::Duration) {
        {
            let mut inner = self.lock();
            let now = std::time::Instant::now();
            if inner.snapshot_at.is_some_and(|at| now < at + every) {
                return;
            }
            inner.snapshot_at = Some(now);
        }
        self.journal_snapshot();
    }

    /// Journals again what a standby that just came needs: each field's newest record
    /// (its desired value and latest outcome) and every pending one.
    pub(crate) fn journal_snapshot(&self) {
        let mut inner = self.lock();
        let generations: Vec<u64> = inner
            .fields
            .values()
            .flat_map(|history| {
                let newest = history.back().map(|r| r.generation);
                let pending = history
                    .iter()
                    .filter(|r| r.status == WriteStatus::Pending)
                    .map(|r| r.generation);
                pending.chain(newest)
            })
            .collect();
        let mut any = false;
        for generation in generations {
            any |= inner.journal(generation);
        }
        drop(inner);
        if any {
            self.journaled.notify_one();
        }
    }

    /// Takes a record the other node of the pair shipped: new, or a later state of one
    /// adopted before (never an earlier one). Answers whether it was taken.
    pub(crate) fn adopt(&self, record: WriteRecord) -> bool {
        let mut inner = self.lock();
        let generation = record.generation;
        if generation == 0 {
            return false;
        }
        let pending = record.status == WriteStatus::Pending;
        match inner.record(generation) {
            Some(kept) if kept.finished.is_some() && record.finished.is_none() => return false,
            Some(kept) => *kept = record,
            None => place(&mut inner, record),
        }
        if pending && inner.index.contains_key(&generation) {
            inner.adopted_pending.insert(generation);
        } else {
            inner.adopted_pending.remove(&generation);
        }
        true
    }

    /// This node takes over in `epoch`: every adopted write still pending (its outcome
    /// never came from the old active) ends failed, saying so.
    pub(crate) fn orphan_adopted(&self, epoch: u64) -> usize {
        let pending: Vec<u64> = {
            let mut inner = self.lock();
            let (old, kept) = std::mem::take(&mut inner.adopted_pending)
                .into_iter()
                .partition(|g| crate::role::epoch_of(*g) < epoch);
            inner.adopted_pending = kept;
            old.into_iter().collect()
        };
        for &generation in &pending {
            let why = format!(
                "accepted by the other gateway of the pair in epoch {}, which was lost before its outcome reached this one: it may or may not have reached the device; this gateway does not write it",
                crate::role::epoch_of(generation)
            );
            self.finish(generation, WriteStatus::Failed, Some(why));
        }
        pending.len()
    }
}

/// Puts an adopted record in its field's history, in generation order, within the
/// history's bound.
fn place(inner: &mut Inner, record: WriteRecord) {
    let generation = record.generation;
    let key = (record.device.clone(), record.field.clone());
    let history = inner.fields.entry(key.clone()).or_default();
    let at = history.partition_point(|r| r.generation < generation);
    history.insert(at, record);
    let dropped = (history.len() > FIELD_HISTORY)
        .then(|| history.pop_front().map(|r| r.generation))
        .flatten();
    inner.index.insert(generation, key);
    if let Some(old) = dropped {
        inner.index.remove(&old);
        inner.adopted_pending.remove(&old);
    }
}

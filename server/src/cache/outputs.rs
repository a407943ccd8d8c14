//! A device's outputs as clients asked for them: per field the pending write (last value
//! wins), the newest value ever requested (written again after a reconnect) and the newest
//! write's generation; and why a write failed.

use std::sync::{Arc, Mutex};

use super::lock;
use crate::codec::{CodecError, Value};
use crate::link::frame::Exception;
use crate::link::{LinkFault, TxError};
use crate::profile::RegisterKind;
use crate::write_log::{Origin, WriteLog, WriteStatus};

/// Why a write did not reach the device.
#[derive(Debug, Clone, thiserror::Error)]
pub(crate) enum WriteError {
    /// The device answered with an exception.
    #[error("{0}")]
    Exception(Exception),
    /// The device did not answer properly, after the retries.
    #[error("{0}")]
    NoResponse(TxError),
    /// An earlier write of the same turn failed this way, so this one was not sent.
    #[error("not sent: {0}")]
    NotSent(Box<WriteError>),
    /// The value does not encode into the field's registers.
    #[error("{0}")]
    Encode(CodecError),
    #[error("a {} cannot be written", .0.name())]
    ReadOnly(RegisterKind),
    #[error("{0}; the latest value is written when the link is back")]
    LinkDown(LinkFault),
    #[error("the device does not answer; the latest value is written when it answers again")]
    DeviceDown,
    /// The link is down, and the device's outputs are not written again by themselves.
    #[error(
        "{0}; not written, and not written by itself when the link is back (rewrite_outputs: never): ask again then"
    )]
    LinkDownLeft(LinkFault),
    /// The device does not answer, and its outputs are not written again by themselves.
    #[error(
        "the device does not answer; not written, and not written by itself when it answers again (rewrite_outputs: never): ask again then"
    )]
    DeviceDownLeft,
    #[error("the device was removed before the value was written")]
    Removed,
    /// The device refused the value, in its own words (an OPC UA status code's name).
    #[error("the device refused it: {0}")]
    Refused(String),
    /// The device did not answer this value, sent, again: it is not written again by
    /// itself.
    #[error(
        "{0}; the device did not answer this value {LOST_AT_WRITE} times in a row, so it is not written again until it is asked again"
    )]
    Unanswered(TxError),
    /// The link was lost with this value sent, again: it is not written again by itself.
    #[error(
        "{0}; the link was lost with this value sent {LOST_AT_WRITE} times in a row, so it is not written again until it is asked again"
    )]
    GaveUp(LinkFault),
    /// Not put on the field: this gateway is not (or no longer) the active of its pair in
    /// the epoch that accepted the write.
    #[error("{0}")]
    Fenced(crate::role::Fenced),
}

/// How many times in a row the link may be lost with a field's value sent before that
/// value is no longer written again after a reconnect (a device that drops its connection
/// at a request it does not take would otherwise be asked again at every reconnect).
pub(crate) const LOST_AT_WRITE: u32 = 3;

impl WriteError {
    /// Whether the device answered that it does not take the value (so writing it again
    /// after a reconnect would be refused again), rather than failing to answer.
    fn is_refusal(&self) -> bool {
        match self {
            WriteError::Exception(x) => matches!(
                *x,
                Exception::ILLEGAL_FUNCTION
                    | Exception::ILLEGAL_DATA_ADDRESS
                    | Exception::ILLEGAL_DATA_VALUE
            ),
            WriteError::Encode(_) | WriteError::ReadOnly(_) | WriteError::Refused(_) => true,
            _ => false,
        }
    }
}

impl From<TxError> for WriteError {
    fn from(e: TxError) -> Self {
        match e {
            TxError::Exception(x) => WriteError::Exception(x),
            other => WriteError::NoResponse(other),
        }
    }
}

/// A value checked for a field of a device: the field is writable, the value of its type and
/// within its raw register after scaling; or a relinquish (no value) of a field whose
/// protocol has one. Only [`super::Device::check_write`] and
/// [`super::Device::check_relinquish`] make one.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Checked {
    idx: usize,
    value: Option<Value>,
}

impl Checked {
    /// Made by the device's checks only (the cache's own constructor).
    pub(super) fn new(idx: usize, value: Option<Value>) -> Checked {
        Checked { idx, value }
    }

    /// The field's index in its profile.
    pub(crate) fn idx(&self) -> usize {
        self.idx
    }

    /// The value; `None` for a relinquish.
    pub(crate) fn value(&self) -> Option<&Value> {
        self.value.as_ref()
    }

    /// The field's index and the value.
    pub(crate) fn into_parts(self) -> (usize, Option<Value>) {
        (self.idx, self.value)
    }
}

/// A write taken by the device's task to put on the bus; `value` is `None` for a
/// relinquish.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct TakenWrite {
    pub(crate) field: usize,
    pub(crate) generation: u64,
    pub(crate) value: Option<Value>,
}

#[derive(Debug, Default)]
struct WriteSlot {
    /// The newest requested value not yet taken by the link (`None`: a relinquish).
    pending: Option<(u64, Option<Value>)>,
    /// The newest value ever requested, written again after a reconnect (none after a
    /// relinquish: nothing is desired of the output then).
    latest: Option<Value>,
    /// The generation of the newest write.
    last_generation: Option<u64>,
    /// The write the device's task took and has not finished.
    in_flight: Option<u64>,
    /// The scan-cycle stream that requested the newest value, if one did.
    writer: Option<u64>,
    /// How many times in a row the link was lost with this field's value sent.
    lost_at_write: u32,
    /// The device acknowledged the newest requested value.
    reached: bool,
    /// The newest requested value is not written again after a reconnect: the device was
    /// read holding another value since it was written (someone else wrote the output).
    left: bool,
}

/// The write slots of one device's fields, and the gateway's write log they report to.
#[derive(Debug)]
pub(crate) struct Outputs {
    slots: Mutex<Vec<WriteSlot>>,
    log: Arc<WriteLog>,
    /// Set (under the slots' lock) when a re-planned device took the slots over: a request
    /// that comes later is for the successor.
    moved: std::sync::atomic::AtomicBool,
    /// Whether the newest requested values are written again after a reconnect or the
    /// device's return (`rewrite_outputs`, else the protocol's default), resolved when the
    /// device is made.
    rewrites: std::sync::atomic::AtomicBool,
    /// Whether a slot may hold a pending write: set with one, cleared when every pending
    /// write is taken (both under the slots' lock), so that a device's task looks at one
    /// flag each cycle, not at every field.
    pending: std::sync::atomic::AtomicBool,
}

impl Outputs {
    pub(crate) fn new(fields: usize, log: Arc<WriteLog>) -> Self {
        Outputs {
            slots: Mutex::new((0..fields).map(|_| WriteSlot::default()).collect()),
            log,
            moved: std::sync::atomic::AtomicBool::new(false),
            rewrites: std::sync::atomic::AtomicBool::new(false),
            pending: std::sync::atomic::AtomicBool::new(false),
        }
    }

    /// Sets whether the newest requested values are written again after a reconnect.
    pub(crate) fn set_rewrites(&self, rewrites: bool) {
        self.rewrites
            .store(rewrites, std::sync::atomic::Ordering::Release);
    }

    /// Whether the newest requested values are written again after a reconnect.
    pub(crate) fn rewrites(&self) -> bool {
        self.rewrites.load(std::sync::atomic::Ordering::Acquire)
    }

    fn is_moved(&self) -> bool {
        self.moved.load(std::sync::atomic::Ordering::Acquire)
    }

    /// Takes over the slots of `old`'s fields that a re-planned device keeps (`(old index,
    /// new index)`): the pending write, the newest requested value (not when the device `moved` to
    /// another link or slave id), the newest generation and its writer. A write on the bus stays `old`'s to finish. Requests to `old` are refused
    /// from now on (they go to the successor).
    pub(crate) fn take_over(&self, old: &Outputs, kept: &[(usize, usize)], moved: bool) {
        let mut from = lock(&old.slots);
        let mut to = lock(&self.slots);
        for &(before, idx) in kept {
            let (s, t) = (&mut from[before], &mut to[idx]);
            t.pending = s.pending.take();
            if t.pending.is_some() {
                self.pending
                    .store(true, std::sync::atomic::Ordering::Release);
            }
            // What was asked of the old place is not the new place's desired value (a write
            // still waiting goes on: it was asked of the device by name).
            t.latest = if moved {
                t.pending.as_ref().and_then(|(_, v)| v.clone())
            } else {
                s.latest.clone()
            };
            (t.reached, t.left) = (s.reached && !moved, s.left);
            t.last_generation = s.last_generation;
            t.writer = s.writer;
        }
        old.moved.store(true, std::sync::atomic::Ordering::Release);
    }

    /// The scan-cycle stream that requested field `idx`'s newest value, if one did.
    pub(crate) fn writer(&self, idx: usize) -> Option<u64> {
        lock(&self.slots)[idx].writer
    }

    /// As [`Outputs::request`], from `origin`, by the scan-cycle stream `writer` if one
    /// asks (remembered with the value, under the same lock).
    pub(crate) fn request_from(
        &self,
        device: &str,
        field: &str,
        idx: usize,
        value: Value,
        origin: Origin,
        writer: Option<u64>,
    ) -> Option<u64> {
        let mut slots = lock(&self.slots);
        if self.is_moved() {
            return None;
        }
        let at = (device, field, origin, writer);
        Some(self.put(&mut slots[idx], at, Some(value)))
    }

    /// Makes `value` field `slot`'s pending write and newest requested value, superseding
    /// the write it replaces; answers its generation.
    fn put(
        &self,
        slot: &mut WriteSlot,
        (device, field, origin, writer): (&str, &str, Origin, Option<u64>),
        value: Option<Value>,
    ) -> u64 {
        let generation = self.log.begin_from(device, field, value.clone(), origin);
        self.pending
            .store(true, std::sync::atomic::Ordering::Release);
        if let Some((old, _)) = slot.pending.replace((generation, value.clone())) {
            self.log.finish(old, WriteStatus::Superseded, None);
        }
        slot.lost_at_write = 0;
        (slot.reached, slot.left) = (false, false);
        slot.latest = value;
        slot.last_generation = Some(generation);
        slot.writer = writer;
        generation
    }

    /// Requests several checked writes at once (`(field name, proof)`), under one lock: the
    /// device's task takes all of them or none, so one client request is one write group.
    /// The writes come back when the slots were taken over by a successor.
    pub(crate) fn request_all<'a>(
        &self,
        device: &str,
        writes: Vec<(&'a str, Checked)>,
        origin: Origin,
        writer: Option<u64>,
    ) -> Result<Vec<u64>, Vec<(&'a str, Checked)>> {
        let mut slots = lock(&self.slots);
        if self.is_moved() {
            return Err(writes);
        }
        Ok(writes
            .into_iter()
            .map(|(field, checked)| {
                let (idx, value) = checked.into_parts();
                self.put(&mut slots[idx], (device, field, origin, writer), value)
            })
            .collect())
    }

    /// Records a write of field `idx`'s requested value that the device's task sends now
    /// on its own (after a reconnect); it becomes the field's newest write.
    pub(crate) fn replay(&self, device: &str, field: &str, idx: usize, value: Value) -> u64 {
        let mut slots = lock(&self.slots);
        let generation = self
            .log
            .begin_from(device, field, Some(value), Origin::Replay);
        slots[idx].last_generation = Some(generation);
        slots[idx].in_flight = Some(generation);
        generation
    }

    /// Whether a write of field `idx` is waiting or on the bus.
    pub(crate) fn is_due(&self, idx: usize) -> bool {
        let slots = lock(&self.slots);
        slots[idx].pending.is_some() || slots[idx].in_flight.is_some()
    }

    /// Takes every pending write.
    pub(crate) fn take(&self) -> Vec<TakenWrite> {
        let mut slots = lock(&self.slots);
        self.pending
            .store(false, std::sync::atomic::Ordering::Release);
        slots
            .iter_mut()
            .enumerate()
            .filter_map(|(field, slot)| {
                let (generation, value) = slot.pending.take()?;
                slot.in_flight = Some(generation);
                Some(TakenWrite {
                    field,
                    generation,
                    value,
                })
            })
            .collect()
    }

    /// The newest value requested for field `idx`.
    pub(crate) fn latest(&self, idx: usize) -> Option<Value> {
        lock(&self.slots)[idx].latest.clone()
    }

    /// The generation of the newest write to field `idx`.
    pub(crate) fn last_generation(&self, idx: usize) -> Option<u64> {
        lock(&self.slots)[idx].last_generation
    }

    pub(crate) fn has_pending(&self) -> bool {
        self.pending.load(std::sync::atomic::Ordering::Acquire)
    }

    /// The newest value requested for each output that is written again after a
    /// reconnect, and whether the device acknowledged it; none when the device's outputs
    /// are not written again.
    pub(crate) fn replayable(&self) -> Vec<(usize, Value, bool)> {
        if !self.rewrites() {
            return Vec::new();
        }
        lock(&self.slots)
            .iter()
            .enumerate()
            .filter(|(_, s)| !s.left)
            .filter_map(|(i, s)| s.latest.clone().map(|v| (i, v, s.reached)))
            .collect()
    }

    /// Whether an output would be written again after a reconnect.
    pub(crate) fn has_replayable(&self) -> bool {
        self.rewrites()
            && lock(&self.slots)
                .iter()
                .any(|s| s.latest.is_some() && !s.left)
    }

    /// Field `idx`'s newest requested value is not written again after reconnects: the
    /// device was read holding `held` since (someone else wrote it). The log says so with
    /// an entry of its own (origin `replay`, `superseded`).
    pub(crate) fn leave(&self, device: &str, field: &str, idx: usize, held: &Value) {
        let mut slots = lock(&self.slots);
        let Some(value) = slots[idx].latest.clone() else {
            return;
        };
        slots[idx].left = true;
        let generation = self
            .log
            .begin_from(device, field, Some(value), Origin::Replay);
        slots[idx].last_generation = Some(generation);
        let why = format!(
            "not written again after the reconnect: the device was read holding {held} since it was written (someone else wrote it); `write_mode: reconcile` makes the gateway own the output"
        );
        self.log
            .finish(generation, WriteStatus::Superseded, Some(why));
    }

    /// Records the outcome of a taken write that took `attempts` transactions; answers the
    /// field it was for, when it was the field's write on the bus.
    ///
    /// A value the device refused is not written again after a reconnect, nor one the link
    /// was lost with, sent, [`LOST_AT_WRITE`] times in a row (that outcome says so).
    pub(crate) fn finish(
        &self,
        generation: u64,
        mut result: Result<(), WriteError>,
        attempts: u32,
    ) -> Option<usize> {
        if !self.rewrites() {
            result = result.map_err(|e| match e {
                WriteError::LinkDown(f) => WriteError::LinkDownLeft(f),
                WriteError::DeviceDown => WriteError::DeviceDownLeft,
                other => other,
            });
        }
        let mut forgets = false;
        let field = {
            let mut slots = lock(&self.slots);
            let idx = slots.iter().position(|s| s.in_flight == Some(generation));
            if let Some(i) = idx {
                let slot = &mut slots[i];
                slot.in_flight = None;
                if slot.last_generation == Some(generation) {
                    let had = slot.latest.is_some();
                    result = settle(slot, result, attempts);
                    forgets = had && slot.latest.is_none();
                }
            }
            idx
        };
        let outcome = match result {
            Ok(()) => (WriteStatus::Written, None, attempts),
            Err(e) => (WriteStatus::Failed, Some(e.to_string()), attempts),
        };
        self.log.finish_forgetting(generation, outcome, forgets);
        field
    }
}

#[path = "outputs_adopt.rs"]
mod adopt;

/// What a finished write leaves of the newest requested value: forgotten when the device
/// refused it or the link was lost with it sent too many times in a row (the outcome then
/// says so); a write sent `attempts` times.
fn settle(
    slot: &mut WriteSlot,
    result: Result<(), WriteError>,
    attempts: u32,
) -> Result<(), WriteError> {
    match result {
        Ok(()) => {
            slot.lost_at_write = 0;
            slot.reached = true;
            Ok(())
        }
        // The link lost with the value sent, or a device that takes its reads but never
        // answers this value: not asked it again at every return.
        Err(e @ (WriteError::LinkDown(_) | WriteError::NoResponse(_))) if attempts > 0 => {
            slot.lost_at_write += 1;
            if slot.lost_at_write < LOST_AT_WRITE {
                return Err(e);
            }
            slot.latest = None;
            Err(match e {
                WriteError::LinkDown(fault) => WriteError::GaveUp(fault),
                WriteError::NoResponse(tx) => WriteError::Unanswered(tx),
                other => other,
            })
        }
        Err(e) => {
            if e.is_refusal() {
                slot.latest = None;
            }
            Err(e)
        }
    }
}

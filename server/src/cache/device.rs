//! One device: its profile, the latest sample of every field, its diagnostics, its
//! requested outputs and, for a simulated device, the memory that stands for the device.

mod reads;
pub(crate) use reads::Stamp;
mod writes;

use std::sync::{Arc, Mutex, RwLock};
use std::time::{Duration, SystemTime};

use tokio::sync::{Notify, watch};
use tokio::time::Instant;

use super::outputs::{Checked, Outputs, TakenWrite, WriteError};
use super::sample::{DeviceCode, Diagnostics, FieldError, Quality, Sample};
use super::slot::{Slot, SlotReceiver};
use super::{AccessError, lock};
use crate::codec::{CodecError, Value};
use crate::config::DeviceConfig;
use crate::profile::{Direction, Field, Profile, Protocol, RegisterKind};
use crate::write_log::{Origin, WriteLog};

/// The longest string a simulated STRING field holds (the IEC default STRING length).
pub(crate) const SIM_STRING_MAX: usize = 254;

/// One configured device: its profile, cached samples, diagnostics and requested outputs.
#[derive(Debug)]
pub struct Device {
    pub(crate) config: DeviceConfig,
    pub(crate) profile: Arc<Profile>,
    /// Shared with the device that replaces this one on a reload, for the fields both have.
    samples: Vec<Slot<Sample>>,
    diagnostics: Arc<watch::Sender<Diagnostics>>,
    outputs: Outputs,
    /// Whether the device is polled as it is, was replaced by a re-planned one, or removed.
    fate: watch::Sender<Fate>,
    /// Values of a simulated device's fields.
    sim: Option<Mutex<Vec<Value>>>,
    /// The link and slave id the device is polled with; a device declared at run time
    /// without them reports error 1 or 2 until it is declared again with them.
    binding: RwLock<Binding>,
    /// Wakes the task that owns the device (its link's task, or its simulator).
    wake: Mutex<Arc<Notify>>,
    /// Stops a simulated device's task when the device is removed.
    task: Mutex<Option<tokio_util::sync::CancellationToken>>,
    /// When its last I/O cycle ended, answered or not.
    last_cycle: Mutex<Option<tokio::time::Instant>>,
    /// Its link's progress, while it is a member of one.
    line: Mutex<Option<Arc<super::Progress>>>,
    /// Whether its link's task writes the newest requested outputs when it first polls it
    /// (a new device, or one a reload moved to another link or slave id); a device
    /// re-planned in place does not: its outputs were written already.
    rewrite_first: bool,
    /// Which device this is, as its fields' samples know it: a read is stored only into a
    /// sample that still belongs to the device (and so the place) it was read from.
    place: u64,
    /// Whether a stale spell may have been told of a good value since the source last
    /// vouched for its values ([`Device::vouch`] looks at the fields only then).
    stale_told: std::sync::atomic::AtomicBool,
}

/// Every device made gets the next place.
static PLACES: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);

/// What became of a device: the streams that follow it carry on with its successor's
/// fields, or end with the reason.
#[derive(Debug, Clone)]
pub(crate) enum Fate {
    Live,
    /// Re-planned by a configuration reload: this device carries on, sharing the values and
    /// subscribers of every field both have.
    Replaced(Arc<Device>),
    /// Removed, for this reason.
    Removed(&'static str),
}

/// Where a device is reached.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct Binding {
    pub(crate) link: Option<String>,
    pub(crate) slave_id: Option<u8>,
    /// Where it is on the link in its protocol's own keys (a BACnet device's instance).
    pub(crate) at: Vec<(&'static str, String)>,
}

impl Binding {
    /// The device's error code for this binding before its first answer: 1 or 2 for what is
    /// missing, else 10 (not responding yet), so `error_code` is 0 exactly when `connected`
    /// is true. A simulated device needs no binding and answers from the start.
    fn code(&self, protocol: Protocol) -> DeviceCode {
        let simulated = protocol == Protocol::Simulated;
        match (simulated, &self.link, self.slave_id) {
            (true, _, _) => DeviceCode::Ok,
            (false, None, _) => DeviceCode::NoLink,
            (false, _, None) if protocol.is_modbus() => DeviceCode::NoSlave,
            (false, Some(_), _) => DeviceCode::CommError,
        }
    }
}

impl Device {
    pub(crate) fn new(
        config: DeviceConfig,
        profile: Arc<Profile>,
        log: Arc<WriteLog>,
        wake: Arc<Notify>,
    ) -> Self {
        let n = profile.fields.len();
        let simulated = profile.protocol == Protocol::Simulated;
        let binding = Binding {
            link: config.link.clone(),
            slave_id: config.slave_id,
            at: config.at.clone(),
        };
        let error_code = binding.code(profile.protocol);
        let place = PLACES.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        // Resolved here, once: the device says what it will do before its link takes it in.
        let outputs = Outputs::new(n, log);
        outputs.set_rewrites(
            config
                .rewrite_outputs
                .map_or(profile.protocol.rewrites_outputs(), |r| {
                    r == crate::config::RewriteOutputs::OnReconnect
                }),
        );
        Device {
            samples: (0..n)
                .map(|_| {
                    Slot::new(Sample {
                        place,
                        ..Sample::never_read()
                    })
                })
                .collect(),
            diagnostics: Arc::new(watch::Sender::new(Diagnostics {
                connected: simulated,
                error_code,
                io_cycles: 0,
                last_response_ms: 0.0,
            })),
            outputs,
            fate: watch::Sender::new(Fate::Live),
            sim: simulated
                .then(|| Mutex::new(profile.fields.iter().map(|f| Value::zero(f.ty)).collect())),
            config,
            profile,
            binding: RwLock::new(binding),
            wake: Mutex::new(wake),
            task: Mutex::new(None),
            last_cycle: Mutex::new(None),
            line: Mutex::new(None),
            rewrite_first: true,
            place,
            stale_told: std::sync::atomic::AtomicBool::new(false),
        }
    }

    /// Which device this is, as its samples know it.
    pub(super) fn place(&self) -> u64 {
        self.place
    }

    /// Whether the newest requested outputs are written when the device is first polled.
    pub(crate) fn rewrite_first(&self) -> bool {
        self.rewrite_first
    }

    /// Marks every good value stale (its link is being reopened): it stays, and is good
    /// again when read again.
    pub(crate) fn mark_stale(&self) {
        for sample in &self.samples {
            sample.send_if_modified(|s| {
                let good = s.quality == Quality::Good;
                if good {
                    s.quality = Quality::Stale;
                    s.stale_told = true;
                }
                good
            });
        }
    }

    /// The device that carries on from `old` with another configuration or profile: every
    /// field of the same name and type keeps its value, quality, timestamp, subscribers and
    /// requested outputs (a write waiting for the bus is taken over, never lost or sent
    /// twice), the diagnostics go on; fields that are new start never read. `old` is not
    /// changed until [`Device::replaced_by`].
    pub(crate) fn succeed(
        old: &Device,
        config: DeviceConfig,
        profile: Arc<Profile>,
        log: Arc<WriteLog>,
        wake: Arc<Notify>,
    ) -> Self {
        let mut next = Device::new(config, profile, log, wake);
        let mut kept = Vec::new();
        // A device moved to another link or slave id is another device until it is read:
        // what the old place held is not served as its good value.
        let moved = next.binding() != old.binding() && !next.is_simulated();
        for (idx, field) in next.profile.fields.iter().enumerate() {
            if let Some(before) = old.kept_field(field) {
                next.samples[idx] = old.samples[before].clone();
                let same_registers = old.field(before).encoding == field.encoding
                    && old.field(before).register == field.register;
                let place = next.place;
                if moved || !same_registers {
                    next.samples[idx].send_modify(|s| {
                        *s = Sample {
                            retold: s.retold,
                            place,
                            ..Sample::never_read()
                        }
                    });
                } else {
                    // The old device's reads still on the way are not stored from now on
                    // (its place, or its registers, may no longer be this field's).
                    next.samples[idx].send_if_modified(|s| {
                        s.place = place;
                        false
                    });
                }
                kept.push((before, idx));
            }
        }
        if next.is_simulated() == old.is_simulated() {
            next.diagnostics = old.diagnostics.clone();
            let code = next.binding().code(next.profile.protocol);
            if next.binding() != old.binding() {
                next.diagnostics.send_if_modified(|d| {
                    let changed = d.connected != next.is_simulated() || d.error_code != code;
                    d.connected = next.is_simulated();
                    d.error_code = code;
                    changed
                });
            }
        }
        if let (Some(from), Some(to)) = (&old.sim, &next.sim) {
            let from = lock(from);
            let mut to = lock(to);
            for &(before, idx) in &kept {
                to[idx] = from[before].clone();
            }
        }
        next.outputs.take_over(&old.outputs, &kept, moved);
        // A device moved to another link or slave id is another device: nothing asked of the
        // old place is written to the new one on the gateway's own account.
        next.rewrite_first = false;
        *lock(&next.last_cycle) = *lock(&old.last_cycle);
        // The kept samples may have been told stale by the old device.
        *next.stale_told.get_mut() = true;
        next
    }

    /// The index of the field of this device that `field` of a successor keeps: the same
    /// name (ignoring case) and type.
    fn kept_field(&self, field: &Field) -> Option<usize> {
        self.profile
            .field_index(&field.name)
            .filter(|&i| self.field(i).ty == field.ty)
    }

    /// This device was replaced by `next` (a reload re-planned it): its own task stops, the
    /// writes it still held for removed fields fail, and whoever follows it moves to `next`.
    pub(crate) fn replaced_by(&self, next: Arc<Device>) {
        if let Some(token) = self.task.lock().unwrap_or_else(|e| e.into_inner()).take() {
            token.cancel();
        }
        for w in self.take_writes() {
            self.finish_write(w.generation, Err(WriteError::Removed));
        }
        self.fate.send_replace(Fate::Replaced(next));
    }

    /// Whether the device is live, replaced or removed; each change is seen by the receiver.
    pub(crate) fn watch_fate(&self) -> watch::Receiver<Fate> {
        self.fate.subscribe()
    }

    /// The device that is polled in this one's place now: itself, or the newest of the
    /// devices that replaced it.
    pub(crate) fn current(self: &Arc<Self>) -> Arc<Device> {
        let mut device = self.clone();
        loop {
            let next = match &*device.fate.borrow() {
                Fate::Replaced(next) => Some(next.clone()),
                Fate::Live | Fate::Removed(_) => None,
            };
            match next {
                Some(next) => device = next,
                None => return device,
            }
        }
    }

    /// Whether the device was removed (not replaced).
    pub(crate) fn is_removed(&self) -> bool {
        matches!(*self.fate.borrow(), Fate::Removed(_))
    }

    /// Field `idx` of this device in `next` (which replaced it), when `next` kept it.
    pub(crate) fn kept_in(&self, idx: usize, next: &Device) -> Option<usize> {
        next.samples.iter().position(|s| s.same(&self.samples[idx]))
    }

    /// Remembers the token that stops the device's own task (a simulated device's).
    pub(crate) fn attach_task(&self, token: tokio_util::sync::CancellationToken) {
        *self.task.lock().unwrap_or_else(|e| e.into_inner()) = Some(token);
    }

    /// The device was removed (`why`): its own task stops, the writes still waiting fail,
    /// and the streams that follow it end with the reason.
    pub(crate) fn retire(&self, why: &'static str) {
        if let Some(token) = self.task.lock().unwrap_or_else(|e| e.into_inner()).take() {
            token.cancel();
        }
        for w in self.take_writes() {
            self.finish_write(w.generation, Err(WriteError::Removed));
        }
        self.set_unreachable();
        self.fate.send_replace(Fate::Removed(why));
    }

    /// The link and slave id the device is polled with now.
    pub(crate) fn binding(&self) -> Binding {
        self.binding
            .read()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }

    pub(crate) fn slave_id(&self) -> Option<u8> {
        self.binding
            .read()
            .unwrap_or_else(|e| e.into_inner())
            .slave_id
    }

    /// Binds a device declared without a link or slave id; `wake` is its link's.
    pub(crate) fn bind(&self, binding: Binding, wake: Arc<Notify>) {
        let code = binding.code(self.profile.protocol);
        *self.binding.write().unwrap_or_else(|e| e.into_inner()) = binding;
        *lock(&self.wake) = wake;
        self.diagnostics.send_if_modified(|d| {
            let changed = d.error_code != code;
            d.error_code = code;
            changed
        });
    }

    pub(crate) fn name(&self) -> &str {
        &self.config.name
    }

    pub(crate) fn is_simulated(&self) -> bool {
        self.sim.is_some()
    }

    /// How long a value stays good without a refresh while its line is idle.
    pub(crate) fn stale_after(&self) -> Duration {
        (self.config.refresh_rate * 3 + self.config.timeout).max(Duration::from_secs(1))
    }

    pub(crate) fn set_line(&self, line: Arc<super::Progress>) {
        *lock(&self.line) = Some(line);
    }

    /// A sample's quality as of `now`. A good value not refreshed within `stale_after` is
    /// stale when nothing is being done about it: its link has done no transaction within
    /// that time either (down, reopening, stalled), or it has no link (a simulator). While
    /// the link works, the device's poll is queued behind others: the value is late, not
    /// stale (`starved` in the diagnostics says so), so a busy line does not turn its
    /// values stale and good again with every cycle. A stale spell that was told lasts
    /// until the next refresh, whatever the line does meanwhile.
    pub(crate) fn quality(&self, sample: &Sample, now: Instant) -> Quality {
        match sample.quality {
            Quality::Good if sample.stale_told => return Quality::Stale,
            Quality::Good => {}
            other => return other,
        }
        let stale_after = self.stale_after();
        match sample.quality_at(now, stale_after) {
            Quality::Stale
                if lock(&self.line)
                    .as_ref()
                    .is_some_and(|line| line.working(now, stale_after)) =>
            {
                Quality::Good
            }
            q => q,
        }
    }

    /// Whether the device answers but gets no line time: connected, and its last I/O cycle
    /// ended longer ago than its values take to go stale (its polls wait behind other
    /// traffic). A device that stopped answering is backed off on purpose, not starved.
    pub(crate) fn starved(&self, now: tokio::time::Instant) -> bool {
        let last = *lock(&self.last_cycle);
        self.diagnostics().connected
            && last.is_some_and(|at| now.saturating_duration_since(at) > self.stale_after())
    }

    /// A field index by name, ignoring case as IEC identifiers do.
    pub(crate) fn field_index(&self, name: &str) -> Result<usize, AccessError> {
        self.profile
            .field_index(name)
            .ok_or_else(|| AccessError::UnknownField {
                device: self.name().to_owned(),
                field: crate::text::quote(name),
            })
    }

    pub(crate) fn field(&self, idx: usize) -> &Field {
        &self.profile.fields[idx]
    }

    pub(crate) fn sample(&self, idx: usize) -> Sample {
        self.samples[idx].borrow().clone()
    }

    pub(crate) fn subscribe(&self, idx: usize) -> SlotReceiver<Sample> {
        self.samples[idx].subscribe()
    }

    pub(crate) fn diagnostics(&self) -> Diagnostics {
        self.diagnostics.borrow().clone()
    }

    /// Whether `other` (a successor) keeps this device's diagnostics.
    pub(crate) fn shares_diagnostics(&self, other: &Device) -> bool {
        Arc::ptr_eq(&self.diagnostics, &other.diagnostics)
    }

    pub(crate) fn subscribe_diagnostics(&self) -> watch::Receiver<Diagnostics> {
        self.diagnostics.subscribe()
    }

    /// Records the end of an I/O cycle. Subscribers are woken when `connected` or
    /// `error_code` change, not on every cycle.
    pub(crate) fn record_cycle(&self, ok: bool, response: Duration) {
        *lock(&self.last_cycle) = Some(tokio::time::Instant::now());
        self.diagnostics.send_if_modified(|d| {
            let before = (d.connected, d.error_code);
            d.connected = ok;
            d.error_code = if ok {
                DeviceCode::Ok
            } else {
                DeviceCode::CommError
            };
            if ok {
                d.io_cycles += 1;
            }
            d.last_response_ms = (response.as_secs_f64() * 1e6).round() / 1000.0;
            before != (d.connected, d.error_code)
        });
    }

    /// Records that the device could not be reached at all (its link is down).
    pub(crate) fn set_unreachable(&self) {
        self.diagnostics.send_if_modified(|d| {
            let changed = d.connected || d.error_code != DeviceCode::CommError;
            d.connected = false;
            d.error_code = DeviceCode::CommError;
            changed
        });
    }

    /// Sets an input (or inout) of a simulated device; it shows on the next cycle.
    pub(crate) fn simulate(&self, idx: usize, value: Value) -> Result<(), AccessError> {
        let Some(memory) = &self.sim else {
            return Err(AccessError::NotSimulated(self.name().to_owned()));
        };
        let field = self.field(idx);
        if field.direction == Direction::Output {
            return Err(AccessError::NotAnInput {
                device: self.name().to_owned(),
                field: field.name.clone(),
            });
        }
        self.check_value(idx, &value)?;
        lock(memory)[idx] = value;
        Ok(())
    }

    /// The values a simulated device holds now (applying `writes` first).
    pub(crate) fn sim_cycle(&self, writes: &[TakenWrite]) -> Option<Vec<Value>> {
        let memory = self.sim.as_ref()?;
        let mut memory = lock(memory);
        // A relinquish is refused before it is requested: a simulated device has none.
        for w in writes {
            if let Some(value) = &w.value {
                memory[w.field] = value.clone();
            }
        }
        Some(memory.clone())
    }
}

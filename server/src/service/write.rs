//! Writes: checked first, then requested (last value wins); several at once are all or
//! nothing; each is followed by its generation; a scan cycle writes only what changed.

use std::sync::Arc;

use super::{Service, ServiceError};
use crate::cache::{AccessError, Checked, Device};
use crate::codec::{CodecError, IecType, Value};
use crate::profile::Direction;
use crate::write_log::{FIELD_HISTORY, Lookup, WriteRecord};

/// A write that passed every check and can be requested: only [`Service::prepare`] makes
/// one, and it carries the proof of its check (with the registers the value becomes), so
/// nothing downstream checks or encodes it again.
#[derive(Debug, Clone)]
pub(crate) struct Prepared {
    device: Arc<Device>,
    checked: Checked,
}

impl Prepared {
    pub(crate) fn idx(&self) -> usize {
        self.checked.idx()
    }

    /// The value; `None` for a relinquish.
    pub(crate) fn value(&self) -> Option<&Value> {
        self.checked.value()
    }
}

/// A requested write: follow it by its generation.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Accepted {
    pub(crate) device: String,
    pub(crate) field: String,
    pub(crate) generation: u64,
}

/// Field `idx` of `device` refused by its protocol, in the driver's words.
fn refused(device: &Device, idx: usize, why: String) -> AccessError {
    let f = device.field(idx);
    AccessError::InvalidValue {
        device: device.name().to_owned(),
        field: f.name.clone(),
        ty: f.ty,
        reason: Box::new(CodecError::Protocol(why)),
    }
}

/// Field `field` of `device` and the value `convert` makes for its type.
fn typed<E: Into<CodecError>>(
    device: &Device,
    field: &str,
    convert: impl FnOnce(IecType) -> Result<Value, E>,
) -> Result<(usize, Value), AccessError> {
    let idx = device.field_index(field)?;
    let f = device.field(idx);
    let value = convert(f.ty).map_err(|e| AccessError::InvalidValue {
        device: device.name().to_owned(),
        field: f.name.clone(),
        ty: f.ty,
        reason: Box::new(e.into()),
    })?;
    Ok((idx, value))
}

impl Service {
    /// Checks a write of field `field` of `device`: the field exists and is writable, and
    /// the value (converted by the front-end's `convert` for the field's type) fits it.
    /// Nothing is written.
    pub(crate) fn prepare<E: Into<CodecError>>(
        &self,
        device: &Arc<Device>,
        field: &str,
        convert: impl FnOnce(IecType) -> Result<Value, E>,
    ) -> Result<Prepared, AccessError> {
        let (idx, value) = typed(device, field, convert)?;
        let checked = device.check_write(idx, value)?;
        // What the device's protocol cannot hold there is refused now, not after sending.
        if let Some(value) = checked.value() {
            crate::drivers::check_value(device, idx, value)
                .map_err(|why| refused(device, idx, why))?;
        }
        Ok(Prepared {
            device: device.clone(),
            checked,
        })
    }

    /// Checks a relinquish of field `field` of `device` (a write of no value, JSON
    /// `null`): the field exists and is writable, and its protocol has a relinquish.
    pub(crate) fn prepare_relinquish(
        &self,
        device: &Arc<Device>,
        field: &str,
    ) -> Result<Prepared, AccessError> {
        let idx = device.field_index(field)?;
        let checked = device.check_relinquish(idx)?;
        crate::drivers::check_relinquish(device, idx).map_err(|why| refused(device, idx, why))?;
        Ok(Prepared {
            device: device.clone(),
            checked,
        })
    }

    /// Like [`Service::prepare`] for a device given by name, or a field given by its
    /// located address.
    pub(crate) fn prepare_named<E: Into<CodecError>>(
        &self,
        device: &str,
        field: &str,
        convert: impl FnOnce(IecType) -> Result<Value, E>,
    ) -> Result<Prepared, ServiceError> {
        let (device, idx) = self.field(device, field)?;
        let name = device.field(idx).name.clone();
        Ok(self.prepare(&device, &name, convert)?)
    }

    /// Like [`Service::prepare_relinquish`] for a device given by name, or a field given by
    /// its located address; refused when a value was given too (`with_value`).
    pub(crate) fn prepare_relinquish_named(
        &self,
        device: &str,
        field: &str,
        with_value: bool,
    ) -> Result<Prepared, ServiceError> {
        let (device, idx) = self.field(device, field)?;
        if with_value {
            let f = device.field(idx);
            return Err(refused(
                &device,
                idx,
                format!(
                    "{}: a relinquish carries no value; leave value unset",
                    f.name
                ),
            )
            .into());
        }
        let name = device.field(idx).name.clone();
        Ok(self.prepare_relinquish(&device, &name)?)
    }

    /// Requests one checked write.
    pub(crate) fn write(&self, write: Prepared) -> Result<Accepted, ServiceError> {
        self.write_as(write, None)
    }

    /// As [`Service::write`], by the scan-cycle stream `writer` when one asks.
    pub(crate) fn write_as(
        &self,
        write: Prepared,
        writer: Option<u64>,
    ) -> Result<Accepted, ServiceError> {
        let mut accepted = self.request_group(vec![write], writer)?;
        accepted.pop().ok_or(ServiceError::ShuttingDown)
    }

    /// Requests every write, or none of them if any was refused; then every refusal is
    /// named.
    pub(crate) fn write_all<E: Into<ServiceError>>(
        &self,
        writes: Vec<Result<Prepared, E>>,
    ) -> Result<Vec<Accepted>, ServiceError> {
        self.accepting_writes()?;
        let (ok, refused): (Vec<_>, Vec<_>) = writes.into_iter().partition(Result::is_ok);
        if !refused.is_empty() {
            let refused: Vec<ServiceError> = refused
                .into_iter()
                .filter_map(Result::err)
                .map(Into::into)
                .collect();
            // Refusals that are not about a name or a value (a located address that is
            // bound to nothing, say) stand alone.
            let mut access = Vec::new();
            for e in refused {
                match e {
                    ServiceError::Access(a) => access.push(a),
                    other => return Err(other),
                }
            }
            return Err(ServiceError::NothingWritten(access));
        }
        self.request_group(ok.into_iter().filter_map(Result::ok).collect(), None)
    }

    /// Requests checked writes as one: those of one device together, so its task takes
    /// them in one go and plans them as one write group. Answers in the order given.
    fn request_group(
        &self,
        writes: Vec<Prepared>,
        writer: Option<u64>,
    ) -> Result<Vec<Accepted>, ServiceError> {
        self.accepting_writes()?;
        // Devices in the order they first appear; each with its writes (position, proof).
        type Group = (Arc<Device>, Vec<(usize, Checked)>);
        let mut groups: Vec<Group> = Vec::new();
        for (at, w) in writes.into_iter().enumerate() {
            match groups.iter_mut().find(|(d, _)| Arc::ptr_eq(d, &w.device)) {
                Some((_, items)) => items.push((at, w.checked)),
                None => groups.push((w.device, vec![(at, w.checked)])),
            }
        }
        let mut accepted: Vec<(usize, Accepted)> = Vec::new();
        for (device, items) in groups {
            let positions: Vec<(usize, String)> = items
                .iter()
                .map(|(at, c)| (*at, device.field(c.idx()).name.clone()))
                .collect();
            let checked = items.into_iter().map(|(_, checked)| checked).collect();
            let generations = Self::request_on_current(device.clone(), checked, writer)?;
            for ((at, field), generation) in positions.into_iter().zip(generations) {
                accepted.push((
                    at,
                    Accepted {
                        device: device.name().to_owned(),
                        field,
                        generation,
                    },
                ));
            }
        }
        accepted.sort_by_key(|(at, _)| *at);
        Ok(accepted.into_iter().map(|(_, a)| a).collect())
    }

    /// Requests checked writes of `device`; when a reload replaced the device meanwhile,
    /// each value is checked again against its successor's field of the same name and
    /// requested there (a removed device or field refuses the write).
    fn request_on_current(
        mut device: Arc<Device>,
        mut checked: Vec<Checked>,
        writer: Option<u64>,
    ) -> Result<Vec<u64>, ServiceError> {
        loop {
            if device.is_removed() {
                return Err(AccessError::UnknownDevice(device.name().to_owned()).into());
            }
            match device.request_writes(checked, writer) {
                Ok(generations) => return Ok(generations),
                Err(back) => {
                    let next = device.current();
                    checked = back
                        .into_iter()
                        .map(|c| {
                            let name = device.field(c.idx()).name.clone();
                            let idx = next.field_index(&name)?;
                            match c.value() {
                                Some(value) => next.check_write(idx, value.clone()),
                                None => next.check_relinquish(idx),
                            }
                        })
                        .collect::<Result<_, AccessError>>()?;
                    device = next;
                }
            }
        }
    }

    /// Where the write with `generation` stands.
    pub(crate) fn write_outcome(&self, generation: u64) -> Result<WriteRecord, ServiceError> {
        match self.cache.writes.get(generation) {
            Lookup::Found(record) => Ok(record),
            Lookup::Expired => Err(ServiceError::WriteExpired {
                generation,
                kept: FIELD_HISTORY,
            }),
            Lookup::Unknown => Err(ServiceError::UnknownWrite(generation)),
        }
    }

    /// The type of the field a write record is about, if the field still exists.
    pub(crate) fn written_type(&self, record: &WriteRecord) -> Option<IecType> {
        let device = self.cache.device(&record.device).ok()?;
        let idx = device.profile.field_index(&record.field)?;
        Some(device.field(idx).ty)
    }

    /// A scan-cycle stream ended: for every device with `on_client_loss`, the safe value of
    /// each such output the stream wrote last is written once `after` has passed, unless
    /// somebody wrote the output meanwhile.
    pub(crate) fn client_lost(&self, stream: u64) {
        for device in self.cache.devices() {
            let Some(loss) = device.config.on_client_loss.clone() else {
                continue;
            };
            let safe: Vec<(usize, crate::codec::Value)> = loss
                .safe
                .iter()
                .filter_map(|(field, text)| {
                    crate::config::safe_value(&device.profile, field, text).ok()
                })
                .filter(|(idx, _)| device.outputs().writer(*idx) == Some(stream))
                .collect();
            if safe.is_empty() {
                continue;
            }
            tracing::info!(device = %device.name(), after = ?loss.after, "scan-cycle client gone; its outputs get their safe values unless it returns");
            let token = self.tasks.token().clone();
            let metrics = self.tasks.metrics().clone();
            self.tasks.spawn(async move {
                tokio::select! {
                    _ = token.cancelled() => return,
                    _ = tokio::time::sleep(loss.after) => {}
                }
                for (idx, value) in safe {
                    if device.outputs().writer(idx) != Some(stream) {
                        continue; // written since: that writer's value stands
                    }
                    let field = device.field(idx).name.clone();
                    tracing::warn!(device = %device.name(), field = %field, value = %value, "client lost: writing the safe value");
                    device.request_own(idx, value, crate::write_log::Origin::Safety);
                    metrics.safe_value_written(device.name());
                }
            });
        }
    }

    /// The newest write to a field, if one is still in the log.
    pub(crate) fn last_write(&self, device: &Device, idx: usize) -> Option<WriteRecord> {
        match self.cache.writes.get(device.last_write(idx)?) {
            Lookup::Found(record) => Some(record),
            _ => None,
        }
    }

    /// Sets an input of a simulated device, as if the device had read it.
    pub(crate) fn simulate<E: Into<CodecError>>(
        &self,
        device: &Arc<Device>,
        field: &str,
        convert: impl FnOnce(IecType) -> Result<Value, E>,
    ) -> Result<(usize, Value), ServiceError> {
        self.accepting_writes()?;
        let (idx, value) = typed(device, field, convert)?;
        device.simulate(idx, value.clone())?;
        Ok((idx, value))
    }
}

/// A remote runtime's scan cycles on one stream: outputs in, inputs and diagnostics out.
#[derive(Debug)]
pub(crate) struct ScanCycle {
    service: Arc<Service>,
    devices: Vec<Arc<Device>>,
    cycle: u64,
    /// This stream, as the writer of the outputs it requests.
    id: u64,
}

/// Numbers scan-cycle streams.
static NEXT_STREAM: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);

impl Drop for ScanCycle {
    /// The stream is gone: outputs with an `on_client_loss` safe value that it wrote last
    /// get their safe value once the device's `after` has passed.
    fn drop(&mut self) {
        self.service.client_lost(self.id);
    }
}

/// What one cycle did: its number, the devices whose inputs go back, the writes it
/// requested, and what it refused (as messages for the runtime).
#[derive(Debug)]
pub(crate) struct CycleOutcome {
    pub(crate) cycle: u64,
    pub(crate) devices: Vec<Arc<Device>>,
    pub(crate) acks: Vec<Accepted>,
    pub(crate) errors: Vec<String>,
}

impl CycleOutcome {
    /// The inputs (and inouts) of the cycle's devices.
    pub(crate) fn inputs(&self) -> impl Iterator<Item = (&Arc<Device>, usize)> {
        self.devices.iter().flat_map(|d| {
            (0..d.profile.fields.len())
                .filter(|&i| d.field(i).direction != Direction::Output)
                .map(move |i| (d, i))
        })
    }
}

impl ScanCycle {
    pub(crate) fn new(service: Arc<Service>) -> Self {
        ScanCycle {
            service,
            devices: Vec::new(),
            cycle: 0,
            id: NEXT_STREAM.fetch_add(1, std::sync::atomic::Ordering::Relaxed),
        }
    }

    /// One cycle. `devices`, when not empty, replaces the devices whose inputs are
    /// returned. An output equal to the newest value already requested for its field is
    /// not written again: a runtime sends all its outputs every cycle, and only changes
    /// become bus writes. Such an output the device holds another value in is named in the
    /// cycle's errors (a failed write, a device that changed it), and is written again by
    /// the device's `write_mode: reconcile`.
    /// Whether `w` is what its field was last asked: the same value as the newest requested,
    /// or a relinquish after a relinquish (a runtime that relinquishes an output every cycle
    /// sends the device one NULL, not one a cycle).
    fn requested_already(&self, w: &Prepared) -> bool {
        match w.value() {
            Some(v) => w.device.latest_value(w.idx()).as_ref() == Some(v),
            None => self
                .service
                .last_write(&w.device, w.idx())
                .is_some_and(|r| r.value.is_none()),
        }
    }

    pub(crate) fn step(
        &mut self,
        devices: &[String],
        outputs: Vec<Result<Prepared, ServiceError>>,
    ) -> CycleOutcome {
        let mut errors = Vec::new();
        if !devices.is_empty() {
            self.devices.clear();
            for name in devices {
                match self.service.cache.device(name) {
                    Ok(d) => self.devices.push(d),
                    Err(e) => errors.push(e.to_string()),
                }
            }
        }
        let mut changed = Vec::new();
        for out in outputs {
            match out {
                Ok(w) if self.requested_already(&w) => {
                    if w.device.mismatch(w.idx()).is_some() {
                        let actual = w.device.sample(w.idx()).value;
                        errors.push(format!(
                            "{}.{}: the device holds {}, not the requested {}{}",
                            w.device.name(),
                            w.device.field(w.idx()).name,
                            actual.map_or_else(|| "nothing".to_owned(), |v| v.to_string()),
                            w.value().map(ToString::to_string).unwrap_or_default(),
                            self.service
                                .last_write(&w.device, w.idx())
                                .and_then(|r| r.error.map(|e| format!(" (last write: {e})")))
                                .unwrap_or_default()
                        ));
                    }
                }
                Ok(w) => changed.push(w),
                Err(e) => errors.push(e.to_string()),
            }
        }
        // The cycle's changed outputs as one request: one write group per device.
        let acks = match self.service.request_group(changed, Some(self.id)) {
            Ok(acks) => acks,
            Err(e) => {
                errors.push(e.to_string());
                Vec::new()
            }
        };
        self.cycle += 1;
        CycleOutcome {
            cycle: self.cycle,
            devices: self.devices.clone(),
            acks,
            errors,
        }
    }
}

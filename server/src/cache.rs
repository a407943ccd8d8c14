//! The latest value of every field, the diagnostics of every device and link, and the
//! pending writes. Reads from every API are served from here, never from the bus.
//!
//! Each field has a `watch` channel: readers take the newest sample without locking the
//! writer out, and subscribers are woken only when the value or its quality changes, so a
//! slow subscriber sees the newest value rather than a backlog.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, RwLock, RwLockReadGuard, RwLockWriteGuard};
use std::time::{Duration, SystemTime};

use tokio::sync::{Notify, watch};
use tokio::time::Instant;

use crate::codec::{CodecError, IecType, Value};
use crate::config::{Config, DeviceConfig, LinkConfig};
use crate::profile::{Catalog, Field, Profile, Protocol, RegisterKind};
use crate::writes::{WriteLog, WriteStatus};

/// The longest string a simulated STRING field holds (the IEC default STRING length).
pub const SIM_STRING_MAX: usize = 254;

pub use iogate_types::Quality;

/// A field's latest value.
#[derive(Debug, Clone, PartialEq)]
pub struct Sample {
    /// The last good value; kept (and marked) when later reads fail.
    pub value: Option<Value>,
    pub quality: Quality,
    /// Why the quality is bad.
    pub error: Option<String>,
    /// When the value was last refreshed.
    pub updated: Option<(Instant, SystemTime)>,
}

impl Sample {
    fn never_read() -> Self {
        Sample {
            value: None,
            quality: Quality::NeverRead,
            error: None,
            updated: None,
        }
    }

    /// The quality as of `now`: a good value not refreshed within `stale_after` is stale.
    pub fn quality_at(&self, now: Instant, stale_after: Duration) -> Quality {
        match (self.quality, self.updated) {
            (Quality::Good, Some((at, _))) if now.saturating_duration_since(at) > stale_after => {
                Quality::Stale
            }
            (q, _) => q,
        }
    }
}

/// Device diagnostics, as the seed's device function blocks report them.
#[derive(Debug, Clone, PartialEq)]
pub struct Diagnostics {
    pub connected: bool,
    /// 0 OK, 1 no link, 2 no slave, 10 communication error.
    pub error_code: i16,
    pub io_cycles: u64,
    pub last_response_ms: f64,
}

pub const DEVICE_OK: i16 = 0;
pub const DEVICE_NO_LINK: i16 = 1;
pub const DEVICE_NO_SLAVE: i16 = 2;
pub const DEVICE_COMM_ERROR: i16 = 10;

/// Link diagnostics, as the seed's `SerialLink` reports them.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LinkDiagnostics {
    pub connected: bool,
    /// 0 OK, 1 no port configured, 2 open failed, 3 port lost.
    pub error_code: i16,
}

/// Why an API request on the cache cannot be served.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AccessError {
    #[error("unknown device `{0}`")]
    UnknownDevice(String),
    #[error("device {device} has no field `{field}`")]
    UnknownField { device: String, field: String },
    #[error("unknown link `{0}`")]
    UnknownLink(String),
    #[error("unknown profile `{0}`")]
    UnknownProfile(String),
    #[error("field {device}.{field} is an input: it cannot be written")]
    NotWritable { device: String, field: String },
    #[error("field {device}.{field} is an output: its value is what clients write")]
    NotAnInput { device: String, field: String },
    #[error("device {0} is not simulated")]
    NotSimulated(String),
    #[error("field {device}.{field} ({ty}): {reason}")]
    InvalidValue {
        device: String,
        field: String,
        ty: IecType,
        reason: String,
    },
}

/// A write taken by the device's task to put on the bus.
#[derive(Debug, Clone, PartialEq)]
pub struct TakenWrite {
    pub field: usize,
    pub generation: u64,
    pub value: Value,
}

#[derive(Debug, Default)]
struct WriteSlot {
    /// The newest requested value not yet taken by the link.
    pending: Option<(u64, Value)>,
    /// The newest value ever requested, written again after a reconnect.
    latest: Option<Value>,
    /// The generation of the newest write.
    last_generation: Option<u64>,
}

/// One configured device: its profile, cached samples, diagnostics and pending writes.
#[derive(Debug)]
pub struct Device {
    pub config: DeviceConfig,
    pub profile: Arc<Profile>,
    samples: Vec<watch::Sender<Sample>>,
    diagnostics: watch::Sender<Diagnostics>,
    writes: Mutex<Vec<WriteSlot>>,
    /// Values of a simulated device's fields.
    sim: Option<Mutex<Vec<Value>>>,
    log: Arc<WriteLog>,
    /// Wakes the task that owns the device (its link's task, or its simulator).
    wake: Arc<Notify>,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // Sections under these locks are single assignments; a poisoned lock holds whole values.
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl Device {
    pub fn new(
        config: DeviceConfig,
        profile: Arc<Profile>,
        log: Arc<WriteLog>,
        wake: Arc<Notify>,
    ) -> Self {
        let n = profile.fields.len();
        let simulated = profile.protocol == Protocol::Simulated;
        let error_code = match (simulated, &config.link, config.slave_id) {
            (false, None, _) => DEVICE_NO_LINK,
            (false, _, None) => DEVICE_NO_SLAVE,
            _ => DEVICE_OK,
        };
        Device {
            samples: (0..n)
                .map(|_| watch::Sender::new(Sample::never_read()))
                .collect(),
            diagnostics: watch::Sender::new(Diagnostics {
                connected: false,
                error_code,
                io_cycles: 0,
                last_response_ms: 0.0,
            }),
            writes: Mutex::new((0..n).map(|_| WriteSlot::default()).collect()),
            sim: simulated
                .then(|| Mutex::new(profile.fields.iter().map(|f| Value::zero(f.ty)).collect())),
            config,
            profile,
            log,
            wake,
        }
    }

    pub fn name(&self) -> &str {
        &self.config.name
    }

    pub fn is_simulated(&self) -> bool {
        self.sim.is_some()
    }

    /// How long a value stays good without a refresh.
    pub fn stale_after(&self) -> Duration {
        (self.config.refresh_rate * 3 + self.config.timeout).max(Duration::from_secs(1))
    }

    /// A field index by name, ignoring case as IEC identifiers do.
    pub fn field_index(&self, name: &str) -> Result<usize, AccessError> {
        self.profile
            .field_index(name)
            .ok_or_else(|| AccessError::UnknownField {
                device: self.name().to_owned(),
                field: name.to_owned(),
            })
    }

    pub fn field(&self, idx: usize) -> &Field {
        &self.profile.fields[idx]
    }

    pub fn sample(&self, idx: usize) -> Sample {
        self.samples[idx].borrow().clone()
    }

    pub fn subscribe(&self, idx: usize) -> watch::Receiver<Sample> {
        self.samples[idx].subscribe()
    }

    pub fn diagnostics(&self) -> Diagnostics {
        self.diagnostics.borrow().clone()
    }

    pub fn subscribe_diagnostics(&self) -> watch::Receiver<Diagnostics> {
        self.diagnostics.subscribe()
    }

    /// Stores a freshly read value (or why it could not be read). Subscribers are woken only
    /// when the value or its quality changes.
    pub fn publish(&self, idx: usize, read: Result<Value, String>) {
        let now = (Instant::now(), SystemTime::now());
        self.samples[idx].send_if_modified(|s| {
            let before = (s.value.clone(), s.quality);
            match read {
                Ok(v) => {
                    s.value = Some(v);
                    s.quality = Quality::Good;
                    s.error = None;
                }
                Err(e) => {
                    s.quality = Quality::Bad;
                    s.error = Some(e);
                }
            }
            s.updated = Some(now);
            before != (s.value.clone(), s.quality)
        });
    }

    /// Records the end of an I/O cycle. Subscribers are woken when `connected` or
    /// `error_code` change, not on every cycle.
    pub fn record_cycle(&self, ok: bool, response: Duration) {
        self.diagnostics.send_if_modified(|d| {
            let before = (d.connected, d.error_code);
            d.connected = ok;
            d.error_code = if ok { DEVICE_OK } else { DEVICE_COMM_ERROR };
            if ok {
                d.io_cycles += 1;
            }
            d.last_response_ms = (response.as_secs_f64() * 1e6).round() / 1000.0;
            before != (d.connected, d.error_code)
        });
    }

    /// Checks that `value` can be written to field `idx`: the field is writable and the value
    /// fits the field's type and raw register after scaling.
    pub fn check_write(&self, idx: usize, value: &Value) -> Result<(), AccessError> {
        let field = self.field(idx);
        if !field.direction.is_writable() {
            return Err(AccessError::NotWritable {
                device: self.name().to_owned(),
                field: field.name.clone(),
            });
        }
        self.check_value(idx, value)
    }

    fn check_value(&self, idx: usize, value: &Value) -> Result<(), AccessError> {
        let field = self.field(idx);
        let invalid = |reason: String| AccessError::InvalidValue {
            device: self.name().to_owned(),
            field: field.name.clone(),
            ty: field.ty,
            reason,
        };
        if !value.is_of(field.ty) {
            return Err(invalid(format!("a {} value is needed", field.ty)));
        }
        if self.is_simulated() || field.register.kind == RegisterKind::Virtual {
            if let Value::String(s) = value
                && s.len() > SIM_STRING_MAX
            {
                return Err(invalid(
                    CodecError::TooLong {
                        len: s.len(),
                        max: SIM_STRING_MAX,
                    }
                    .to_string(),
                ));
            }
            return Ok(());
        }
        field
            .encoding
            .encode(value)
            .map(drop)
            .map_err(|e| invalid(e.to_string()))
    }

    /// Requests a write: the newest value replaces any pending one (which is then
    /// superseded). Returns the write's generation.
    pub fn request_write(&self, idx: usize, value: Value) -> Result<u64, AccessError> {
        self.check_write(idx, &value)?;
        let generation = {
            let mut slots = lock(&self.writes);
            let slot = &mut slots[idx];
            let generation = self
                .log
                .begin(self.name(), &self.field(idx).name, value.clone());
            if let Some((old, _)) = slot.pending.replace((generation, value.clone())) {
                self.log.finish(old, WriteStatus::Superseded, None);
            }
            slot.latest = Some(value);
            slot.last_generation = Some(generation);
            generation
        };
        self.wake.notify_one();
        Ok(generation)
    }

    /// Takes every pending write, for the device's task to put on the bus.
    pub fn take_writes(&self) -> Vec<TakenWrite> {
        let mut slots = lock(&self.writes);
        slots
            .iter_mut()
            .enumerate()
            .filter_map(|(field, slot)| {
                slot.pending.take().map(|(generation, value)| TakenWrite {
                    field,
                    generation,
                    value,
                })
            })
            .collect()
    }

    /// The newest value requested for field `idx`.
    pub fn latest_value(&self, idx: usize) -> Option<Value> {
        lock(&self.writes)[idx].latest.clone()
    }

    /// The generation of the newest write to field `idx`.
    pub fn last_write(&self, idx: usize) -> Option<u64> {
        lock(&self.writes)[idx].last_generation
    }

    /// Whether any write is waiting.
    pub fn has_pending_writes(&self) -> bool {
        lock(&self.writes).iter().any(|s| s.pending.is_some())
    }

    /// The newest value requested for each output, for writing again after a reconnect.
    pub fn latest_requested(&self) -> Vec<(usize, Value)> {
        lock(&self.writes)
            .iter()
            .enumerate()
            .filter_map(|(i, s)| s.latest.clone().map(|v| (i, v)))
            .collect()
    }

    /// Reports the outcome of a taken write.
    pub fn finish_write(&self, generation: u64, result: Result<(), String>) {
        match result {
            Ok(()) => self.log.finish(generation, WriteStatus::Written, None),
            Err(e) => self.log.finish(generation, WriteStatus::Failed, Some(e)),
        }
    }

    /// Whether any value was ever requested for an output.
    pub fn has_requested_values(&self) -> bool {
        lock(&self.writes).iter().any(|s| s.latest.is_some())
    }

    /// Marks every field read from the bus as bad, keeping the last good values.
    pub fn fail_reads(&self, reason: &str) {
        for (idx, field) in self.profile.fields.iter().enumerate() {
            if field.register.kind != RegisterKind::Virtual {
                self.publish(idx, Err(reason.to_owned()));
            }
        }
    }

    /// Records that the device could not be reached at all (its link is down).
    pub fn set_unreachable(&self) {
        self.diagnostics.send_if_modified(|d| {
            let changed = d.connected || d.error_code != DEVICE_COMM_ERROR;
            d.connected = false;
            d.error_code = DEVICE_COMM_ERROR;
            changed
        });
    }

    /// Sets an input (or inout) of a simulated device; it shows on the next cycle.
    pub fn simulate(&self, idx: usize, value: Value) -> Result<(), AccessError> {
        let Some(memory) = &self.sim else {
            return Err(AccessError::NotSimulated(self.name().to_owned()));
        };
        let field = self.field(idx);
        if field.direction == crate::profile::Direction::Output {
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
        for w in writes {
            memory[w.field] = w.value.clone();
        }
        Some(memory.clone())
    }
}

/// A link, its diagnostics and the devices on it.
#[derive(Debug)]
pub struct Link {
    pub config: LinkConfig,
    diagnostics: watch::Sender<LinkDiagnostics>,
    /// Wakes the link's task when a write to one of its devices is requested, or a device
    /// is added.
    pub wake: Arc<Notify>,
    members: RwLock<Vec<Arc<Device>>>,
    /// Counts changes of `members`, so the link's task notices new devices.
    version: AtomicU64,
}

impl Link {
    pub fn new(config: LinkConfig) -> Self {
        Link {
            wake: Arc::new(Notify::new()),
            config,
            diagnostics: watch::Sender::new(LinkDiagnostics {
                connected: false,
                error_code: 0,
            }),
            members: RwLock::new(Vec::new()),
            version: AtomicU64::new(0),
        }
    }

    pub fn name(&self) -> &str {
        &self.config.name
    }

    pub fn diagnostics(&self) -> LinkDiagnostics {
        self.diagnostics.borrow().clone()
    }

    pub fn set_diagnostics(&self, diagnostics: LinkDiagnostics) {
        self.diagnostics.send_if_modified(|d| {
            let changed = *d != diagnostics;
            *d = diagnostics;
            changed
        });
    }

    /// The devices on the link, in the order they were added.
    pub fn members(&self) -> Vec<Arc<Device>> {
        read(&self.members).clone()
    }

    pub fn version(&self) -> u64 {
        self.version.load(Ordering::Acquire)
    }

    fn add_member(&self, device: Arc<Device>) {
        write(&self.members).push(device);
        self.version.fetch_add(1, Ordering::AcqRel);
        self.wake.notify_one();
    }
}

fn read<T>(l: &RwLock<T>) -> RwLockReadGuard<'_, T> {
    l.read().unwrap_or_else(|e| e.into_inner())
}

fn write<T>(l: &RwLock<T>) -> RwLockWriteGuard<'_, T> {
    l.write().unwrap_or_else(|e| e.into_inner())
}

#[derive(Debug, Default)]
pub(crate) struct Registry {
    pub(crate) links: Vec<Arc<Link>>,
    pub(crate) devices: Vec<Arc<Device>>,
}

impl Registry {
    pub(crate) fn device(&self, name: &str) -> Option<&Arc<Device>> {
        self.devices.iter().find(|d| d.name() == name)
    }

    pub(crate) fn link(&self, name: &str) -> Option<&Arc<Link>> {
        self.links.iter().find(|l| l.name() == name)
    }
}

/// Everything the APIs read: profiles, links, devices, write outcomes. Links and devices
/// come from the config and can be added at run time (`EnsureLink`, `EnsureDevice`).
#[derive(Debug)]
pub struct Cache {
    pub catalog: Catalog,
    pub writes: Arc<WriteLog>,
    registry: RwLock<Registry>,
}

impl Cache {
    /// Builds the cache for a config whose devices were checked against `catalog`.
    pub fn new(config: &Config, catalog: Catalog) -> Self {
        let cache = Cache {
            catalog,
            writes: Arc::new(WriteLog::default()),
            registry: RwLock::new(Registry::default()),
        };
        {
            let mut registry = write(&cache.registry);
            for l in &config.links {
                cache.insert_link(&mut registry, l.clone());
            }
            for d in &config.devices {
                if let Some(profile) = cache.catalog.get(&d.profile).cloned() {
                    cache.insert_device(&mut registry, d.clone(), profile);
                }
            }
        }
        cache
    }

    pub(crate) fn insert_link(&self, registry: &mut Registry, config: LinkConfig) -> Arc<Link> {
        let link = Arc::new(Link::new(config));
        registry.links.push(link.clone());
        link
    }

    pub(crate) fn insert_device(
        &self,
        registry: &mut Registry,
        config: DeviceConfig,
        profile: Arc<Profile>,
    ) -> Arc<Device> {
        let link = config
            .link
            .as_ref()
            .and_then(|name| registry.link(name))
            .cloned();
        let wake = link
            .as_ref()
            .map_or_else(|| Arc::new(Notify::new()), |l| l.wake.clone());
        let device = Arc::new(Device::new(config, profile, self.writes.clone(), wake));
        registry.devices.push(device.clone());
        if let Some(link) = link {
            link.add_member(device.clone());
        }
        device
    }

    /// Runs `f` with the registry locked for changes: checks and inserts happen at once.
    pub(crate) fn change<T>(&self, f: impl FnOnce(&mut Registry) -> T) -> T {
        f(&mut write(&self.registry))
    }

    /// Every device, in the order they were added.
    pub fn devices(&self) -> Vec<Arc<Device>> {
        read(&self.registry).devices.clone()
    }

    /// Every link, in the order they were added.
    pub fn links(&self) -> Vec<Arc<Link>> {
        read(&self.registry).links.clone()
    }

    pub fn device(&self, name: &str) -> Result<Arc<Device>, AccessError> {
        read(&self.registry)
            .device(name)
            .cloned()
            .ok_or_else(|| AccessError::UnknownDevice(name.to_owned()))
    }

    pub fn link(&self, name: &str) -> Result<Arc<Link>, AccessError> {
        read(&self.registry)
            .link(name)
            .cloned()
            .ok_or_else(|| AccessError::UnknownLink(name.to_owned()))
    }

    pub fn profile(&self, name: &str) -> Result<&Arc<Profile>, AccessError> {
        self.catalog
            .get(name)
            .ok_or_else(|| AccessError::UnknownProfile(name.to_owned()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::writes::Lookup;

    fn cache() -> Cache {
        let config = crate::config::parse(
            "c.yaml",
            "links:\n  - { name: bus, tcp: { host: 127.0.0.1 } }\ndevices:\n  - { name: io, profile: Io, link: bus, slave_id: 1 }\n",
        )
        .expect("config");
        let profile = crate::profile::load_str(
            "io.yaml",
            "name: Io\nfields:\n  - { name: DI, type: BOOL, direction: input, register: { address: 0, kind: discrete_input } }\n  - { name: SP, type: REAL, direction: output, register: { address: 0, kind: holding_register, scale: 0.1, raw_type: UINT } }\n",
        )
        .expect("profile");
        Cache::new(&config, Catalog::new([profile]))
    }

    #[test]
    fn a_burst_of_writes_leaves_one_pending_and_supersedes_the_rest() {
        let cache = cache();
        let io = cache.device("io").expect("device");
        let sp = io.field_index("sp").expect("field ignoring case");
        let gens: Vec<u64> = (0..5)
            .map(|i| io.request_write(sp, Value::Real(i as f32)).expect("write"))
            .collect();
        let taken = io.take_writes();
        assert_eq!(taken.len(), 1);
        assert_eq!(taken[0].value, Value::Real(4.0));
        assert_eq!(taken[0].generation, gens[4]);
        for g in &gens[..4] {
            let Lookup::Found(r) = cache.writes.get(*g) else {
                panic!("missing")
            };
            assert_eq!(r.status, WriteStatus::Superseded);
        }
        io.finish_write(taken[0].generation, Ok(()));
        let Lookup::Found(r) = cache.writes.get(gens[4]) else {
            panic!("missing")
        };
        assert_eq!(r.status, WriteStatus::Written);
        assert_eq!(io.latest_requested(), vec![(sp, Value::Real(4.0))]);
    }

    #[test]
    fn writing_an_input_or_out_of_raw_range_is_refused() {
        let cache = cache();
        let io = cache.device("io").expect("device");
        assert!(matches!(
            io.request_write(0, Value::Bool(true)),
            Err(AccessError::NotWritable { .. })
        ));
        // 0.1 * 65535 is the largest value a UINT register holds.
        assert!(io.request_write(1, Value::Real(6553.5)).is_ok());
        assert!(matches!(
            io.request_write(1, Value::Real(6553.6)),
            Err(AccessError::InvalidValue { .. })
        ));
        assert!(matches!(
            io.request_write(1, Value::Bool(true)),
            Err(AccessError::InvalidValue { .. })
        ));
    }

    #[tokio::test(start_paused = true)]
    async fn good_values_go_stale_without_refresh() {
        let cache = cache();
        let io = cache.device("io").expect("device");
        assert_eq!(io.sample(0).quality, Quality::NeverRead);
        io.publish(0, Ok(Value::Bool(true)));
        let stale_after = io.stale_after();
        assert_eq!(
            io.sample(0).quality_at(Instant::now(), stale_after),
            Quality::Good
        );
        tokio::time::advance(stale_after + Duration::from_millis(1)).await;
        assert_eq!(
            io.sample(0).quality_at(Instant::now(), stale_after),
            Quality::Stale
        );
        io.publish(0, Err("exception 02".into()));
        let s = io.sample(0);
        assert_eq!(s.quality, Quality::Bad);
        assert_eq!(s.value, Some(Value::Bool(true)), "last good value is kept");
    }

    #[tokio::test]
    async fn subscribers_wake_only_on_change() {
        let cache = cache();
        let io = cache.device("io").expect("device");
        let mut rx = io.subscribe(0);
        rx.mark_unchanged();
        io.publish(0, Ok(Value::Bool(true)));
        assert!(rx.has_changed().expect("open"));
        rx.mark_unchanged();
        io.publish(0, Ok(Value::Bool(true)));
        assert!(!rx.has_changed().expect("open"), "same value, no wake-up");
        assert!(io.sample(0).updated.is_some());
    }
}

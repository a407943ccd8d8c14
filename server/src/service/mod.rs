//! Every operation a client can ask of the gateway, once: choose fields, read a snapshot,
//! write one or many fields (all or nothing), follow a write, subscribe to changes, run a
//! scan cycle, declare a link or a device. REST, gRPC and any later front-end are adapters
//! over this layer: they parse their request, call one function here, and map the result
//! or the [`ServiceError`] to their own wire format. None of them decides a rule.

mod bounds;
mod declared;
pub(crate) mod doors;
pub(crate) mod ha;
pub(crate) mod listening;
mod modbus_map;
mod refusal;
mod reload;
pub(crate) mod scan;
mod select;
pub(crate) mod serial_ports;
mod standing;
mod subscribe;
mod transact;
mod view;
mod write;

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use crate::cache::{AccessError, Cache, Device, Link};
use crate::declare::{self, DeclareError, DeviceDeclaration, Ensured, LinkDeclaration};
use crate::metrics::Metrics;
use crate::profile::Profile;
use crate::runtime::Tasks;

pub(crate) use crate::cache::Refusal;
pub(crate) use modbus_map::ModbusImage;
pub(crate) use reload::{
    Action, ConfigStatus, Item, Kind, ReloadError, Reloading, Report, Trigger, changed,
    changed_text, duration, restarted_section,
};
pub(crate) use select::Selection;
pub(crate) use standing::{Standing, StandingSet, StandingStatus};
pub(crate) use subscribe::{Change, Changes};
pub(crate) use view::FieldView;
pub(crate) use write::{Accepted, Prepared, ScanCycle};

/// Why the service refused a request.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ServiceError {
    /// A name, a field or a value was refused.
    #[error(transparent)]
    Access(#[from] AccessError),
    /// A write of several fields where some were refused: none was written. Never empty.
    #[error("nothing was written: {}", join(.0))]
    NothingWritten(Vec<AccessError>),
    /// A write generation the log never handed out.
    #[error("no write has generation {0}")]
    UnknownWrite(u64),
    /// A write too old to be kept in the log.
    #[error(
        "write {generation} aged out: each field keeps its last {kept} writes, and newer ones replaced it"
    )]
    WriteExpired { generation: u64, kept: usize },
    #[error(transparent)]
    Declare(#[from] DeclareError),
    #[error("the gateway is shutting down")]
    ShuttingDown,
    #[error("the gateway is read-only (security.read_only): nothing is written")]
    ReadOnly,
    #[error("too many open change streams (at most {0}); try again later")]
    TooManyStreams(usize),
    #[error(
        "this client has {0} change streams open, its most (listen.max_streams_per_client); close one first"
    )]
    TooManyClientStreams(usize),
    /// A link's inbox was full, or could not reach the request by its deadline: nothing
    /// was sent.
    #[error(
        "RS485 busy: link {0} has more requests waiting than it takes; nothing was sent, try again"
    )]
    Busy(String),
    #[error("{0}")]
    Location(#[from] iogate_types::LocationError),
    /// A raw transaction's parameters, with every message of the read block that applies.
    #[error("{}", crate::transaction::params::messages(.0))]
    Transaction(Vec<crate::transaction::params::ParamError>),
    #[error("no transaction `{0}`")]
    UnknownTransaction(String),
    #[error("transaction `{0}` exists with other settings")]
    TransactionConflict(String),
    /// A trigger of a disabled standing transaction: it would run nothing.
    #[error("transaction `{0}` is disabled: enable it first, a trigger runs only an enabled one")]
    TransactionDisabled(String),
    /// A located address no field is bound to.
    #[error("no field is bound to {0}")]
    Unbound(String),
    /// A scan that cannot run as asked.
    #[error("{0}")]
    Scan(String),
    #[error("scan {id} is running on link {link}; one scan a link at a time")]
    ScanRunning { link: String, id: u64 },
    #[error("no scan {0} (the last {kept} scans are kept)", kept = scan::KEPT_SCANS)]
    UnknownScan(u64),
    /// This gateway is the standby of an active/standby pair: the active takes writes.
    #[error("{}", ha::standby_message(.0.as_ref()))]
    Standby(Option<crate::role::Peer>),
}

/// The refusals, the first ten of them named (a request with thousands of bad keys gets a
/// short answer).
fn join(errors: &[AccessError]) -> String {
    const NAMED: usize = 10;
    let mut text = errors
        .iter()
        .take(NAMED)
        .map(ToString::to_string)
        .collect::<Vec<_>>()
        .join("; ");
    if errors.len() > NAMED {
        text.push_str(&format!("; and {} more", errors.len() - NAMED));
    }
    text
}

/// The running gateway as its clients see it.
#[derive(Debug)]
pub struct Service {
    pub cache: Arc<Cache>,
    pub(crate) metrics: Arc<Metrics>,
    tasks: Tasks,
    ready: AtomicBool,
    /// The Modbus TCP server's map and memory, when one is configured; a reload replaces it.
    modbus: std::sync::RwLock<Option<Arc<ModbusImage>>>,
    standing: StandingSet,
    /// What clients declared, as a pair hands it over.
    declared: declared::Declared,
    /// What run-time declarations may reach.
    policy: std::sync::RwLock<crate::config::security::DeclarePolicy>,
    /// Who may do what.
    pub(crate) tokens: crate::auth::TokenTable,
    /// `security.read_only`: every write is refused.
    read_only: AtomicBool,
    /// Open change streams (SSE, Subscribe, Exchange), bounded by `listen.max_streams`.
    streams: crate::metrics::Bound,
    /// The same, from each client address (`listen.max_streams_per_client`).
    client_streams: crate::metrics::PerClient,
    /// The front-ends that run, as the rest of the gateway sees them.
    pub(crate) doors: doors::Doors,
    /// What reloads the configuration, when it came from a file.
    reloader: std::sync::OnceLock<Arc<dyn Reloading>>,
    /// The Modbus server's serial ports.
    serial_ports: serial_ports::SerialPorts,
    /// Scans of links, running and done.
    scans: scan::Scans,
    /// Where the servers listen.
    pub(crate) listening: listening::Listening,
    /// What the front-ends add to the API's description.
    pub(crate) described: doors::Described,
}

/// A place among the open change streams; dropping it frees the place.
#[derive(Debug)]
pub(crate) struct StreamSlot {
    _held: crate::metrics::Held,
    _client: Option<crate::metrics::ClientHeld>,
}

impl Service {
    /// The service of a gateway whose tasks are started by `tasks`; not ready until
    /// [`Service::set_ready`].
    pub(crate) fn new(cache: Arc<Cache>, tasks: Tasks) -> Self {
        Service {
            streams: (tasks.metrics()).bound("streams", crate::config::DEFAULT_MAX_STREAMS),
            client_streams: (tasks.metrics()).per_client(
                "streams_per_client",
                crate::config::DEFAULT_MAX_STREAMS_PER_CLIENT,
            ),
            metrics: tasks.metrics().clone(),
            cache,
            tasks,
            ready: AtomicBool::new(false),
            modbus: std::sync::RwLock::new(None),
            standing: StandingSet::default(),
            declared: declared::Declared::default(),
            policy: std::sync::RwLock::new(crate::config::security::DeclarePolicy::default()),
            tokens: crate::auth::TokenTable::default(),
            read_only: AtomicBool::new(false),
            doors: doors::Doors::default(),
            reloader: std::sync::OnceLock::new(),
            serial_ports: serial_ports::SerialPorts::default(),
            scans: scan::Scans::default(),
            listening: listening::Listening::default(),
            described: doors::Described::default(),
        }
    }

    /// A place for one more change stream of `client` (its address, when known), or
    /// `TooManyClientStreams` (it holds its most) or `TooManyStreams`.
    pub(crate) fn stream_slot_for(
        &self,
        client: Option<std::net::IpAddr>,
    ) -> Result<StreamSlot, ServiceError> {
        let client =
            match client {
                Some(ip) => Some(self.client_streams.take(ip).ok_or_else(|| {
                    ServiceError::TooManyClientStreams(self.client_streams.limit())
                })?),
                None => None,
            };
        match self.streams.take() {
            Some(held) => Ok(StreamSlot {
                _held: held,
                _client: client,
            }),
            None => Err(ServiceError::TooManyStreams(self.streams.limit())),
        }
    }

    /// The service with the tokens and the read-only switch of `security:`.
    pub(crate) fn with_access(self, tokens: crate::auth::Tokens, read_only: bool) -> Self {
        self.set_access(tokens, read_only);
        self
    }

    /// Puts the tokens and the read-only switch of `security:` in force.
    pub(crate) fn set_access(&self, tokens: crate::auth::Tokens, read_only: bool) {
        self.tokens.replace(tokens);
        self.read_only.store(read_only, Ordering::Release);
    }

    /// Puts a declaration policy in force.
    pub(crate) fn set_policy(&self, policy: crate::config::security::DeclarePolicy) {
        *self.policy.write().unwrap_or_else(|e| e.into_inner()) = policy;
    }

    pub(crate) fn is_read_only(&self) -> bool {
        self.read_only.load(Ordering::Acquire)
    }

    /// Refuses writes when the gateway is read-only (or shutting down).
    pub(crate) fn accepting_writes(&self) -> Result<(), ServiceError> {
        self.accepting()?;
        self.owning_field()?;
        if self.is_read_only() {
            Err(ServiceError::ReadOnly)
        } else {
            Ok(())
        }
    }

    /// The service with `listen.max_streams`.
    pub(crate) fn with_max_streams(self, max: [usize; 2]) -> Self {
        self.set_max_streams(max);
        self
    }

    /// Puts `listen.max_streams` and `listen.max_streams_per_client` in force for the
    /// streams opened from now on.
    pub(crate) fn set_max_streams(&self, [max, per_client]: [usize; 2]) {
        self.client_streams.set_limit(per_client);
        self.streams.set_limit(max);
    }

    /// The service with a declaration policy other than the default.
    pub(crate) fn with_policy(self, policy: crate::config::security::DeclarePolicy) -> Self {
        self.set_policy(policy);
        self
    }

    /// The service with what the front-ends add to the API's description.
    pub(crate) fn with_described(mut self, described: doors::Described) -> Self {
        self.described = described;
        self
    }

    /// The service with a Modbus TCP server's image.
    pub(crate) fn with_modbus(self, image: ModbusImage) -> Self {
        self.set_modbus(Some(image));
        self
    }

    /// Puts a Modbus TCP server's image in force (or none).
    pub(crate) fn set_modbus(&self, image: Option<ModbusImage>) {
        *self.modbus.write().unwrap_or_else(|e| e.into_inner()) = image.map(Arc::new);
    }

    pub(crate) fn tasks(&self) -> &Tasks {
        &self.tasks
    }

    pub(crate) fn set_ready(&self, ready: bool) {
        self.ready.store(ready, Ordering::Relaxed);
    }

    /// Serving: started and not shutting down.
    pub(crate) fn is_ready(&self) -> bool {
        self.ready.load(Ordering::Relaxed) && !self.is_shutting_down()
    }

    pub(crate) fn is_shutting_down(&self) -> bool {
        self.tasks.token().is_cancelled()
    }

    /// Refuses new work (writes, streams, declarations) once shutdown has begun.
    pub(crate) fn accepting(&self) -> Result<(), ServiceError> {
        if self.is_shutting_down() {
            Err(ServiceError::ShuttingDown)
        } else {
            Ok(())
        }
    }

    pub(crate) fn devices(&self) -> Vec<Arc<Device>> {
        self.cache.devices()
    }

    /// Wakes when a device is added or removed.
    pub(crate) fn watch_devices(&self) -> tokio::sync::watch::Receiver<u64> {
        self.cache.watch_devices()
    }

    pub(crate) fn device(&self, name: &str) -> Result<Arc<Device>, ServiceError> {
        Ok(self.cache.device(name)?)
    }

    /// A field named either `device` + `field`, or by a located address (`%QX2.6`) in
    /// `field` (with `device` empty) or in `device`, as the Modbus server's map binds it.
    pub(crate) fn field(
        &self,
        device: &str,
        field: &str,
    ) -> Result<(Arc<Device>, usize), ServiceError> {
        let located = [field, device]
            .into_iter()
            .find(|t| t.trim_start().starts_with('%'));
        match located {
            Some(at) if device.is_empty() || field.is_empty() || device.starts_with('%') => {
                self.located(at)
            }
            _ => {
                let d = self.cache.device(device)?;
                let idx = d.field_index(field)?;
                Ok((d, idx))
            }
        }
    }

    /// The field bound to a located address.
    pub(crate) fn located(&self, at: &str) -> Result<(Arc<Device>, usize), ServiceError> {
        let location = iogate_types::Location::parse(at)?;
        self.modbus()
            .and_then(|m| {
                m.bound.iter().find_map(|b| match b.binding.target {
                    crate::map::Target::Field(idx) if b.binding.at == location => {
                        Some((b.device.clone(), idx))
                    }
                    _ => None,
                })
            })
            .ok_or_else(|| ServiceError::Unbound(location.to_string()))
    }

    pub(crate) fn links(&self) -> Vec<Arc<Link>> {
        self.cache.links()
    }

    pub fn link(&self, name: &str) -> Result<Arc<Link>, ServiceError> {
        Ok(self.cache.link(name)?)
    }

    pub(crate) fn profiles(&self) -> Vec<Arc<Profile>> {
        self.cache.catalog().iter().cloned().collect()
    }

    pub(crate) fn profile(&self, name: &str) -> Result<Arc<Profile>, ServiceError> {
        Ok(self.cache.profile(name)?)
    }

    /// Declares a link (idempotent); a new one starts polling at once.
    pub(crate) fn ensure_link(&self, decl: LinkDeclaration) -> Result<Ensured<Link>, ServiceError> {
        self.accepting()?;
        self.owning_field()?;
        let policy = self
            .policy
            .read()
            .unwrap_or_else(|e| e.into_inner())
            .clone();
        let ensured = declare::ensure_link(&self.cache, &self.tasks, &policy, decl.clone());
        let ensured = self.counted(ensured)?;
        self.declared.link(ensured.value.name(), &decl);
        Ok(ensured)
    }

    /// Declares a device (idempotent); a new one is polled by its link at once.
    pub(crate) fn ensure_device(
        &self,
        decl: DeviceDeclaration,
    ) -> Result<Ensured<Device>, ServiceError> {
        self.accepting()?;
        self.owning_field()?;
        let ensured = self.counted(declare::ensure_device(
            &self.cache,
            &self.tasks,
            decl.clone(),
        ))?;
        self.declared.device(&decl);
        Ok(ensured)
    }

    /// Removes a device declared at run time.
    pub(crate) fn remove_device(&self, name: &str) -> Result<Arc<Device>, ServiceError> {
        self.accepting()?;
        self.owning_field()?;
        let removed = declare::remove_device(&self.cache, name)?;
        self.declared.undevice(name);
        Ok(removed)
    }

    /// Removes a link declared at run time that no device or standing transaction uses.
    pub(crate) fn remove_link(&self, name: &str) -> Result<Arc<Link>, ServiceError> {
        self.accepting()?;
        self.owning_field()?;
        let users = self
            .standing()
            .all()
            .iter()
            .filter(|s| s.link == name)
            .map(|s| s.name.clone())
            .collect();
        let removed = declare::remove_link(&self.cache, name, users)?;
        self.declared.unlink(name);
        Ok(removed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn demo_service() -> Service {
        let setup = crate::app::Setup::demo_simulated().expect("demo");
        let cache = Arc::new(Cache::new(&setup.config, setup.catalog));
        let tasks = Tasks::new(
            tokio_util::task::TaskTracker::new(),
            tokio_util::sync::CancellationToken::new(),
            Arc::new(Metrics::new()),
        );
        Service::new(cache, tasks)
    }

    #[tokio::test]
    async fn a_subscriber_is_not_told_what_came_and_went_before_it_looked() {
        use futures_util::{FutureExt, StreamExt};
        let service = demo_service();
        let sim = service.cache.device("sim").expect("sim");
        let idx = sim.field_index("DI_0").expect("field");
        sim.publish(idx, Ok(crate::codec::Value::Bool(false)));
        let selection = service
            .select::<&str, &str>(&[], &[("sim", "DI_0")])
            .expect("selection");
        let mut changes = service.subscribe(selection, false).expect("stream");
        let value = |c: Option<Change>| match c {
            Some(Change::Value { sample, .. }) => sample.value,
            other => panic!("expected a value, got {other:?}"),
        };
        assert_eq!(
            value(changes.next().await),
            Some(crate::codec::Value::Bool(false))
        );
        // True and back to false before the subscriber looks: nothing to tell.
        sim.publish(idx, Ok(crate::codec::Value::Bool(true)));
        sim.publish(idx, Ok(crate::codec::Value::Bool(false)));
        assert!(changes.next().now_or_never().is_none(), "nothing new");
        sim.publish(idx, Ok(crate::codec::Value::Bool(true)));
        assert_eq!(
            value(changes.next().await),
            Some(crate::codec::Value::Bool(true))
        );
    }

    #[tokio::test]
    async fn diagnostics_are_followed_into_a_successor_with_diagnostics_of_its_own() {
        use futures_util::StreamExt;
        let service = demo_service();
        let sim = service.cache.device("sim").expect("sim");
        let selection = service
            .select::<&str, &str>(&["sim"], &[])
            .expect("selection");
        let mut changes = service.subscribe(selection, true).expect("stream");
        let connected = |c: Option<Change>| match c {
            Some(Change::Diagnostics { diagnostics, .. }) => diagnostics.connected,
            other => panic!("expected diagnostics, got {other:?}"),
        };
        let mut diagnostics = changes
            .by_ref()
            .filter(|c| std::future::ready(matches!(c, Change::Diagnostics { .. })));
        let wait = std::time::Duration::from_secs(5);
        let mut next_told = async || {
            tokio::time::timeout(wait, diagnostics.next())
                .await
                .ok()
                .flatten()
        };
        assert!(connected(next_told().await), "simulated: connected");
        // Re-planned as a Modbus TCP device: not connected until it answers.
        let mut profile = (*sim.profile).clone();
        profile.protocol = crate::profile::Protocol::ModbusTcp;
        let next = service.cache.change(|r| {
            service
                .cache
                .replace_device(r, &sim, sim.config.clone(), Arc::new(profile))
        });
        assert!(!next.shares_diagnostics(&sim));
        assert!(!connected(next_told().await), "the successor's own");
        next.record_cycle(true, std::time::Duration::from_millis(3));
        assert!(connected(next_told().await), "and as they change");
    }

    #[test]
    fn change_streams_are_bounded_and_their_places_come_back() {
        let service = demo_service();
        let default = crate::config::DEFAULT_MAX_STREAMS;
        let held: Vec<StreamSlot> = (0..default)
            .map(|_| service.stream_slot_for(None).expect("a place"))
            .collect();
        assert!(matches!(
            service.stream_slot_for(None),
            Err(ServiceError::TooManyStreams(n)) if n == default
        ));
        // `listen.max_streams` raised (a reload): more places.
        service.set_max_streams([default + 1, default + 1]);
        let one_more = service
            .stream_slot_for(None)
            .expect("a place under the new limit");
        assert!(service.stream_slot_for(None).is_err());
        drop(held);
        drop(one_more);
        assert!(
            service.stream_slot_for(None).is_ok(),
            "places come back when streams end"
        );
    }
}

//! The latest value of every field, the diagnostics of every device and link, and the
//! pending writes. Reads from every API are served from here, never from the bus.
//!
//! Each field has a `watch` channel: readers take the newest sample without locking the
//! writer out, and subscribers are woken only when the value or its quality changes, so a
//! slow subscriber sees the newest value rather than a backlog.

mod device;
mod link;
mod outputs;
pub(crate) mod sample;
mod slot;

use std::sync::{Arc, Mutex, MutexGuard, RwLock, RwLockReadGuard, RwLockWriteGuard};

use tokio::sync::Notify;

use crate::codec::IecType;
use crate::config::{Config, DeviceConfig, LinkConfig};
use crate::profile::{Catalog, Profile};
use crate::text::quote;
use crate::write_log::WriteLog;

pub(crate) use device::{Binding, Device, Fate, Stamp};
pub use link::{
    INBOX_CAPACITY, Inbox, Link, LinkState, Passthrough, PassthroughError, Probe, Progress, Stage,
    Utilisation,
};
pub(crate) use outputs::{Checked, TakenWrite, WriteError};
pub(crate) use sample::{Diagnostics, FieldError, LinkDiagnostics, Sample};
pub(crate) use slot::{Forms, SlotReceiver};

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // Sections under these locks are single assignments; a poisoned lock holds whole values.
    m.lock().unwrap_or_else(|e| e.into_inner())
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
        /// Why, as a kind (its message is rendered from it).
        reason: Box<crate::codec::CodecError>,
    },
}

/// The kinds of refusal, whatever refuses (a name, a value, a declaration, the service):
/// each front-end maps them to its wire in one table.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Refusal {
    /// The request itself is wrong: a value, a parameter, a declaration.
    Invalid,
    /// It names something that does not exist.
    NotFound,
    /// It contradicts what is (writing an input, a conflicting declaration).
    Conflict,
    /// The gateway's policy does not allow it (read-only, declarations not allowed).
    Forbidden,
    /// It names something that existed and is no longer kept (an old write).
    Gone,
    /// The gateway cannot take requests now (shutting down).
    Unavailable,
    /// Too many open streams: come back later.
    TooMany,
    /// A link's inbox is full (or could not reach it in time): nothing was sent; try again.
    Busy,
}

fn read<T>(l: &RwLock<T>) -> RwLockReadGuard<'_, T> {
    l.read().unwrap_or_else(|e| e.into_inner())
}

fn write<T>(l: &RwLock<T>) -> RwLockWriteGuard<'_, T> {
    l.write().unwrap_or_else(|e| e.into_inner())
}

/// The link a device's config names (if it exists) and the `Notify` that wakes the
/// device's task: the link's, or one of its own.
fn link_of(registry: &Registry, config: &DeviceConfig) -> (Option<Arc<Link>>, Arc<Notify>) {
    let link = config
        .link
        .as_ref()
        .and_then(|name| registry.link(name))
        .cloned();
    let wake = link
        .as_ref()
        .map_or_else(|| Arc::new(Notify::new()), |l| l.wake.clone());
    (link, wake)
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
    /// The profiles in force; a configuration reload replaces them.
    catalog: RwLock<Arc<Catalog>>,
    pub(crate) writes: Arc<WriteLog>,
    registry: RwLock<Registry>,
    /// Counts changes of the set of devices (added or removed at run time), for front-ends
    /// that publish every device.
    device_set: tokio::sync::watch::Sender<u64>,
}

impl Cache {
    /// Builds the cache for a config whose devices were checked against `catalog`.
    pub(crate) fn new(config: &Config, catalog: Catalog) -> Self {
        let cache = Cache {
            catalog: RwLock::new(Arc::new(catalog)),
            writes: Arc::new(WriteLog::default()),
            registry: RwLock::new(Registry::default()),
            device_set: tokio::sync::watch::Sender::new(0),
        };
        {
            let mut registry = write(&cache.registry);
            for l in &config.links {
                cache.insert_link(&mut registry, l.clone());
            }
            for d in &config.devices {
                if let Some(profile) = cache.catalog().get(&d.profile).cloned() {
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
        let (link, wake) = link_of(registry, &config);
        let bound = config.slave_id.is_some() || !profile.protocol.is_modbus();
        let device = Arc::new(Device::new(config, profile, self.writes.clone(), wake));
        registry.devices.push(device.clone());
        self.device_set.send_modify(|n| *n += 1);
        if let Some(link) = link.filter(|_| bound) {
            link.add_member(device.clone());
        }
        device
    }

    /// Binds a device that was declared without its link or slave id; once it has both, its
    /// link's task polls it.
    pub(crate) fn bind_device(&self, registry: &Registry, device: &Arc<Device>, binding: Binding) {
        let link = binding.link.as_ref().and_then(|name| registry.link(name));
        let wake = link.map_or_else(|| Arc::new(Notify::new()), |l| l.wake.clone());
        let member = link
            .filter(|_| binding.slave_id.is_some() || !device.profile.protocol.is_modbus())
            .cloned();
        device.bind(binding, wake);
        if let Some(link) = member {
            link.add_member(device.clone());
        }
    }

    /// Takes a device out (`why`): off its link, its task stopped, its waiting writes
    /// failed, its streams ended with the reason.
    pub(crate) fn remove_device(
        &self,
        registry: &mut Registry,
        device: &Arc<Device>,
        why: &'static str,
    ) {
        registry.devices.retain(|d| !Arc::ptr_eq(d, device));
        self.device_set.send_modify(|n| *n += 1);
        if let Some(link) = device
            .binding()
            .link
            .and_then(|l| registry.link(&l).cloned())
        {
            link.remove_member(device);
        }
        device.retire(why);
    }

    /// Puts a successor of `old` with `config` and `profile` in its place (a reload
    /// re-planned it): the registry, the link's members (in one change when the link stays),
    /// and whoever follows `old` move to it. Answers the successor.
    pub(crate) fn replace_device(
        &self,
        registry: &mut Registry,
        old: &Arc<Device>,
        config: DeviceConfig,
        profile: Arc<Profile>,
    ) -> Arc<Device> {
        let (link, wake) = link_of(registry, &config);
        let next = Arc::new(Device::succeed(
            old,
            config,
            profile,
            self.writes.clone(),
            wake,
        ));
        if let Some(slot) = registry.devices.iter_mut().find(|d| Arc::ptr_eq(d, old)) {
            *slot = next.clone();
        }
        let old_link = old
            .binding()
            .link
            .and_then(|l| registry.link(&l).cloned())
            .filter(|_| old.slave_id().is_some() || !old.profile.protocol.is_modbus());
        let new_link =
            link.filter(|_| next.slave_id().is_some() || !next.profile.protocol.is_modbus());
        match (old_link, new_link) {
            (Some(a), Some(b)) if Arc::ptr_eq(&a, &b) => a.replace_member(old, next.clone()),
            (a, b) => {
                if let Some(a) = a {
                    a.remove_member(old);
                }
                if let Some(b) = b {
                    b.add_member(next.clone());
                }
            }
        }
        old.replaced_by(next.clone());
        self.device_set.send_modify(|n| *n += 1);
        next
    }

    /// Takes a link out and stops its task (which closes its port or socket).
    pub(crate) fn remove_link(&self, registry: &mut Registry, link: &Arc<Link>) {
        registry.links.retain(|l| !Arc::ptr_eq(l, link));
        link.stop();
    }

    /// Runs `f` with the registry locked for changes: checks and inserts happen at once.
    pub(crate) fn change<T>(&self, f: impl FnOnce(&mut Registry) -> T) -> T {
        f(&mut write(&self.registry))
    }

    /// Wakes when a device is added or removed.
    pub(crate) fn watch_devices(&self) -> tokio::sync::watch::Receiver<u64> {
        self.device_set.subscribe()
    }

    /// Every device, in the order they were added.
    pub(crate) fn devices(&self) -> Vec<Arc<Device>> {
        read(&self.registry).devices.clone()
    }

    /// Every link, in the order they were added.
    pub(crate) fn links(&self) -> Vec<Arc<Link>> {
        read(&self.registry).links.clone()
    }

    pub(crate) fn device(&self, name: &str) -> Result<Arc<Device>, AccessError> {
        read(&self.registry)
            .device(name)
            .cloned()
            .ok_or_else(|| AccessError::UnknownDevice(quote(name)))
    }

    pub fn link(&self, name: &str) -> Result<Arc<Link>, AccessError> {
        read(&self.registry)
            .link(name)
            .cloned()
            .ok_or_else(|| AccessError::UnknownLink(quote(name)))
    }

    pub(crate) fn profile(&self, name: &str) -> Result<Arc<Profile>, AccessError> {
        self.catalog()
            .get(name)
            .cloned()
            .ok_or_else(|| AccessError::UnknownProfile(quote(name)))
    }

    /// The profiles in force.
    pub(crate) fn catalog(&self) -> Arc<Catalog> {
        read(&self.catalog).clone()
    }

    /// Puts a reloaded set of profiles in force (devices keep the profile they run with
    /// until they are re-planned).
    pub(crate) fn set_catalog(&self, catalog: Catalog) {
        *write(&self.catalog) = Arc::new(catalog);
    }
}

#[cfg(test)]
mod tests;

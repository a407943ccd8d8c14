//! What a reload changes in the running gateway besides its front-ends: the catalog, links
//! and devices (links first, as a device may move to a new link; devices; then the links
//! let go), standing transactions, and the Modbus server's located image.

use std::sync::Arc;

use super::diff::Diff;
use crate::config::modbus_server::ModbusServerConfig;
use crate::map::Plan;
use crate::service::{ModbusImage, Service};
use crate::setup::Setup;

/// The catalog, links and devices of `new`, as `diff` says they changed.
pub(super) fn registry(service: &Arc<Service>, new: &Setup, diff: &Diff) {
    let cache = &service.cache;
    let tasks = service.tasks();
    if diff.profiles {
        cache.set_catalog(new.catalog.clone());
    }
    // Links first (a device may move to a new link), devices, then links let go.
    for name in &diff.links.added {
        if let Some(config) = new.config.links.iter().find(|l| &l.name == name) {
            let link = cache.change(|r| cache.insert_link(r, config.clone()));
            tasks.spawn_link(link);
        }
    }
    for name in &diff.links.changed {
        if let (Ok(link), Some(config)) = (
            cache.link(name),
            new.config.links.iter().find(|l| &l.name == name),
        ) {
            link.reconfigure(config.clone());
        }
    }
    for name in &diff.devices.removed {
        cache.change(|r| {
            if let Some(device) = r.device(name).cloned() {
                cache.remove_device(r, &device, "the device was removed from the configuration");
            }
        });
    }
    for name in &diff.devices.changed {
        let (Some(config), Ok(old_device)) = (
            new.config.devices.iter().find(|d| &d.name == name),
            cache.device(name),
        ) else {
            continue;
        };
        let Some(profile) = new.catalog.get(&config.profile).cloned() else {
            continue;
        };
        let next = cache.change(|r| cache.replace_device(r, &old_device, config.clone(), profile));
        if next.is_simulated() {
            tasks.spawn_sim(next);
        }
    }
    for name in &diff.devices.added {
        let Some(config) = new.config.devices.iter().find(|d| &d.name == name) else {
            continue;
        };
        let Some(profile) = new.catalog.get(&config.profile).cloned() else {
            continue;
        };
        let device = cache.change(|r| cache.insert_device(r, config.clone(), profile));
        if device.is_simulated() {
            tasks.spawn_sim(device);
        }
    }
    for name in &diff.links.removed {
        cache.change(|r| {
            if let Some(link) = r.link(name).cloned() {
                cache.remove_link(r, &link);
            }
        });
    }
}

/// Standing transactions: the removed and changed ones stopped, the changed and added ones
/// started.
pub(super) fn transactions(service: &Arc<Service>, new: &Setup, diff: &Diff) {
    for name in diff
        .transactions
        .removed
        .iter()
        .chain(&diff.transactions.changed)
    {
        service.drop_transaction(name);
    }
    for name in diff
        .transactions
        .changed
        .iter()
        .chain(&diff.transactions.added)
    {
        if let Some(config) = new.config.transactions.iter().find(|t| &t.name == name)
            && let Err(e) = service.ensure_transaction(config.clone())
        {
            tracing::error!(transaction = %name, error = %e, "standing transaction not started");
        }
    }
}

/// The Modbus server's image: rebuilt over the devices now in the cache (`modbus`, when
/// its section or map changed), or dropped with its section.
pub(super) fn image(
    service: &Service,
    modbus: Option<(ModbusServerConfig, Plan)>,
    old: &Setup,
    new: &Setup,
) {
    if let Some((server, plan)) = modbus {
        let image = match service.modbus() {
            Some(image) => image.reloaded(&server, &plan, &service.cache),
            None => ModbusImage::new(&server, &plan, &service.cache),
        };
        match image {
            Ok(image) => service.set_modbus(Some(image)),
            Err(e) => tracing::error!(error = %e, "Modbus server memory not carried over"),
        }
    } else if new.config.modbus_server.is_none() && old.config.modbus_server.is_some() {
        service.set_modbus(None);
    }
}

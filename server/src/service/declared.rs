//! What clients declared at run time (links, devices, standing transactions), as one set
//! an active/standby pair hands over: the active publishes it whenever it changes, and the
//! standby makes its own declarations the same (its link tasks touch nothing while it is
//! standby), so the node that takes over polls what the old active polled.

use std::collections::BTreeMap;
use std::sync::Mutex;

use serde::{Deserialize, Serialize};
use tokio::sync::watch;

use super::Service;
use crate::config::transactions::StandingConfig;
use crate::declare::{DeviceDeclaration, LinkDeclaration};

/// The declarations, by name.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub(crate) struct DeclaredSet {
    links: BTreeMap<String, LinkDeclaration>,
    devices: BTreeMap<String, DeviceDeclaration>,
    #[serde(default)]
    transactions: BTreeMap<String, StandingConfig>,
}

/// The links and devices declared here, and a counter woken at every change (a
/// transaction's too: they are read from the live set).
#[derive(Debug)]
pub(crate) struct Declared {
    set: Mutex<DeclaredSet>,
    changed: watch::Sender<u64>,
}

impl Default for Declared {
    fn default() -> Self {
        Declared {
            set: Mutex::new(DeclaredSet::default()),
            changed: watch::Sender::new(0),
        }
    }
}

impl Declared {
    fn with(&self, f: impl FnOnce(&mut DeclaredSet)) {
        f(&mut self.set.lock().unwrap_or_else(|e| e.into_inner()));
        self.touch();
    }

    /// Something declared changed.
    pub(crate) fn touch(&self) {
        self.changed.send_modify(|n| *n += 1);
    }

    pub(crate) fn link(&self, name: &str, decl: &LinkDeclaration) {
        let mut decl = decl.clone();
        decl.name = Some(name.to_owned());
        self.with(|s| {
            s.links.insert(name.to_owned(), decl);
        });
    }

    pub(crate) fn device(&self, decl: &DeviceDeclaration) {
        self.with(|s| {
            s.devices.insert(decl.name.clone(), decl.clone());
        });
    }

    pub(crate) fn unlink(&self, name: &str) {
        self.with(|s| {
            s.links.remove(name);
        });
    }

    pub(crate) fn undevice(&self, name: &str) {
        self.with(|s| {
            s.devices.remove(name);
        });
    }
}

impl Service {
    /// Wakes at every change of what was declared.
    pub(crate) fn watch_declared(&self) -> watch::Receiver<u64> {
        self.declared.changed.subscribe()
    }

    /// What was declared here, as the active of a pair publishes it.
    pub(crate) fn declared_set(&self) -> Vec<u8> {
        let mut set = self
            .declared
            .set
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone();
        set.transactions = self
            .standing()
            .all()
            .iter()
            .filter(|s| s.line() == 0)
            .map(|s| (s.name.clone(), s.config()))
            .collect();
        serde_json::to_vec(&set).unwrap_or_default()
    }

    /// Makes this standby's declarations those the active published: what it no longer has
    /// removed (transactions, devices, then links), what it has ensured (links, devices,
    /// then transactions). Each failure is logged; the rest go on.
    pub(crate) fn adopt_declarations(self: &std::sync::Arc<Self>, payload: &[u8]) {
        if self.tasks.role().owns_field() {
            return;
        }
        let new: DeclaredSet = match serde_json::from_slice(payload) {
            Ok(set) => set,
            Err(e) => {
                tracing::warn!(error = %e, "HA: the active's declarations cannot be read: ignored");
                return;
            }
        };
        let old = self
            .declared
            .set
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone();
        let failed = |what: &str, name: &str, e: &dyn std::fmt::Display| {
            tracing::warn!(what, name, error = %e, "HA: a declaration of the active not taken here");
        };
        for s in self.standing().all().iter().filter(|s| s.line() == 0) {
            if new.transactions.get(&s.name) != Some(&s.config()) {
                self.unstand(&s.name);
            }
        }
        for (name, decl) in &old.devices {
            if new.devices.get(name) != Some(decl)
                && let Err(e) = crate::declare::remove_device(&self.cache, name)
            {
                failed("device", name, &e);
            }
        }
        for name in old.links.keys().filter(|n| !new.links.contains_key(*n)) {
            if let Err(e) = crate::declare::remove_link(&self.cache, name, Vec::new()) {
                failed("link", name, &e);
            }
        }
        for (name, decl) in &new.links {
            let policy = self
                .policy
                .read()
                .unwrap_or_else(|e| e.into_inner())
                .clone();
            let ensured =
                crate::declare::ensure_link(&self.cache, &self.tasks, &policy, decl.clone());
            if let Err(e) = ensured {
                failed("link", name, &e);
            }
        }
        for (name, decl) in &new.devices {
            if let Err(e) = crate::declare::ensure_device(&self.cache, &self.tasks, decl.clone()) {
                failed("device", name, &e);
            }
        }
        for (name, config) in &new.transactions {
            if let Err(e) = self.ensure_transaction(config.clone()) {
                failed("transaction", name, &e);
            }
        }
        let mut kept = new;
        kept.transactions.clear();
        *self.declared.set.lock().unwrap_or_else(|e| e.into_inner()) = kept;
    }
}

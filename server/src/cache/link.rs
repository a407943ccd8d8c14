//! One link as the cache sees it: its configuration, its diagnostics and the devices on it
//! (which can grow at run time; the link's task notices by the version counter).

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, RwLock};

use tokio::sync::{Notify, watch};

use super::Device;
use super::sample::LinkDiagnostics;
use crate::config::LinkConfig;
use crate::link::LinkCode;

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
                error_code: LinkCode::Ok,
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
        super::read(&self.members).clone()
    }

    pub fn version(&self) -> u64 {
        self.version.load(Ordering::Acquire)
    }

    pub(super) fn add_member(&self, device: Arc<Device>) {
        super::write(&self.members).push(device);
        self.version.fetch_add(1, Ordering::AcqRel);
        self.wake.notify_one();
    }
}

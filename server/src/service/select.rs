//! Choosing fields: by device, by `device.field`, or everything; and reading them.

use std::sync::Arc;

use super::{Service, ServiceError};
use crate::cache::{Device, Diagnostics, Sample};

/// One field of one device.
#[derive(Debug, Clone)]
pub(crate) struct FieldRef {
    pub(crate) device: Arc<Device>,
    pub(crate) idx: usize,
}

/// The chosen fields, each once, in the order asked for; and their devices, each once.
#[derive(Debug, Clone, Default)]
pub(crate) struct Selection {
    pub(crate) fields: Vec<FieldRef>,
    pub(crate) devices: Vec<Arc<Device>>,
    /// Nothing was named: every device, and (in a subscription) the devices added later.
    pub(crate) everything: bool,
    /// The devices' diagnostics only, not their fields' values.
    pub(crate) no_values: bool,
}

impl Selection {
    /// The same devices without their fields' values (diagnostics only).
    pub(crate) fn without_values(mut self) -> Self {
        self.fields.clear();
        self.no_values = true;
        self
    }

    fn push(&mut self, device: &Arc<Device>, idx: usize) {
        if !self.devices.iter().any(|d| Arc::ptr_eq(d, device)) {
            self.devices.push(device.clone());
        }
        if !self
            .fields
            .iter()
            .any(|f| Arc::ptr_eq(&f.device, device) && f.idx == idx)
        {
            self.fields.push(FieldRef {
                device: device.clone(),
                idx,
            });
        }
    }
}

/// The current samples of a selection and the diagnostics of its devices.
#[derive(Debug, Clone)]
pub(crate) struct Snapshot {
    pub(crate) values: Vec<(FieldRef, Sample)>,
    pub(crate) diagnostics: Vec<(Arc<Device>, Diagnostics)>,
}

impl Service {
    /// Every field of the named devices plus the named `(device, field)` pairs; every field
    /// of every device when nothing is named. An unknown name refuses the whole selection.
    pub(crate) fn select<D, F>(
        &self,
        devices: &[D],
        fields: &[(F, F)],
    ) -> Result<Selection, ServiceError>
    where
        D: AsRef<str>,
        F: AsRef<str>,
    {
        let mut chosen = Selection {
            everything: devices.is_empty() && fields.is_empty(),
            ..Selection::default()
        };
        let named = if chosen.everything {
            self.cache.devices()
        } else {
            devices
                .iter()
                .map(|n| self.cache.device(n.as_ref()))
                .collect::<Result<_, _>>()?
        };
        for device in &named {
            for idx in 0..device.profile.fields.len() {
                chosen.push(device, idx);
            }
            if device.profile.fields.is_empty() {
                chosen.devices.push(device.clone());
            }
        }
        for (device, field) in fields {
            let (device, idx) = self.field(device.as_ref(), field.as_ref())?;
            chosen.push(&device, idx);
        }
        Ok(chosen)
    }

    /// The newest samples of `selection`, never waiting for a bus.
    pub(crate) fn read(&self, selection: &Selection) -> Snapshot {
        Snapshot {
            values: selection
                .fields
                .iter()
                .map(|f| (f.clone(), f.device.sample(f.idx)))
                .collect(),
            diagnostics: selection
                .devices
                .iter()
                .map(|d| (d.clone(), d.diagnostics()))
                .collect(),
        }
    }
}

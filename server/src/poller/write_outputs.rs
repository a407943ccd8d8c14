//! Putting a device's requested outputs on its link: the writes taken (last value wins),
//! refused at once while the device is backed off, the latest values written again after a
//! reconnect where the device's `rewrite_outputs` says so (and nobody else wrote them since),
//! and the rest left to the driver, which finishes each with its outcome.

use std::time::Duration;

use super::{Driven, Step};
use crate::cache::{Device, WriteError};
use crate::drivers::WriteItem;
use crate::drivers::{Driver, Session};

/// The requested values again, after a reconnect or the device's return: each a write of
/// its own in the log (origin `replay`), never an unrecorded one. Only a value asked for in
/// this node's current epoch is written again (`fenced`): what was asked of an earlier
/// active spell, before the other node of the pair wrote the field, is not.
fn replayed(device: &Device, items: &mut Vec<WriteItem>, fenced: impl Fn(u64) -> bool) {
    for (field, value) in device.replayable() {
        let asked_now = device.last_write(field).is_some_and(|g| !fenced(g));
        if asked_now && !items.iter().any(|it| it.field == field) {
            let name = &device.field(field).name;
            let generation = device
                .outputs()
                .replay(device.name(), name, field, value.clone());
            items.push(WriteItem {
                field,
                value: Some(value),
                generation: Some(generation),
            });
        }
    }
}

impl From<crate::cache::TakenWrite> for WriteItem {
    fn from(w: crate::cache::TakenWrite) -> Self {
        WriteItem {
            field: w.field,
            value: w.value,
            generation: Some(w.generation),
        }
    }
}

impl<D: Driver> Driven<D> {
    pub(super) async fn write_device(&mut self, i: usize, session: &mut D::Session) -> Step {
        let p = &mut self.devices[i];
        let device = p.device.clone();
        let mut taken = device.take_writes();
        // Fenced: a write accepted in another epoch, or after the lease ran out, is not
        // this gateway's to put on the field.
        taken.retain(|w| match self.role.may_write(w.generation) {
            Ok(()) => true,
            Err(fenced) => {
                device.finish_write(w.generation, Err(WriteError::Fenced(fenced)));
                false
            }
        });
        if p.backoff.is_some() {
            for w in taken {
                device.finish_write(w.generation, Err(WriteError::DeviceDown));
            }
            return Ok(());
        }
        let mut items: Vec<WriteItem> = taken.into_iter().map(WriteItem::from).collect();
        if p.rewrite {
            replayed(&device, &mut items, |g| self.role.may_write(g).is_err());
            p.rewrite = false;
        }
        let written = session.write(&device, &mut p.plan, items).await;
        if written.is_err() {
            p.rewrite = true;
        }
        if let Some(e) = written? {
            p.rewrite = true;
            p.lost(&e, Duration::ZERO);
        }
        Ok(())
    }
}

//! Putting a device's requested outputs on the bus: grouped into as few transactions as
//! the device allows, each outcome reported; a device without FC15/FC16 is written item by
//! item from then on.

use std::collections::VecDeque;
use std::time::Duration;

use super::bus::Bus;
use super::{LinkTask, Step, connection_fault};
use crate::cache::WriteError;
use crate::link::TxError;
use crate::link::frame::Exception;
use crate::plan::{self, WriteItem, WriteOp};

impl LinkTask {
    pub(super) async fn write_device(&mut self, i: usize, bus: &mut Bus) -> Step {
        let p = &mut self.devices[i];
        let device = p.device.clone();
        let taken = device.take_writes();
        if p.backoff.is_some() {
            for w in taken {
                device.finish_write(w.generation, Err(WriteError::DeviceDown));
            }
            return Ok(());
        }
        let mut items: Vec<WriteItem> = taken
            .into_iter()
            .map(|w| WriteItem {
                field: w.field,
                value: w.value,
                generation: Some(w.generation),
            })
            .collect();
        if p.rewrite {
            for (field, value) in device.outputs().latest_requested() {
                if !items.iter().any(|it| it.field == field) {
                    items.push(WriteItem {
                        field,
                        value,
                        generation: None,
                    });
                }
            }
            p.rewrite = false;
        }
        let finish = |item: &WriteItem, result: Result<(), WriteError>| {
            if let Some(g) = item.generation {
                device.finish_write(g, result);
            }
        };
        let (ops, refused) = plan::write_ops(&device.profile, &items, p.single_writes);
        for (n, reason) in refused {
            finish(&items[n], Err(reason));
        }
        let mut ops: VecDeque<WriteOp> = ops.into();
        while let Some(op) = ops.pop_front() {
            let result = match &op {
                WriteOp::Direct { request, .. } => bus
                    .transact(&device, request, device.config.retries)
                    .await
                    .0
                    .map(drop),
                WriteOp::Bits { address, bits, .. } => {
                    bus.write_bits(&device, *address, bits).await
                }
            };
            match result {
                Ok(()) => {
                    for &n in op.items() {
                        finish(&items[n], Ok(()));
                        device.publish(items[n].field, Ok(items[n].value.clone()));
                    }
                }
                Err(TxError::Exception(Exception::ILLEGAL_FUNCTION))
                    if op.is_multiple() && op.items().len() > 1 =>
                {
                    // The device has no FC15/FC16: write these (and later ones) one by one.
                    tracing::info!(device = %device.name(), slave = p.slave, "device refused FC15/FC16; writing items one at a time");
                    p.single_writes = true;
                    let subset = op.items().to_vec();
                    let sub: Vec<WriteItem> = subset.iter().map(|&n| items[n].clone()).collect();
                    let (singles, _) = plan::write_ops(&device.profile, &sub, true);
                    for single in singles.into_iter().rev() {
                        ops.push_front(single.remap(&subset));
                    }
                }
                Err(e) => {
                    let failed = WriteError::from(e.clone());
                    for &n in op.items() {
                        finish(&items[n], Err(failed.clone()));
                    }
                    if matches!(e, TxError::Exception(_)) {
                        continue;
                    }
                    // The device or the link is gone: the rest cannot be written now.
                    for rest in ops.drain(..) {
                        for &n in rest.items() {
                            finish(
                                &items[n],
                                Err(WriteError::NotSent(Box::new(failed.clone()))),
                            );
                        }
                    }
                    p.rewrite = true;
                    if let Some(fault) = connection_fault(&e) {
                        return Err(fault);
                    }
                    tracing::warn!(device = %device.name(), slave = p.slave, error = %e, "write got no answer; backing off");
                    p.lost(e, Duration::ZERO);
                }
            }
        }
        Ok(())
    }
}

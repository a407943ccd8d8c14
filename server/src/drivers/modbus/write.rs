//! Putting a Modbus device's requested outputs on the bus: grouped into as few
//! transactions as the device allows, each outcome reported; a device without FC15/FC16 is
//! written item by item from then on.

use std::collections::VecDeque;
use std::time::Duration;

use super::{Bus, Plan, connection_fault};
use super::{WriteOp, write_ops};
use crate::cache::{Device, FieldError, WriteError};
use crate::drivers::WriteItem;
use crate::drivers::{finish, written};
use crate::link::frame::Exception;
use crate::link::{LinkFault, TxError};

/// The first wait before a write answered "busy" (06) or "acknowledge" (05) is sent again;
/// it doubles with each try, up to [`BUSY_BACKOFF_MAX`].
pub(crate) const BUSY_BACKOFF: Duration = Duration::from_millis(20);
pub(crate) const BUSY_BACKOFF_MAX: Duration = Duration::from_millis(320);

/// Whether an exception says "later", not "no".
fn transient(e: &TxError) -> bool {
    matches!(e, TxError::Exception(x) if *x == Exception::ACKNOWLEDGE || *x == Exception::SERVER_DEVICE_BUSY)
}

/// Sends one write operation; a device that answers busy or acknowledge gets it again after
/// a short backoff, within the device's `retries` (timeouts are retried by the bus). Answers
/// the result and how many transactions it took.
async fn send(bus: &mut Bus, device: &Device, op: &WriteOp) -> (Result<(), TxError>, u32) {
    let mut again = 0;
    let mut backoff = BUSY_BACKOFF;
    let _ = bus.take_sent();
    loop {
        let result = match op {
            WriteOp::Direct { request, .. } => bus
                .transact(device, request, device.config.retries)
                .await
                .0
                .map(drop),
            WriteOp::Bits { address, bits, .. } => bus.write_bits(device, *address, bits).await,
        };
        match result {
            Err(e) if transient(&e) && again < device.config.retries => {
                tracing::debug!(device = %device.name(), error = %e, retry_in = ?backoff, "write refused for now; sending it again");
                again += 1;
                tokio::time::sleep(backoff).await;
                backoff = (backoff * 2).min(BUSY_BACKOFF_MAX);
            }
            result => return (result, bus.take_sent()),
        }
    }
}

/// The items of `op` as single writes, before the rest of `ops`.
fn one_by_one(device: &Device, items: &[WriteItem], op: &WriteOp, ops: &mut VecDeque<WriteOp>) {
    let subset = op.items().to_vec();
    let sub: Vec<WriteItem> = subset.iter().map(|&n| items[n].clone()).collect();
    let (singles, _) = write_ops(&device.profile, &sub, true);
    for single in singles.into_iter().rev() {
        ops.push_front(single.remap(&subset));
    }
}

/// Writes `items` in the fewest transactions the device allows, finishing each with its
/// outcome. `Some` when the device stopped answering.
pub(super) async fn outputs(
    bus: &mut Bus,
    device: &Device,
    plan: &mut Plan,
    items: Vec<WriteItem>,
) -> Result<Option<FieldError>, LinkFault> {
    let (ops, refused) = write_ops(&device.profile, &items, plan.single_writes);
    for (n, reason) in refused {
        finish(device, &items[n], Err(reason), 0);
    }
    let mut ops: VecDeque<WriteOp> = ops.into();
    while let Some(op) = ops.pop_front() {
        let (result, attempts) = send(bus, device, &op).await;
        match result {
            Ok(()) => {
                for &n in op.items() {
                    written(device, &items[n], attempts);
                }
            }
            Err(TxError::Exception(Exception::ILLEGAL_FUNCTION))
                if op.is_multiple() && op.items().len() > 1 =>
            {
                // The device has no FC15/FC16: write these (and later ones) one by one.
                tracing::info!(device = %device.name(), slave = plan.slave, "device refused FC15/FC16; writing items one at a time");
                plan.single_writes = true;
                one_by_one(device, &items, &op, &mut ops);
            }
            Err(e) => {
                // The link lost with the write sent counts towards not writing it again
                // after every reconnect (`Outputs::finish`).
                let failed = match connection_fault(&e) {
                    Some(fault) => WriteError::LinkDown(fault),
                    None => WriteError::from(e.clone()),
                };
                for &n in op.items() {
                    finish(device, &items[n], Err(failed.clone()), attempts);
                }
                if matches!(e, TxError::Exception(_)) {
                    continue;
                }
                // The device or the link is gone: the rest cannot be written now.
                for rest in ops.drain(..) {
                    for &n in rest.items() {
                        finish(
                            device,
                            &items[n],
                            Err(WriteError::NotSent(Box::new(failed.clone()))),
                            0,
                        );
                    }
                }
                if let Some(fault) = connection_fault(&e) {
                    return Err(fault);
                }
                tracing::warn!(device = %device.name(), slave = plan.slave, error = %e, "write got no answer; backing off");
                return Ok(Some(FieldError::NoResponse(e)));
            }
        }
    }
    Ok(None)
}

//! A Modbus device's read cycle: each read batch with its retries, decoded and published;
//! a batch the device refuses is split.

use std::time::Duration;

use super::{Bus, Plan, connection_fault};
use crate::cache::{Device, FieldError};
use crate::drivers::Read;
use crate::link::frame::Exception;
use crate::link::{LinkFault, TxError};

/// Reads every batch of the device's plan and publishes its fields.
pub(super) async fn cycle(
    bus: &mut Bus,
    device: &Device,
    plan: &mut Plan,
) -> Result<Read, LinkFault> {
    let mut k = 0;
    let mut last_response = Duration::ZERO;
    while k < plan.reads.len() {
        let batch = plan.reads[k].clone();
        let (result, elapsed) = bus
            .transact(device, &batch.request(), device.config.retries)
            .await;
        match result {
            Ok(response) => {
                last_response = elapsed;
                let now = crate::cache::Stamp::now();
                for (field, value) in batch.decode(&device.profile, &response) {
                    device.publish_at(field, value, now);
                }
                k += 1;
            }
            Err(TxError::Exception(x))
                if (x == Exception::ILLEGAL_DATA_ADDRESS || x == Exception::ILLEGAL_DATA_VALUE)
                    && batch.fields.len() > 1 =>
            {
                if let Some((a, b)) = batch.split(&device.profile) {
                    tracing::info!(device = %device.name(), address = batch.address, count = batch.count, exception = %x, "device refused a batch; splitting it");
                    plan.reads.splice(k..=k, [a, b]);
                }
            }
            Err(TxError::Exception(x)) => {
                last_response = elapsed;
                let now = crate::cache::Stamp::now();
                for &field in &batch.fields {
                    device.publish_at(field, Err(FieldError::Exception(x)), now);
                }
                k += 1;
            }
            Err(e) => {
                if let Some(fault) = connection_fault(&e) {
                    return Err(fault);
                }
                return Ok(Read::Silent(FieldError::NoResponse(e)));
            }
        }
    }
    Ok(Read::Answered(last_response))
}

//! Modbus (RTU and ASCII on serial lines; MBAP, RTU or ASCII frames over TCP) as a driver:
//! a link opens its port or socket (`crate::link`), a device's reads are the batches
//! `read_batches` makes from its profile (`batches.rs`), its writes the fewest transactions
//! `write_ops` allows (`groups.rs`), a serial line's time is budgeted by `budget.rs`, and
//! `describe.rs` prints the plan. The bytes and the transaction rules stay in `crate::link`,
//! shared with the Modbus server and the scan.

mod batches;
mod budget;
mod bus;
mod describe;
mod groups;
mod read;
mod write;

use std::sync::Arc;

pub(crate) use batches::{ReadBatch, read_batches, read_request};
pub(crate) use budget::{cycle_time, transaction_time, utilisation};
pub(crate) use bus::Bus;
pub(crate) use groups::{WriteOp, write_ops};

use super::{Driver, Facts, Planned, Probed, Read, Session, WriteItem};
use crate::cache::{Device, FieldError, Link, Passthrough, PassthroughError, Probe};
use crate::config::{LinkConfig, Transport};
use crate::link::timing::LineTiming;
use crate::link::{self, LinkFault, TxError};
use crate::metrics::Metrics;

/// The Modbus driver.
pub(crate) struct Modbus;

/// What is kept of a Modbus device.
pub(crate) struct Plan {
    pub(crate) slave: u8,
    /// Its read batches; a batch the device refuses is split here, and kept split.
    pub(crate) reads: Vec<ReadBatch>,
    /// The device refused FC15/FC16 (exception 01): write items one at a time.
    pub(crate) single_writes: bool,
}

impl Driver for Modbus {
    type Plan = Plan;
    type Session = Bus;
    const NAME: &'static str = "modbus";
    const READS_BACK_TO_BACK: bool = true;
    /// A serial line's or a TCP link's settings are the config reader's own.
    type Settings = ();

    const READ_SETTINGS: super::ReadSettings<()> = |_, _, _| Some(());

    fn serves(config: &LinkConfig) -> bool {
        matches!(
            config.transport,
            Transport::Serial(_) | Transport::Tcp { .. }
        )
    }

    fn speaks(protocol: crate::profile::Protocol) -> bool {
        protocol.is_modbus()
    }

    fn describe(link: &LinkConfig, devices: &Planned<'_>, _: &Facts, out: &mut String) {
        describe::link(link, devices, out);
    }

    fn plan_warnings(link: &LinkConfig, devices: &Planned<'_>) -> Vec<String> {
        describe::warnings(link, devices)
    }

    fn plan(device: &Device) -> Plan {
        Plan {
            slave: device.slave_id().unwrap_or(0),
            reads: read_batches(
                &device.profile,
                device.config.max_batch,
                device.config.max_gap,
            ),
            single_writes: false,
        }
    }

    fn planned_utilisation<'a>(
        config: &LinkConfig,
        devices: impl Iterator<Item = (&'a Device, &'a Plan)>,
    ) -> Option<f64> {
        let Transport::Serial(s) = &config.transport else {
            return None;
        };
        Some(utilisation(
            devices.map(|(d, p)| (&d.config, p.reads.as_slice())),
            &LineTiming::new(s),
            config.guard_time,
        ))
    }

    async fn open(
        config: &LinkConfig,
        link: &Arc<Link>,
        metrics: &Arc<Metrics>,
    ) -> Result<Bus, LinkFault> {
        let conn = link::open(config, config.guard_time).await?;
        Ok(Bus::new(
            conn,
            metrics.clone(),
            link.name().to_owned(),
            link.progress.clone(),
            link.utilisation.clone(),
        ))
    }
}

/// Whether a transaction's failure ends the connection.
pub(crate) fn connection_fault(e: &TxError) -> Option<LinkFault> {
    match e {
        TxError::Io(io) => Some(LinkFault::Lost(io.clone())),
        _ => None,
    }
}

impl Session for Bus {
    type Plan = Plan;

    async fn read(&mut self, device: &Arc<Device>, plan: &mut Plan) -> Result<Read, LinkFault> {
        read::cycle(self, device, plan).await
    }

    async fn probe(&mut self, device: &Arc<Device>, plan: &mut Plan) -> Result<Probed, LinkFault> {
        let Some(first) = plan.reads.first() else {
            return Ok(Probed::Nothing);
        };
        let (result, _) = self.transact(device, &first.request(), 0).await;
        match result {
            Ok(_) | Err(TxError::Exception(_)) => Ok(Probed::Answers),
            Err(e) => match connection_fault(&e) {
                Some(fault) => Err(fault),
                None => Ok(Probed::Silent(FieldError::NoResponse(e))),
            },
        }
    }

    async fn write(
        &mut self,
        device: &Arc<Device>,
        plan: &mut Plan,
        items: Vec<WriteItem>,
    ) -> Result<Option<FieldError>, LinkFault> {
        write::outputs(self, device, plan, items).await
    }

    /// Sends a queued request as it is, and answers it.
    async fn pass_through(&mut self, queued: Passthrough, label: &str) -> Result<(), LinkFault> {
        if let Some(stage) = &queued.stage {
            stage.send_replace(crate::cache::Stage::Sent);
        }
        let (result, _) = self
            .transact_as(label, queued.slave, queued.timeout, &queued.request, 0)
            .await;
        let fault = result.as_ref().err().and_then(connection_fault);
        let _ = queued.reply.send(result.map_err(PassthroughError::from));
        fault.map_or(Ok(()), Err)
    }

    /// Sends a scan's probe between polls; a link that is not RTU answers it unsent.
    async fn scan_probe(&mut self, queued: Probe) -> Result<(), LinkFault> {
        let result = self.probe_slot(&queued).await;
        let fault = result.as_ref().err().and_then(connection_fault);
        let _ = queued.reply.send(result.map_err(PassthroughError::from));
        fault.map_or(Ok(()), Err)
    }
}

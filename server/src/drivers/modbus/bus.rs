//! The open connection of a link's task and what is measured on it: each transaction with
//! its retries, byte counts, and the bus time used against the time planned.

use std::sync::Arc;
use std::time::Duration;

use tokio::time::Instant;

use crate::cache::{Device, Progress, Utilisation};
use crate::link::frame::{Malformed, Request, Response};
use crate::link::{Connection, Counters, TxError};
use crate::metrics::Metrics;

const UTILISATION_WINDOW: Duration = Duration::from_secs(1);

/// The connection and what is measured on it.
pub(crate) struct Bus {
    conn: Connection,
    metrics: Arc<Metrics>,
    link: String,
    busy: Duration,
    window_start: Instant,
    counted: Counters,
    /// Each transaction's deadline, for the watchdog.
    progress: Arc<Progress>,
    /// The link's utilisation: the planned share read, the measured one kept (besides the
    /// metrics).
    utilisation: Arc<Utilisation>,
    /// Transactions sent since the caller last took the count.
    sent: u32,
}

/// A transaction's bound beyond its timeout: the request's and the answer's time on the
/// slowest line (256 bytes at 1200 baud), and the silences around them.
const WIRE_BOUND: Duration = Duration::from_secs(5);

impl Bus {
    pub(crate) fn new(
        conn: Connection,
        metrics: Arc<Metrics>,
        link: String,
        progress: Arc<Progress>,
        utilisation: Arc<Utilisation>,
    ) -> Self {
        Bus {
            progress,
            utilisation,
            sent: 0,
            counted: conn.counters(),
            conn,
            metrics,
            link,
            busy: Duration::ZERO,
            window_start: Instant::now(),
        }
    }

    /// One transaction, tried `1 + retries` times when the device does not answer properly.
    pub(crate) async fn transact(
        &mut self,
        device: &Device,
        request: &Request,
        retries: u32,
    ) -> (Result<Response, TxError>, Duration) {
        let slave = device.slave_id().unwrap_or(0);
        let timeout = device.config.timeout;
        self.transact_as(device.name(), slave, timeout, request, retries)
            .await
    }

    /// A scan's probe: the bytes heard within its slot. Only an RTU connection carries one
    /// (an MBAP or ASCII link answers with an invalid-response error, nothing sent).
    pub(crate) async fn probe_slot(
        &mut self,
        probe: &crate::cache::Probe,
    ) -> Result<Vec<u8>, TxError> {
        let crate::link::Connection::Rtu(rtu) = &mut self.conn else {
            return Err(TxError::Invalid(crate::link::frame::Malformed::NotRtu));
        };
        let started = Instant::now();
        self.progress.started(started + probe.slot + WIRE_BOUND);
        self.sent = self.sent.saturating_add(1);
        let heard = rtu
            .probe(probe.slave, &probe.pdu, started + probe.slot, probe.early)
            .await;
        self.progress.ended();
        self.busy += started.elapsed();
        self.account();
        heard
    }

    /// One transaction to `slave`, counted in the metrics under `label` (a device name).
    pub(crate) async fn transact_as(
        &mut self,
        label: &str,
        slave: u8,
        timeout: Duration,
        request: &Request,
        retries: u32,
    ) -> (Result<Response, TxError>, Duration) {
        let mut attempt = 0;
        loop {
            let started = Instant::now();
            self.progress.started(started + timeout + WIRE_BOUND);
            self.sent = self.sent.saturating_add(1);
            let result = self.conn.transact(slave, request, timeout).await;
            self.progress.ended();
            let elapsed = started.elapsed();
            self.busy += elapsed;
            self.metrics
                .transaction(label, request.function(), &result, elapsed);
            self.account();
            match &result {
                Err(e @ (TxError::Timeout | TxError::Crc | TxError::Invalid(_)))
                    if attempt < retries =>
                {
                    tracing::debug!(device = %label, function = %request.function(), attempt, error = %e, "retrying");
                    attempt += 1;
                }
                _ => return (result, elapsed),
            }
        }
    }

    /// Transactions sent since the last call (retries included).
    pub(crate) fn take_sent(&mut self) -> u32 {
        std::mem::take(&mut self.sent)
    }

    /// Sets bits of a holding register, keeping the others: FC03 read, then FC06 write.
    pub(crate) async fn write_bits(
        &mut self,
        device: &Device,
        address: u16,
        bits: &[(u8, bool)],
    ) -> Result<(), TxError> {
        let retries = device.config.retries;
        let read = Request::ReadHoldingRegisters { address, count: 1 };
        let current = match self.transact(device, &read, retries).await.0? {
            Response::Registers(regs) if regs.len() == 1 => regs[0],
            other => {
                return Err(TxError::Invalid(Malformed::Unexpected {
                    function: read.function(),
                    response: other,
                }));
            }
        };
        let value = bits.iter().fold(current, |acc, &(bit, on)| {
            if on {
                acc | 1 << bit
            } else {
                acc & !(1 << bit)
            }
        });
        let write = Request::WriteSingleRegister { address, value };
        self.transact(device, &write, retries).await.0.map(drop)
    }

    /// Moves byte counts and the measured utilisation into the metrics.
    fn account(&mut self) {
        let now = self.conn.counters();
        self.metrics.link_bytes(
            &self.link,
            now.bytes_sent - self.counted.bytes_sent,
            now.bytes_received - self.counted.bytes_received,
            now.bytes_discarded - self.counted.bytes_discarded,
        );
        self.counted = now;
        let window = self.window_start.elapsed();
        if window >= UTILISATION_WINDOW {
            let measured = (self.busy.as_secs_f64() / window.as_secs_f64()).min(1.0);
            let (planned, _) = self.utilisation.get();
            self.metrics.link_utilisation(&self.link, planned, measured);
            self.utilisation.set_measured(measured);
            self.busy = Duration::ZERO;
            self.window_start = Instant::now();
        }
    }
}

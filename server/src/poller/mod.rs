//! The task that owns a link: it opens (and reopens) the port, then polls the link's devices,
//! each at its `refresh_rate`, the most overdue first; pending writes go before reads. A
//! device that stops answering is backed off: until it answers again it costs the link one
//! probe transaction (one timeout) per backoff period, and the other devices keep their rates.
//!
//! `bus` holds the connection and its measurements, `read` a device's poll cycle, `write`
//! putting its requested outputs on the bus.

mod bus;
mod poll_cycle;
pub(crate) mod watchdog;
mod write_outputs;

use std::sync::Arc;
use std::time::Duration;

use tokio::time::{Instant, sleep_until};
use tokio_util::sync::CancellationToken;

use tokio::sync::watch;

use crate::cache::{
    Device, FieldError, Inbox, Link, LinkDiagnostics, LinkState, Passthrough, PassthroughError,
    Probe, WriteError,
};
use crate::config::{LinkConfig, Transport};
use crate::link::timing::LineTiming;
use crate::link::{self, LinkCode, LinkFault, TxError};
use crate::metrics::Metrics;
use crate::plan::{self, ReadBatch};
use bus::Bus;

/// Waits between attempts to open a link: doubling from the first to the last.
pub(crate) const REOPEN_MIN: Duration = Duration::from_millis(250);
pub(crate) const REOPEN_MAX: Duration = Duration::from_secs(8);
/// How long a device that stopped answering is left alone: doubling up to the maximum.
pub(crate) const BACKOFF_MIN: Duration = Duration::from_secs(1);
pub(crate) const BACKOFF_MAX: Duration = Duration::from_secs(16);
/// Connecting to a TCP endpoint gives up after this long.
pub(crate) const CONNECT_TIMEOUT: Duration = Duration::from_secs(3);

/// A step of the task ends the connection only when the port or socket failed.
type Step = Result<(), LinkFault>;

struct Polled {
    device: Arc<Device>,
    slave: u8,
    reads: Vec<ReadBatch>,
    next_due: Instant,
    /// Set while the device does not answer: when to probe it next, and the period.
    backoff: Option<(Instant, Duration)>,
    /// Write the latest requested outputs again (after a reconnect).
    rewrite: bool,
    /// The device refused FC15/FC16 (exception 01): write items one at a time.
    single_writes: bool,
    /// When each output was last written again by `write_mode: reconcile`.
    reconciled: std::collections::HashMap<usize, Instant>,
}

impl Polled {
    fn due(&self) -> Instant {
        self.backoff.map_or(self.next_due, |(until, _)| until)
    }

    /// Leaves the device alone for the first backoff period, or twice the last one.
    fn back_off(&mut self) {
        let period = self
            .backoff
            .map_or(BACKOFF_MIN, |(_, d)| (d * 2).min(BACKOFF_MAX));
        self.backoff = Some((Instant::now() + period, period));
    }

    /// The device stopped answering (`error` after the retries): it is disconnected, its
    /// fields are bad, it is backed off, and its outputs are written again when it is back.
    fn lost(&mut self, error: TxError, cycle: Duration) {
        self.device.record_cycle(false, cycle);
        self.device.fail_reads(&FieldError::NoResponse(error));
        self.backoff = None;
        self.back_off();
        self.rewrite = true;
    }
}

/// How a wait for the next attempt to open a link ended.
enum Waited {
    Shutdown,
    /// The time to try again came.
    Retry,
    /// The link was declared again with other settings: open it now.
    Reconfigured,
}

enum Ended {
    Shutdown,
    Lost(LinkFault),
    /// The link's settings changed (a configuration reload): open it again with them.
    Reconfigured,
}

/// Whether a transaction's failure ends the connection.
fn connection_fault(e: &TxError) -> Option<LinkFault> {
    match e {
        TxError::Io(io) => Some(LinkFault::Lost(io.clone())),
        _ => None,
    }
}

pub(crate) struct LinkTask {
    link: Arc<Link>,
    /// The link's settings and members as published; taken in between transactions.
    state: watch::Receiver<LinkState>,
    /// The settings taken in last.
    config: LinkConfig,
    devices: Vec<Polled>,
    metrics: Arc<Metrics>,
    /// Round-robin position for writes.
    cursor: usize,
}

impl LinkTask {
    pub(crate) fn new(link: Arc<Link>, metrics: Arc<Metrics>) -> Self {
        let state = link.subscribe();
        let config = link.config();
        let mut task = LinkTask {
            link,
            state,
            config,
            devices: Vec::new(),
            metrics,
            cursor: 0,
        };
        task.sync_members();
        task
    }

    /// Takes in the link's newest settings and members, if they changed since the last
    /// look: new devices are polled at once, removed ones let go.
    fn sync_members(&mut self) {
        if self.state.has_changed().unwrap_or(false) {
            self.take_state();
        }
    }

    /// Takes in the link's newest settings and members.
    fn take_state(&mut self) {
        let LinkState { config, members } = self.state.borrow_and_update().clone();
        self.config = config;
        let now = Instant::now();
        self.devices
            .retain(|p| members.iter().any(|m| Arc::ptr_eq(m, &p.device)));
        self.cursor = 0;
        let new: Vec<_> = members
            .into_iter()
            .filter(|m| !self.devices.iter().any(|p| Arc::ptr_eq(m, &p.device)))
            .collect();
        for device in new {
            tracing::debug!(link = %self.link.name(), device = %device.name(), "polling device");
            let rewrite = device.rewrite_first();
            self.devices.push(Polled {
                slave: device.slave_id().unwrap_or(0),
                reads: plan::read_batches(
                    &device.profile,
                    device.config.max_batch,
                    device.config.max_gap,
                ),
                device,
                next_due: now,
                backoff: None,
                rewrite,
                single_writes: false,
                reconciled: std::collections::HashMap::new(),
            });
        }
        let config = &self.config;
        // The bus utilisation the refresh rates demand (serial links), kept with the link.
        let planned = match &config.transport {
            Transport::Serial(s) => Some(plan::utilisation(
                self.devices
                    .iter()
                    .map(|p| (&p.device.config, p.reads.as_slice())),
                &LineTiming::new(s),
                config.guard_time,
            )),
            Transport::Tcp { .. } => None,
        };
        self.link.utilisation.set_planned(planned);
        if let Some(u) = planned {
            self.metrics
                .link_utilisation(self.link.name(), planned, 0.0);
            if u > 1.0 {
                tracing::warn!(link = %self.link.name(), utilisation = format!("{:.0}%", u * 100.0), "the refresh rates need more than the line can carry");
            }
        }
    }

    fn set_state(&self, connected: bool, error_code: LinkCode) {
        self.link.set_diagnostics(LinkDiagnostics {
            connected,
            error_code,
        });
    }

    pub(crate) async fn run(mut self, token: CancellationToken) {
        let name = self.link.name().to_owned();
        let mut reopen = REOPEN_MIN;
        let mut lost = false;
        // Why the link is down, logged once per distinct reason.
        let mut down: Option<LinkFault> = None;
        'reopen: loop {
            self.sync_members();
            let tried = self.config.clone();
            let opened = tokio::select! {
                _ = token.cancelled() => break,
                r = tokio::time::timeout(CONNECT_TIMEOUT, link::open(&tried, tried.guard_time)) => r,
            };
            match opened.unwrap_or(Err(LinkFault::ConnectTimeout(CONNECT_TIMEOUT))) {
                Err(fault) => {
                    self.set_state(false, if lost { LinkCode::Lost } else { fault.code() });
                    if down.as_ref().map(ToString::to_string) != Some(fault.to_string()) {
                        tracing::warn!(link = %name, error = %fault, retry_in = ?reopen, "cannot open the link");
                    }
                    self.all_unreachable(&fault);
                    down = Some(fault);
                }
                Ok(conn) => {
                    reopen = REOPEN_MIN;
                    let bus = self.opened(conn, lost);
                    match self.serve(bus, &token, &tried).await {
                        Ended::Shutdown => break,
                        Ended::Reconfigured => {
                            tracing::info!(link = %name, "link settings changed: reopening");
                            self.set_state(false, LinkCode::Ok);
                            for p in &self.devices {
                                p.device.mark_stale();
                            }
                            reopen = REOPEN_MIN;
                            continue 'reopen;
                        }
                        Ended::Lost(fault) => {
                            tracing::warn!(link = %name, error = %fault, "link lost, reopening");
                            lost = true;
                            self.set_state(false, LinkCode::Lost);
                            self.all_unreachable(&fault);
                            down = Some(fault);
                        }
                    }
                }
            }
            match self
                .wait_down(&token, Instant::now() + reopen, down.as_ref(), &tried)
                .await
            {
                Waited::Shutdown => break 'reopen,
                Waited::Reconfigured => {
                    reopen = REOPEN_MIN;
                    continue 'reopen;
                }
                Waited::Retry => {}
            }
            reopen = (reopen * 2).min(REOPEN_MAX);
        }
        self.set_state(false, self.link.diagnostics().error_code);
        tracing::debug!(link = %name, "link task stopped");
    }

    /// The link just opened: its state and metrics say so, every device is due now and has
    /// its outputs written again.
    fn opened(&mut self, conn: link::Connection, lost: bool) -> Bus {
        let name = self.link.name().to_owned();
        if lost {
            self.metrics.link_reconnected(&name);
        }
        tracing::info!(link = %name, "link open");
        self.set_state(true, LinkCode::Ok);
        let now = Instant::now();
        for p in &mut self.devices {
            p.rewrite = true;
            p.next_due = now;
            p.backoff = None;
        }
        Bus::new(
            conn,
            self.metrics.clone(),
            name,
            self.link.progress.clone(),
            self.link.utilisation.clone(),
        )
    }

    /// Waits for the next attempt to open the link (`retry_at`). While the link is down,
    /// writes (and devices declared meanwhile) are answered at once rather than then.
    async fn wait_down(
        &mut self,
        token: &CancellationToken,
        retry_at: Instant,
        down: Option<&LinkFault>,
        tried: &LinkConfig,
    ) -> Waited {
        loop {
            tokio::select! {
                _ = token.cancelled() => return Waited::Shutdown,
                _ = sleep_until(retry_at) => return Waited::Retry,
                _ = self.link.wake.notified() => {
                    if let Some(fault) = down {
                        self.all_unreachable(fault);
                    }
                }
                Ok(()) = self.state.changed() => {
                    self.take_state();
                    if self.config != *tried {
                        // Declared again with a port: open it now.
                        return Waited::Reconfigured;
                    }
                    if let Some(fault) = down {
                        self.all_unreachable(fault);
                    }
                }
            }
        }
    }

    /// What of the inbox may go on the line: a request or probe whose caller has gone, or
    /// whose deadline would pass before its answer could come, is never sent.
    fn admit(&self, queued: Inbox) -> Option<Inbox> {
        if queued.abandoned() {
            self.metrics.inbox_dropped(self.link.name(), "abandoned");
            return None;
        }
        if queued.too_late(Instant::now()) {
            self.metrics.inbox_dropped(self.link.name(), "expired");
            queued.refuse(PassthroughError::Expired);
            return None;
        }
        Some(queued)
    }

    /// Sends a queued request as it is, and answers it.
    async fn pass_through(&mut self, queued: Passthrough, bus: &mut Bus) -> Step {
        if let Some(stage) = &queued.stage {
            stage.send_replace(crate::cache::Stage::Taken);
        }
        let label = self
            .devices
            .iter()
            .find(|p| p.slave == queued.slave)
            .map_or_else(
                || format!("unit{}", queued.slave),
                |p| p.device.name().to_owned(),
            );
        if let Some(stage) = &queued.stage {
            stage.send_replace(crate::cache::Stage::Sent);
        }
        let (result, _) = bus
            .transact_as(&label, queued.slave, queued.timeout, &queued.request, 0)
            .await;
        let fault = result.as_ref().err().and_then(connection_fault);
        let _ = queued.reply.send(result.map_err(PassthroughError::from));
        fault.map_or(Ok(()), Err)
    }

    /// Sends a scan's probe between polls; a link that is not RTU answers it unsent.
    async fn probe(&mut self, queued: Probe, bus: &mut Bus) -> Step {
        let result = bus.probe(&queued).await;
        let fault = result.as_ref().err().and_then(connection_fault);
        let _ = queued.reply.send(result.map_err(PassthroughError::from));
        fault.map_or(Ok(()), Err)
    }

    fn all_unreachable(&self, fault: &LinkFault) {
        while let Some(queued) = self.link.take_queued() {
            queued.refuse(PassthroughError::LinkDown(fault.clone()));
        }
        for p in &self.devices {
            p.device.set_unreachable();
            p.device.fail_reads(&FieldError::Unreachable(fault.clone()));
            for w in p.device.take_writes() {
                p.device
                    .finish_write(w.generation, Err(WriteError::LinkDown(fault.clone())));
            }
        }
    }

    async fn serve(
        &mut self,
        mut bus: Bus,
        token: &CancellationToken,
        opened: &LinkConfig,
    ) -> Ended {
        // Requests and polling share the line: while a poll is due, at most one request
        // goes between two poll cycles, so a device keeps its refresh rate as far as the
        // line carries it, however many requests wait.
        let mut after_request = false;
        loop {
            if token.is_cancelled() {
                return Ended::Shutdown;
            }
            self.sync_members();
            if self.config != *opened {
                return Ended::Reconfigured;
            }
            let due = self.next_due(Instant::now());
            let request = if after_request && due.is_some() {
                None
            } else {
                self.link.take_queued()
            };
            after_request = request.is_some();
            let step = if let Some(queued) = request {
                match self.admit(queued) {
                    Some(Inbox::Request(r)) => self.pass_through(r, &mut bus).await,
                    Some(Inbox::Probe(p)) => self.probe(p, &mut bus).await,
                    None => Ok(()),
                }
            } else if let Some(i) = self.next_writer() {
                self.write_device(i, &mut bus).await
            } else if let Some(i) = due {
                self.poll_device(i, &mut bus).await
            } else {
                let until = self
                    .devices
                    .iter()
                    .map(Polled::due)
                    .min()
                    .unwrap_or_else(|| Instant::now() + Duration::from_secs(3600));
                tokio::select! {
                    _ = token.cancelled() => return Ended::Shutdown,
                    _ = sleep_until(until) => {}
                    _ = self.link.wake.notified() => {}
                    Ok(()) = self.state.changed() => self.take_state(),
                }
                Ok(())
            };
            if let Err(fault) = step {
                return Ended::Lost(fault);
            }
        }
    }

    /// The next device, in round-robin order, with writes to put on the bus.
    fn next_writer(&mut self) -> Option<usize> {
        let n = self.devices.len();
        let found = (0..n).map(|k| (self.cursor + k) % n).find(|&i| {
            let p = &self.devices[i];
            let outputs = p.device.outputs();
            outputs.has_pending() || (p.rewrite && p.backoff.is_none() && outputs.has_requested())
        })?;
        self.cursor = (found + 1) % n;
        Some(found)
    }

    /// The most overdue device, if any is due.
    fn next_due(&self, now: Instant) -> Option<usize> {
        self.devices
            .iter()
            .enumerate()
            .filter(|(_, p)| p.due() <= now)
            .min_by_key(|(_, p)| p.due())
            .map(|(i, _)| i)
    }
}

#[cfg(test)]
#[path = "tests.rs"]
mod tests;

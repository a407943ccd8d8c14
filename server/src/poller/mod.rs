//! The task that owns a link, whatever its field protocol (`crate::drivers`): it opens (and
//! reopens) the link, then polls the link's devices, each at its `refresh_rate`, the most
//! overdue first; pending writes go before reads. A device that stops answering is backed
//! off: until it answers again it costs the link one probe (one timeout) per backoff period,
//! and the other devices keep their rates.
//!
//! `poll_cycle` is a device's poll cycle, `write_outputs` putting its requested outputs on
//! the link, `watchdog` the look at every link's progress. [`LinkTask::run`] lists the
//! drivers.

mod inbox;
mod link_task;
mod poll_cycle;
pub(crate) mod watchdog;
mod write_outputs;

use std::sync::Arc;
use std::time::Duration;

use tokio::time::{Instant, sleep_until};
use tokio_util::sync::CancellationToken;

use tokio::sync::watch;

use crate::cache::{
    Device, FieldError, Inbox, Link, LinkDiagnostics, LinkState, PassthroughError, WriteError,
};
use crate::config::LinkConfig;
use crate::drivers::{Driver, Session};
use crate::link::{LinkCode, LinkFault};
use crate::metrics::Metrics;
use crate::role::Role;
pub(crate) use link_task::LinkTask;

/// Waits between attempts to open a link: doubling from the first to the last.
pub(crate) const REOPEN_MIN: Duration = Duration::from_millis(250);
pub(crate) const REOPEN_MAX: Duration = Duration::from_secs(8);
/// How long a link stopped cleanly may take to tell the other end it leaves.
const CLOSE_TIMEOUT: Duration = Duration::from_secs(1);
/// How long a device that stopped answering is left alone: doubling up to the maximum.
pub(crate) const BACKOFF_MIN: Duration = Duration::from_secs(1);
pub(crate) const BACKOFF_MAX: Duration = Duration::from_secs(16);

/// A step of the task ends the connection only when the port or socket failed.
type Step = Result<(), LinkFault>;

struct Polled<P> {
    device: Arc<Device>,
    /// What the driver keeps of the device.
    plan: P,
    next_due: Instant,
    /// Set while the device does not answer: when to probe it next, and the period.
    backoff: Option<(Instant, Duration)>,
    /// Write the latest requested outputs again (after a reconnect).
    rewrite: bool,
    /// When each output was last written again by `write_mode: reconcile`.
    reconciled: std::collections::HashMap<usize, Instant>,
}

impl<P> Polled<P> {
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
    fn lost(&mut self, error: &FieldError, cycle: Duration) {
        self.device.record_cycle(false, cycle);
        self.device.fail_reads(error);
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

/// A link run with the driver `D`.
pub(crate) struct Driven<D: Driver> {
    link: Arc<Link>,
    /// The link's settings and members as published; taken in between transactions.
    state: watch::Receiver<LinkState>,
    /// The settings taken in last.
    config: LinkConfig,
    devices: Vec<Polled<D::Plan>>,
    metrics: Arc<Metrics>,
    /// Round-robin position for writes.
    cursor: usize,
    /// A device was read on the open connection: the link works, not merely opens.
    answered: bool,
    /// Whether a write may go on the field now (an active/standby pair's fence).
    role: Arc<Role>,
}

impl<D: Driver> Driven<D> {
    pub(crate) fn new(link: Arc<Link>, metrics: Arc<Metrics>) -> Self {
        let state = link.subscribe();
        let config = link.config();
        let mut task = Driven {
            link,
            state,
            config,
            devices: Vec::new(),
            metrics,
            cursor: 0,
            answered: false,
            role: Arc::new(Role::alone()),
        };
        task.sync_members();
        task
    }

    fn with_role(mut self, role: Arc<Role>) -> Self {
        self.role = role;
        self
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
                plan: D::plan(&device),
                device,
                next_due: now,
                backoff: None,
                rewrite,
                reconciled: std::collections::HashMap::new(),
            });
        }
        // The bus utilisation the refresh rates demand (serial links), kept with the link.
        let planned = D::planned_utilisation(
            &self.config,
            self.devices.iter().map(|p| (p.device.as_ref(), &p.plan)),
        );
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

    /// Runs the link until shutdown (or until it is given a protocol of another driver).
    async fn run(mut self, token: &CancellationToken) -> Ended {
        let name = self.link.name().to_owned();
        let mut reopen = REOPEN_MIN;
        let mut lost = false;
        // Why the link is down, logged once per distinct reason.
        let mut down: Option<LinkFault> = None;
        'reopen: loop {
            self.sync_members();
            if !D::serves(&self.config) {
                // Given another protocol: its driver takes over.
                return Ended::Reconfigured;
            }
            let tried = self.config.clone();
            // What the driver tells of the other end is of the connection it opens.
            self.link.clear_peer();
            let opened = tokio::select! {
                _ = token.cancelled() => break,
                r = tokio::time::timeout(D::OPEN_TIMEOUT, D::open(&tried, &self.link, &self.metrics)) => r,
            };
            match opened.unwrap_or(Err(LinkFault::ConnectTimeout(D::OPEN_TIMEOUT))) {
                Err(fault) => {
                    self.set_state(false, if lost { LinkCode::Lost } else { fault.code() });
                    self.link.set_down(Some(fault.to_string()));
                    if down.as_ref().map(ToString::to_string) != Some(fault.to_string()) {
                        tracing::warn!(link = %name, error = %fault, retry_in = ?reopen, "cannot open the link");
                    }
                    self.all_unreachable(&fault);
                    down = Some(fault);
                }
                Ok(mut conn) => {
                    self.opened(lost);
                    let opened_at = Instant::now();
                    let ended = self.serve(&mut conn, token, &tried).await;
                    if (self.answered || self.devices.is_empty())
                        && opened_at.elapsed() >= REOPEN_MAX
                    {
                        // The link worked, not merely opened (a device read, for longer
                        // than the longest wait): a loss now is retried soon.
                        reopen = REOPEN_MIN;
                    }
                    // Stopped, given other settings or lost: what was opened on the other
                    // end is closed where the protocol can say so (a peer's connections
                    // and sessions are scarce), bounded.
                    let _ = tokio::time::timeout(CLOSE_TIMEOUT, conn.close()).await;
                    match ended {
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
                            tracing::warn!(link = %name, error = %fault, retry_in = ?reopen, "link lost, reopening");
                            lost = true;
                            self.set_state(false, LinkCode::Lost);
                            self.link.set_down(Some(format!("lost: {fault}")));
                            self.all_unreachable(&fault);
                            down = Some(fault);
                        }
                    }
                }
            }
            match self
                .wait_down(token, Instant::now() + reopen, down.as_ref(), &tried)
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
        Ended::Shutdown
    }

    /// The link just opened: its state and metrics say so, every device is due now and has
    /// its outputs written again.
    fn opened(&mut self, lost: bool) {
        let name = self.link.name();
        if lost {
            self.metrics.link_reconnected(name);
        }
        tracing::info!(link = %name, protocol = D::NAME, "link open");
        self.answered = false;
        self.set_state(true, LinkCode::Ok);
        self.link.set_down(None);
        let now = Instant::now();
        for p in &mut self.devices {
            p.rewrite = true;
            p.next_due = now;
            p.backoff = None;
        }
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

    fn all_unreachable(&self, fault: &LinkFault) {
        while let Some(queued) = self.link.take_queued() {
            queued.refuse(PassthroughError::LinkDown(fault.clone()));
        }
        for p in &self.devices {
            p.device.set_unreachable();
            let why = FieldError::Unreachable(fault.clone());
            if D::STALE_WHILE_AWAY {
                p.device.doubt_reads(&why);
            } else {
                p.device.fail_reads(&why);
            }
            for w in p.device.take_writes() {
                p.device
                    .finish_write(w.generation, Err(WriteError::LinkDown(fault.clone())));
            }
        }
    }

    async fn serve(
        &mut self,
        session: &mut D::Session,
        token: &CancellationToken,
        opened: &LinkConfig,
    ) -> Ended {
        // Requests and polling share the line: while a poll is due, at most one request
        // goes between two poll cycles, so a device keeps its refresh rate as far as the
        // line carries it, however many requests wait.
        let mut after_request = false;
        // The wait for the next device due, to its microsecond: tokio's timer rounds up to
        // its next millisecond, which paced a device at a 1 ms refresh by the timer (a
        // millisecond and more between cycles) rather than by the refresh and the answers.
        let mut timer = crate::link::precise::Timer::new();
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
                    Some(Inbox::Request(r)) => self.pass_through(r, session).await,
                    Some(Inbox::Probe(p)) => session.scan_probe(p).await,
                    None => Ok(()),
                }
            } else if let Some(i) = self.next_writer() {
                self.write_device(i, session).await
            } else if let Some(i) = due {
                self.poll_device(i, session).await
            } else {
                let until = self
                    .devices
                    .iter()
                    .map(Polled::due)
                    .min()
                    .unwrap_or_else(|| Instant::now() + Duration::from_secs(3600));
                tokio::select! {
                    _ = token.cancelled() => return Ended::Shutdown,
                    _ = timer.sleep_until_coarse(until) => {}
                    _ = self.link.wake.notified() => {}
                    Ok(()) = self.state.changed() => self.take_state(),
                    fault = session.lost() => return Ended::Lost(fault),
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
            outputs.has_pending() || (p.rewrite && p.backoff.is_none() && outputs.has_replayable())
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

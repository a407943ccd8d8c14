//! A device's poll cycle: a probe while the device is backed off, then its driver's read;
//! the next poll on the device's grid; outputs written again where the device holds other
//! values (`write_mode: reconcile`).

use std::time::Duration;

use tokio::time::Instant;

use super::{Driven, Step};
use crate::config::WriteMode;
use crate::drivers::{Driver, Probed, Read, Session};

impl<D: Driver> Driven<D> {
    pub(super) async fn poll_device(&mut self, i: usize, session: &mut D::Session) -> Step {
        let p = &mut self.devices[i];
        let device = p.device.clone();
        let started = Instant::now();
        if p.backoff.is_some() {
            // A probe: one request, no retries.
            match session.probe(&device, &mut p.plan).await? {
                Probed::Answers => {
                    tracing::info!(device = %device.name(), "device answers again");
                    p.backoff = None;
                    p.rewrite = true;
                    if device.outputs().has_replayable() {
                        // Its outputs go first (as after a reconnect), judged by what the
                        // device was last read holding, then its read.
                        p.next_due = started;
                        return Ok(());
                    }
                }
                Probed::Silent(e) => {
                    p.back_off();
                    device.fail_reads(&e);
                    return Ok(());
                }
                Probed::Nothing => {
                    p.backoff = None;
                    return Ok(());
                }
            }
        }
        match session.read(&device, &mut p.plan).await? {
            Read::Answered(last_response) => {
                device.record_cycle(true, last_response);
                self.answered = true;
            }
            Read::Silent(e) => {
                if device.diagnostics().connected || p.backoff.is_none() {
                    tracing::warn!(device = %device.name(), error = %e, backoff = ?super::BACKOFF_MIN, "device does not answer");
                }
                p.lost(&e, started.elapsed());
                return Ok(());
            }
        }
        p.next_due = match device.config.refresh_rate {
            // Back to back: due again now, after the devices that were due before this
            // cycle started.
            Duration::ZERO if D::READS_BACK_TO_BACK => started,
            // A protocol whose values come by themselves has nothing to read back to back:
            // its link is looked at on a period that costs nothing while nobody asks.
            Duration::ZERO => next_on_grid(p.next_due, EVENTS_PERIOD, started),
            refresh => next_on_grid(p.next_due, refresh, started),
        };
        if device.config.write_mode == WriteMode::Reconcile {
            p.reconcile();
        }
        Ok(())
    }
}

/// A device's next poll: the first point of its grid (`due + n * period`) after the poll
/// that was due at `due` started. Late starts never shift the grid, so a 10 ms device is
/// polled 100 times a second when the line allows; a poll more than a period late skips the
/// points it missed (one poll, never a burst to catch up).
pub(crate) fn next_on_grid(due: Instant, period: Duration, started: Instant) -> Instant {
    let late = started.saturating_duration_since(due);
    let periods = late.as_nanos() / period.as_nanos().max(1) + 1;
    due + period * u32::try_from(periods).unwrap_or(u32::MAX)
}

/// How often a device at `0ms` of a protocol that does not read back to back is read.
const EVENTS_PERIOD: Duration = Duration::from_millis(100);

/// The least time between two reconciling writes of one output.
pub(crate) const RECONCILE_MIN: Duration = Duration::from_millis(100);

impl<P> super::Polled<P> {
    /// Requests the desired value of every output the device was just read holding another
    /// value in (origin `reconcile`), each at most once per refresh period and 100 ms.
    fn reconcile(&mut self) {
        let now = Instant::now();
        let every = self.device.config.refresh_rate.max(RECONCILE_MIN);
        for idx in 0..self.device.profile.fields.len() {
            let Some(desired) = self.device.mismatch(idx) else {
                continue;
            };
            if self
                .reconciled
                .get(&idx)
                .is_some_and(|at| now.duration_since(*at) < every)
            {
                continue;
            }
            self.reconciled.insert(idx, now);
            let field = &self.device.field(idx).name;
            tracing::info!(device = %self.device.name(), field = %field, "device holds another value than requested; writing it again");
            self.device
                .request_own(idx, desired, crate::write_log::Origin::Reconcile);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test(start_paused = true)]
    async fn polls_stay_on_their_grid_over_a_thousand_periods_however_late_they_start() {
        let period = Duration::from_millis(10);
        let start = Instant::now();
        let mut due = start;
        for n in 1..=1000u32 {
            // Started up to 9.9 ms late (the line busy with others, the timer's rounding).
            let late = Duration::from_micros(u64::from(n * 7919 % 9900));
            due = next_on_grid(due, period, due + late);
            assert_eq!(due, start + period * n, "poll {n}");
        }
    }

    #[tokio::test(start_paused = true)]
    async fn a_line_that_cannot_keep_up_skips_missed_polls_and_never_bursts() {
        let period = Duration::from_millis(10);
        let start = Instant::now();
        // Started 55 ms late: the points at 10..50 ms are skipped, the next is at 60 ms.
        let next = next_on_grid(start, period, start + Duration::from_millis(55));
        assert_eq!(next, start + Duration::from_millis(60));
        // A poll that starts exactly on a later point is due one period on.
        let next = next_on_grid(start, period, start + Duration::from_millis(30));
        assert_eq!(next, start + Duration::from_millis(40));
    }
}

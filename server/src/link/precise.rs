//! Waiting to a tenth of a millisecond, for line timing (inter-frame silences, guard times,
//! the late-reply window). tokio's timer rounds every deadline up to its next millisecond
//! tick, and the poller's timeout rounds again, which costs up to 2 ms per silence: on a
//! 115200-baud line, where the silence is 1.75 ms and a 10-register read 6.4 ms, that is a
//! third of the line. So a [`Timer`] waits on its own timerfd, armed to the nanosecond and
//! woken through the runtime's reactor like any socket, until [`FINISH`] before the
//! deadline, and finishes on the monotonic clock, yielding to other tasks between looks.
//! The timerfd alone wakes 90 µs late at the median on a virtual machine (its idle vCPU has
//! to be woken); the finish makes the median 0 and the 99th percentile about 10 µs (the
//! `suite` benchmark prints both). A core is busy only for that last stretch of a wait,
//! never while the line is idle.
//!
//! Under tokio's paused clock (tests) the wait is the runtime's own timer. Where a timerfd
//! cannot be had (another OS, or no file descriptor left), it is the runtime's timer too:
//! correct, only less exact.

use std::time::Duration;

use tokio::time::Instant;

/// How long before a deadline the timerfd hands over to the clock: above the wake-up
/// latency of nearly every timerfd expiration.
pub(crate) const FINISH: Duration = Duration::from_micros(250);

/// A timer for one user at a time (a link's transport keeps one).
#[derive(Default)]
pub struct Timer {
    #[cfg(target_os = "linux")]
    fd: Option<tokio::io::unix::AsyncFd<linux::Fd>>,
}

impl Timer {
    pub fn new() -> Self {
        Timer::default()
    }

    /// Returns at `deadline` (at once when it has passed).
    pub async fn sleep_until(&mut self, deadline: Instant) {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return;
        }
        if paused() {
            // The runtime's timer (other tasks run, and their timers fire, meanwhile) to
            // within its millisecond tick; then the crate's own tests step the clock exactly,
            // and elsewhere the timer ends the wait (at its next tick, in virtual time).
            if let Some(early) = deadline.checked_sub(Duration::from_millis(2))
                && early > Instant::now()
            {
                tokio::time::sleep_until(early).await;
            }
            #[cfg(test)]
            {
                let rest = deadline.saturating_duration_since(Instant::now());
                if !rest.is_zero() {
                    tokio::time::advance(rest).await;
                }
            }
            #[cfg(not(test))]
            tokio::time::sleep_until(deadline).await;
            return;
        }
        let real = std::time::Instant::now() + left;
        if left > FINISH {
            #[cfg(target_os = "linux")]
            let done = self.wait_on_fd(left - FINISH).await.is_ok();
            #[cfg(not(target_os = "linux"))]
            let done = false;
            if !done {
                tokio::time::sleep_until(deadline).await;
                return;
            }
        }
        while std::time::Instant::now() < real {
            tokio::task::yield_now().await;
        }
    }

    /// The timerfd alone, without the finish on the clock (no core busy while waiting;
    /// about 90 µs late at the median): the poller's wait for its next device due, and
    /// the benchmark's comparison.
    pub async fn sleep_until_coarse(&mut self, deadline: Instant) {
        let left = deadline.saturating_duration_since(Instant::now());
        #[cfg(target_os = "linux")]
        if !left.is_zero() && !paused() && self.wait_on_fd(left).await.is_ok() {
            return;
        }
        tokio::time::sleep_until(deadline).await;
    }

    #[cfg(target_os = "linux")]
    async fn wait_on_fd(&mut self, left: Duration) -> std::io::Result<()> {
        let fd = match &mut self.fd {
            Some(fd) => fd,
            // `AsyncFd::new` is deprecated in favour of the unsafe `register`, whose contract
            // (the value owns its descriptor and never closes or replaces it while
            // registered) `linux::Fd` keeps: it owns the timerfd and only arms and reads it.
            #[allow(deprecated)]
            empty => empty.insert(tokio::io::unix::AsyncFd::new(linux::Fd::new()?)?),
        };
        // Arming it again resets its count of expirations: a stale wake-up left by a wait
        // that was given up reads as nothing, below, and is waited past.
        fd.get_ref().arm(left)?;
        loop {
            let mut ready = fd.readable().await?;
            match ready.try_io(|fd| fd.get_ref().expired()) {
                Ok(result) => return result,
                Err(_would_block) => continue,
            }
        }
    }
}

/// Whether tokio's clock is paused: it stands still while real time passes.
fn paused() -> bool {
    let (clock, real) = (Instant::now(), std::time::Instant::now());
    while real.elapsed() < Duration::from_micros(2) {
        std::hint::spin_loop();
    }
    Instant::now() == clock
}

#[cfg(target_os = "linux")]
mod linux {
    use std::io;
    use std::os::fd::{AsFd, AsRawFd, RawFd};
    use std::time::Duration;

    use nix::sys::time::TimeSpec;
    use nix::sys::timerfd::{ClockId, Expiration, TimerFd, TimerFlags, TimerSetTimeFlags};

    /// A non-blocking CLOCK_MONOTONIC timerfd (tokio's clock is the monotonic clock).
    pub(crate) struct Fd(TimerFd);

    impl Fd {
        pub(crate) fn new() -> io::Result<Fd> {
            let flags = TimerFlags::TFD_NONBLOCK | TimerFlags::TFD_CLOEXEC;
            Ok(Fd(TimerFd::new(ClockId::CLOCK_MONOTONIC, flags)?))
        }

        /// Fires once, `after` from now.
        pub(crate) fn arm(&self, after: Duration) -> io::Result<()> {
            // A zero expiration would disarm it.
            let after = after.max(Duration::from_nanos(1));
            let expiration = Expiration::OneShot(TimeSpec::from_duration(after));
            Ok(self.0.set(expiration, TimerSetTimeFlags::empty())?)
        }

        /// Consumes the expiration; `WouldBlock` when it has not fired.
        pub(crate) fn expired(&self) -> io::Result<()> {
            Ok(self.0.wait()?)
        }
    }

    impl AsRawFd for Fd {
        fn as_raw_fd(&self) -> RawFd {
            self.0.as_fd().as_raw_fd()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test(start_paused = true)]
    async fn under_a_paused_clock_waits_end_exactly_at_their_deadline() {
        let mut timer = Timer::new();
        for wait in [
            Duration::from_micros(50),
            Duration::from_micros(330),
            Duration::from_micros(1750),
            Duration::from_millis(40),
        ] {
            let start = Instant::now();
            timer.sleep_until(start + wait).await;
            assert_eq!(start.elapsed(), wait);
        }
    }

    #[tokio::test]
    async fn a_deadline_in_the_past_does_not_wait() {
        let start = Instant::now();
        Timer::new().sleep_until(start).await;
        assert!(start.elapsed() < Duration::from_millis(5));
    }

    /// Real time: never early; how late is for the benchmark to tell (a shared machine can
    /// be late by anything), so only a gross bound is asserted here.
    #[tokio::test]
    async fn real_waits_are_never_early() {
        let mut timer = Timer::new();
        for wait in [
            Duration::from_micros(100),
            Duration::from_micros(1750),
            Duration::from_millis(3),
        ] {
            let start = Instant::now();
            timer.sleep_until(start + wait).await;
            let took = start.elapsed();
            assert!(took >= wait, "{wait:?}: {took:?}");
            assert!(
                took < wait + Duration::from_millis(500),
                "{wait:?}: {took:?}"
            );
        }
    }

    /// A wait given up (the line spoke first) leaves its timer armed; the next wait is not
    /// ended by the old expiration.
    #[tokio::test]
    async fn a_wait_given_up_does_not_end_the_next_one_early() {
        let mut timer = Timer::new();
        let start = Instant::now();
        let _ = tokio::time::timeout(
            Duration::from_millis(1),
            timer.sleep_until(start + Duration::from_micros(1500)),
        )
        .await;
        // Let the abandoned expiration pass.
        std::thread::sleep(Duration::from_millis(3));
        let again = Instant::now();
        timer.sleep_until(again + Duration::from_millis(5)).await;
        assert!(
            again.elapsed() >= Duration::from_millis(5),
            "{:?}",
            again.elapsed()
        );
    }
}

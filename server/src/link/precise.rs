//! Waiting to a tenth of a millisecond, for line timing (inter-frame silences, guard times,
//! the late-reply window). tokio's timer rounds every deadline up to its next millisecond
//! tick (and the poller's timeout rounds again), which costs up to 2 ms per silence: on a
//! 115200-baud line, where the silence is 0.33 ms and a 10-register read 3 ms, that is a
//! third of the line. So: sleep on the runtime's timer until [`COARSE_MARGIN`] before the
//! deadline ([`coarse`]), then finish on the precise clock ([`finish`]), yielding to other
//! tasks between looks. A
//! core is busy only for that last margin of each wait, never while the line is idle.
//!
//! Under tokio's paused clock (tests) the finish is the timer's own.

use std::time::Duration;

use tokio::time::Instant;

/// How long before a deadline the runtime's timer hands over to the precise clock.
pub const COARSE_MARGIN: Duration = Duration::from_micros(1500);

/// The last stretch to `deadline` (at most about [`COARSE_MARGIN`]) on the precise clock.
pub async fn finish(deadline: Instant) {
    let left = deadline.saturating_duration_since(Instant::now());
    if left.is_zero() {
        return;
    }
    // The same span on the monotonic clock. With tokio's clock running the two agree; a
    // clock that stands still while real time passes is paused, and its timer finishes.
    let (start, real_start) = (Instant::now(), std::time::Instant::now());
    let real = real_start + left.min(COARSE_MARGIN * 2);
    loop {
        let real_now = std::time::Instant::now();
        if real_now >= real {
            break;
        }
        if Instant::now() == start && real_now - real_start > Duration::from_micros(20) {
            break; // paused
        }
        tokio::task::yield_now().await;
    }
    let now = Instant::now();
    if now < deadline {
        // Only a paused clock gets here. The crate's own tests step it exactly; elsewhere its
        // timer ends the wait (at its next millisecond tick, in virtual time).
        #[cfg(test)]
        tokio::time::advance(deadline - now).await;
        #[cfg(not(test))]
        tokio::time::sleep_until(deadline).await;
    }
}

/// The instant before `deadline` at which a coarse timer (the runtime's, rounding up by up
/// to a millisecond) should fire so that it is not late: `None` when the deadline is too
/// near for one.
pub fn coarse(deadline: Instant) -> Option<Instant> {
    let early = deadline.checked_sub(COARSE_MARGIN)?;
    (early > Instant::now()).then_some(early)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The whole wait as its users make it: the coarse timer, then [`finish`].
    async fn sleep_until(deadline: Instant) {
        if let Some(early) = coarse(deadline) {
            tokio::time::sleep_until(early).await;
        }
        finish(deadline).await;
    }

    #[tokio::test(start_paused = true)]
    async fn under_a_paused_clock_waits_end_exactly_at_their_deadline() {
        for wait in [
            Duration::from_micros(50),
            Duration::from_micros(330),
            Duration::from_micros(1750),
            Duration::from_millis(40),
        ] {
            let start = Instant::now();
            sleep_until(start + wait).await;
            let took = start.elapsed();
            assert!(took >= wait, "{wait:?}: {took:?}");
            assert!(
                took <= wait + Duration::from_micros(100),
                "{wait:?}: {took:?}"
            );
        }
    }

    #[tokio::test]
    async fn a_deadline_in_the_past_does_not_wait() {
        let start = Instant::now();
        sleep_until(start).await;
        assert!(start.elapsed() < Duration::from_millis(5));
    }

    #[tokio::test]
    async fn coarse_fires_a_margin_early_or_not_at_all() {
        let now = Instant::now();
        assert_eq!(coarse(now + Duration::from_micros(500)), None);
        let far = now + Duration::from_millis(10);
        let early = coarse(far).expect("far enough");
        assert_eq!(far - early, COARSE_MARGIN);
    }
}

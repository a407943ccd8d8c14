//! What the command door logs of what clients send, within a bound: at most
//! [`PER_MESSAGE`] lines about one message and [`PER_SECOND`] lines a second; the lines
//! held back are counted and told in one line when their second is over (the front-end's
//! timer asks) or with the next line logged. A client that sends a DCMD of 100,000
//! metrics, or a thousand refused writes a second, cannot make the gateway write its log
//! full.

use std::time::{Duration, Instant};

/// Lines about one message.
pub(super) const PER_MESSAGE: u32 = 5;
/// Lines a second about every message together.
pub(super) const PER_SECOND: u32 = 20;

#[derive(Debug)]
pub(super) struct Said {
    second: Instant,
    in_second: u32,
    in_message: u32,
    held: u64,
}

impl Default for Said {
    fn default() -> Self {
        Said {
            second: Instant::now(),
            in_second: 0,
            in_message: 0,
            held: 0,
        }
    }
}

impl Said {
    /// A new message from a client starts.
    pub(super) fn message(&mut self) {
        self.in_message = 0;
    }

    /// Says how many lines were held back, once their second is over (the timer calls it,
    /// so a flood's count is told when the flood ends, not with the next message).
    pub(super) fn flush(&mut self) {
        if self.held > 0 && self.second.elapsed() >= Duration::from_secs(1) {
            self.second = Instant::now();
            self.in_second = 0;
            self.tell_held();
            self.in_second += 1;
        }
    }

    fn tell_held(&mut self) {
        tracing::warn!(
            lines = self.held,
            "lines about clients' MQTT messages not logged (at most {PER_MESSAGE} a message, {PER_SECOND} a second)"
        );
        self.held = 0;
    }

    /// Whether a line about the current message may be logged now; one that may not is
    /// counted (and said once the budget allows).
    pub(super) fn may(&mut self) -> bool {
        let now = Instant::now();
        if now.duration_since(self.second) >= Duration::from_secs(1) {
            self.second = now;
            self.in_second = 0;
        }
        if self.in_message >= PER_MESSAGE || self.in_second >= PER_SECOND {
            self.held += 1;
            return false;
        }
        if self.held > 0 {
            self.tell_held();
            self.in_second += 1;
        }
        self.in_second += 1;
        self.in_message += 1;
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_message_of_many_lines_and_a_flood_of_messages_are_bounded() {
        let mut said = Said::default();
        said.message();
        let logged = (0..100_000).filter(|_| said.may()).count();
        assert_eq!(logged, PER_MESSAGE as usize);
        assert_eq!(said.held, 100_000 - u64::from(PER_MESSAGE));
        let mut logged = 0;
        for _ in 0..1000 {
            said.message();
            logged += usize::from(said.may());
        }
        assert!(logged <= PER_SECOND as usize, "{logged}");
        // Told when its second is over, by the timer, with no message after it.
        assert!(said.held > 0);
        said.flush();
        assert!(said.held > 0, "not before the second ends");
        said.second -= Duration::from_secs(1);
        said.flush();
        assert_eq!(said.held, 0);
    }
}

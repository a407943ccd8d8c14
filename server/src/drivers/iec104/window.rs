//! What both ends of a 104 connection keep of its I-frames: the send and receive numbers
//! (modulo 2^15), at most `k` frames sent and not acknowledged (each within t1), frames
//! received acknowledged after `w` or t2, and a test frame after t3 of silence, confirmed
//! within t1. Bytes are the connection's; this only counts and says what is due.

use std::collections::VecDeque;
use std::time::Duration;

use tokio::time::Instant;

use super::apci;

/// A broken rule of the windows: the connection is closed, naming it.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub(crate) enum Broken {
    #[error("I-frame N(S) {got} where {expected} was next: frames lost or repeated")]
    Sequence { expected: u16, got: u16 },
    #[error("the peer acknowledged N(R) {got}, outside the frames sent ({low} to {high})")]
    Acknowledged { got: u16, low: u16, high: u16 },
    #[error("an I-frame was not acknowledged within t1 ({0:?})")]
    Unacknowledged(Duration),
    #[error("TESTFR act was not confirmed within t1 ({0:?})")]
    Untested(Duration),
}

/// The standard's windows and timers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Limits {
    pub(crate) k: u16,
    pub(crate) w: u16,
    pub(crate) t1: Duration,
    pub(crate) t2: Duration,
    pub(crate) t3: Duration,
}

/// What a look at the timers found due.
#[derive(Debug, Default, PartialEq, Eq)]
pub(crate) struct Due {
    /// An S-frame (t2 of an unacknowledged received frame).
    pub(crate) confirm: bool,
    /// A TESTFR act (t3 of silence).
    pub(crate) test: bool,
}

pub(crate) struct Window {
    limits: Limits,
    /// V(S): the next I-frame's send number; V(R): the next one expected.
    vs: u16,
    vr: u16,
    /// The send numbers of I-frames not acknowledged yet, with when each went.
    sent: VecDeque<(u16, Instant)>,
    /// I-frames received and not acknowledged, and when the first of them came.
    unconfirmed: u16,
    first_unconfirmed: Option<Instant>,
    /// When the peer was last heard; when a TESTFR act went unanswered.
    heard: Instant,
    testing: Option<Instant>,
}

impl Window {
    pub(crate) fn new(limits: Limits) -> Window {
        Window {
            limits,
            vs: 0,
            vr: 0,
            sent: VecDeque::new(),
            unconfirmed: 0,
            first_unconfirmed: None,
            heard: Instant::now(),
            testing: None,
        }
    }

    /// Whether another I-frame may be sent (fewer than k unacknowledged).
    pub(crate) fn room(&self) -> bool {
        (self.sent.len() as u16) < self.limits.k
    }

    pub(crate) fn unacknowledged(&self) -> u16 {
        self.sent.len() as u16
    }

    pub(crate) fn unconfirmed(&self) -> u16 {
        self.unconfirmed
    }

    /// The earliest timer: t1 of the oldest unacknowledged frame or the test, t2 of the
    /// first unconfirmed frame, t3 of silence.
    pub(crate) fn deadline(&self) -> Instant {
        let l = &self.limits;
        // t3 runs until a test is sent; then t1 on its confirmation (a t3 already past
        // would wake the task at once, again and again, until t1).
        let mut at = match self.testing {
            Some(t) => t + l.t1,
            None => self.heard + l.t3,
        };
        if let Some((_, sent)) = self.sent.front() {
            at = at.min(*sent + l.t1);
        }
        if let Some(first) = self.first_unconfirmed {
            at = at.min(first + l.t2);
        }
        at
    }

    /// What is due now, or the rule broken.
    pub(crate) fn due(&mut self) -> Result<Due, Broken> {
        let (now, l) = (Instant::now(), self.limits);
        if self.sent.front().is_some_and(|(_, t)| now >= *t + l.t1) {
            return Err(Broken::Unacknowledged(l.t1));
        }
        if self.testing.is_some_and(|t| now >= t + l.t1) {
            return Err(Broken::Untested(l.t1));
        }
        let confirm = self.first_unconfirmed.is_some_and(|t| now >= t + l.t2);
        let test = self.testing.is_none() && now >= self.heard + l.t3;
        if test {
            self.testing = Some(now);
        }
        Ok(Due { confirm, test })
    }

    /// The peer was heard (any frame).
    pub(crate) fn heard(&mut self) {
        self.heard = Instant::now();
    }

    /// The TESTFR act was confirmed.
    pub(crate) fn tested(&mut self) {
        self.testing = None;
    }

    /// N(S) and N(R) of the next I-frame, counted as sent (it acknowledges what came).
    pub(crate) fn send(&mut self) -> (u16, u16) {
        let numbers = (self.vs, self.vr);
        self.sent.push_back((self.vs, Instant::now()));
        self.vs = (self.vs + 1) % apci::MODULO;
        self.unconfirmed = 0;
        self.first_unconfirmed = None;
        numbers
    }

    /// N(R) of an S-frame acknowledging everything received.
    pub(crate) fn confirm(&mut self) -> u16 {
        self.unconfirmed = 0;
        self.first_unconfirmed = None;
        self.vr
    }

    /// An I-frame came: whether w frames now wait for an acknowledgement.
    pub(crate) fn received(&mut self, send: u16, recv: u16) -> Result<bool, Broken> {
        if send != self.vr {
            return Err(Broken::Sequence {
                expected: self.vr,
                got: send,
            });
        }
        self.acknowledged(recv)?;
        self.vr = (self.vr + 1) % apci::MODULO;
        self.unconfirmed += 1;
        self.first_unconfirmed.get_or_insert_with(Instant::now);
        Ok(self.unconfirmed >= self.limits.w)
    }

    /// Takes the acknowledgement N(R): every frame before it is acknowledged.
    pub(crate) fn acknowledged(&mut self, recv: u16) -> Result<(), Broken> {
        let oldest = self.sent.front().map_or(self.vs, |(n, _)| *n);
        let outstanding = apci::distance(oldest, self.vs);
        if apci::distance(oldest, recv) > outstanding {
            return Err(Broken::Acknowledged {
                got: recv,
                low: oldest,
                high: self.vs,
            });
        }
        while self.sent.front().is_some_and(|(n, _)| {
            apci::distance(*n, recv) > 0 && apci::distance(*n, recv) <= outstanding
        }) {
            self.sent.pop_front();
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn window(k: u16, w: u16) -> Window {
        let s = Duration::from_secs(1);
        Window::new(Limits {
            k,
            w,
            t1: s * 15,
            t2: s * 10,
            t3: s * 20,
        })
    }

    #[test]
    fn at_most_k_frames_go_unacknowledged_and_acknowledgements_are_checked() {
        let mut w = window(2, 1);
        assert_eq!(w.send(), (0, 0));
        assert_eq!(w.send(), (1, 0));
        assert!(!w.room());
        assert_eq!(
            w.acknowledged(3),
            Err(Broken::Acknowledged {
                got: 3,
                low: 0,
                high: 2
            })
        );
        w.acknowledged(1).expect("one acknowledged");
        assert!(w.room());
        assert_eq!(w.unacknowledged(), 1);
    }

    #[test]
    fn frames_out_of_sequence_break_the_connection_and_w_asks_for_a_confirmation() {
        let mut w = window(12, 2);
        assert_eq!(w.received(0, 0), Ok(false));
        assert_eq!(w.received(1, 0), Ok(true));
        assert_eq!(w.confirm(), 2);
        assert_eq!(
            w.received(5, 0),
            Err(Broken::Sequence {
                expected: 2,
                got: 5
            })
        );
    }

    #[tokio::test(start_paused = true)]
    async fn a_test_sent_waits_t1_for_its_confirmation_not_t3_again() {
        let mut w = window(12, 8);
        let start = Instant::now();
        assert_eq!(w.deadline(), start + Duration::from_secs(20));
        tokio::time::advance(Duration::from_secs(20)).await;
        assert_eq!(
            w.due(),
            Ok(Due {
                confirm: false,
                test: true
            })
        );
        // Not t3, already past: the task would wake at once until t1.
        assert_eq!(w.deadline(), start + Duration::from_secs(35));
        tokio::time::advance(Duration::from_secs(15)).await;
        assert_eq!(w.due(), Err(Broken::Untested(Duration::from_secs(15))));
    }
}

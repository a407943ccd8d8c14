//! Report by exception: a field is published when it changes (beyond its deadband, or in
//! quality), at most once per `min_interval` (a change inside it is sent when it ends, the
//! newest value only), and at least once per `max_interval` when it does not change.

use std::collections::HashMap;

use tokio::time::Instant;
use tokio_util::time::{DelayQueue, delay_queue};

use crate::api::mqtt::config::{Deadband, ReportConfig};
use crate::codec::Value;
use iogate_types::Quality;

/// A field: the device's position in the front-end's list and the field's index.
pub(crate) type Key = (usize, usize);

#[derive(Default)]
struct Reported {
    value: Option<Value>,
    quality: Option<Quality>,
    sent: Option<Instant>,
    /// A change held back by `min_interval`.
    held: bool,
    timer: Option<delay_queue::Key>,
    /// A value (not only a never-read state) has been published.
    valued: bool,
}

/// What to do with a change.
#[derive(Debug, PartialEq, Eq)]
pub(crate) enum Decision {
    Send,
    /// Within the deadband: nothing.
    Skip,
    /// Inside `min_interval`: sent when [`Reporter::due`] gives the key back.
    Hold,
}

pub(crate) struct Reporter {
    config: ReportConfig,
    fields: HashMap<Key, Reported>,
    timers: DelayQueue<Key>,
}

impl Reporter {
    pub(crate) fn new(config: ReportConfig) -> Self {
        Reporter {
            config,
            fields: HashMap::new(),
            timers: DelayQueue::new(),
        }
    }

    /// Whether a change of `key` to `value` and `quality` is published now; `deadband` is
    /// the field's own (from its profile), else the section's.
    pub(crate) fn change(
        &mut self,
        key: Key,
        value: Option<&Value>,
        quality: Quality,
        deadband: Option<Deadband>,
        now: Instant,
    ) -> Decision {
        let band = deadband.unwrap_or(self.config.deadband);
        let min = self.config.min_interval;
        let r = self.fields.entry(key).or_default();
        if r.sent.is_some() && r.quality == Some(quality) && within(band, r.value.as_ref(), value) {
            return Decision::Skip;
        }
        if let Some(sent) = r.sent
            && now < sent + min
        {
            if !r.held {
                r.held = true;
                let at = sent + min;
                match r.timer {
                    Some(k) => self.timers.reset_at(&k, at),
                    None => r.timer = Some(self.timers.insert_at(key, at)),
                }
            }
            return Decision::Hold;
        }
        Decision::Send
    }

    /// Records that `key` was published with `value` and `quality` at `now`.
    pub(crate) fn sent(&mut self, key: Key, value: Option<&Value>, quality: Quality, now: Instant) {
        let max = self.config.max_interval;
        let r = self.fields.entry(key).or_default();
        r.value = value.cloned();
        r.valued |= value.is_some();
        r.quality = Some(quality);
        r.sent = Some(now);
        r.held = false;
        if max.is_zero() {
            if let Some(k) = r.timer.take() {
                self.timers.remove(&k);
            }
            return;
        }
        match r.timer {
            Some(k) => self.timers.reset_at(&k, now + max),
            None => r.timer = Some(self.timers.insert_at(key, now + max)),
        }
    }

    /// Whether a value of `key` has been published (its never-read state does not count):
    /// the next one is else the field's first value.
    pub(crate) fn has_sent_value(&self, key: Key) -> bool {
        self.fields.get(&key).is_some_and(|r| r.valued)
    }

    /// Whether `key` has a change held back by `min_interval` (else what is due for it is
    /// a heartbeat).
    pub(crate) fn is_held(&self, key: Key) -> bool {
        self.fields.get(&key).is_some_and(|r| r.held)
    }

    /// The next field whose held change or heartbeat is due.
    pub(crate) async fn due(&mut self) -> Key {
        loop {
            match std::future::poll_fn(|cx| self.timers.poll_expired(cx)).await {
                Some(expired) => {
                    let key = expired.into_inner();
                    if let Some(r) = self.fields.get_mut(&key) {
                        r.timer = None;
                    }
                    return key;
                }
                // Nothing scheduled: wait for ever (the caller selects on other events).
                None => std::future::pending::<()>().await,
            }
        }
    }
}

/// Whether `new` is within `band` of `old`.
fn within(band: Deadband, old: Option<&Value>, new: Option<&Value>) -> bool {
    band.within(old, new)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    fn config(deadband: Deadband, min_ms: u64, max_ms: u64) -> ReportConfig {
        ReportConfig {
            deadband,
            min_interval: Duration::from_millis(min_ms),
            max_interval: Duration::from_millis(max_ms),
        }
    }

    #[tokio::test(start_paused = true)]
    async fn changes_within_the_deadband_are_skipped() {
        let mut r = Reporter::new(config(Deadband::Absolute(0.5), 0, 0));
        let now = Instant::now();
        let v = |x| Some(Value::Real(x));
        assert_eq!(
            r.change((0, 0), v(10.0).as_ref(), Quality::Good, None, now),
            Decision::Send
        );
        r.sent((0, 0), v(10.0).as_ref(), Quality::Good, now);
        assert_eq!(
            r.change((0, 0), v(10.4).as_ref(), Quality::Good, None, now),
            Decision::Skip
        );
        assert_eq!(
            r.change((0, 0), v(10.6).as_ref(), Quality::Good, None, now),
            Decision::Send
        );
        // A change of quality is always sent.
        assert_eq!(
            r.change((0, 0), v(10.0).as_ref(), Quality::Stale, None, now),
            Decision::Send
        );
        // A field's own deadband wins.
        assert_eq!(
            r.change(
                (0, 0),
                v(10.6).as_ref(),
                Quality::Good,
                Some(Deadband::Percent(10.0)),
                now
            ),
            Decision::Skip
        );
    }

    #[tokio::test(start_paused = true)]
    async fn min_interval_holds_a_change_until_it_ends() {
        let mut r = Reporter::new(config(Deadband::None, 100, 0));
        let t0 = Instant::now();
        r.sent((1, 2), Some(&Value::Int(1)), Quality::Good, t0);
        assert_eq!(
            r.change((1, 2), Some(&Value::Int(2)), Quality::Good, None, t0),
            Decision::Hold
        );
        assert_eq!(
            r.change((1, 2), Some(&Value::Int(3)), Quality::Good, None, t0),
            Decision::Hold
        );
        assert_eq!(r.due().await, (1, 2));
        assert_eq!(Instant::now() - t0, Duration::from_millis(100));
    }

    #[tokio::test(start_paused = true)]
    async fn max_interval_is_a_heartbeat() {
        let mut r = Reporter::new(config(Deadband::None, 0, 1000));
        let t0 = Instant::now();
        r.sent((0, 1), Some(&Value::Bool(true)), Quality::Good, t0);
        assert_eq!(r.due().await, (0, 1));
        assert_eq!(Instant::now() - t0, Duration::from_secs(1));
    }
}

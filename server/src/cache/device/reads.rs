//! What reads put into a device's fields: a value or why it could not be read, with its
//! source's doubt and timestamp; stale spells told; every field failed or doubted at once.

use std::sync::atomic::Ordering;

use super::*;

/// When values came, read once for a batch of them: the monotonic clock (for quality) and
/// the wall clock (their timestamp when the source gives none). Two clock readings a field
/// were a sixth of the gateway's CPU at 100,000 fields a second.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Stamp {
    pub(crate) instant: Instant,
    pub(crate) system: SystemTime,
}

impl Stamp {
    pub(crate) fn now() -> Stamp {
        Stamp {
            instant: Instant::now(),
            system: SystemTime::now(),
        }
    }
}

impl Device {
    /// Stores a freshly read value (or why it could not be read). Subscribers are woken only
    /// when the value or its quality changes.
    pub(crate) fn publish(&self, idx: usize, read: Result<Value, FieldError>) {
        self.publish_from(idx, read, None, None, Stamp::now());
    }

    /// [`Self::publish`] for one of many values that came together at `now`.
    pub(crate) fn publish_at(&self, idx: usize, read: Result<Value, FieldError>, now: Stamp) {
        self.publish_from(idx, read, None, None, now);
    }

    /// Stores a value as its source reported it: `doubt` when the source vouches for it
    /// only in part (the value is kept, stale, with the reason), `at` the source's own
    /// timestamp of it (else `now`'s); `now` when it came (one clock reading for a batch).
    pub(crate) fn publish_from(
        &self,
        idx: usize,
        read: Result<Value, FieldError>,
        doubt: Option<FieldError>,
        at: Option<SystemTime>,
        now: Stamp,
    ) {
        let now = (now.instant, at.unwrap_or(now.system));
        let place = self.place();
        self.samples[idx].send_if_modified(|s| {
            if s.place != place {
                // Read by a device a reload has replaced: perhaps another place's value.
                return false;
            }
            // Changed: another value or quality, or a stale spell told that now ends.
            let mut changed = s.stale_told;
            match read {
                Ok(v) => {
                    let quality = if doubt.is_some() {
                        Quality::Stale
                    } else {
                        Quality::Good
                    };
                    changed |= s.quality != quality || s.value.as_ref() != Some(&v);
                    s.value = Some(v);
                    s.quality = quality;
                    s.error = doubt.map(Box::new);
                }
                Err(e) => {
                    changed |= s.quality != Quality::Bad;
                    s.quality = Quality::Bad;
                    s.error = Some(Box::new(e));
                }
            }
            s.updated = Some(now);
            s.stale_told = false;
            changed
        });
    }

    /// Wakes the subscribers of every field whose good value went stale as of `now` (once
    /// per stale spell), so that streams show `stale` without waiting for another change.
    pub(crate) fn tell_stale(&self, now: Instant) {
        let went_stale = |s: &Sample| !s.stale_told && self.quality(s, now) == Quality::Stale;
        for sample in &self.samples {
            // A read lock first: most fields are fresh, or stale and told.
            if !went_stale(&sample.borrow()) {
                continue;
            }
            let told = sample.send_if_modified(|s| {
                let tell = went_stale(s);
                s.stale_told |= tell;
                tell
            });
            if told {
                self.stale_told.store(true, Ordering::Release);
            }
        }
    }

    /// The source vouches for every good value it has not changed (a connection that
    /// lives, whose station sends only changes): a stale spell told of them ends.
    pub(crate) fn vouch(&self) {
        // Nothing told since the last time: nothing to end (and no field looked at).
        if !self.stale_told.swap(false, Ordering::AcqRel) {
            return;
        }
        for sample in &self.samples {
            if !sample.borrow().stale_told {
                continue;
            }
            sample.send_if_modified(|s| {
                let told = s.stale_told && s.quality == Quality::Good;
                s.stale_told &= !told;
                told
            });
        }
    }

    /// Marks every field read from the bus as bad, keeping the last good values.
    pub(crate) fn fail_reads(&self, reason: &FieldError) {
        for (idx, field) in self.profile.fields.iter().enumerate() {
            if field.register.kind != RegisterKind::Virtual {
                self.publish(idx, Err(reason.clone()));
            }
        }
    }

    /// Marks every field read from the device as stale with `reason`, keeping its value and
    /// its timestamp (a field never read is bad with it).
    pub(crate) fn doubt_reads(&self, reason: &FieldError) {
        for (idx, field) in self.profile.fields.iter().enumerate() {
            if field.register.kind == RegisterKind::Virtual {
                continue;
            }
            self.samples[idx].send_if_modified(|s| {
                let quality = if s.value.is_some() {
                    Quality::Stale
                } else {
                    Quality::Bad
                };
                let changed = s.quality != quality;
                s.quality = quality;
                s.error = Some(Box::new(reason.clone()));
                s.stale_told = false;
                changed
            });
        }
    }
}

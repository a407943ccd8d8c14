//! Following changes: each chosen field (its slot) and each chosen device's diagnostics (a
//! `watch`) is a receiver, merged into one stream. A subscriber first gets every current value, then
//! each change; a slow one skips to the newest value of a field instead of building a
//! backlog. A field follows its device through a configuration reload (the successor
//! shares the field's channel, so nothing is repeated or lost); a removed field or device
//! ends with a `Removed` change saying why. A subscription to everything also takes in the
//! devices added after it began. The stream ends when the gateway shuts down.

use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};

use std::collections::HashSet;

use futures_util::stream::SelectAll;
use futures_util::{Stream, StreamExt};
use tokio::sync::watch;
use tokio_stream::wrappers::WatchStream;

use super::{Selection, Service, ServiceError};
use crate::cache::{Cache, Device, Diagnostics, Fate, Forms, Sample, SlotReceiver};

/// A change of a field's value (or quality), or of a device's diagnostics; or the end of a
/// field or device that was removed.
#[derive(Debug, Clone)]
pub(crate) enum Change {
    Value {
        device: Arc<Device>,
        idx: usize,
        sample: Sample,
        /// The front-ends' encodings of this change, made once for all subscribers.
        forms: Forms<Sample>,
    },
    Diagnostics {
        device: Arc<Device>,
        diagnostics: Diagnostics,
    },
    /// The field (or, without one, the device) is gone; nothing more comes for it.
    Removed {
        device: String,
        field: Option<String>,
        reason: &'static str,
    },
}

/// The stream of a subscription.
pub(crate) type Changes = Pin<Box<dyn Stream<Item = Change> + Send>>;

/// Which watch a change came from: (device, field), the field `usize::MAX` for diagnostics.
type Key = (usize, usize);
const DIAGNOSTICS: usize = usize::MAX;
/// Keys of fields a reload added to a followed device, apart from the fields it had.
const NEW_FIELDS: usize = usize::MAX / 2;

/// Why a field of a re-planned device ends.
const FIELD_REMOVED: &str = "the field is no longer in the device's profile";

/// What a followed stream watches: one field's samples, or the device's diagnostics.
enum Watched {
    Field(usize, SlotReceiver<Sample>),
    Diagnostics(watch::Receiver<Diagnostics>),
}

/// One field or one device's diagnostics, followed through replacements of the device.
struct Followed {
    device: Arc<Device>,
    watched: Watched,
    fate: watch::Receiver<Fate>,
    ended: bool,
    /// The field's sample this subscriber was last given: changes that come and go before
    /// it takes the next one (stale and good again, a value and back) are not repeated.
    given: Option<Sample>,
}

impl Followed {
    fn new(device: Arc<Device>, field: Option<usize>) -> Self {
        let watched = match field {
            Some(idx) => {
                let mut rx = device.subscribe(idx);
                rx.mark_changed();
                Watched::Field(idx, rx)
            }
            None => {
                let mut rx = device.subscribe_diagnostics();
                rx.mark_changed();
                Watched::Diagnostics(rx)
            }
        };
        let mut fate = device.watch_fate();
        // A device replaced or removed before the stream began is followed at once.
        fate.mark_changed();
        Followed {
            device,
            watched,
            fate,
            ended: false,
            given: None,
        }
    }

    fn removed(&mut self, reason: &'static str) -> Change {
        self.ended = true;
        Change::Removed {
            device: self.device.name().to_owned(),
            field: match &self.watched {
                Watched::Field(idx, _) => Some(self.device.field(*idx).name.clone()),
                Watched::Diagnostics(_) => None,
            },
            reason,
        }
    }

    /// The next change, or `None` once the field or device ended.
    async fn next(&mut self) -> Option<Change> {
        if self.ended {
            return None;
        }
        loop {
            let device = self.device.clone();
            tokio::select! {
                biased;
                fate = self.fate.changed() => {
                    if fate.is_err() {
                        return None;
                    }
                    let now = self.fate.borrow_and_update().clone();
                    match now {
                        Fate::Live => {}
                        Fate::Removed(reason) => return Some(self.removed(reason)),
                        Fate::Replaced(next) => {
                            match &mut self.watched {
                                Watched::Field(idx, _) => match self.device.kept_in(*idx, &next) {
                                    Some(kept) => *idx = kept,
                                    None => return Some(self.removed(FIELD_REMOVED)),
                                },
                                // A successor with diagnostics of its own (simulated in a
                                // real one's place, or the other way) is followed in them.
                                Watched::Diagnostics(rx) => {
                                    if !self.device.shares_diagnostics(&next) {
                                        *rx = next.subscribe_diagnostics();
                                        rx.mark_changed();
                                    }
                                }
                            }
                            self.fate = next.watch_fate();
                            self.fate.mark_changed();
                            self.device = next;
                        }
                    }
                }
                changed = async {
                    match &mut self.watched {
                        Watched::Field(_, rx) => rx.changed().await.is_ok(),
                        Watched::Diagnostics(rx) => rx.changed().await.is_ok(),
                    }
                } => {
                    if !changed {
                        return None;
                    }
                    return Some(match &mut self.watched {
                        Watched::Field(idx, rx) => {
                            let sample = rx.borrow_and_update().clone();
                            if self.given.as_ref().is_some_and(|g| g.same_state(&sample)) {
                                continue;
                            }
                            self.given = Some(sample.clone());
                            Change::Value {
                                device,
                                idx: *idx,
                                sample,
                                forms: rx.forms(),
                            }
                        }
                        Watched::Diagnostics(rx) => Change::Diagnostics {
                            device,
                            diagnostics: rx.borrow_and_update().clone(),
                        },
                    });
                }
            }
        }
    }

    fn into_stream(self) -> Changes {
        Box::pin(futures_util::stream::unfold(self, |mut f| async move {
            f.next().await.map(|change| (change, f))
        }))
    }
}

/// Devices added to the gateway after a subscription to everything began, and fields
/// added to its devices by a reload.
struct Additions {
    cache: Arc<Cache>,
    set: WatchStream<u64>,
    /// Every device the subscription follows (by its first instance).
    known: Vec<Arc<Device>>,
    /// Each followed device as last looked at, with the names of the fields followed.
    fields: Vec<(Arc<Device>, Vec<String>)>,
    diagnostics: bool,
    values: bool,
}

/// A subscription's streams, and the devices it takes in as they are added. The streams
/// are polled as they are woken (a change costs the same whether the subscription follows
/// ten fields or a hundred thousand); each is followed once, by its key.
struct Subscription {
    streams: SelectAll<Changes>,
    keys: HashSet<Key>,
    additions: Option<Additions>,
}

impl Subscription {
    fn insert(&mut self, key: Key, followed: Followed) {
        if self.keys.insert(key) {
            self.streams.push(followed.into_stream());
        }
    }

    fn follow(&mut self, n: usize, device: &Arc<Device>, diagnostics: bool, fields: bool) {
        if diagnostics {
            self.insert((n, DIAGNOSTICS), Followed::new(device.clone(), None));
        }
        if fields {
            for idx in 0..device.profile.fields.len() {
                self.insert((n, idx), Followed::new(device.clone(), Some(idx)));
            }
        }
    }

    /// Follows every device of the gateway that is neither followed nor the successor of a
    /// followed one.
    fn take_in_new(&mut self) {
        let Some(additions) = &mut self.additions else {
            return;
        };
        let current: Vec<Arc<Device>> = additions.known.iter().map(|d| d.current()).collect();
        let new: Vec<Arc<Device>> = additions
            .cache
            .devices()
            .into_iter()
            .filter(|d| !current.iter().any(|c| Arc::ptr_eq(c, d)))
            .collect();
        let (diagnostics, values) = (additions.diagnostics, additions.values);
        let first = additions.known.len();
        additions.known.extend(new.iter().cloned());
        // Fields a reload added to a followed device.
        let mut grown: Vec<(usize, Arc<Device>, usize)> = Vec::new();
        if values {
            for (n, (device, names)) in additions.fields.iter_mut().enumerate() {
                let now = device.current();
                if Arc::ptr_eq(&now, device) || now.is_removed() {
                    continue;
                }
                for (idx, field) in now.profile.fields.iter().enumerate() {
                    if !names
                        .iter()
                        .any(|name| name.eq_ignore_ascii_case(&field.name))
                    {
                        names.push(field.name.clone());
                        grown.push((n, now.clone(), idx));
                    }
                }
                *device = now;
            }
        }
        for device in &new {
            additions.fields.push((
                device.clone(),
                device
                    .profile
                    .fields
                    .iter()
                    .map(|f| f.name.clone())
                    .collect(),
            ));
        }
        for (n, device, idx) in grown {
            self.insert((n, idx + NEW_FIELDS), Followed::new(device, Some(idx)));
        }
        for (k, device) in new.iter().enumerate() {
            self.follow(first + k, device, diagnostics, values);
        }
    }
}

impl Stream for Subscription {
    type Item = Change;

    fn poll_next(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<Change>> {
        let mut grown = false;
        if let Some(additions) = &mut self.additions {
            while let Poll::Ready(Some(_)) = additions.set.poll_next_unpin(cx) {
                grown = true;
            }
        }
        if grown {
            self.take_in_new();
        }
        match self.streams.poll_next_unpin(cx) {
            Poll::Ready(None) if self.additions.is_some() => Poll::Pending,
            other => other,
        }
    }
}

impl Service {
    /// Values and diagnostics of exactly `devices`: for a front-end that keeps its own
    /// picture of the device set and follows it again when the set changes.
    pub(crate) fn subscribe_devices(
        &self,
        devices: &[Arc<Device>],
    ) -> Result<Changes, ServiceError> {
        let names: Vec<&str> = devices.iter().map(|d| d.name()).collect();
        let selection = self.select::<_, &str>(&names, &[])?;
        self.subscribe(selection, true)
    }

    /// Current values then changes of `selection`'s fields, and of its devices'
    /// diagnostics when `diagnostics` is set; a selection of everything also follows the
    /// devices added later.
    pub(crate) fn subscribe(
        &self,
        selection: Selection,
        diagnostics: bool,
    ) -> Result<Changes, ServiceError> {
        self.subscribe_for(selection, diagnostics, None)
    }

    /// [`Service::subscribe`] for the client at `client` (one of its streams).
    pub(crate) fn subscribe_for(
        &self,
        selection: Selection,
        diagnostics: bool,
        client: Option<std::net::IpAddr>,
    ) -> Result<Changes, ServiceError> {
        self.accepting()?;
        let slot = self.stream_slot_for(client)?;
        let mut subscription = Subscription {
            streams: SelectAll::new(),
            keys: HashSet::new(),
            additions: None,
        };
        for (n, device) in selection.devices.iter().enumerate() {
            subscription.follow(n, device, diagnostics, false);
        }
        let position = |device: &Arc<Device>| {
            selection
                .devices
                .iter()
                .position(|d| Arc::ptr_eq(d, device))
                .unwrap_or(usize::MAX - 1)
        };
        for f in selection.fields.iter() {
            subscription.insert(
                (position(&f.device), f.idx),
                Followed::new(f.device.clone(), Some(f.idx)),
            );
        }
        if selection.everything {
            let mut set = self.cache.watch_devices();
            set.mark_unchanged();
            subscription.additions = Some(Additions {
                cache: self.cache.clone(),
                set: WatchStream::from_changes(set),
                known: selection.devices.clone(),
                fields: selection
                    .devices
                    .iter()
                    .map(|d| {
                        (
                            d.clone(),
                            d.profile.fields.iter().map(|f| f.name.clone()).collect(),
                        )
                    })
                    .collect(),
                diagnostics,
                values: !selection.no_values,
            });
        }
        let shutdown = self.tasks().token().clone().cancelled_owned();
        // The slot goes with the stream: freed when the client goes away.
        Ok(Box::pin(
            subscription
                .map(move |change| {
                    let _held = &slot;
                    change
                })
                .take_until(shutdown),
        ))
    }
}

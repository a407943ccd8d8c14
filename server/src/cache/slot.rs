//! A field's latest sample that tasks wait on: what a tokio `watch` channel gives (the
//! newest value, a version, waiting for the next change, the end when the last owner goes)
//! in about a fifth of its memory. A `watch` channel carries nine `Notify`s for waiters
//! spread over cores (about 430 bytes besides its value); a gateway has one per field, and
//! most fields have one subscriber or none, so a slot has one.
//!
//! A slot also keeps the wire forms of its value ([`Forms`]): a front-end's encoding of a
//! change (a gRPC message, a Server-Sent Event) made by the first receiver that takes it
//! and handed as shared bytes to every other, so a change to 10,000 subscribers is encoded
//! once, not 10,000 times.

use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, RwLock, RwLockReadGuard};
use std::time::{Duration, Instant};

use bytes::Bytes;
use tokio::sync::Notify;

/// An owner's side: changes the value and wakes the receivers. Owners are counted (a
/// device and the one that succeeds it share a field's slot); when the last is dropped the
/// receivers end.
#[derive(Debug)]
pub(crate) struct Slot<T> {
    shared: Arc<Shared<T>>,
}

#[derive(Debug)]
struct Shared<T> {
    value: RwLock<T>,
    /// Changed (under the write lock) with every change told.
    version: AtomicU64,
    /// Owners ([`Slot`]s) alive; at 0 nothing more will change.
    owners: AtomicUsize,
    changed: Notify,
    /// The wire forms made of one version (none until a receiver asks for one).
    forms: Mutex<Option<Box<Made>>>,
}

/// How long a wire form is handed out. A form may say more than the value (a field's
/// quality by its age, the state of its last write), which can change while the value does
/// not: a form is reused only while it is at most this old, so what a receiver is given
/// is never older than a delivery this late would have been.
pub(crate) const FORM_LIFETIME: Duration = Duration::from_millis(50);

/// The wire forms of one version, by the name of the form.
#[derive(Debug)]
struct Made {
    version: u64,
    at: Instant,
    forms: Vec<(&'static str, Bytes)>,
}

/// The wire forms of the version a receiver took (see the module): each made once, by the
/// first receiver that needs it.
#[derive(Debug, Clone)]
pub(crate) struct Forms<T> {
    shared: Arc<Shared<T>>,
    version: u64,
}

impl<T> Forms<T> {
    /// The form named `form` of this version: the one already made (within
    /// [`FORM_LIFETIME`]), or the one `make` makes now, kept for the other receivers. A
    /// receiver behind the newest version makes its own and keeps nothing.
    pub(crate) fn get_or_make(&self, form: &'static str, make: impl FnOnce() -> Bytes) -> Bytes {
        let mut made = self.shared.forms.lock().unwrap_or_else(|e| e.into_inner());
        let now = Instant::now();
        let current = made.as_ref().is_some_and(|m| {
            m.version == self.version && now.saturating_duration_since(m.at) <= FORM_LIFETIME
        });
        if current {
            if let Some((_, bytes)) = made
                .as_ref()
                .and_then(|m| m.forms.iter().find(|(name, _)| *name == form))
            {
                return bytes.clone();
            }
        } else if made.as_ref().is_some_and(|m| m.version > self.version)
            || self.shared.version.load(Ordering::Acquire) != self.version
        {
            drop(made);
            return make();
        }
        // Made under the lock: a receiver arriving meanwhile waits for these bytes rather
        // than making the same form again.
        let bytes = make();
        match made.as_mut() {
            Some(m) if current => m.forms.push((form, bytes.clone())),
            _ => {
                *made = Some(Box::new(Made {
                    version: self.version,
                    at: now,
                    forms: vec![(form, bytes.clone())],
                }))
            }
        }
        bytes
    }
}

/// The owner is gone.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("the value's owner is gone")]
pub(crate) struct Closed;

/// A waiter's side: the version it last took.
#[derive(Debug)]
pub(crate) struct SlotReceiver<T> {
    shared: Arc<Shared<T>>,
    seen: u64,
}

impl<T> Shared<T> {
    fn read(&self) -> RwLockReadGuard<'_, T> {
        // Changes are whole; a panic in one leaves a value that is still one.
        self.value.read().unwrap_or_else(|e| e.into_inner())
    }

    /// The last owner is gone.
    fn closed(&self) -> bool {
        self.owners.load(Ordering::Acquire) == 0
    }
}

impl<T> Slot<T> {
    pub(crate) fn new(value: T) -> Self {
        Slot {
            shared: Arc::new(Shared {
                value: RwLock::new(value),
                version: AtomicU64::new(0),
                owners: AtomicUsize::new(1),
                changed: Notify::new(),
                forms: Mutex::new(None),
            }),
        }
    }

    /// Whether both own the same value.
    pub(crate) fn same(&self, other: &Slot<T>) -> bool {
        Arc::ptr_eq(&self.shared, &other.shared)
    }

    /// The value, read-locked while the guard lives.
    pub(crate) fn borrow(&self) -> RwLockReadGuard<'_, T> {
        self.shared.read()
    }

    /// A receiver that has seen the current value.
    pub(crate) fn subscribe(&self) -> SlotReceiver<T> {
        SlotReceiver {
            shared: self.shared.clone(),
            seen: self.shared.version.load(Ordering::Acquire),
        }
    }

    /// Changes the value with `modify`; when it says the change is worth telling, the
    /// receivers are woken. Answers what `modify` said.
    pub(crate) fn send_if_modified(&self, modify: impl FnOnce(&mut T) -> bool) -> bool {
        let told = {
            let mut value = self.shared.value.write().unwrap_or_else(|e| e.into_inner());
            let told = modify(&mut value);
            if told {
                self.shared.version.fetch_add(1, Ordering::AcqRel);
            }
            told
        };
        if told {
            self.shared.changed.notify_waiters();
        }
        told
    }

    /// Changes the value with `modify` and wakes the receivers.
    pub(crate) fn send_modify(&self, modify: impl FnOnce(&mut T)) {
        self.send_if_modified(|value| {
            modify(value);
            true
        });
    }
}

impl<T> Clone for Slot<T> {
    /// Another owner of the same value.
    fn clone(&self) -> Self {
        self.shared.owners.fetch_add(1, Ordering::AcqRel);
        Slot {
            shared: self.shared.clone(),
        }
    }
}

impl<T> Drop for Slot<T> {
    fn drop(&mut self) {
        if self.shared.owners.fetch_sub(1, Ordering::AcqRel) == 1 {
            self.shared.changed.notify_waiters();
        }
    }
}

impl<T> SlotReceiver<T> {
    /// The next [`SlotReceiver::changed`] returns at once.
    pub(crate) fn mark_changed(&mut self) {
        self.seen = self.shared.version.load(Ordering::Acquire).wrapping_sub(1);
    }

    /// Waits until the value has changed since this receiver last took it; `Closed` once
    /// the owner is gone and every change was taken.
    pub(crate) async fn changed(&mut self) -> Result<(), Closed> {
        loop {
            // Registered before the version is looked at, so no change slips between.
            let notified = self.shared.changed.notified();
            tokio::pin!(notified);
            notified.as_mut().enable();
            if self.shared.version.load(Ordering::Acquire) != self.seen {
                return Ok(());
            }
            if self.shared.closed() {
                return Err(Closed);
            }
            notified.await;
        }
    }

    /// The current value counts as taken.
    #[cfg(test)]
    pub(crate) fn mark_unchanged(&mut self) {
        self.seen = self.shared.version.load(Ordering::Acquire);
    }

    /// Whether the value changed since this receiver last took it; `Closed` once the
    /// owner is gone and every change was taken.
    #[cfg(test)]
    pub(crate) fn has_changed(&self) -> Result<bool, Closed> {
        if self.shared.version.load(Ordering::Acquire) != self.seen {
            Ok(true)
        } else if self.shared.closed() {
            Err(Closed)
        } else {
            Ok(false)
        }
    }

    /// The value, marked as taken (the version read under the same lock as the value).
    pub(crate) fn borrow_and_update(&mut self) -> RwLockReadGuard<'_, T> {
        let value = self.shared.read();
        self.seen = self.shared.version.load(Ordering::Acquire);
        value
    }

    /// The wire forms of the value this receiver last took.
    pub(crate) fn forms(&self) -> Forms<T> {
        Forms {
            shared: self.shared.clone(),
            version: self.seen,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[tokio::test]
    async fn a_receiver_wakes_for_told_changes_only_and_takes_the_newest() {
        let slot = Slot::new(0u32);
        let mut rx = slot.subscribe();
        assert!(
            tokio::time::timeout(Duration::from_millis(20), rx.changed())
                .await
                .is_err(),
            "nothing changed yet"
        );
        assert!(!slot.send_if_modified(|v| {
            *v = 1;
            false
        }));
        assert!(
            tokio::time::timeout(Duration::from_millis(20), rx.changed())
                .await
                .is_err(),
            "a change not told does not wake"
        );
        slot.send_modify(|v| *v = 2);
        slot.send_modify(|v| *v = 3);
        rx.changed().await.expect("changed");
        assert_eq!(*rx.borrow_and_update(), 3, "the newest, not a backlog");
        assert!(
            tokio::time::timeout(Duration::from_millis(20), rx.changed())
                .await
                .is_err()
        );
        rx.mark_changed();
        rx.changed().await.expect("marked");
    }

    #[tokio::test]
    async fn a_waiting_receiver_is_woken_and_the_last_owner_gone_ends_it() {
        let slot = Slot::new(String::new());
        let mut rx = slot.subscribe();
        let (took, taken) = tokio::sync::oneshot::channel();
        let waiter = tokio::spawn(async move {
            rx.changed().await.expect("changed");
            let _ = took.send(rx.borrow_and_update().clone());
            let second = rx.changed().await;
            let value = rx.borrow_and_update().clone();
            (second, value, rx.changed().await)
        });
        slot.send_modify(|v| v.push_str("new"));
        assert_eq!(taken.await.expect("taken"), "new");
        // Two owners (a device and its successor): the first gone ends nothing.
        let other = slot.clone();
        assert!(other.same(&slot));
        drop(slot);
        other.send_modify(|v| v.push('!'));
        drop(other);
        let (second, value, end) = waiter.await.expect("task");
        assert_eq!(second, Ok(()), "the second owner's change");
        assert_eq!(value, "new!");
        assert_eq!(end, Err(Closed), "both owners gone");
    }

    #[test]
    fn a_form_is_made_once_per_version_and_not_kept_for_a_receiver_behind() {
        let slot = Slot::new(1u32);
        let (mut a, mut b) = (slot.subscribe(), slot.subscribe());
        slot.send_modify(|v| *v = 2);
        let made = std::cell::Cell::new(0);
        let make = |v: u32| {
            made.set(made.get() + 1);
            Bytes::from(v.to_string())
        };
        let va = *a.borrow_and_update();
        assert_eq!(a.forms().get_or_make("text", || make(va)), "2");
        let vb = *b.borrow_and_update();
        assert_eq!(b.forms().get_or_make("text", || make(vb)), "2");
        assert_eq!(
            made.get(),
            1,
            "the second receiver is given the first's form"
        );
        assert_eq!(b.forms().get_or_make("other", || Bytes::from("x")), "x");
        assert_eq!(made.get(), 1);
        // A receiver that took version 2 asks after version 3 was made: its own form.
        let behind = a.forms();
        slot.send_modify(|v| *v = 3);
        let vb = *b.borrow_and_update();
        assert_eq!(b.forms().get_or_make("text", || make(vb)), "3");
        assert_eq!(behind.get_or_make("text", || make(2)), "2");
        assert_eq!(made.get(), 3);
        // The newest form is still there for the others.
        assert_eq!(b.forms().get_or_make("text", || make(0)), "3");
        assert_eq!(made.get(), 3);
    }
}

//! Where the ASDUs a station sends go: a monitored value to every field at its common
//! address and information object address (with its quality and time tag), an answer to
//! an activation (its confirmation, termination, or a mirror naming it unknown) to the
//! request waiting for it. What nobody waits for and no field names is dropped, counted.

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime};

use tokio::sync::mpsc;

use super::asdu::{Asdu, Time, cause};
use super::types::{Kind, TypeId};
use super::value;
use crate::cache::{Device, FieldError, Stamp};

/// A field a station's values go to.
struct Entry {
    device: Arc<Device>,
    idx: usize,
    /// The type it is fixed to (`asdu:`), if it is.
    fixed: Option<TypeId>,
    /// Whether a value came for it on this connection.
    seen: bool,
}

/// A request waiting for its answers: the type, common address and object it was sent with.
struct Waiting {
    type_id: TypeId,
    common_address: u16,
    ioa: u32,
    answers: mpsc::UnboundedSender<Asdu>,
}

#[derive(Default)]
pub(crate) struct Router {
    points: Mutex<HashMap<(u16, u32), Vec<Entry>>>,
    waiting: Mutex<Vec<Waiting>>,
    /// The station said it initialised (M_EI_NA_1): its values are asked again.
    pub(crate) restarted: AtomicBool,
    /// The connection ended: nothing more comes, and nobody waits.
    closed: AtomicBool,
    /// ASDUs that were malformed, or for no field and no request.
    pub(crate) malformed: AtomicU64,
    pub(crate) unrouted: AtomicU64,
}

/// What waits for a request's answers; dropped, it waits no more.
pub(crate) struct Answers {
    router: Arc<Router>,
    rx: mpsc::UnboundedReceiver<Asdu>,
}

impl Drop for Answers {
    fn drop(&mut self) {
        self.rx.close();
        lock(&self.router.waiting).retain(|w| !w.answers.is_closed());
    }
}

impl Answers {
    /// The next answer, within `within`.
    pub(crate) async fn next(&mut self, within: Duration) -> Option<Asdu> {
        tokio::time::timeout(within, self.rx.recv())
            .await
            .ok()
            .flatten()
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

impl Router {
    /// The device's input fields at `common_address`, each by its `ioa`, replacing what an
    /// earlier plan of it registered.
    pub(crate) fn register(
        &self,
        device: &Arc<Device>,
        common_address: u16,
        ioas: &[(usize, u32, Option<TypeId>)],
    ) {
        let mut points = lock(&self.points);
        for entries in points.values_mut() {
            entries.retain(|e| !Arc::ptr_eq(&e.device, device));
        }
        for &(idx, ioa, fixed) in ioas {
            points
                .entry((common_address, ioa))
                .or_default()
                .push(Entry {
                    device: device.clone(),
                    idx,
                    fixed,
                    seen: false,
                });
        }
    }

    /// The device's fields at `common_address` no value came for on this connection.
    pub(crate) fn unseen(&self, device: &Arc<Device>, common_address: u16) -> Vec<(usize, u32)> {
        let points = lock(&self.points);
        let mut out: Vec<(usize, u32)> = points
            .iter()
            .filter(|((ca, _), _)| *ca == common_address)
            .flat_map(|((_, ioa), entries)| {
                entries
                    .iter()
                    .filter(|e| !e.seen && Arc::ptr_eq(&e.device, device))
                    .map(move |e| (e.idx, *ioa))
            })
            .collect();
        out.sort_unstable();
        out
    }

    /// Waits for the answers to a request of `type_id` at `common_address` and `ioa`.
    pub(crate) fn expect(
        self: &Arc<Self>,
        type_id: TypeId,
        common_address: u16,
        ioa: u32,
    ) -> Answers {
        let (tx, rx) = mpsc::unbounded_channel();
        if self.closed.load(Ordering::Relaxed) {
            // Its sender dropped: the wait ends at once.
            return Answers {
                router: self.clone(),
                rx,
            };
        }
        lock(&self.waiting).push(Waiting {
            type_id,
            common_address,
            ioa,
            answers: tx,
        });
        Answers {
            router: self.clone(),
            rx,
        }
    }

    /// The connection ended: every request waiting for answers stops waiting now (the
    /// loss is seen at once, not at the end of t1).
    pub(crate) fn close(&self) {
        let mut waiting = lock(&self.waiting);
        self.closed.store(true, Ordering::Relaxed);
        waiting.clear();
    }

    /// An ASDU the station sent.
    pub(crate) fn take(&self, octets: &[u8]) {
        let asdu = match Asdu::decode(octets) {
            Ok(a) => a,
            Err(e) => {
                self.malformed.fetch_add(1, Ordering::Relaxed);
                tracing::warn!(error = %e, "IEC 104: a malformed ASDU from the station, dropped");
                return;
            }
        };
        let kind = asdu.kind();
        if kind == Kind::EndOfInit {
            self.restarted.store(true, Ordering::Relaxed);
            return;
        }
        if monitored(kind) && !matches!(asdu.cause, cause::ACT_CON | cause::ACT_TERM) {
            self.publish(&asdu);
            return;
        }
        let first = asdu.objects.first().map_or(0, |o| o.ioa);
        let waiting = lock(&self.waiting);
        let to = waiting.iter().find(|w| {
            w.type_id == asdu.type_id && w.common_address == asdu.common_address && w.ioa == first
        });
        match to {
            Some(w) => {
                let _ = w.answers.send(asdu);
            }
            None => {
                self.unrouted.fetch_add(1, Ordering::Relaxed);
            }
        }
    }

    fn publish(&self, asdu: &Asdu) {
        let now = Stamp::now();
        let mut points = lock(&self.points);
        let mut unrouted = 0;
        for o in &asdu.objects {
            let Some(entries) = points.get_mut(&(asdu.common_address, o.ioa)) else {
                unrouted += 1;
                continue;
            };
            let at = o.time.and_then(|t| when(t, now.system));
            for e in entries.iter_mut() {
                if e.fixed.is_some_and(|f| f != asdu.type_id) {
                    let why = format!(
                        "the station sent {} where the profile fixes {}",
                        asdu.type_id.name(),
                        e.fixed.map_or("", |f| f.name())
                    );
                    e.device
                        .publish_at(e.idx, Err(FieldError::Device(why)), now);
                    continue;
                }
                e.seen = true;
                let field = &e.device.profile.fields[e.idx];
                let read = value::reading(&o.element, field.stored_type())
                    .and_then(|(raw, doubt)| Ok((field.value_of_raw(raw)?, doubt)));
                match read {
                    Ok((v, doubt)) => {
                        e.device
                            .publish_from(e.idx, Ok(v), doubt.map(FieldError::Device), at, now)
                    }
                    Err(why) => e
                        .device
                        .publish_at(e.idx, Err(FieldError::Device(why)), now),
                }
            }
        }
        if unrouted > 0 {
            self.unrouted.fetch_add(unrouted, Ordering::Relaxed);
        }
    }
}

/// Whether ASDUs of `kind` carry monitored values.
fn monitored(kind: Kind) -> bool {
    matches!(
        kind,
        Kind::Single
            | Kind::Double
            | Kind::Step
            | Kind::Bits
            | Kind::Normalized
            | Kind::NormalizedBare
            | Kind::Scaled
            | Kind::Float
            | Kind::Counter
    )
}

/// The wall-clock time a time tag names (none when the station marks it invalid).
fn when(t: Time, now: SystemTime) -> Option<SystemTime> {
    let since = |ms: i64| {
        SystemTime::UNIX_EPOCH.checked_add(Duration::from_millis(u64::try_from(ms).ok()?))
    };
    match t {
        Time::Full(c) if !c.invalid => since(c.millis),
        Time::Short(c) if !c.invalid => {
            let now_ms = now.duration_since(SystemTime::UNIX_EPOCH).ok()?.as_millis() as i64;
            since(c.near(now_ms))
        }
        _ => None,
    }
}

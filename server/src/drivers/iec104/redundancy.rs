//! A redundancy group of two connections to one station (its address and its `backup`), as
//! IEC 60870-5-104 defines it: one started (data transfer on), the other opened and held
//! stopped, tested after t3 of quiet. When the started one is lost, the standby is started
//! (STARTDT) at once and its devices interrogated again; the lost address is then opened
//! again as the standby. A standby that does not connect, or connects and is lost, is tried
//! again after a delay that doubles up to a minute, and comes back to a second only after
//! one was held a minute; the pace is the group's, kept while the link is reopened, so a
//! station that accepts and then fails is not stormed. A station that closes its started
//! connection as the standby connects (it keeps one connection at a time) gets no standby
//! for ten minutes: its backup is tried meanwhile only when the started connection fails.

use std::collections::HashMap;
use std::sync::{Arc, LazyLock, Mutex};
use std::time::Duration;

use tokio::sync::watch;
use tokio::time::Instant;

use super::config::Settings;
use super::conn::{self, Connection, Opening};
use super::route::Router;
use crate::cache::Link;

const FIRST_DELAY: Duration = Duration::from_secs(1);
const MOST_DELAY: Duration = Duration::from_secs(60);
/// A started connection the station closed between the standby's TCP connect and this
/// long after it was held was closed for it (a station closes the old connection as it
/// accepts the new).
const EVICTED_WITHIN: Duration = Duration::from_millis(100);
/// How long no standby is held for a station found to keep one connection at a time.
const SINGLE_FOR: Duration = Duration::from_secs(600);

/// The group's two addresses.
pub(super) type Addresses = [(String, u16); 2];

/// How a group's standby is tried: kept while the link is reopened, by link and
/// addresses; forgotten once it says nothing a fresh one would not (no delay past the
/// first, nothing to wait for), so groups configured and gone leave nothing behind.
#[derive(Debug, Clone, Copy)]
struct Pace {
    delay: Duration,
    /// No attempt before then.
    next: Option<Instant>,
    /// The station keeps one connection at a time: no standby is held until then.
    single: Option<Instant>,
}

impl Pace {
    /// Whether this pace says nothing a fresh one would not as of `now`: no station
    /// keeping one connection, and either the first delay with no attempt waited for, or
    /// no attempt for longer than the longest delay (a group that backs off tries at least
    /// that often; one that went longer held its standby, or is gone).
    fn is_fresh(&self, now: Instant) -> bool {
        let waited = |n: Instant| n <= now;
        let quiet = |n: Instant| n + MOST_DELAY <= now;
        self.single.is_none_or(waited)
            && ((self.delay <= FIRST_DELAY && self.next.is_none_or(waited))
                || self.next.is_some_and(quiet))
    }
}

static PACES: LazyLock<Mutex<HashMap<String, Pace>>> = LazyLock::new(Mutex::default);

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

fn pace(key: &str) -> Pace {
    lock(&PACES).get(key).copied().unwrap_or(Pace {
        delay: FIRST_DELAY,
        next: None,
        single: None,
    })
}

fn set_pace(key: &str, f: impl FnOnce(&mut Pace)) {
    let mut paces = lock(&PACES);
    let p = paces.entry(key.to_owned()).or_insert(Pace {
        delay: FIRST_DELAY,
        next: None,
        single: None,
    });
    f(p);
    let now = Instant::now();
    paces.retain(|_, p| !p.is_fresh(now));
}

pub(super) fn endpoint((host, port): &(String, u16)) -> String {
    format!("{host}:{port}")
}

/// Where the standby is: none, its TCP connected and its test frame awaited (the connect
/// began then), or held.
enum Slot {
    Empty,
    Testing(Instant),
    Held(Held),
}

/// The standby of a redundancy group, kept by its own task.
pub(super) struct Standby {
    slot: Arc<watch::Sender<Slot>>,
    /// How long a standby's test frame may take (t1).
    opening: Duration,
    /// Which of the two addresses is started (the standby is the other).
    active: watch::Sender<usize>,
    addresses: Arc<Addresses>,
    key: String,
    link: Arc<Link>,
    task: tokio::task::JoinHandle<()>,
}

impl Drop for Standby {
    fn drop(&mut self) {
        self.task.abort();
    }
}

impl Standby {
    /// Holds a standby to the address other than `active` (none for a station found to
    /// keep one connection at a time).
    pub(super) fn hold(
        addresses: Addresses,
        active: usize,
        settings: Settings,
        link: Arc<Link>,
    ) -> Standby {
        let key = format!(
            "{}|{}|{}",
            link.name(),
            endpoint(&addresses[0]),
            endpoint(&addresses[1])
        );
        let slot = Arc::new(watch::Sender::new(Slot::Empty));
        let opening = settings.t1;
        let (tx, rx) = watch::channel(active);
        let addresses = Arc::new(addresses);
        let keeping = Keeping {
            slot: slot.clone(),
            active: rx,
            addresses: addresses.clone(),
            settings,
            link: link.clone(),
            key: key.clone(),
        };
        let task = tokio::spawn(keeping.run());
        Standby {
            slot,
            opening,
            active: tx,
            addresses,
            key,
            link,
            task,
        }
    }

    /// The standby connection, if one is held and alive, now the started one's: its
    /// address is then the active one, and the other is held as the standby. A standby
    /// that connected as the started connection was lost (at `lost_at`) took its place at
    /// the station: it is started, and no standby is held for a while. `closed`: the
    /// station closed the lost connection (the gateway did not).
    pub(super) async fn take(
        &self,
        lost_at: Option<Instant>,
        closed: bool,
    ) -> Option<(Connection, String)> {
        let mut slot = self.slot.subscribe();
        // One whose TCP connected before the loss (perhaps its cause) is waited for, its
        // test frame within t1; one whose TCP connect is pending is not.
        let testing = matches!(*slot.borrow_and_update(), Slot::Testing(began) if lost_at.is_some_and(|at| at >= began));
        if testing {
            let tested = slot.wait_for(|s| !matches!(s, Slot::Testing(_)));
            let _ = tokio::time::timeout(self.opening, tested).await;
        }
        if !matches!(*slot.borrow(), Slot::Held(_)) {
            return None;
        }
        let Slot::Held(Held { conn, began, held }) = self.slot.send_replace(Slot::Empty) else {
            return None;
        };
        if conn.lost.borrow().is_some() {
            return None;
        }
        if closed && lost_at.is_some_and(|at| at >= began && at <= held + EVICTED_WITHIN) {
            set_pace(&self.key, |p| p.single = Some(Instant::now() + SINGLE_FOR));
            tracing::warn!(link = %self.link.name(), "IEC 104: the station closed its started connection when the standby connected; no standby is held for ten minutes");
        }
        let now = 1 - *self.active.borrow();
        self.active.send_replace(now);
        Some((conn, endpoint(&self.addresses[now])))
    }
}

const NOT_HELD: &str = "not held for ten minutes: the station closed its started connection when the standby connected (it keeps one connection at a time); meanwhile the other address is tried when the started one fails";

/// A standby held: its connection, when its connect began and when it was held.
struct Held {
    conn: Connection,
    began: Instant,
    held: Instant,
}

/// What the standby's task keeps.
struct Keeping {
    slot: Arc<watch::Sender<Slot>>,
    active: watch::Receiver<usize>,
    addresses: Arc<Addresses>,
    settings: Settings,
    link: Arc<Link>,
    key: String,
}

impl Keeping {
    /// Opens the address not started, on the group's pace, and holds it until it is lost
    /// or taken.
    async fn run(mut self) {
        let mut attempts = 0u64;
        loop {
            let p = pace(&self.key);
            if let Some(until) = p.single.filter(|u| *u > Instant::now()) {
                self.link.set_peer("standby", NOT_HELD.to_owned());
                tokio::time::sleep_until(until).await;
                set_pace(&self.key, |p| p.single = None);
                continue;
            }
            if let Some(next) = p.next {
                tokio::time::sleep_until(next).await;
            }
            attempts += 1;
            let why = self.attempt().await;
            let delay = pace(&self.key).delay;
            set_pace(&self.key, |p| {
                p.next = Some(Instant::now() + delay);
                p.delay = (delay * 2).min(MOST_DELAY);
            });
            let next = endpoint(&self.addresses[1 - *self.active.borrow()]);
            self.link.set_peer(
                "standby",
                format!(
                    "{next}: not held ({why}); attempt {} in {delay:?}",
                    attempts + 1
                ),
            );
        }
    }

    /// One standby: why it is not held any more.
    async fn attempt(&mut self) -> String {
        let other = self.addresses[1 - *self.active.borrow_and_update()].clone();
        let at = endpoint(&other);
        let router = Arc::new(Router::default());
        let began = Instant::now();
        let io = match conn::connect(&other.0, other.1, &self.settings).await {
            Ok(io) => io,
            Err(e) => return e.to_string(),
        };
        self.slot.send_replace(Slot::Testing(began));
        let opened = conn::handshake(io, &self.settings, router, Opening::Standby).await;
        let c = match opened {
            Ok(c) => c,
            Err(e) => {
                self.slot.send_replace(Slot::Empty);
                return e.to_string();
            }
        };
        let mut lost = c.lost.clone();
        let held = Instant::now();
        self.slot.send_replace(Slot::Held(Held {
            conn: c,
            began,
            held,
        }));
        self.link.set_peer(
            "standby",
            format!("{at} (connected, data transfer stopped)"),
        );
        tokio::select! {
            _ = lost.wait_for(Option::is_some) => {}
            _ = self.active.changed() => {}
        }
        if held.elapsed() >= MOST_DELAY {
            set_pace(&self.key, |p| p.delay = FIRST_DELAY);
        }
        if !matches!(self.slot.send_replace(Slot::Empty), Slot::Held(_)) {
            return format!("{at} took over from the started connection");
        }
        lost.borrow()
            .as_ref()
            .map_or("closed".into(), ToString::to_string)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pace_is_kept_while_it_holds_back_and_forgotten_once_fresh() {
        let key = "pace-test|127.0.0.1:1|127.0.0.1:2";
        let held = |key: &str| lock(&PACES).contains_key(key);
        set_pace(key, |p| {
            p.delay = FIRST_DELAY * 4;
            p.next = Some(Instant::now() + Duration::from_secs(4));
        });
        assert!(held(key), "a doubled delay is kept");
        assert_eq!(pace(key).delay, FIRST_DELAY * 4);
        set_pace(key, |p| p.delay = FIRST_DELAY);
        assert!(held(key), "an attempt still waited for is kept");
        set_pace(key, |p| p.next = None);
        assert!(!held(key), "a pace like a fresh one is forgotten");
        assert_eq!(pace(key).delay, FIRST_DELAY);
        set_pace(key, |p| p.single = Some(Instant::now() + SINGLE_FOR));
        assert!(held(key), "a station keeping one connection is remembered");
        set_pace(key, |p| p.single = Some(Instant::now()));
        assert!(!held(key));
        set_pace(key, |p| {
            p.delay = MOST_DELAY;
            p.next = Some(Instant::now());
        });
        assert!(held(key), "a group backing off is remembered");
        let long_ago = Instant::now()
            .checked_sub(MOST_DELAY + Duration::from_secs(1))
            .expect("the clock is past a minute");
        set_pace(key, |p| p.next = Some(long_ago));
        assert!(
            !held(key),
            "no attempt for longer than the longest delay: forgotten"
        );
    }
}

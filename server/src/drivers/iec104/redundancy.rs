//! A redundancy group of two connections to one station (its address and its `backup`), as
//! IEC 60870-5-104 defines it: one started (data transfer on), the other opened and held
//! stopped, tested after t3 of quiet. When the started one is lost, the standby is started
//! (STARTDT) at once and its devices interrogated again; the lost address is then opened
//! again as the standby. A standby that does not connect, or connects and is lost, is tried
//! again after a delay that doubles up to a minute, and comes back to a second only after
//! one was held a minute: a station that accepts and then fails is not stormed.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use tokio::sync::watch;
use tokio::time::Instant;

use super::config::Settings;
use super::conn::{self, Connection, Opening};
use super::route::Router;
use crate::cache::Link;

const FIRST_DELAY: Duration = Duration::from_secs(1);
const MOST_DELAY: Duration = Duration::from_secs(60);

/// The group's two addresses.
pub(super) type Addresses = [(String, u16); 2];

/// The standby of a redundancy group, kept by its own task.
pub(super) struct Standby {
    slot: Arc<Mutex<Option<Connection>>>,
    /// Which of the two addresses is started (the standby is the other).
    active: watch::Sender<usize>,
    addresses: Arc<Addresses>,
    task: tokio::task::JoinHandle<()>,
}

impl Drop for Standby {
    fn drop(&mut self) {
        self.task.abort();
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

pub(super) fn endpoint((host, port): &(String, u16)) -> String {
    format!("{host}:{port}")
}

impl Standby {
    /// Holds a standby to the address other than `active`.
    pub(super) fn hold(
        addresses: Addresses,
        active: usize,
        settings: Settings,
        link: Arc<Link>,
    ) -> Standby {
        let slot = Arc::new(Mutex::new(None));
        let (tx, rx) = watch::channel(active);
        let addresses = Arc::new(addresses);
        let task = tokio::spawn(keep(slot.clone(), rx, addresses.clone(), settings, link));
        Standby {
            slot,
            active: tx,
            addresses,
            task,
        }
    }

    /// The standby connection, if one is held and alive, now the started one's: its
    /// address is then the active one, and the other is held as the standby.
    pub(super) fn take(&self) -> Option<(Connection, String)> {
        let conn = lock(&self.slot).take()?;
        if conn.lost.borrow().is_some() {
            return None;
        }
        let now = 1 - *self.active.borrow();
        self.active.send_replace(now);
        Some((conn, endpoint(&self.addresses[now])))
    }
}

/// The standby's task: opens the address not started, holds it until it is lost or taken.
async fn keep(
    slot: Arc<Mutex<Option<Connection>>>,
    mut active: watch::Receiver<usize>,
    addresses: Arc<Addresses>,
    s: Settings,
    link: Arc<Link>,
) {
    let mut delay = FIRST_DELAY;
    let mut attempts = 0u64;
    loop {
        let other = &addresses[1 - *active.borrow_and_update()];
        let at = endpoint(other);
        attempts += 1;
        let opened = conn::open(
            &other.0,
            other.1,
            &s,
            Arc::new(Router::default()),
            Opening::Standby,
        )
        .await;
        let why = match opened {
            Ok(c) => {
                let mut lost = c.lost.clone();
                let held = Instant::now();
                *lock(&slot) = Some(c);
                link.set_peer(
                    "standby",
                    format!("{at} (connected, data transfer stopped)"),
                );
                tokio::select! {
                    _ = lost.wait_for(Option::is_some) => {}
                    _ = active.changed() => {}
                }
                if held.elapsed() >= MOST_DELAY {
                    delay = FIRST_DELAY;
                }
                if lock(&slot).take().is_none() {
                    format!("{at} took over from the started connection")
                } else {
                    lost.borrow()
                        .as_ref()
                        .map_or("closed".into(), ToString::to_string)
                }
            }
            Err(e) => e.to_string(),
        };
        let next = endpoint(&addresses[1 - *active.borrow()]);
        link.set_peer(
            "standby",
            format!(
                "{next}: not held ({why}); attempt {} in {delay:?}",
                attempts + 1
            ),
        );
        tokio::time::sleep(delay).await;
        delay = (delay * 2).min(MOST_DELAY);
    }
}

//! This gateway's role in an active/standby pair (`ha:`), as the rest of the house sees it:
//! alone (no pair), active under a lease with its epoch, or standby. `ha/` decides it with
//! the arbiter; the link tasks, the service and the front-ends only read it.
//!
//! Every write is fenced: its generation carries the epoch that accepted it (the high 32
//! bits, [`epoch_of`]), and a link writes it only while this gateway is active in that
//! same epoch and its lease is still valid ([`Role::may_write`]). A process paused past its
//! lease (a stopped VM, a long GC-like stall) writes nothing when it wakes.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU16, AtomicU64, Ordering};

use serde::Serialize;
use tokio::sync::watch;
use tokio::time::Instant;

/// Where an epoch sits in a write's generation.
const EPOCH_SHIFT: u32 = 32;

/// The epoch a write generation was handed out in.
pub(crate) fn epoch_of(generation: u64) -> u64 {
    generation >> EPOCH_SHIFT
}

/// The first generation of `epoch`.
pub(crate) fn first_generation(epoch: u64) -> u64 {
    (epoch << EPOCH_SHIFT) | 1
}

/// What this gateway is in its pair.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum Standing {
    /// No `ha:` section: the gateway owns its field alone.
    Alone,
    /// It holds the lease: it polls the field and takes writes.
    Active,
    /// The other node holds the lease (or nobody does yet): it touches nothing in the field.
    Standby,
}

/// A node of the pair and how clients reach it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, serde::Deserialize, utoipa::ToSchema)]
pub struct Peer {
    pub node: String,
    /// Each server's address, by server name (`http`, `grpc`, `opcua`, `modbus`).
    pub addresses: BTreeMap<String, String>,
}

/// The role as it changes (not as it is renewed: a renewal wakes nobody).
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct Lease {
    pub(crate) standing: Standing,
    /// The epoch of the newest lease this gateway knows of (its own while active).
    pub(crate) epoch: u64,
    /// Who is active, when anyone is known to be.
    pub(crate) active: Option<Peer>,
}

/// Why a write was not put on the field.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub(crate) enum Fenced {
    #[error("this gateway is the standby of its pair: it writes nothing to the field")]
    Standby,
    #[error(
        "accepted in epoch {accepted}, but the pair is in epoch {now}: not written by the old epoch"
    )]
    OldEpoch { accepted: u64, now: u64 },
    #[error("the lease was not renewed in time: this gateway stopped writing")]
    Expired,
}

/// The role cell: one per gateway.
#[derive(Debug)]
pub(crate) struct Role {
    /// This node's name, when it is in a pair.
    node: Option<String>,
    /// The arbiter's name and the lease, when in a pair.
    terms: Option<(&'static str, std::time::Duration)>,
    lease: watch::Sender<Lease>,
    /// Until when the active's lease holds, in nanoseconds after `base` (0: not held).
    until: AtomicU64,
    base: Instant,
    takeovers: AtomicU64,
    /// The pair's one Sparkplug edge node: the `bdSeq` of this node's newest session, and
    /// of the other node's as its lease renewals said ([`NO_SESSION`]: none).
    edge_session: AtomicU16,
    heard_session: AtomicU16,
}

/// No Sparkplug session known.
const NO_SESSION: u16 = u16::MAX;

impl Role {
    /// The role of a gateway without a pair: always allowed to write.
    pub(crate) fn alone() -> Role {
        Role::new(None, Standing::Alone)
    }

    /// The role of node `node` of a pair whose lease of `lease` the arbiter `arbiter`
    /// grants; standby until it does.
    pub(crate) fn paired(node: &str, arbiter: &'static str, lease: std::time::Duration) -> Role {
        let mut role = Role::new(Some(node.to_owned()), Standing::Standby);
        role.terms = Some((arbiter, lease));
        role
    }

    /// The arbiter's name and the lease, when in a pair.
    pub(crate) fn terms(&self) -> Option<(&'static str, std::time::Duration)> {
        self.terms
    }

    fn new(node: Option<String>, standing: Standing) -> Role {
        let (lease, _) = watch::channel(Lease {
            standing,
            epoch: 0,
            active: None,
        });
        Role {
            node,
            terms: None,
            lease,
            until: AtomicU64::new(0),
            base: Instant::now(),
            takeovers: AtomicU64::new(0),
            edge_session: AtomicU16::new(NO_SESSION),
            heard_session: AtomicU16::new(NO_SESSION),
        }
    }

    /// This node's Sparkplug session is `bd_seq` (its MQTT front-end says so at each
    /// connection).
    pub(crate) fn set_edge_session(&self, bd_seq: u8) {
        self.edge_session
            .store(u16::from(bd_seq), Ordering::Relaxed);
    }

    /// This node's Sparkplug `bdSeq`, when it has one.
    pub(crate) fn edge_session(&self) -> Option<u8> {
        u8::try_from(self.edge_session.load(Ordering::Relaxed)).ok()
    }

    /// The active of the pair is in Sparkplug session `bd_seq` (heard by a standby).
    pub(crate) fn heard_edge_session(&self, bd_seq: u8) {
        self.heard_session
            .store(u16::from(bd_seq), Ordering::Relaxed);
    }

    /// The other node's newest Sparkplug `bdSeq` heard, once: a node taking over births
    /// with the next.
    pub(crate) fn take_heard_edge_session(&self) -> Option<u8> {
        u8::try_from(self.heard_session.swap(NO_SESSION, Ordering::Relaxed)).ok()
    }

    pub(crate) fn node(&self) -> Option<&str> {
        self.node.as_deref()
    }

    pub(crate) fn lease(&self) -> Lease {
        self.lease.borrow().clone()
    }

    pub(crate) fn standing(&self) -> Standing {
        self.lease.borrow().standing
    }

    /// Wakes at every change of role, epoch or active node.
    pub(crate) fn watch(&self) -> watch::Receiver<Lease> {
        self.lease.subscribe()
    }

    /// How many times this gateway became active.
    pub(crate) fn takeovers(&self) -> u64 {
        self.takeovers.load(Ordering::Relaxed)
    }

    /// Resolves once the gateway owns its field (at once for a gateway alone).
    pub(crate) async fn owning(&self) {
        let mut lease = self.watch();
        while !self.owns_field() {
            if lease.changed().await.is_err() {
                std::future::pending::<()>().await;
            }
        }
    }

    /// Whether the field is this gateway's: alone, or active with a lease still valid.
    pub(crate) fn owns_field(&self) -> bool {
        match self.standing() {
            Standing::Alone => true,
            Standing::Active => self.valid(),
            Standing::Standby => false,
        }
    }

    fn valid(&self) -> bool {
        let until = self.until.load(Ordering::Acquire);
        until != 0 && (Instant::now() - self.base).as_nanos() < u128::from(until)
    }

    /// Whether the write of `generation` may go on the field now.
    pub(crate) fn may_write(&self, generation: u64) -> Result<(), Fenced> {
        let lease = self.lease.borrow();
        match lease.standing {
            Standing::Alone => Ok(()),
            Standing::Standby => Err(Fenced::Standby),
            Standing::Active if epoch_of(generation) != lease.epoch => Err(Fenced::OldEpoch {
                accepted: epoch_of(generation),
                now: lease.epoch,
            }),
            Standing::Active if !self.valid() => Err(Fenced::Expired),
            Standing::Active => Ok(()),
        }
    }

    /// The lease of `epoch` is granted, valid until `until`: this gateway is active.
    pub(crate) fn activate(&self, epoch: u64, until: Instant, me: Peer) {
        self.renew(until);
        self.takeovers.fetch_add(1, Ordering::Relaxed);
        self.lease.send_replace(Lease {
            standing: Standing::Active,
            epoch,
            active: Some(me),
        });
    }

    /// The lease holds until `until` (a renewal the arbiter confirmed).
    pub(crate) fn renew(&self, until: Instant) {
        let nanos = until.saturating_duration_since(self.base).as_nanos();
        self.until.store(
            u64::try_from(nanos).unwrap_or(u64::MAX).max(1),
            Ordering::Release,
        );
    }

    /// This gateway is standby (again): it writes nothing from now on. `active` is the node
    /// holding the lease, when one is known, at `epoch`.
    pub(crate) fn stand_by(&self, epoch: u64, active: Option<Peer>) {
        self.until.store(0, Ordering::Release);
        self.lease.send_if_modified(|lease| {
            let new = Lease {
                standing: Standing::Standby,
                epoch: epoch.max(lease.epoch),
                active,
            };
            let changed = *lease != new;
            *lease = new;
            changed
        });
    }

    /// When this gateway's lease runs out, while it is active.
    pub(crate) fn until(&self) -> Option<Instant> {
        let until = self.until.load(Ordering::Acquire);
        (until != 0).then(|| self.base + std::time::Duration::from_nanos(until))
    }
}

/// Resolves when the gateway no longer owns the field it owned in `epoch`: it stood down,
/// or holds a later lease (a lease lost and taken again is another epoch). Never for a
/// gateway alone; when the role is gone (shutdown) at once.
pub(crate) async fn stood_down(lease: &mut watch::Receiver<Lease>, epoch: u64) {
    loop {
        {
            let now = lease.borrow_and_update();
            let owns = match now.standing {
                Standing::Alone => true,
                Standing::Active => now.epoch == epoch,
                Standing::Standby => false,
            };
            if !owns {
                return;
            }
        }
        if lease.changed().await.is_err() {
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    fn me() -> Peer {
        Peer {
            node: "a".into(),
            addresses: BTreeMap::new(),
        }
    }

    #[test]
    fn alone_writes_everything() {
        assert_eq!(Role::alone().may_write(7), Ok(()));
    }

    #[tokio::test]
    async fn only_the_epoch_that_accepted_a_write_puts_it_on_the_field() {
        let role = Role::paired("a", "mqtt", Duration::from_secs(3));
        assert_eq!(role.may_write(first_generation(0)), Err(Fenced::Standby));
        role.activate(3, Instant::now() + Duration::from_secs(5), me());
        assert_eq!(role.may_write(first_generation(3) + 9), Ok(()));
        assert_eq!(
            role.may_write(first_generation(2)),
            Err(Fenced::OldEpoch {
                accepted: 2,
                now: 3
            })
        );
        role.stand_by(4, None);
        assert_eq!(role.may_write(first_generation(3)), Err(Fenced::Standby));
        assert!(!role.owns_field());
    }

    #[tokio::test(start_paused = true)]
    async fn a_lease_not_renewed_in_time_stops_the_writes() {
        let role = Role::paired("a", "mqtt", Duration::from_secs(3));
        role.activate(1, Instant::now() + Duration::from_secs(3), me());
        assert!(role.owns_field());
        tokio::time::advance(Duration::from_millis(3001)).await;
        assert_eq!(role.may_write(first_generation(1)), Err(Fenced::Expired));
        assert!(!role.owns_field());
    }
}

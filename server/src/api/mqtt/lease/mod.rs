//! The lease of an active/standby pair held through the broker of the `mqtt:` section
//! (`ha: {arbiter: mqtt}`), as a Sparkplug primary host holds its STATE:
//!
//! - The lock is a connection with the client id both nodes share (`iogate-ha-<group>`):
//!   the broker lets one connection hold a client id at a time. It carries a Will that
//!   releases the claim, so a holder that dies or is cut off releases it through the broker
//!   (at once for a killed process, after 1.5 keep-alives for a silent one).
//! - The claim is a retained message (`iogate/ha/<group>/claim`): who holds the lease, its
//!   epoch, and how clients reach the holder. The epoch is read under the lock (the
//!   retained claim, after a subscription and a ping that comes back behind it) and the
//!   next one published, so it only grows.
//! - The lock's keep-alive is two thirds of the lease (whole seconds, [`keep_alive`]): the
//!   broker drops a silent connection after 1.5 keep-alives, about the lease. Brokers count
//!   in whole seconds (Mosquitto compares `time_t`s), so a drop may come up to a second
//!   early: the holder's own lease ([`holds`]) is three quarters of the earliest drop. It
//!   renews with a QoS 1 message (`iogate/ha/<group>/alive`) three times within it; each
//!   acknowledgement extends the lease to the renewal's *sending* time plus [`holds`]. The
//!   broker received that renewal after it was sent: a holder cut off stops writing before
//!   the broker can release the lock, and the standby takes over about a lease after.
//! - A standby watches the claim on a connection of its own and takes the lock when the
//!   claim is released, absent, or silent (no claim nor renewal) for two leases.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Duration;

use tokio::time::{Instant, sleep_until};
use tokio_util::sync::CancellationToken;

use super::Prepared;
use super::conn::{ConnError, Connection};
use super::packet::{Connect, Incoming, Will};
use crate::role::{Peer, Role};
use crate::write_log::{WriteLog, WriteRecord};

mod claim;
mod handover;
mod hold;
mod ship;

pub(crate) use handover::run as handover;
use hold::{hold, release};

use claim::{Claim, Seen, Topics};

/// How long a newly granted lease is held before the field is touched: a node that lost
/// a start-up race (both saw no claim) is pushed off the lock in this time.
const SETTLE_MAX: Duration = Duration::from_millis(500);
/// The longest wait between attempts to reach the broker.
const RETRY_MAX: Duration = Duration::from_secs(1);

/// What the lease task is given.
pub(crate) struct LeaseSetup {
    pub(crate) prepared: Prepared,
    pub(crate) group: String,
    pub(crate) node: String,
    pub(crate) lease: Duration,
    pub(crate) role: Arc<Role>,
    /// This node as clients reach it (its servers' addresses), when it claims the lease.
    pub(crate) me: Arc<dyn Fn() -> Peer + Send + Sync>,
    /// Called with the epoch before this node becomes active in it.
    pub(crate) entering: Arc<dyn Fn(u64) + Send + Sync>,
    /// The write log whose journal the active ships to the standby.
    pub(crate) log: Arc<WriteLog>,
    /// Takes the records the active shipped (on the standby), with the active's epoch.
    pub(crate) adopt: Arc<dyn Fn(u64, Vec<WriteRecord>) + Send + Sync>,
    /// Whose declarations the active publishes and the standby takes.
    pub(crate) service: Arc<crate::service::Service>,
}

/// How the watch of a standby ended.
enum Watched {
    Stop,
    Take,
}

/// How holding the lease ended.
enum Held {
    Stop,
    Lost(String),
}

/// Runs the lease until `token` is cancelled: watches, takes, holds, and stands down.
pub(crate) async fn run(setup: LeaseSetup, token: CancellationToken) {
    let topics = Topics::new(&setup.group);
    let mut seen = Seen {
        claim: None,
        epoch: 0,
        heard: Instant::now(),
        bd_seq: None,
    };
    let mut wait = Duration::ZERO;
    loop {
        if wait > Duration::ZERO {
            tokio::select! {
                _ = token.cancelled() => return,
                _ = tokio::time::sleep(wait) => {}
            }
        }
        match watch(&setup, &topics, &mut seen, &token).await {
            Ok(Watched::Stop) => return,
            Ok(Watched::Take) => {}
            Err(e) => {
                wait = retry(wait, setup.lease);
                tracing::warn!(error = %e, retry_in = ?wait, "HA: cannot watch the lease on the MQTT broker");
                continue;
            }
        }
        match take(&setup, &topics, &seen, &token).await {
            Ok(Some(holding)) => {
                wait = Duration::ZERO;
                seen.epoch = holding.epoch;
                match hold(&setup, &topics, holding, &token).await {
                    Held::Stop => return,
                    Held::Lost(why) => {
                        tracing::warn!(why = %why, "HA: the lease is lost: standing by");
                        seen.heard = Instant::now();
                    }
                }
            }
            Ok(None) => return,
            Err(e) => {
                setup.role.stand_by(seen.epoch, None);
                wait = retry(wait, setup.lease);
                tracing::warn!(error = %e, retry_in = ?wait, "HA: cannot take the lease");
            }
        }
    }
}

fn retry(wait: Duration, lease: Duration) -> Duration {
    (wait * 2).clamp(Duration::from_millis(100), RETRY_MAX.min(lease / 3))
}

/// The lock's keep-alive for a lease: two thirds of it, rounded up to whole seconds.
fn keep_alive(lease: Duration) -> Duration {
    Duration::from_secs((lease.as_secs() * 2).div_ceil(3).max(1))
}

/// How long an acknowledged renewal holds the lease, from when it was sent: three quarters
/// of the earliest moment a broker counting whole seconds may drop the silent lock
/// (1.5 keep-alives, rounded down, less a second).
fn holds(lease: Duration) -> Duration {
    let k = keep_alive(lease).as_secs();
    let earliest = Duration::from_secs((k * 3 / 2).saturating_sub(1));
    earliest * 3 / 4
}

fn connect(setup: &LeaseSetup, client_id: String, will: Option<Will>) -> Connect {
    let config = &setup.prepared.config;
    Connect {
        client_id,
        keep_alive: keep_alive(setup.lease).as_secs().min(u64::from(u16::MAX)) as u16,
        clean_start: true,
        username: config.username.clone(),
        password: setup.prepared.password.clone(),
        will,
    }
}

async fn open(setup: &LeaseSetup, connect: &Connect) -> Result<Connection, ConnError> {
    let prepared = &setup.prepared;
    Connection::open(&prepared.config, prepared.tls.as_ref(), connect).await
}

/// Subscribes to `filters` and reads until a ping sent behind the subscription comes back:
/// every retained message the subscription brings is in `seen` then.
async fn subscribed(
    conn: &mut Connection,
    filters: &[(String, u8)],
    topics: &Topics,
    seen: &mut Seen,
) -> Result<(), ConnError> {
    conn.subscribe(filters).await?;
    loop {
        match conn.read().await? {
            Incoming::SubAck { codes, .. } => {
                if codes.iter().any(|&c| c >= 0x80) {
                    return Err(ConnError::Refused(
                        "the subscription to the lease",
                        codes[0],
                    ));
                }
                break;
            }
            Incoming::Publish(p) => publish_in(conn, &p, topics, seen).await?,
            _ => {}
        }
    }
    conn.keep_alive().await?;
    loop {
        match conn.read().await? {
            Incoming::PingResp => return Ok(()),
            Incoming::Publish(p) => publish_in(conn, &p, topics, seen).await?,
            _ => {}
        }
    }
}

async fn publish_in(
    conn: &mut Connection,
    p: &super::packet::Publish,
    topics: &Topics,
    seen: &mut Seen,
) -> Result<(), ConnError> {
    seen.take(&p.topic, &p.payload, topics);
    if p.qos > 0 {
        conn.puback(p.pkid).await?;
    }
    Ok(())
}

/// A standby's watch: until the lease is free to take (or the gateway stops).
async fn watch(
    setup: &LeaseSetup,
    topics: &Topics,
    seen: &mut Seen,
    token: &CancellationToken,
) -> Result<Watched, ConnError> {
    let id = format!("iogate-ha-{}-{}", setup.group, setup.node);
    let mut conn = open(setup, &connect(setup, id, None)).await?;
    let filters = [
        (topics.claim.clone(), 1),
        (topics.alive.clone(), 0),
        (topics.writes.clone(), 0),
        (topics.declared.clone(), 0),
    ];
    seen.heard = Instant::now();
    subscribed(&mut conn, &filters, topics, seen).await?;
    // The active ships each field's newest record again for a standby that comes.
    conn.publish(&topics.hello, setup.node.as_bytes(), 0, false, 0)
        .await?;
    conn.flush().await?;
    // Whether the lease's messages changed what this node knows (a shipment does not).
    let mut told = true;
    loop {
        if std::mem::take(&mut told) {
            let active = seen.claim.as_ref().filter(|c| c.held).map(Claim::peer);
            setup.role.stand_by(seen.epoch, active);
            if let Some(bd_seq) = seen.bd_seq {
                setup.role.heard_edge_session(bd_seq);
            }
        }
        if seen.free(setup.lease) {
            conn.disconnect().await;
            return Ok(Watched::Take);
        }
        let silent = seen.heard + 2 * setup.lease;
        let ping = conn.keep_alive_due().unwrap_or(silent);
        tokio::select! {
            _ = token.cancelled() => {
                conn.disconnect().await;
                return Ok(Watched::Stop);
            }
            packet = conn.read() => {
                if let Incoming::Publish(p) = packet? {
                    if p.topic == topics.writes {
                        adopt(setup, &p.payload);
                    } else if p.topic == topics.declared {
                        setup.service.adopt_declarations(&p.payload);
                    } else {
                        told = true;
                    }
                    publish_in(&mut conn, &p, topics, seen).await?;
                }
            }
            _ = sleep_until(ping) => conn.keep_alive().await?,
            _ = sleep_until(silent) => told = true,
        }
    }
}

/// The lock held, in `epoch`.
pub(super) struct Holding {
    conn: Connection,
    epoch: u64,
    /// When the claim that granted it was sent.
    sent: Instant,
}

/// Takes the lock, reads the epoch under it, claims the next one and settles; `None` when
/// the gateway stops first.
async fn take(
    setup: &LeaseSetup,
    topics: &Topics,
    seen: &Seen,
    token: &CancellationToken,
) -> Result<Option<Holding>, ConnError> {
    let released = |epoch| Claim {
        node: setup.node.clone(),
        epoch,
        held: false,
        addresses: BTreeMap::new(),
        bd_seq: None,
    };
    let will = Will {
        topic: topics.claim.clone(),
        payload: serde_json::to_vec(&released(seen.epoch + 1)).unwrap_or_default(),
        qos: 1,
        retain: true,
    };
    let id = format!("iogate-ha-{}", setup.group);
    let mut conn = open(setup, &connect(setup, id, Some(will))).await?;
    let mut under = Seen {
        claim: None,
        epoch: seen.epoch,
        heard: Instant::now(),
        bd_seq: None,
    };
    let filters = [(topics.claim.clone(), 1), (topics.hello.clone(), 0)];
    subscribed(&mut conn, &filters, topics, &mut under).await?;
    let epoch = under.epoch + 1;
    let me = (setup.me)();
    let claim = Claim {
        node: setup.node.clone(),
        epoch,
        held: true,
        addresses: me.addresses,
        bd_seq: None,
    };
    let sent = Instant::now();
    let payload = serde_json::to_vec(&claim).unwrap_or_default();
    conn.publish(&topics.claim, &payload, 1, true, epoch)
        .await?;
    conn.flush().await?;
    let settle = Instant::now() + SETTLE_MAX.min(setup.lease / 6);
    let unanswered = sent + setup.lease;
    let mut acked = false;
    loop {
        if acked && Instant::now() >= settle {
            return Ok(Some(Holding { conn, epoch, sent }));
        }
        let wake = if acked { settle } else { unanswered };
        tokio::select! {
            _ = token.cancelled() => {
                release(conn, topics, released(epoch)).await;
                return Ok(None);
            }
            packet = conn.read() => match packet? {
                Incoming::PubAck { pkid, .. } => acked |= conn.acked(pkid) == Some(epoch),
                Incoming::Publish(p) if p.qos > 0 => conn.puback(p.pkid).await?,
                _ => {}
            },
            _ = sleep_until(wake) => if !acked {
                let url = setup.prepared.config.url.to_string();
                return Err(ConnError::Timeout(url, setup.lease));
            },
        }
    }
}

/// Takes a shipment of the active's write records (a standby).
fn adopt(setup: &LeaseSetup, payload: &[u8]) {
    match ship::unpack(payload) {
        Some((epoch, records)) => (setup.adopt)(epoch, records),
        None => tracing::warn!(
            bytes = payload.len(),
            "HA: a message on the pair's writes topic that is not a shipment of records: ignored"
        ),
    }
}

#[cfg(test)]
mod tests;

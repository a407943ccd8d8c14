//! Holding the broker's lease: renewals, the claims and hellos the holder hears, the
//! records and declarations it ships, and giving the lease back.

use std::collections::BTreeMap;
use std::time::Duration;

use tokio::time::{Instant, sleep_until};
use tokio_util::sync::CancellationToken;

use super::claim::{Claim, Topics};
use super::{Held, Holding, LeaseSetup, holds, ship};
use crate::api::mqtt::conn::{ConnError, Connection};
use crate::api::mqtt::packet::{Incoming, Publish};

/// Active: renews the lease until it is lost or the gateway stops.
pub(super) async fn hold(
    setup: &LeaseSetup,
    topics: &Topics,
    mut holding: Holding,
    token: &CancellationToken,
) -> Held {
    let epoch = holding.epoch;
    let me = (setup.me)();
    (setup.entering)(epoch);
    let valid = holds(setup.lease);
    setup.role.activate(epoch, holding.sent + valid, me.clone());
    tracing::info!(epoch, node = %setup.node, "HA: this node is active");
    let every = valid / 3;
    let mut next = Instant::now() + every;
    // The declarations this node holds are the pair's from now on (retained: state).
    let mut declared = setup.service.watch_declared();
    declared.mark_changed();
    // Renewals in flight: tag -> when sent.
    let mut sent: BTreeMap<u64, Instant> = BTreeMap::new();
    let mut tag = epoch << 20;
    let mut gathering = ship::Gathering::new();
    let lost = |why: String| {
        setup.role.stand_by(epoch, None);
        Held::Lost(why)
    };
    loop {
        let until = setup.role.until().unwrap_or_else(Instant::now);
        tokio::select! {
            _ = token.cancelled() => {
                setup.role.stand_by(epoch, None);
                let claim = Claim { node: setup.node.clone(), epoch, held: false, addresses: BTreeMap::new(), bd_seq: None };
                release(holding.conn, topics, claim).await;
                return Held::Stop;
            }
            _ = sleep_until(until) => {
                return lost(format!("the lease was not renewed in time ({} renewals unanswered)", sent.len()));
            }
            _ = sleep_until(next) => {
                next += every;
                tag += 1;
                sent.insert(tag, Instant::now());
                let out = async {
                    holding.conn.publish(&topics.alive, &alive(setup, epoch), 1, false, tag).await?;
                    holding.conn.flush().await
                };
                if let Err(e) = out.await {
                    return lost(e.to_string());
                }
            }
            Ok(()) = declared.changed() => {
                if let Err(e) = ship::declared(&mut holding.conn, &topics.declared, &setup.service).await {
                    return lost(e.to_string());
                }
            }
            _ = setup.log.journaled(), if !gathering.waiting() => gathering.journaled(),
            _ = sleep_until(gathering.due()), if gathering.waiting() => {
                gathering.shipped();
                if let Err(e) = ship::ship(&mut holding.conn, &topics.writes, epoch, &setup.log).await {
                    return lost(e.to_string());
                }
            }
            packet = holding.conn.read() => match packet {
                Err(e) => return lost(e.to_string()),
                Ok(Incoming::PubAck { pkid, .. }) => {
                    if let Some(at) = holding.conn.acked(pkid).and_then(|t| sent.remove(&t)) {
                        sent.retain(|_, s| *s > at);
                        setup.role.renew(at + valid);
                        tracing::trace!(epoch, answered_in = ?at.elapsed(), "HA: lease renewed");
                    }
                }
                Ok(Incoming::Publish(p)) => {
                    if p.qos > 0 && holding.conn.puback(p.pkid).await.is_err() {
                        return lost("the broker connection failed".into());
                    }
                    if let Some(why) = heard_by_holder(setup, topics, &p) {
                        return lost(why);
                    }
                }
                Ok(_) => {}
            },
        }
    }
}

/// A renewal: the holder, its epoch, and its Sparkplug session.
fn alive(setup: &LeaseSetup, epoch: u64) -> Vec<u8> {
    serde_json::to_vec(&Claim {
        node: setup.node.clone(),
        epoch,
        held: true,
        addresses: BTreeMap::new(),
        bd_seq: setup.role.edge_session(),
    })
    .unwrap_or_default()
}

/// What the holder makes of a message: a standby's hello is answered with a snapshot of
/// the records; another node's claim ends the lease (the reason).
fn heard_by_holder(setup: &LeaseSetup, topics: &Topics, p: &Publish) -> Option<String> {
    if p.topic == topics.hello {
        // At most one snapshot a second, however often a client says hello.
        setup.log.journal_snapshot_at_most(Duration::from_secs(1));
        return None;
    }
    let claim = serde_json::from_slice::<Claim>(&p.payload).ok()?;
    (p.topic == topics.claim && claim.held && claim.node != setup.node)
        .then(|| format!("node {} claims epoch {}", claim.node, claim.epoch))
}

/// Gives the lease back: the released claim, then a clean DISCONNECT (the Will is not
/// published: the claim says it already).
pub(super) async fn release(mut conn: Connection, topics: &Topics, claim: Claim) {
    let payload = serde_json::to_vec(&claim).unwrap_or_default();
    let published = tokio::time::timeout(Duration::from_secs(1), async {
        conn.publish(&topics.claim, &payload, 1, true, u64::MAX)
            .await?;
        conn.flush().await?;
        loop {
            if let Incoming::PubAck { pkid, .. } = conn.read().await?
                && conn.acked(pkid) == Some(u64::MAX)
            {
                return Ok::<(), ConnError>(());
            }
        }
    })
    .await;
    if !matches!(published, Ok(Ok(()))) {
        tracing::warn!(
            "HA: the lease's release was not acknowledged; the broker releases it by the Will"
        );
    }
    conn.disconnect().await;
}

//! The handover over the broker when the lease is held elsewhere (`arbiter: etcd` or
//! `kubernetes`): the same messages as under the broker's own lease, on a connection of
//! their own. Active, the node ships its write records and publishes its declarations,
//! and answers a standby's hello; standby, it adopts what the active ships.

use std::time::Duration;

use tokio::time::{Instant, sleep, sleep_until};
use tokio_util::sync::CancellationToken;

use super::claim::Topics;
use super::{LeaseSetup, adopt, connect, open, retry, ship};
use crate::api::mqtt::conn::ConnError;
use crate::api::mqtt::packet::Incoming;
use crate::role::Standing;

/// Runs the handover until `token` is cancelled, connecting again when the broker fails.
pub(crate) async fn run(setup: LeaseSetup, token: CancellationToken) {
    let topics = Topics::new(&setup.group);
    let mut wait = Duration::ZERO;
    loop {
        tokio::select! {
            _ = token.cancelled() => return,
            _ = sleep(wait) => {}
        }
        match session(&setup, &topics, &token).await {
            Ok(()) => return,
            Err(e) => {
                wait = retry(wait, setup.lease);
                tracing::warn!(error = %e, retry_in = ?wait, "HA: the handover's broker connection failed");
            }
        }
    }
}

/// One connection to the broker, until it fails (`Err`) or the gateway stops.
async fn session(
    setup: &LeaseSetup,
    topics: &Topics,
    token: &CancellationToken,
) -> Result<(), ConnError> {
    let id = format!("iogate-ha-{}-{}-handover", setup.group, setup.node);
    let mut conn = open(setup, &connect(setup, id, None)).await?;
    let filters = [
        (topics.writes.clone(), 0),
        (topics.declared.clone(), 0),
        (topics.hello.clone(), 0),
    ];
    conn.subscribe(&filters).await?;
    let mut roles = setup.role.watch();
    let mut declared = setup.service.watch_declared();
    let mut active = None;
    let mut gathering = ship::Gathering::new();
    loop {
        let lease = roles.borrow_and_update().clone();
        let now_active = lease.standing == Standing::Active;
        if active != Some(now_active) {
            active = Some(now_active);
            if now_active {
                declared.mark_changed();
            } else {
                // Standing by: the active ships each field's newest record again.
                conn.publish(&topics.hello, setup.node.as_bytes(), 0, false, 0)
                    .await?;
                conn.flush().await?;
            }
        }
        let far = Instant::now() + Duration::from_secs(3600);
        let ping = conn.keep_alive_due().unwrap_or(far);
        tokio::select! {
            _ = token.cancelled() => {
                conn.disconnect().await;
                return Ok(());
            }
            Ok(()) = roles.changed() => {}
            Ok(()) = declared.changed(), if now_active => {
                ship::declared(&mut conn, &topics.declared, &setup.service).await?;
            }
            _ = setup.log.journaled(), if now_active && !gathering.waiting() => gathering.journaled(),
            _ = sleep_until(gathering.due()), if gathering.waiting() => {
                gathering.shipped();
                if now_active {
                    ship::ship(&mut conn, &topics.writes, lease.epoch, &setup.log).await?;
                }
            }
            _ = sleep_until(ping) => conn.keep_alive().await?,
            packet = conn.read() => {
                if let Incoming::Publish(p) = packet? {
                    if p.qos > 0 {
                        conn.puback(p.pkid).await?;
                    }
                    if now_active && p.topic == topics.hello {
                        setup.log.journal_snapshot_at_most(Duration::from_secs(1));
                    } else if !now_active && p.topic == topics.writes {
                        adopt(setup, &p.payload);
                    } else if !now_active && p.topic == topics.declared {
                        setup.service.adopt_declarations(&p.payload);
                    }
                }
            }
        }
    }
}

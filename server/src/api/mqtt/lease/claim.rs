//! The lease's messages: the retained claim, the renewals, and what a standby makes of
//! them.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
use tokio::time::{Duration, Instant};

use crate::role::Peer;

/// The retained claim.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(super) struct Claim {
    pub(super) node: String,
    pub(super) epoch: u64,
    pub(super) held: bool,
    #[serde(default)]
    pub(super) addresses: BTreeMap<String, String>,
    /// The Sparkplug `bdSeq` of the holder's edge node session (in renewals): the node
    /// that takes over births with the next.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub(super) bd_seq: Option<u8>,
}

impl Claim {
    pub(super) fn peer(&self) -> Peer {
        Peer {
            node: self.node.clone(),
            addresses: self.addresses.clone(),
        }
    }
}

/// What a standby knows of the lease.
#[derive(Debug)]
pub(super) struct Seen {
    pub(super) claim: Option<Claim>,
    /// The highest epoch heard of.
    pub(super) epoch: u64,
    /// When the holder was last heard of (a claim or a renewal).
    pub(super) heard: Instant,
    /// The holder's newest Sparkplug `bdSeq`, as its renewals said.
    pub(super) bd_seq: Option<u8>,
}

impl Seen {
    pub(super) fn take(&mut self, topic: &str, payload: &[u8], topics: &Topics) {
        if topic == topics.claim {
            // An empty retained message clears the claim (an operator's reset).
            if payload.is_empty() {
                self.claim = None;
                return;
            }
            if let Ok(claim) = serde_json::from_slice::<Claim>(payload) {
                self.epoch = self.epoch.max(claim.epoch);
                self.heard = Instant::now();
                self.claim = Some(claim);
            }
        } else if topic == topics.alive
            && let Ok(alive) = serde_json::from_slice::<Claim>(payload)
        {
            self.epoch = self.epoch.max(alive.epoch);
            self.heard = Instant::now();
            self.bd_seq = alive.bd_seq.or(self.bd_seq);
        }
    }

    /// Whether the lease is free to take: nobody claims it, the holder released it, or
    /// has not been heard of for two leases.
    pub(super) fn free(&self, lease: Duration) -> bool {
        match &self.claim {
            None => true,
            Some(c) => !c.held || self.heard.elapsed() >= 2 * lease,
        }
    }
}

pub(super) struct Topics {
    pub(super) claim: String,
    pub(super) alive: String,
    /// The write records the active ships ([`super::ship`]).
    pub(super) writes: String,
    /// A standby that comes asks for the records again.
    pub(super) hello: String,
    /// The links, devices and transactions clients declared (retained).
    pub(super) declared: String,
}

impl Topics {
    pub(super) fn new(group: &str) -> Topics {
        let topic = |leaf| format!("iogate/ha/{group}/{leaf}");
        Topics {
            claim: topic("claim"),
            alive: topic("alive"),
            writes: topic("writes"),
            hello: topic("hello"),
            declared: topic("declared"),
        }
    }
}

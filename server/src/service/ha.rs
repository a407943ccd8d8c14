//! The gateway's place in its active/standby pair, as every front-end shows it.

use serde::Serialize;

use super::{Service, ServiceError};
use crate::role::{Peer, Standing};
use crate::write_log::WriteRecord;

/// This gateway in its pair (`GET /api/v1/ha`).
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct HaView {
    /// This node's name (`ha.node`); null for a gateway alone.
    pub node: Option<String>,
    /// `active`: it polls the field and takes writes (a gateway alone is active);
    /// `standby`: the other node does, and this one touches nothing in the field.
    pub role: &'static str,
    /// Whether the gateway is one node of a pair (`ha:`).
    pub paired: bool,
    /// The newest lease's epoch this node knows of: it only grows, and every write carries
    /// the epoch that accepted it.
    pub epoch: u64,
    /// The node holding the lease and how to reach its servers, when one is known.
    pub active: Option<Peer>,
    /// Who grants the lease (`mqtt`, ...), for a pair.
    pub arbiter: Option<&'static str>,
    /// The lease's length in milliseconds, for a pair.
    pub lease_ms: Option<u64>,
    /// How long this node's lease still holds without a renewal, while it is active.
    pub lease_left_ms: Option<u64>,
    /// How many times this node became active since it started.
    pub takeovers: u64,
}

impl Service {
    /// This node becomes active in `epoch`: its writes carry it from now on, and the
    /// writes the old active took and never finished (as far as this node heard) end
    /// failed, saying why.
    pub(crate) fn take_over(&self, epoch: u64) {
        self.cache.writes.enter_epoch(epoch);
        let orphaned = self.cache.writes.orphan_adopted(epoch);
        if orphaned > 0 {
            tracing::warn!(
                orphaned,
                epoch,
                "HA: writes the old active took had no outcome yet: failed here, not written"
            );
        }
    }

    /// Takes the write records the active of the pair shipped (this node is its standby):
    /// their outcomes for clients following them, and each output's desired value.
    pub(crate) fn adopt_writes(&self, epoch: u64, records: Vec<WriteRecord>) {
        if self.tasks.role().owns_field() {
            tracing::warn!(
                epoch,
                "HA: write records shipped by another node while this one is active: ignored"
            );
            return;
        }
        // Only records of this gateway's own fields are kept: the log is bounded per field,
        // and a name nobody has would make a field of its own.
        for record in records {
            let Ok(device) = self.cache.device(&record.device) else {
                continue;
            };
            let Ok(idx) = device.field_index(&record.field) else {
                continue;
            };
            if self.cache.writes.adopt(record.clone()) {
                device.outputs().adopt(idx, &record);
            }
        }
    }

    /// Refuses what only the active of a pair does (writes, declarations, transactions).
    pub(crate) fn owning_field(&self) -> Result<(), ServiceError> {
        let role = self.tasks.role();
        if role.owns_field() {
            return Ok(());
        }
        // A node whose own lease ran out names no active: it is not one any more.
        let active = role
            .lease()
            .active
            .filter(|p| Some(p.node.as_str()) != role.node());
        Err(ServiceError::Standby(active))
    }

    /// This gateway in its pair.
    pub(crate) fn ha(&self) -> HaView {
        let role = self.tasks().role();
        let lease = role.lease();
        let terms = role.terms();
        let active_now = role.owns_field();
        HaView {
            node: role.node().map(str::to_owned),
            role: match (lease.standing, active_now) {
                (Standing::Alone, _) | (Standing::Active, true) => "active",
                _ => "standby",
            },
            paired: terms.is_some(),
            epoch: lease.epoch,
            active: lease.active,
            arbiter: terms.map(|(a, _)| a),
            lease_ms: terms.map(|(_, l)| l.as_millis() as u64),
            lease_left_ms: role
                .until()
                .filter(|_| active_now && lease.standing == Standing::Active)
                .map(|u| {
                    u.saturating_duration_since(tokio::time::Instant::now())
                        .as_millis() as u64
                }),
            takeovers: role.takeovers(),
        }
    }
}

impl HaView {
    /// The pair's families in the OpenMetrics text (`iogate_ha_role`, `iogate_ha_epoch`,
    /// `iogate_ha_takeovers_total`); nothing for a gateway alone.
    pub(crate) fn encode_metrics(&self, out: &mut String) -> std::fmt::Result {
        use std::fmt::Write as _;
        if !self.paired {
            return Ok(());
        }
        writeln!(
            out,
            "# HELP iogate_ha_role This node's role in its active/standby pair: 1 for the role it has."
        )?;
        writeln!(out, "# TYPE iogate_ha_role gauge")?;
        for role in ["active", "standby"] {
            writeln!(
                out,
                "iogate_ha_role{{role=\"{role}\"}} {}",
                u8::from(self.role == role)
            )?;
        }
        writeln!(
            out,
            "# HELP iogate_ha_epoch The newest lease epoch this node knows of."
        )?;
        writeln!(out, "# TYPE iogate_ha_epoch gauge")?;
        writeln!(out, "iogate_ha_epoch {}", self.epoch)?;
        writeln!(
            out,
            "# HELP iogate_ha_takeovers How many times this node became active."
        )?;
        writeln!(out, "# TYPE iogate_ha_takeovers counter")?;
        writeln!(out, "iogate_ha_takeovers_total {}", self.takeovers)
    }
}

/// What a standby says when it refuses.
pub(super) fn standby_message(active: Option<&crate::role::Peer>) -> String {
    match active {
        Some(peer) => {
            let at = peer
                .addresses
                .get("http")
                .map(|a| format!(" at {a}"))
                .unwrap_or_default();
            format!(
                "this gateway is the standby of its pair: the active, node {}{at}, takes writes",
                peer.node
            )
        }
        None => {
            "this gateway is the standby of its pair, and no node is active yet: try again shortly"
                .into()
        }
    }
}

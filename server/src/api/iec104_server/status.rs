//! What the outstation does, for `/metrics` and `/readyz`: its masters (connected, and in
//! data transfer), the ASDUs it sent and received, the information objects it sent by
//! cause, the commands' confirmations and terminations by outcome, and why connections
//! ended. The counters are kept by the gateway's metrics, so they go on across restarts of
//! the outstation; every master's task adds to them as it goes (read from the ASDU it sent,
//! so what is counted is what went on the wire).

use std::sync::Arc;

use prometheus_client::encoding::EncodeLabelSet;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::registry::Registry;
use serde::Serialize;

use crate::drivers::iec104::asdu::cause;
use crate::metrics::{DirectionLabels, OutcomeLabels};
use crate::service::doors::Door;

pub const IEC104_SERVER_MASTERS: &str = "iogate_iec104_server_masters";
pub const IEC104_SERVER_ASDUS: &str = "iogate_iec104_server_asdus";
pub const IEC104_SERVER_OBJECTS: &str = "iogate_iec104_server_objects";
pub const IEC104_SERVER_COMMANDS: &str = "iogate_iec104_server_commands";
pub const IEC104_SERVER_CLOSED: &str = "iogate_iec104_server_connections_closed";

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub(crate) struct TransferLabels {
    pub(crate) data_transfer: &'static str,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub(crate) struct CauseLabels {
    pub(crate) cause: &'static str,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub(crate) struct ReasonLabels {
    pub(crate) reason: &'static str,
}

#[derive(Debug)]
pub(crate) struct Iec104Metrics {
    registry: Registry,
    masters: Family<TransferLabels, Gauge>,
    asdus: Family<DirectionLabels, Counter>,
    objects: Family<CauseLabels, Counter>,
    commands: Family<OutcomeLabels, Counter>,
    closed: Family<ReasonLabels, Counter>,
}

impl Iec104Metrics {
    pub(crate) fn new() -> Self {
        let mut registry = Registry::default();
        let m = Iec104Metrics {
            registry: Registry::default(),
            masters: Family::default(),
            asdus: Family::default(),
            objects: Family::default(),
            commands: Family::default(),
            closed: Family::default(),
        };
        registry.register(
            IEC104_SERVER_MASTERS,
            "IEC 104 masters connected, by whether data transfer is started (STARTDT) or stopped",
            m.masters.clone(),
        );
        registry.register(
            IEC104_SERVER_ASDUS,
            "ASDUs (I-frames) the IEC 104 outstation sent and received",
            m.asdus.clone(),
        );
        registry.register(
            IEC104_SERVER_OBJECTS,
            "Information objects the IEC 104 outstation sent, by cause: spontaneous, interrogated (general or counter), requested (a read)",
            m.objects.clone(),
        );
        registry.register(
            IEC104_SERVER_COMMANDS,
            "IEC 104 commands answered, by outcome: confirmed (ACTCON), refused (a negative ACTCON or the cause why), terminated and failed (ACTTERM)",
            m.commands.clone(),
        );
        registry.register(
            IEC104_SERVER_CLOSED,
            "IEC 104 masters' connections ended, by reason",
            m.closed.clone(),
        );
        Iec104Metrics { registry, ..m }
    }

    fn masters(&self, started: bool) -> Gauge {
        let data_transfer = if started { "started" } else { "stopped" };
        self.masters
            .get_or_create(&TransferLabels { data_transfer })
            .clone()
    }

    /// A master connected (data transfer stopped).
    pub(crate) fn connected(&self) {
        self.masters(false).inc();
    }

    /// A master's data transfer was started or stopped.
    pub(crate) fn transfer(&self, started: bool) {
        self.masters(!started).dec();
        self.masters(started).inc();
    }

    /// A master's connection ended, with data transfer `started` or not, for `reason`.
    pub(crate) fn ended(&self, started: bool, reason: &'static str) {
        self.masters(started).dec();
        self.closed.get_or_create(&ReasonLabels { reason }).inc();
    }

    pub(crate) fn received(&self) {
        let direction = "received";
        self.asdus
            .get_or_create(&DirectionLabels { direction })
            .inc();
    }

    /// An ASDU sent: counted, with its objects by cause and its commands by outcome.
    pub(crate) fn sent(&self, asdu: &[u8]) {
        let direction = "sent";
        self.asdus
            .get_or_create(&DirectionLabels { direction })
            .inc();
        let [ty, count, cot, ..] = *asdu else {
            return;
        };
        let (reason, negative) = (cot & 0x3F, cot & 0x40 != 0);
        let of_cause = match reason {
            cause::SPONTANEOUS => Some("spontaneous"),
            cause::INTERROGATED | cause::COUNTER_INTERROGATED => Some("interrogated"),
            cause::REQUEST if !negative => Some("requested"),
            _ => None,
        };
        if let Some(cause) = of_cause {
            let objects = u64::from(count & 0x7F);
            self.objects
                .get_or_create(&CauseLabels { cause })
                .inc_by(objects);
        }
        // Commands: C_SC_NA_1 to C_BO_NA_1 and their time-tagged forms.
        let command = matches!(ty, 45..=51 | 58..=64);
        // A refusal is a negative confirmation, or a mirror with the cause of why (44-47).
        let outcome = match (reason, negative) {
            (cause::ACT_CON, false) => "confirmed",
            (cause::ACT_TERM, false) => "terminated",
            (cause::ACT_TERM, true) => "failed",
            (_, true) => "refused",
            _ => return,
        };
        if command {
            self.commands
                .get_or_create(&OutcomeLabels { outcome })
                .inc();
        }
    }

    fn count(&self, started: bool) -> i64 {
        self.masters(started).get()
    }
}

/// The outstation in `/readyz`.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub(crate) struct Iec104Health {
    /// Masters connected.
    pub(crate) masters: i64,
    /// Of them, those with data transfer started (STARTDT).
    pub(crate) started: i64,
}

/// The running outstation, as the rest of the gateway sees it.
pub(crate) struct Iec104Door(pub(crate) Arc<Iec104Metrics>);

impl Door for Iec104Door {
    fn name(&self) -> &'static str {
        super::NAME
    }

    fn health(&self) -> Option<serde_json::Value> {
        let started = self.0.count(true);
        serde_json::to_value(Iec104Health {
            masters: self.0.count(false) + started,
            started,
        })
        .ok()
    }

    fn encode_metrics(&self, out: &mut String) -> std::fmt::Result {
        prometheus_client::encoding::text::encode_registry(out, &self.0.registry)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn text(m: &Iec104Metrics) -> String {
        let mut out = String::new();
        prometheus_client::encoding::text::encode_registry(&mut out, &m.registry).expect("encoded");
        out
    }

    #[test]
    fn objects_and_commands_are_counted_from_what_was_sent() {
        let m = Iec104Metrics::new();
        // M_ME_NC_1, 3 objects, spontaneous; 2 interrogated; C_SE_NC_1 ACTCON negative.
        m.sent(&[13, 3, 3, 0, 1, 0]);
        m.sent(&[13, 0x82, 20, 0, 1, 0]);
        m.sent(&[50, 1, 7 | 0x40, 0, 1, 0]);
        m.sent(&[45, 1, 10, 0, 1, 0]);
        // No such object (47), mirrored negative.
        m.sent(&[45, 1, 47 | 0x40, 0, 1, 0]);
        // The interrogation's own confirmation is not a command.
        m.sent(&[100, 1, 7, 0, 1, 0]);
        let out = text(&m);
        assert!(out.contains("iogate_iec104_server_asdus_total{direction=\"sent\"} 6"));
        assert!(out.contains("iogate_iec104_server_objects_total{cause=\"spontaneous\"} 3"));
        assert!(out.contains("iogate_iec104_server_objects_total{cause=\"interrogated\"} 2"));
        assert!(out.contains("iogate_iec104_server_commands_total{outcome=\"refused\"} 2"));
        assert!(out.contains("iogate_iec104_server_commands_total{outcome=\"terminated\"} 1"));
        assert!(!out.contains("outcome=\"confirmed\""), "{out}");
    }

    #[test]
    fn masters_move_between_stopped_and_started() {
        let m = Iec104Metrics::new();
        m.connected();
        m.connected();
        m.transfer(true);
        assert_eq!((m.count(false), m.count(true)), (1, 1));
        m.ended(true, "closed");
        assert_eq!((m.count(false), m.count(true)), (1, 0));
        assert!(text(&m).contains("reason=\"closed\"} 1"));
    }
}

//! The OPC UA server's metrics: a registry of their own, shown only when the server runs,
//! kept by the gateway's metrics across restarts, copied from its counts at the scrape (one
//! source of truth).

use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::registry::Registry;

use crate::metrics::OutcomeLabels;

/// A copy of the server's counts (`OpcUaState::status`), as the metrics show them.
#[derive(Debug, Clone, Default, PartialEq)]
pub(crate) struct OpcUaStatus {
    pub(crate) sessions: u64,
    pub(crate) sessions_created: u64,
    /// Sessions refused because the table was full (Bad_TooManySessions).
    pub(crate) sessions_refused: u64,
    pub(crate) subscriptions: u64,
    pub(crate) monitored_items: u64,
    /// Monitored items refused because every session's together reached the bound.
    pub(crate) monitored_items_refused: u64,
    pub(crate) value_updates: u64,
    pub(crate) writes_accepted: u64,
    pub(crate) writes_refused: u64,
    /// Sessions and requests refused for their security (certificate, signature, user).
    pub(crate) security_rejected: u64,
    /// Client certificates refused and kept in the PKI directory's `rejected/`.
    pub(crate) rejected_certificates: u64,
    /// TCP connections open, and from the address with the most.
    pub(crate) connections: u64,
    pub(crate) connections_most_from_one: u64,
    /// Connections refused at `max_connections`, and at `max_connections_per_client`.
    pub(crate) connections_refused: u64,
    pub(crate) connections_refused_per_client: u64,
}

pub const OPCUA_SESSIONS: &str = "iogate_opcua_sessions";
pub const OPCUA_SESSIONS_CREATED: &str = "iogate_opcua_sessions_created";
pub const OPCUA_SUBSCRIPTIONS: &str = "iogate_opcua_subscriptions";
pub const OPCUA_MONITORED_ITEMS: &str = "iogate_opcua_monitored_items";
pub const OPCUA_MONITORED_ITEMS_REFUSED: &str = "iogate_opcua_monitored_items_refused";
pub const OPCUA_VALUE_UPDATES: &str = "iogate_opcua_value_updates";
pub const OPCUA_WRITES: &str = "iogate_opcua_writes";
pub const OPCUA_SECURITY_REJECTED: &str = "iogate_opcua_security_rejected";
pub const OPCUA_REJECTED_CERTIFICATES: &str = "iogate_opcua_rejected_certificates";

fn grow(counter: &Counter, to: u64) {
    counter.inc_by(to.saturating_sub(counter.get()));
}

#[derive(Debug)]
pub(crate) struct OpcUaMetrics {
    pub(crate) registry: Registry,
    sessions: Gauge,
    sessions_created: Counter,
    subscriptions: Gauge,
    monitored_items: Gauge,
    items_refused: Counter,
    value_updates: Counter,
    writes: Family<OutcomeLabels, Counter>,
    security_rejected: Counter,
    rejected_certificates: Gauge,
}

impl OpcUaMetrics {
    pub(crate) fn new() -> Self {
        let mut registry = Registry::default();
        let m = OpcUaMetrics {
            registry: Registry::default(),
            sessions: Gauge::default(),
            sessions_created: Counter::default(),
            subscriptions: Gauge::default(),
            monitored_items: Gauge::default(),
            items_refused: Counter::default(),
            value_updates: Counter::default(),
            writes: Family::default(),
            security_rejected: Counter::default(),
            rejected_certificates: Gauge::default(),
        };
        registry.register(OPCUA_SESSIONS, "OPC UA sessions open", m.sessions.clone());
        registry.register(
            OPCUA_SESSIONS_CREATED,
            "OPC UA sessions created since the server started",
            m.sessions_created.clone(),
        );
        registry.register(
            OPCUA_SUBSCRIPTIONS,
            "OPC UA subscriptions open",
            m.subscriptions.clone(),
        );
        registry.register(
            OPCUA_MONITORED_ITEMS,
            "OPC UA monitored items on the gateway's variables",
            m.monitored_items.clone(),
        );
        registry.register(
            OPCUA_MONITORED_ITEMS_REFUSED,
            "OPC UA monitored items refused: every session's items together at opcua.max_monitored_items",
            m.items_refused.clone(),
        );
        registry.register(
            OPCUA_VALUE_UPDATES,
            "Values and diagnostics rendered for monitored OPC UA variables from the change streams (once for all the items monitoring one)",
            m.value_updates.clone(),
        );
        registry.register(
            OPCUA_WRITES,
            "Writes from OPC UA by outcome: accepted, refused",
            m.writes.clone(),
        );
        registry.register(
            OPCUA_SECURITY_REJECTED,
            "OPC UA sessions refused for their security (certificate, signature, user)",
            m.security_rejected.clone(),
        );
        registry.register(
            OPCUA_REJECTED_CERTIFICATES,
            "Client certificates refused and kept for review in the PKI directory's rejected/",
            m.rejected_certificates.clone(),
        );
        OpcUaMetrics { registry, ..m }
    }

    /// Copies the server's counts.
    /// The server's counts copied in, then every family encoded into a scrape.
    pub(crate) fn encode(&self, status: &OpcUaStatus, out: &mut String) -> std::fmt::Result {
        self.copy(status);
        prometheus_client::encoding::text::encode_registry(out, &self.registry)
    }

    fn copy(&self, s: &OpcUaStatus) {
        let gauge = |g: &Gauge, v: u64| g.set(i64::try_from(v).unwrap_or(i64::MAX));
        gauge(&self.sessions, s.sessions);
        grow(&self.sessions_created, s.sessions_created);
        gauge(&self.subscriptions, s.subscriptions);
        gauge(&self.monitored_items, s.monitored_items);
        grow(&self.items_refused, s.monitored_items_refused);
        grow(&self.value_updates, s.value_updates);
        for (outcome, n) in [
            ("accepted", s.writes_accepted),
            ("refused", s.writes_refused),
        ] {
            grow(&self.writes.get_or_create(&OutcomeLabels { outcome }), n);
        }
        grow(&self.security_rejected, s.security_rejected);
        gauge(&self.rejected_certificates, s.rejected_certificates);
    }
}

//! The MQTT front-end's metrics: a registry of their own, shown only when the front-end runs,
//! kept by the gateway's metrics across the front-end's restarts. Counts are copied from the
//! front-end's status at the scrape (one source of truth); the publish latency is observed
//! by the front-end as messages are confirmed.

use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::metrics::histogram::{Histogram, exponential_buckets};
use prometheus_client::registry::Registry;

use super::status::MqttStatus;
use crate::metrics::{DirectionLabels, OutcomeLabels};

pub const MQTT_CONNECTED: &str = "iogate_mqtt_connected";
pub const MQTT_RECONNECTS: &str = "iogate_mqtt_reconnects";
pub const MQTT_MESSAGES: &str = "iogate_mqtt_messages";
pub const MQTT_BYTES: &str = "iogate_mqtt_bytes";
pub const MQTT_WRITES: &str = "iogate_mqtt_writes";
pub const MQTT_PUBLISH_LATENCY: &str = "iogate_mqtt_publish_latency_seconds";
pub const MQTT_BUFFER_MESSAGES: &str = "iogate_mqtt_buffer_messages";
pub const MQTT_BUFFER_BYTES: &str = "iogate_mqtt_buffer_bytes";
pub const MQTT_BUFFER_OLDEST: &str = "iogate_mqtt_buffer_oldest_seconds";
pub const MQTT_BUFFER_DROPPED: &str = "iogate_mqtt_buffer_dropped";
pub const MQTT_BUFFER_REPLAYED: &str = "iogate_mqtt_buffer_replayed";
pub const MQTT_DROPPED_IN: &str = "iogate_mqtt_incoming_dropped";

#[derive(Debug)]
pub(crate) struct MqttMetrics {
    pub(crate) registry: Registry,
    connected: Gauge,
    reconnects: Counter,
    messages: Family<DirectionLabels, Counter>,
    bytes: Family<DirectionLabels, Counter>,
    writes: Family<OutcomeLabels, Counter>,
    latency: Histogram,
    buffer_messages: Gauge,
    buffer_bytes: Gauge,
    buffer_oldest: Gauge,
    buffer_dropped: Counter,
    buffer_replayed: Counter,
    dropped_in: Counter,
}

fn grow(counter: &Counter, to: u64) {
    counter.inc_by(to.saturating_sub(counter.get()));
}

impl MqttMetrics {
    pub(crate) fn new() -> Self {
        let mut registry = Registry::default();
        let m = MqttMetrics {
            registry: Registry::default(),
            connected: Gauge::default(),
            reconnects: Counter::default(),
            messages: Family::default(),
            bytes: Family::default(),
            writes: Family::default(),
            // 0.1 ms to about 3 s.
            latency: Histogram::new(exponential_buckets(0.0001, 2.0, 15)),
            buffer_messages: Gauge::default(),
            buffer_bytes: Gauge::default(),
            buffer_oldest: Gauge::default(),
            buffer_dropped: Counter::default(),
            buffer_replayed: Counter::default(),
            dropped_in: Counter::default(),
        };
        registry.register(
            MQTT_CONNECTED,
            "Whether the MQTT front-end is connected to its broker",
            m.connected.clone(),
        );
        registry.register(
            MQTT_RECONNECTS,
            "Connections to the broker made after the first",
            m.reconnects.clone(),
        );
        registry.register(
            MQTT_MESSAGES,
            "MQTT messages published (out) and received (in)",
            m.messages.clone(),
        );
        registry.register(
            MQTT_BYTES,
            "Payload bytes of MQTT messages published (out) and received (in)",
            m.bytes.clone(),
        );
        registry.register(
            MQTT_WRITES,
            "Writes from MQTT (/set, DCMD) by outcome: accepted, refused, retained (a stored message, not executed)",
            m.writes.clone(),
        );
        registry.register(
            MQTT_PUBLISH_LATENCY,
            "From a value's change to the broker's confirmation of its message",
            m.latency.clone(),
        );
        registry.register(
            MQTT_BUFFER_MESSAGES,
            "Messages in the store-and-forward buffer, not yet acknowledged by the broker",
            m.buffer_messages.clone(),
        );
        registry.register(
            MQTT_BUFFER_BYTES,
            "Bytes of the store-and-forward buffer on disk",
            m.buffer_bytes.clone(),
        );
        registry.register(
            MQTT_BUFFER_OLDEST,
            "Age of the oldest message in the store-and-forward buffer",
            m.buffer_oldest.clone(),
        );
        registry.register(
            MQTT_BUFFER_DROPPED,
            "Messages dropped: buffer over max_bytes or max_age, torn by a crash, or no buffer",
            m.buffer_dropped.clone(),
        );
        registry.register(
            MQTT_BUFFER_REPLAYED,
            "Messages replayed from the buffer and acknowledged",
            m.buffer_replayed.clone(),
        );
        registry.register(
            MQTT_DROPPED_IN,
            "Packets from the broker read past and dropped: too big, malformed or unexpected",
            m.dropped_in.clone(),
        );
        MqttMetrics { registry, ..m }
    }

    pub(crate) fn observe_latency(&self, seconds: f64) {
        self.latency.observe(seconds);
    }

    /// The front-end's counts copied in, then every family encoded into a scrape.
    pub(crate) fn encode(&self, status: &MqttStatus, out: &mut String) -> std::fmt::Result {
        self.copy(status);
        prometheus_client::encoding::text::encode_registry(out, &self.registry)
    }

    /// Copies the front-end's counts.
    fn copy(&self, s: &MqttStatus) {
        self.connected.set(i64::from(s.connected));
        grow(&self.reconnects, s.reconnects);
        for (direction, messages, bytes) in [
            ("out", s.messages_out, s.bytes_out),
            ("in", s.messages_in, s.bytes_in),
        ] {
            let labels = DirectionLabels { direction };
            grow(&self.messages.get_or_create(&labels), messages);
            grow(&self.bytes.get_or_create(&labels), bytes);
        }
        for (outcome, n) in [
            ("accepted", s.writes_accepted),
            ("refused", s.writes_refused),
            ("retained", s.retained_ignored),
        ] {
            grow(&self.writes.get_or_create(&OutcomeLabels { outcome }), n);
        }
        let gauge = |g: &Gauge, v: u64| g.set(i64::try_from(v).unwrap_or(i64::MAX));
        gauge(&self.buffer_messages, s.buffer.messages);
        gauge(&self.buffer_bytes, s.buffer.bytes);
        gauge(&self.buffer_oldest, s.buffer.oldest_age_s);
        grow(&self.buffer_dropped, s.buffer.dropped);
        grow(&self.buffer_replayed, s.buffer.replayed);
        grow(&self.dropped_in, s.dropped_in);
    }
}

//! Prometheus metrics at `/metrics`: names are consts, labels stay bounded (link, device,
//! function, outcome, exception code; never a value).
//!
//! Counters of transactions are recorded by the link tasks as they happen. States that the
//! cache already holds (connected, error codes, I/O cycles, write outcomes) are copied into
//! the registry when it is scraped, so there is one source of truth.

use std::sync::atomic::AtomicU64;
use std::time::Duration;

use prometheus_client::encoding::EncodeLabelSet;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::metrics::histogram::{Histogram, exponential_buckets};
use prometheus_client::registry::Registry;

use crate::cache::Cache;
use crate::link::TxError;
use crate::link::frame::Function;

mod format;
mod mqtt;
mod opcua;
pub(crate) use format::Format;
pub use opcua::{
    OPCUA_MONITORED_ITEMS, OPCUA_REJECTED_CERTIFICATES, OPCUA_SECURITY_REJECTED, OPCUA_SESSIONS,
    OPCUA_SESSIONS_CREATED, OPCUA_SUBSCRIPTIONS, OPCUA_VALUE_UPDATES, OPCUA_WRITES,
};

// Counter names get `_total` appended by the encoder.
pub const LINK_UP: &str = "iogate_link_up";
pub const LINK_ERROR_CODE: &str = "iogate_link_error_code";
pub const LINK_STALLED: &str = "iogate_link_stalled";
pub const LINK_RECONNECTS: &str = "iogate_link_reconnects";
pub const LINK_SENT_BYTES: &str = "iogate_link_sent_bytes";
pub const LINK_RECEIVED_BYTES: &str = "iogate_link_received_bytes";
pub const LINK_DISCARDED_BYTES: &str = "iogate_link_discarded_bytes";
pub const LINK_PLANNED_UTILISATION: &str = "iogate_link_planned_utilisation_ratio";
pub const LINK_UTILISATION: &str = "iogate_link_utilisation_ratio";
pub const LINK_INBOX_DEPTH: &str = "iogate_link_inbox_requests";
pub const LINK_INBOX_OLDEST: &str = "iogate_link_inbox_oldest_seconds";
pub const LINK_INBOX_DROPPED: &str = "iogate_link_inbox_dropped";
pub const DEVICE_CONNECTED: &str = "iogate_device_connected";
pub const DEVICE_ERROR_CODE: &str = "iogate_device_error_code";
pub const DEVICE_IO_CYCLES: &str = "iogate_device_io_cycles";
pub const DEVICE_MISMATCHED_OUTPUTS: &str = "iogate_device_mismatched_outputs";
pub const DEVICE_SAFE_WRITES: &str = "iogate_device_safe_value_writes";
/// Counted by result (`_total` is added by the registry).
pub const CONFIG_RELOADS: &str = "iogate_config_reloads";
pub const DEVICE_RESPONSE_TIME: &str = "iogate_device_response_time_seconds";
pub const DEVICE_REQUESTS: &str = "iogate_device_requests";
pub const DEVICE_TIMEOUTS: &str = "iogate_device_timeouts";
pub const DEVICE_CRC_ERRORS: &str = "iogate_device_crc_errors";
pub const DEVICE_EXCEPTIONS: &str = "iogate_device_exceptions";
pub const DEVICE_WRITES: &str = "iogate_device_writes";
pub const TRANSACTION_RUNS: &str = "iogate_transaction_runs";
pub const MODBUS_SERVER_CONNECTIONS: &str = "iogate_modbus_server_connections";
pub const MODBUS_SERVER_REFUSED: &str = "iogate_modbus_server_refused_connections";
pub const MODBUS_SERVER_EVICTED: &str = "iogate_modbus_server_evicted_connections";
pub const MODBUS_SERVER_REQUESTS: &str = "iogate_modbus_server_requests";
pub const MODBUS_SERVER_EXCEPTIONS: &str = "iogate_modbus_server_exceptions";
pub const MODBUS_SERIAL_PORT_UP: &str = "iogate_modbus_serial_port_up";
pub const MODBUS_SERIAL_REOPENS: &str = "iogate_modbus_serial_port_reopens";
pub const MODBUS_SERIAL_FRAMES: &str = "iogate_modbus_serial_frames";
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

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub(crate) struct LinkLabels {
    pub(crate) link: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub(crate) struct DroppedLabels {
    pub(crate) link: String,
    /// `busy` (the inbox was full), `expired` (its deadline would pass), `abandoned` (its
    /// caller had gone).
    pub(crate) reason: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub(crate) struct ResultLabels {
    pub(crate) result: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub(crate) struct DeviceLabels {
    pub(crate) device: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub(crate) struct RequestLabels {
    pub(crate) device: String,
    pub(crate) function: String,
    pub(crate) outcome: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub(crate) struct ExceptionLabels {
    pub(crate) device: String,
    pub(crate) code: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub(crate) struct ServerRequestLabels {
    pub(crate) function: String,
    pub(crate) outcome: String,
}

/// What became of a frame on a serial port of the Modbus server (its index in
/// [`SerialOutcome::ALL`] is its discriminant).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum SerialOutcome {
    Answered,
    Exception,
    /// Applied, not answered.
    Broadcast,
    /// Ignored: for another unit id.
    OtherUnit,
    /// Ignored: a bad CRC or LRC.
    CrcError,
    /// Ignored: too short, too long, not hexadecimal, no request's function code.
    Malformed,
}

impl SerialOutcome {
    pub(crate) const ALL: [SerialOutcome; 6] = [
        SerialOutcome::Answered,
        SerialOutcome::Exception,
        SerialOutcome::Broadcast,
        SerialOutcome::OtherUnit,
        SerialOutcome::CrcError,
        SerialOutcome::Malformed,
    ];

    /// The metric's and the API's name.
    pub(crate) fn label(self) -> &'static str {
        match self {
            SerialOutcome::Answered => "answered",
            SerialOutcome::Exception => "exception",
            SerialOutcome::Broadcast => "broadcast",
            SerialOutcome::OtherUnit => "other_unit",
            SerialOutcome::CrcError => "crc_error",
            SerialOutcome::Malformed => "malformed",
        }
    }
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub(crate) struct PortLabels {
    pub(crate) port: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub(crate) struct FrameLabels {
    pub(crate) port: String,
    /// `answered`, `exception`, `broadcast`, `other_unit`, `crc_error`, `malformed`.
    pub(crate) outcome: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub(crate) struct TransactionLabels {
    pub(crate) transaction: String,
    pub(crate) outcome: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub(crate) struct CodeLabels {
    pub(crate) code: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub(crate) struct WriteLabels {
    pub(crate) device: String,
    pub(crate) outcome: String,
}

type Ratio = Gauge<f64, AtomicU64>;

fn response_histogram() -> Histogram {
    // 0.5 ms to about 4 s.
    Histogram::new(exponential_buckets(0.0005, 2.0, 14))
}

pub struct Metrics {
    registry: Registry,
    link_up: Family<LinkLabels, Gauge>,
    link_error_code: Family<LinkLabels, Gauge>,
    link_stalled: Family<LinkLabels, Gauge>,
    link_reconnects: Family<LinkLabels, Counter>,
    link_sent: Family<LinkLabels, Counter>,
    link_received: Family<LinkLabels, Counter>,
    link_discarded: Family<LinkLabels, Counter>,
    link_planned: Family<LinkLabels, Ratio>,
    link_utilisation: Family<LinkLabels, Ratio>,
    inbox_depth: Family<LinkLabels, Gauge>,
    inbox_oldest: Family<LinkLabels, Ratio>,
    inbox_dropped: Family<DroppedLabels, Counter>,
    device_connected: Family<DeviceLabels, Gauge>,
    device_error_code: Family<DeviceLabels, Gauge>,
    device_io_cycles: Family<DeviceLabels, Counter>,
    device_mismatched: Family<DeviceLabels, Gauge>,
    safe_writes: Family<DeviceLabels, Counter>,
    config_reloads: Family<ResultLabels, Counter>,
    response_time: Family<DeviceLabels, Histogram, fn() -> Histogram>,
    requests: Family<RequestLabels, Counter>,
    timeouts: Family<DeviceLabels, Counter>,
    crc_errors: Family<DeviceLabels, Counter>,
    exceptions: Family<ExceptionLabels, Counter>,
    writes: Family<WriteLabels, Counter>,
    transaction_runs: Family<TransactionLabels, Counter>,
    server_connections: Gauge,
    server_refused: Counter,
    server_evicted: Counter,
    server_requests: Family<ServerRequestLabels, Counter>,
    server_exceptions: Family<CodeLabels, Counter>,
    serial_up: Family<PortLabels, Gauge>,
    serial_reopens: Family<PortLabels, Counter>,
    serial_frames: Family<FrameLabels, Counter>,
    mqtt: mqtt::MqttMetrics,
    opcua: opcua::OpcUaMetrics,
}

impl std::fmt::Debug for Metrics {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Metrics")
    }
}

impl Default for Metrics {
    fn default() -> Self {
        Metrics::new()
    }
}

impl Metrics {
    pub(crate) fn new() -> Self {
        let mut registry = Registry::default();
        let m = Metrics {
            link_up: Family::default(),
            link_error_code: Family::default(),
            link_stalled: Family::default(),
            link_reconnects: Family::default(),
            link_sent: Family::default(),
            link_received: Family::default(),
            link_discarded: Family::default(),
            link_planned: Family::default(),
            link_utilisation: Family::default(),
            inbox_depth: Family::default(),
            inbox_oldest: Family::default(),
            inbox_dropped: Family::default(),
            device_connected: Family::default(),
            device_error_code: Family::default(),
            device_io_cycles: Family::default(),
            device_mismatched: Family::default(),
            safe_writes: Family::default(),
            config_reloads: Family::default(),
            response_time: Family::new_with_constructor(response_histogram),
            requests: Family::default(),
            timeouts: Family::default(),
            crc_errors: Family::default(),
            exceptions: Family::default(),
            writes: Family::default(),
            transaction_runs: Family::default(),
            server_connections: Gauge::default(),
            server_refused: Counter::default(),
            server_evicted: Counter::default(),
            server_requests: Family::default(),
            server_exceptions: Family::default(),
            serial_up: Family::default(),
            serial_reopens: Family::default(),
            serial_frames: Family::default(),
            mqtt: mqtt::MqttMetrics::new(),
            opcua: opcua::OpcUaMetrics::new(),
            registry: Registry::default(),
        };
        registry.register(
            LINK_UP,
            "1 while the link's port or connection is open",
            m.link_up.clone(),
        );
        registry.register(
            LINK_ERROR_CODE,
            "SerialLink error code: 0 OK, 1 no port configured, 2 open failed, 3 port lost",
            m.link_error_code.clone(),
        );
        registry.register(
            LINK_STALLED,
            "1 while the link's task is stuck in a transaction past its bound (timeout, wire time and 5 s)",
            m.link_stalled.clone(),
        );
        registry.register(
            DEVICE_MISMATCHED_OUTPUTS,
            "Outputs the device was read holding another value in than the newest requested, with no write of it waiting",
            m.device_mismatched.clone(),
        );
        registry.register(
            DEVICE_SAFE_WRITES,
            "Safe values written because the scan-cycle client that wrote the output was lost (on_client_loss)",
            m.safe_writes.clone(),
        );
        registry.register(
            CONFIG_RELOADS,
            "Configuration reloads by result: applied, unchanged, invalid (nothing changed), failed (nothing changed)",
            m.config_reloads.clone(),
        );
        for result in ["applied", "unchanged", "invalid", "failed"] {
            let _ = m.config_reloads.get_or_create(&ResultLabels {
                result: result.to_owned(),
            });
        }
        registry.register(
            LINK_RECONNECTS,
            "Times the link was reopened after it was lost",
            m.link_reconnects.clone(),
        );
        registry.register(
            LINK_SENT_BYTES,
            "Bytes sent on the link",
            m.link_sent.clone(),
        );
        registry.register(
            LINK_RECEIVED_BYTES,
            "Bytes received on the link",
            m.link_received.clone(),
        );
        registry.register(
            LINK_DISCARDED_BYTES,
            "Received bytes that answered no request (late replies, noise)",
            m.link_discarded.clone(),
        );
        registry.register(
            LINK_PLANNED_UTILISATION,
            "Share of the line's time the refresh rates demand (serial links)",
            m.link_planned.clone(),
        );
        registry.register(
            LINK_INBOX_DEPTH,
            "Requests (forwarded Modbus, raw transactions) waiting in the link's inbox",
            m.inbox_depth.clone(),
        );
        registry.register(
            LINK_INBOX_OLDEST,
            "How long the oldest request in the link's inbox has waited",
            m.inbox_oldest.clone(),
        );
        registry.register(
            LINK_INBOX_DROPPED,
            "Requests never sent: the inbox was full (busy), the caller's deadline would pass (expired), or the caller had gone (abandoned)",
            m.inbox_dropped.clone(),
        );
        registry.register(
            LINK_UTILISATION,
            "Share of the last interval the link spent in transactions",
            m.link_utilisation.clone(),
        );
        registry.register(
            DEVICE_CONNECTED,
            "1 while the device answers",
            m.device_connected.clone(),
        );
        registry.register(
            DEVICE_ERROR_CODE,
            "Device error code: 0 OK, 1 no link, 2 no slave, 10 communication error",
            m.device_error_code.clone(),
        );
        registry.register(
            DEVICE_IO_CYCLES,
            "Successful I/O cycles",
            m.device_io_cycles.clone(),
        );
        registry.register(
            DEVICE_RESPONSE_TIME,
            "Time from request to good response",
            m.response_time.clone(),
        );
        registry.register(
            DEVICE_REQUESTS,
            "Modbus requests by function and outcome",
            m.requests.clone(),
        );
        registry.register(
            DEVICE_TIMEOUTS,
            "Requests that got no answer in time",
            m.timeouts.clone(),
        );
        registry.register(
            DEVICE_CRC_ERRORS,
            "Responses with a bad CRC",
            m.crc_errors.clone(),
        );
        registry.register(
            DEVICE_EXCEPTIONS,
            "Modbus exception responses by code",
            m.exceptions.clone(),
        );
        registry.register(
            DEVICE_WRITES,
            "Writes by final outcome: written, superseded, failed",
            m.writes.clone(),
        );
        registry.register(
            TRANSACTION_RUNS,
            "Runs of standing transactions, by name and outcome (ok: a correct response)",
            m.transaction_runs.clone(),
        );
        registry.register(
            MODBUS_SERVER_CONNECTIONS,
            "Open connections of Modbus TCP masters",
            m.server_connections.clone(),
        );
        registry.register(
            MODBUS_SERVER_REFUSED,
            "Modbus TCP connections refused (max_connections reached, every connection being answered)",
            m.server_refused.clone(),
        );
        registry.register(
            MODBUS_SERVER_EVICTED,
            "Modbus TCP connections closed for a new master (max_connections reached; the one waiting longest on its master)",
            m.server_evicted.clone(),
        );
        registry.register(
            MODBUS_SERVER_REQUESTS,
            "Requests the Modbus server answered (over TCP and its serial ports), by function and outcome (ok, exception)",
            m.server_requests.clone(),
        );
        registry.register(
            MODBUS_SERVER_EXCEPTIONS,
            "Exception responses of the Modbus server (TCP and serial), by code",
            m.server_exceptions.clone(),
        );
        registry.register(
            MODBUS_SERIAL_PORT_UP,
            "Whether a serial port of the Modbus server is open (1) or lost and being reopened (0)",
            m.serial_up.clone(),
        );
        registry.register(
            MODBUS_SERIAL_REOPENS,
            "Times a serial port of the Modbus server was opened again after it was lost",
            m.serial_reopens.clone(),
        );
        registry.register(
            MODBUS_SERIAL_FRAMES,
            "Frames a serial port of the Modbus server received, by outcome: answered, exception, broadcast (applied, not answered), other_unit (ignored), crc_error (CRC or LRC, ignored), malformed (ignored)",
            m.serial_frames.clone(),
        );
        Metrics { registry, ..m }
    }

    /// One run of a standing transaction.
    pub(crate) fn transaction_run(&self, name: &str, ok: bool) {
        self.transaction_runs
            .get_or_create(&TransactionLabels {
                transaction: name.to_owned(),
                outcome: if ok { "ok" } else { "failed" }.to_owned(),
            })
            .inc();
    }

    /// A master connected (`true`) or went away.
    pub(crate) fn server_connection(&self, open: bool) {
        if open {
            self.server_connections.inc();
        } else {
            self.server_connections.dec();
        }
    }

    pub(crate) fn server_refused(&self) {
        self.server_refused.inc();
    }

    pub(crate) fn server_evicted(&self) {
        self.server_evicted.inc();
    }

    /// The counter of requests the Modbus TCP server answered with `function` (as `fc03`)
    /// and `outcome` (`ok` or `exception`); a handle to keep, so counting costs no lookup.
    pub(crate) fn server_requests(&self, function: &str, outcome: &str) -> Counter {
        self.server_requests
            .get_or_create(&ServerRequestLabels {
                function: function.to_owned(),
                outcome: outcome.to_owned(),
            })
            .clone()
    }

    /// Whether the Modbus server's serial `port` is open; `reopened` counts an opening
    /// after the port was lost.
    pub(crate) fn serial_port(&self, port: &str, open: bool, reopened: bool) {
        let labels = PortLabels {
            port: port.to_owned(),
        };
        self.serial_up.get_or_create(&labels).set(i64::from(open));
        let reopens = self.serial_reopens.get_or_create(&labels);
        if reopened {
            reopens.inc();
        }
    }

    /// The Modbus server's serial `port` is no longer served (a reload removed it).
    pub(crate) fn serial_port_removed(&self, port: &str) {
        let labels = PortLabels {
            port: port.to_owned(),
        };
        self.serial_up.remove(&labels);
        self.serial_reopens.remove(&labels);
        for outcome in SerialOutcome::ALL {
            self.serial_frames.remove(&FrameLabels {
                port: port.to_owned(),
                outcome: outcome.label().to_owned(),
            });
        }
    }

    /// The counters of frames on the serial `port`, one per outcome (indexed as
    /// [`SerialOutcome::ALL`]); handles to keep.
    pub(crate) fn serial_frames(&self, port: &str) -> [Counter; 6] {
        SerialOutcome::ALL.map(|outcome| {
            self.serial_frames
                .get_or_create(&FrameLabels {
                    port: port.to_owned(),
                    outcome: outcome.label().to_owned(),
                })
                .clone()
        })
    }

    /// The counter of the Modbus TCP server's exception responses with `code`.
    pub(crate) fn server_exceptions(&self, code: u8) -> Counter {
        self.server_exceptions
            .get_or_create(&CodeLabels {
                code: format!("{code:02}"),
            })
            .clone()
    }

    /// Records one transaction's outcome.
    pub(crate) fn transaction<T>(
        &self,
        device: &str,
        function: Function,
        result: &Result<T, TxError>,
        elapsed: Duration,
    ) {
        let outcome = match result {
            Ok(_) => "ok",
            Err(e) => e.outcome(),
        };
        self.requests
            .get_or_create(&RequestLabels {
                device: device.to_owned(),
                function: function.label().to_owned(),
                outcome: outcome.to_owned(),
            })
            .inc();
        let labels = DeviceLabels {
            device: device.to_owned(),
        };
        match result {
            Ok(_) => self
                .response_time
                .get_or_create(&labels)
                .observe(elapsed.as_secs_f64()),
            Err(TxError::Timeout) => {
                self.timeouts.get_or_create(&labels).inc();
            }
            Err(TxError::Crc) => {
                self.crc_errors.get_or_create(&labels).inc();
            }
            Err(TxError::Exception(x)) => {
                self.exceptions
                    .get_or_create(&ExceptionLabels {
                        device: device.to_owned(),
                        code: format!("{:02}", x.0),
                    })
                    .inc();
            }
            Err(_) => {}
        }
    }

    pub(crate) fn link_bytes(&self, link: &str, sent: u64, received: u64, discarded: u64) {
        let labels = LinkLabels {
            link: link.to_owned(),
        };
        self.link_sent.get_or_create(&labels).inc_by(sent);
        self.link_received.get_or_create(&labels).inc_by(received);
        self.link_discarded.get_or_create(&labels).inc_by(discarded);
    }

    /// A request dropped from a link's inbox without being sent.
    pub(crate) fn inbox_dropped(&self, link: &str, reason: &str) {
        self.inbox_dropped
            .get_or_create(&DroppedLabels {
                link: link.to_owned(),
                reason: reason.to_owned(),
            })
            .inc();
    }

    pub(crate) fn link_reconnected(&self, link: &str) {
        self.link_reconnects
            .get_or_create(&LinkLabels {
                link: link.to_owned(),
            })
            .inc();
    }

    pub(crate) fn link_utilisation(&self, link: &str, planned: Option<f64>, measured: f64) {
        let labels = LinkLabels {
            link: link.to_owned(),
        };
        if let Some(p) = planned {
            self.link_planned.get_or_create(&labels).set(p);
        }
        self.link_utilisation.get_or_create(&labels).set(measured);
    }

    /// A safe value was written for `device` after its client was lost.
    /// A configuration reload ended with `result`.
    pub(crate) fn config_reload(&self, result: &str) {
        self.config_reloads
            .get_or_create(&ResultLabels {
                result: result.to_owned(),
            })
            .inc();
    }

    pub(crate) fn safe_value_written(&self, device: &str) {
        self.safe_writes
            .get_or_create(&DeviceLabels {
                device: device.to_owned(),
            })
            .inc();
    }

    /// A message published by the MQTT front-end was confirmed `seconds` after its change.
    pub(crate) fn mqtt_publish_latency(&self, seconds: f64) {
        self.mqtt.observe_latency(seconds);
    }

    /// The registry in the text format `format`, with states copied from the cache (and the
    /// MQTT front-end's status, when it runs) first.
    pub(crate) fn render(
        &self,
        cache: &Cache,
        mqtt: Option<&crate::mqtt_status::MqttStatus>,
        opcua: Option<&crate::opcua_status::OpcUaStatus>,
        format: Format,
    ) -> String {
        // State gauges are copied afresh, so removed links and devices leave no series.
        self.link_up.clear();
        self.inbox_depth.clear();
        self.inbox_oldest.clear();
        self.link_error_code.clear();
        self.link_stalled.clear();
        self.device_connected.clear();
        self.device_error_code.clear();
        self.device_mismatched.clear();
        for link in &cache.links() {
            let labels = LinkLabels {
                link: link.name().to_owned(),
            };
            let d = link.diagnostics();
            // Counters exist at zero from the first scrape, so rates and alerts work at once.
            let _ = self.link_reconnects.get_or_create(&labels);
            let _ = self.link_sent.get_or_create(&labels);
            let _ = self.link_received.get_or_create(&labels);
            let _ = self.link_discarded.get_or_create(&labels);
            let _ = self.link_utilisation.get_or_create(&labels);
            let (depth, oldest) = link.inbox();
            self.inbox_depth
                .get_or_create(&labels)
                .set(i64::try_from(depth).unwrap_or(i64::MAX));
            self.inbox_oldest
                .get_or_create(&labels)
                .set(oldest.as_secs_f64());
            for reason in ["busy", "expired", "abandoned"] {
                let _ = self.inbox_dropped.get_or_create(&DroppedLabels {
                    link: labels.link.clone(),
                    reason: reason.to_owned(),
                });
            }
            self.link_up
                .get_or_create(&labels)
                .set(i64::from(d.connected));
            self.link_error_code
                .get_or_create(&labels)
                .set(i64::from(d.error_code.code()));
            self.link_stalled
                .get_or_create(&labels)
                .set(i64::from(link.stalled().is_some()));
        }
        for device in &cache.devices() {
            let labels = DeviceLabels {
                device: device.name().to_owned(),
            };
            let d = device.diagnostics();
            self.device_connected
                .get_or_create(&labels)
                .set(i64::from(d.connected));
            self.device_error_code
                .get_or_create(&labels)
                .set(i64::from(d.error_code.code()));
            let mismatched = (0..device.profile.fields.len())
                .filter(|&idx| device.mismatch(idx).is_some())
                .count();
            self.device_mismatched
                .get_or_create(&labels)
                .set(i64::try_from(mismatched).unwrap_or(i64::MAX));
            let cycles = self.device_io_cycles.get_or_create(&labels);
            cycles.inc_by(d.io_cycles.saturating_sub(cycles.get()));
            if !device.is_simulated() {
                let _ = self.timeouts.get_or_create(&labels);
                let _ = self.crc_errors.get_or_create(&labels);
            }
            for outcome in ["written", "superseded", "failed"] {
                let _ = self.writes.get_or_create(&WriteLabels {
                    device: device.name().to_owned(),
                    outcome: outcome.to_owned(),
                });
            }
        }
        for (device, outcome, n) in cache.writes.outcome_counts() {
            let counter = self.writes.get_or_create(&WriteLabels {
                device,
                outcome: outcome.to_owned(),
            });
            counter.inc_by(n.saturating_sub(counter.get()));
        }
        let mut out = String::new();
        let encoded = (|| {
            use prometheus_client::encoding::text::{encode_eof, encode_registry};
            encode_registry(&mut out, &self.registry)?;
            if let Some(status) = mqtt {
                self.mqtt.copy(status);
                encode_registry(&mut out, &self.mqtt.registry)?;
            }
            if let Some(status) = opcua {
                self.opcua.copy(status);
                encode_registry(&mut out, &self.opcua.registry)?;
            }
            encode_eof(&mut out)
        })();
        if encoded.is_err() {
            tracing::error!("cannot encode the metrics");
        }
        match format {
            Format::OpenMetrics => out,
            Format::Prometheus => format::to_prometheus(&out),
        }
    }
}

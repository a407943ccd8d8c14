//! Prometheus metrics at `/metrics`: names are consts, labels stay bounded (link, device,
//! function, outcome, exception code; never a value).
//!
//! Counters of transactions are recorded by the link tasks as they happen. States that the
//! cache already holds (connected, error codes, I/O cycles, write outcomes) are copied into
//! the registry when it is scraped, so there is one source of truth.

use std::sync::atomic::AtomicU64;
use std::time::Duration;

use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::metrics::histogram::{Histogram, exponential_buckets};
use prometheus_client::registry::Registry;

use crate::cache::Cache;
use crate::link::TxError;
use crate::link::frame::Function;

mod bound;
mod format;
mod labels;
mod names;
mod register;
pub(crate) use bound::{Bound, ClientHeld, Held, PerClient};
pub(crate) use format::Format;
pub(crate) use labels::*;
pub use names::*;

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
    bound_limit: Family<bound::BoundLabels, Gauge>,
    bound_used: Family<bound::BoundLabels, Gauge>,
    bound_refused: Family<bound::BoundLabels, Counter>,
    /// Metrics other parts keep here so that they outlive a restart of their owner (a
    /// front-end's, across reloads), one of each type.
    kept: std::sync::Mutex<Vec<std::sync::Arc<dyn std::any::Any + Send + Sync>>>,
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

    /// The `T` kept here, made by `make` the first time: metrics whose owner may restart
    /// (a front-end stopped and started by a reload) and whose counters go on.
    pub(crate) fn kept<T: std::any::Any + Send + Sync>(
        &self,
        make: impl FnOnce() -> T,
    ) -> std::sync::Arc<T> {
        let mut kept = self.kept.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(found) = kept.iter().find_map(|k| k.clone().downcast::<T>().ok()) {
            return found;
        }
        let made = std::sync::Arc::new(make());
        kept.push(made.clone());
        made
    }

    /// The registry in the text format `format`, with states copied from the cache first,
    /// and then what `more` appends (the running front-ends' families).
    pub(crate) fn render(
        &self,
        cache: &Cache,
        more: impl FnOnce(&mut String) -> std::fmt::Result,
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
            self.link_state(link);
        }
        for device in &cache.devices() {
            self.device_state(device);
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
            more(&mut out)?;
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

    /// A link's state gauges, and its counters at zero from its first scrape (so rates
    /// and alerts work at once).
    fn link_state(&self, link: &crate::cache::Link) {
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

    /// A device's state gauges and counters.
    fn device_state(&self, device: &crate::cache::Device) {
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
}

//! The MQTT front-end: the gateway publishes into one broker, as a Sparkplug B 3.0 edge node
//! (`sparkplug.rs`: births, deaths with `bdSeq`, aliases, `seq`, rebirth, NCMD/DCMD writes,
//! the primary host's STATE) and/or on plain JSON topics (`<prefix>/<device>/<field>` with
//! the JSON of `GET .../fields/{field}`, retained; `<prefix>/<device>/$state`;
//! `<prefix>/$state` with a Will; writes on `.../set` answered on `.../set/result`). Values are
//! reported by exception (`report.rs`). While the broker is away every data message goes to
//! the store-and-forward buffer (`buffer.rs`) and is replayed at `replay_rate` after a
//! reconnect, beside live data: Sparkplug replays are DDATA marked `is_historical`, JSON
//! replays go to `<prefix>/history/<device>/<field>` (not retained, with their original
//! timestamp), so that no replay overwrites a live value.
//!
//! A data message leaves the buffer (or memory) only once the broker confirmed it: a PUBACK
//! for QoS 1, the answer to a ping sent after it for QoS 0 (Sparkplug data is QoS 0 by the
//! specification; a broker handles a connection's packets in order). What was published and
//! not confirmed when a connection ends is buffered and sent again (at least once).
//!
//! Like every front-end it only renders the service: the values, views, write checks and
//! outcomes are the service's; `writes: true` is this front-end's role (write).

mod births;
mod buffer;
mod commands;
pub(crate) mod config;
mod conn;
mod front_end;
pub(crate) mod lease;
mod metrics;
mod outbox;
mod packet;
mod refusal;
mod report;
mod said;
mod session;
mod setup;
mod sparkplug;
mod state;
mod status;

use std::collections::{HashMap, HashSet, VecDeque};
use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use futures_util::StreamExt;
use serde::Serialize;
use tokio::time::Instant;
use tokio_util::sync::CancellationToken;

use super::convert::{DiagnosticsEvent, field_value};
use crate::api::mqtt::config::{JsonConfig, MqttConfig, Password};
use crate::auth::{Operation, Role};
use crate::cache::{Device, Diagnostics};
use crate::service::{Change, FieldView, Service};
use crate::write_log::WriteStatus;
use buffer::{Buffer, Kind, Pos, Record, now_ms};
use conn::{ConnError, Connection, TlsSetup};
pub(crate) use front_end::{MqttFrontEnd, section};
use packet::{Connect, Incoming, Will};
use refusal::Refused;
use report::{Decision, Reporter};
pub(crate) use setup::{Prepared, changed_keys, prepare};
use sparkplug::{Aliases, Form, HostState};
pub(crate) use state::MqttState;
pub(crate) use status::{MqttStatus, SparkplugStatus};

/// The topic level the JSON replays go under.
const HISTORY: &str = "history";
/// The first wait between attempts to connect: doubling up to `reconnect_max`.
const RECONNECT_MIN: Duration = Duration::from_millis(500);
/// Writes from `/set` whose final outcome is still to be published, at most.
const MAX_FOLLOWED_WRITES: usize = 1024;
/// How often followed writes are looked at, the buffer synced and the status copied.
const FOLLOW_EVERY: Duration = Duration::from_millis(50);
/// Messages waiting to be published on a connection, at most: changes wait in the service
/// (newest value per field) while it is full.
const MAX_OUTBOX: usize = 4096;
/// Changes taken in one turn of a session, at most (then what they make is written).
const CHANGES_AT_ONCE: usize = 256;
/// Packets from the broker handled in one turn of a session, at most.
const PACKETS_AT_ONCE: usize = 1024;
/// Live data messages published and not yet confirmed, at most.
const MAX_UNCONFIRMED: usize = 8192;
/// Replayed messages published and not yet confirmed, at most.
const REPLAY_WINDOW: usize = 512;
/// How often the replay's budget is refilled.
const REPLAY_EVERY: Duration = Duration::from_millis(10);

/// The topics of the JSON publisher.
struct Topics<'a>(&'a JsonConfig);

impl Topics<'_> {
    fn field(&self, device: &str, field: &str) -> String {
        format!("{}/{device}/{field}", self.0.prefix)
    }
    fn device_state(&self, device: &str) -> String {
        format!("{}/{device}/$state", self.0.prefix)
    }
    fn gateway_state(&self) -> String {
        format!("{}/$state", self.0.prefix)
    }
    fn set_filter(&self) -> String {
        format!("{}/+/+/set", self.0.prefix)
    }
    /// Where a replayed (buffered) value goes: not the live, retained topic.
    fn history(&self, device: &str, field: &str) -> String {
        format!("{}/{HISTORY}/{device}/{field}", self.0.prefix)
    }
    /// The device and field a `/set` topic names.
    /// The device and field a `/set` topic names. `<prefix>/history/<device>/set` is also
    /// the replay of a field named `set`, which the gateway publishes itself: a topic under
    /// `history/` is never a write (a device named `history` takes no writes here).
    fn parse_set<'t>(&self, topic: &'t str) -> Option<(&'t str, &'t str)> {
        let rest = topic
            .strip_prefix(self.0.prefix.as_str())?
            .strip_prefix('/')?;
        let rest = rest.strip_suffix("/set")?;
        let (device, field) = rest.split_once('/')?;
        (!field.contains('/') && device != HISTORY).then_some((device, field))
    }
}

#[derive(Serialize)]
struct GatewayState {
    online: bool,
    version: &'static str,
}

/// Why the front-end could not start.
#[derive(Debug, thiserror::Error)]
pub(crate) enum StartError {
    #[error(transparent)]
    Buffer(#[from] buffer::BufferError),
}

/// The front-end's running task, to stop it (a reload that changes the `mqtt:` section).
/// Dropping it leaves the task running until the gateway shuts down.
pub(crate) struct Running {
    stop: CancellationToken,
    stopped: tokio::sync::oneshot::Receiver<()>,
    state: Arc<MqttState>,
}

/// How long a stopping front-end may take to say goodbye to its broker.
const STOP_WAIT: Duration = Duration::from_secs(10);

impl Running {
    /// Stops the task: NDEATH and the offline state when connected, what is waiting kept in
    /// the buffer directory (when there is one), the connection closed. Answers the
    /// `bdSeq` the next session starts from, or an error when it did not stop in time.
    pub(crate) async fn stop(self, service: &Service) -> Result<u8, String> {
        self.stop.cancel();
        let stopped = tokio::time::timeout(STOP_WAIT, self.stopped).await;
        service.doors.detach("mqtt");
        let next = self
            .state
            .status()
            .sparkplug
            .map_or(0, |sp| sp.bd_seq.wrapping_add(1));
        match stopped {
            Ok(_) => Ok(next),
            Err(_) => Err(format!(
                "the MQTT front-end did not stop within {}s",
                STOP_WAIT.as_secs()
            )),
        }
    }
}

/// Starts the front-end's task; it runs until the gateway shuts down or [`Running::stop`].
/// The Sparkplug `bdSeq` goes on from the buffer directory's, else from `bd_seq`.
pub(crate) fn spawn(
    service: Arc<Service>,
    prepared: Prepared,
    bd_seq: u8,
) -> Result<Running, StartError> {
    let config = &prepared.config;
    tracing::info!(broker = %config.url, "publishing to MQTT");
    let buffer = match &config.buffer.dir {
        Some(dir) => Some(Buffer::open(dir, &config.buffer)?),
        None => None,
    };
    let bd_seq = config
        .buffer
        .dir
        .as_deref()
        .and_then(read_bd_seq)
        .map_or(bd_seq, |b| b.wrapping_add(1));
    let metrics = service.metrics.kept(metrics::MqttMetrics::new);
    let state = Arc::new(MqttState::new(metrics));
    state.update(|s| {
        s.broker = config.url.to_string();
        s.client_id = config.client_id.clone();
        s.json_prefix = config.json.as_ref().map(|j| j.prefix.clone());
        s.buffer.dir = config.buffer.dir.as_ref().map(|d| d.display().to_string());
        s.sparkplug = config.sparkplug.as_ref().map(|sp| SparkplugStatus {
            group_id: sp.group_id.clone(),
            edge_node_id: sp.edge_node_id.clone(),
            bd_seq,
            primary_host: sp.primary_host.clone(),
            ..SparkplugStatus::default()
        });
    });
    service.doors.attach(state.clone());
    let status = state.status();
    let token = service.tasks().token().child_token();
    let (done, stopped) = tokio::sync::oneshot::channel();
    let running = Running {
        stop: token.clone(),
        stopped,
        state: state.clone(),
    };
    let task = Task {
        reporter: Reporter::new(config.report.clone()),
        spark: config.sparkplug.as_ref().map(sparkplug::Topics::new),
        service: service.clone(),
        state,
        buffer,
        bd_seq,
        started: Instant::now(),
        aliases: Aliases::default(),
        devices: Vec::new(),
        by_key: HashMap::new(),
        diag_sent: HashMap::new(),
        next_ticket: 1,
        status,
        lost: 0,
        said: said::Said::default(),
        prepared,
    };
    service.tasks().spawn(async move {
        task.run(token).await;
        let _ = done.send(());
    });
    Ok(running)
}

/// `wait` give or take a quarter, so that gateways that lost one broker together do not
/// all come back in the same instant.
fn jittered(wait: Duration) -> Duration {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.subsec_nanos());
    // A multiplicative hash of the clock's nanoseconds: 0-1023, evenly spread.
    let spread = nanos.wrapping_mul(2_654_435_761) >> 22;
    let quarter = wait / 4;
    wait - quarter + quarter * 2 * spread / 1024
}

fn read_bd_seq(dir: &Path) -> Option<u8> {
    std::fs::read_to_string(dir.join("bdseq"))
        .ok()?
        .trim()
        .parse()
        .ok()
}

/// A message waiting to be published on the connection.
enum Item {
    /// A data message: tracked until the broker confirms it, and buffered if the connection
    /// ends first when it is a change (a field's first value and heartbeats are not: the
    /// next connection's births and first messages carry the current values).
    Data { record: Record, change: bool },
    /// A JSON message that is not data (states, write results).
    Plain(Out),
    /// A Sparkplug message to a device (DBIRTH, DDATA, DDEATH); `seq` is given when sent.
    Spark {
        kind: &'static str,
        device: String,
        metrics: Vec<sparkplug::Metric>,
    },
    /// NBIRTH: `seq` starts again at 0.
    NodeBirth,
}

/// A publish.
struct Out {
    topic: String,
    payload: Vec<u8>,
    qos: u8,
    retain: bool,
}

impl Out {
    /// A Sparkplug message: QoS 0 and not retained, as the specification has them.
    fn sparkplug(topic: String, payload: Vec<u8>) -> Out {
        Out {
            topic,
            payload,
            qos: 0,
            retain: false,
        }
    }
}

/// A data message published and not yet confirmed.
struct Unconfirmed<T> {
    ticket: u64,
    item: T,
    confirmed: bool,
}

/// One connection's state.
struct Online {
    conn: Connection,
    outbox: VecDeque<Item>,
    /// Data published and not confirmed, each with whether it is a change to keep.
    live: VecDeque<Unconfirmed<(Record, bool)>>,
    replay: VecDeque<Unconfirmed<Pos>>,
    replay_budget: f64,
    /// NBIRTH sent (and the host online, when one is configured).
    node_born: bool,
    /// NBIRTH and DBIRTHs in the outbox, not yet sent: no replayed data goes before them.
    births_waiting: usize,
    born: HashSet<String>,
    seq: u8,
    host: Option<HostState>,
    followed: VecDeque<(u64, String, String)>,
}

/// What woke a session.
enum Event {
    Shutdown,
    Packet(Result<Incoming, ConnError>),
    KeepAlive,
    Change(Option<Change>),
    Due((usize, usize)),
    Devices,
    Replay,
    Timer,
    /// The gateway's role in its pair changed.
    Role,
}

/// Why a session ended.
enum Ended {
    /// The gateway stops.
    Shutdown,
    /// The connection failed.
    Lost(ConnError),
    /// The primary host went offline: NDEATH sent, connect again and wait for it.
    HostOffline,
    /// The gateway stood down in its pair: the edge node dies here and is born on the
    /// new active.
    StoodDown,
}

struct Task {
    service: Arc<Service>,
    state: Arc<MqttState>,
    prepared: Prepared,
    spark: Option<sparkplug::Topics>,
    reporter: Reporter,
    buffer: Option<Buffer>,
    bd_seq: u8,
    started: Instant,
    aliases: Aliases,
    /// The devices subscribed to, and each by its reporting key.
    devices: Vec<Arc<Device>>,
    by_key: HashMap<usize, Arc<Device>>,
    /// The last diagnostics published per device: (connected, error code, when).
    diag_sent: HashMap<String, (bool, i16, Instant)>,
    next_ticket: u64,
    /// Counters, copied into the shared state on the timer.
    status: MqttStatus,
    /// Data messages lost here: no buffer, or a buffer that could not take them, or a
    /// replayed message whose device is gone.
    lost: u64,
    /// What is logged of clients' messages, within its bound.
    said: said::Said,
}

impl Task {
    fn json(&self) -> Option<&JsonConfig> {
        self.prepared.config.json.as_ref()
    }

    fn connect_packet(&self) -> Connect {
        let config = &self.prepared.config;
        // One Will per connection: the edge node's NDEATH when Sparkplug is on, else the
        // JSON gateway state.
        let will = match (&self.spark, &config.json) {
            (Some(t), _) => Some(Will {
                topic: t.node("NDEATH"),
                payload: sparkplug::death(self.bd_seq, now_ms()),
                qos: 1,
                retain: false,
            }),
            (None, Some(json)) => Some(Will {
                topic: Topics(json).gateway_state(),
                payload: state_payload(false),
                qos: json.qos,
                retain: true,
            }),
            (None, None) => None,
        };
        Connect {
            client_id: config.client_id.clone(),
            keep_alive: config.keep_alive.as_secs().min(u64::from(u16::MAX)) as u16,
            clean_start: config.clean_start,
            username: config.username.clone(),
            password: self.prepared.password.clone(),
            will,
        }
    }

    /// Subscribes to every device's changes (again when devices come or go).
    fn subscribe(&mut self) -> Option<crate::service::Changes> {
        self.devices = self.service.devices();
        self.by_key.clear();
        for d in &self.devices {
            let base = self.aliases.base(d.name(), d.profile.fields.len());
            self.by_key.insert(base as usize, d.clone());
        }
        match self.service.subscribe_devices(&self.devices) {
            Ok(changes) => Some(changes),
            Err(e) => {
                tracing::warn!(error = %e, "MQTT: cannot subscribe to the devices' changes");
                None
            }
        }
    }
}

/// Sleeps until `at`, or for ever.
async fn sleep_until(at: Option<Instant>) {
    match at {
        Some(at) => tokio::time::sleep_until(at).await,
        None => std::future::pending().await,
    }
}

/// The next change, or never when there is no subscription.
/// A change ready now (`Some(None)`: the stream ended), without waiting.
async fn ready_change(changes: &mut Option<crate::service::Changes>) -> Option<Option<Change>> {
    use futures_util::StreamExt;
    let stream = changes.as_mut()?;
    std::future::poll_fn(|cx| match stream.poll_next_unpin(cx) {
        std::task::Poll::Ready(next) => std::task::Poll::Ready(Some(next)),
        std::task::Poll::Pending => std::task::Poll::Ready(None),
    })
    .await
}

async fn next_change(changes: &mut Option<crate::service::Changes>) -> Option<Change> {
    match changes {
        Some(c) => c.next().await,
        None => std::future::pending().await,
    }
}

fn state_payload(online: bool) -> Vec<u8> {
    serde_json::to_vec(&GatewayState {
        online,
        version: env!("CARGO_PKG_VERSION"),
    })
    .unwrap_or_default()
}

/// Packets from a broker, both versions, as the session takes them off its buffer.
#[cfg(any(fuzzing, test))]
pub(crate) fn fuzz_packets(data: &[u8]) {
    for version in [config::MqttVersion::V311, config::MqttVersion::V5] {
        let mut buf = data.to_vec();
        while let Ok(Some(_)) = packet::decode(version, &mut buf) {}
    }
}

/// A Sparkplug command's payload.
#[cfg(any(fuzzing, test))]
pub(crate) fn fuzz_command(data: &[u8]) {
    let _ = sparkplug::commands(data);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_replay_topic_is_never_taken_for_a_write() {
        let json = JsonConfig {
            prefix: "iogate/line1".into(),
            qos: 1,
            retain: true,
        };
        let topics = Topics(&json);
        assert_eq!(
            topics.parse_set("iogate/line1/sim/DO_0/set"),
            Some(("sim", "DO_0"))
        );
        // The replay of device `pump`'s field named `set`, which the gateway itself
        // publishes, is not a write of a field `pump` of a device `history`.
        assert_eq!(
            topics.history("pump", "set"),
            "iogate/line1/history/pump/set"
        );
        assert_eq!(topics.parse_set("iogate/line1/history/pump/set"), None);
        assert_eq!(topics.parse_set("other/sim/DO_0/set"), None);
    }
}

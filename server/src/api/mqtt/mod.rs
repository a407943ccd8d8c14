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

mod buffer;
mod conn;
mod metrics;
mod packet;
mod refusal;
mod report;
mod sparkplug;
mod status;

use std::collections::{HashMap, HashSet, VecDeque};
use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use futures_util::StreamExt;
use serde::Serialize;
use tokio::time::Instant;
use tokio_util::sync::CancellationToken;

use super::convert::{self, DiagnosticsEvent, field_value};
use crate::auth::{Operation, Role};
use crate::cache::{Device, Diagnostics};
use crate::config::mqtt::{JsonConfig, MqttConfig, Password};
use crate::service::{Change, FieldView, Service};
use crate::write_log::WriteStatus;
use buffer::{Buffer, Kind, Pos, Record, now_ms};
use conn::{ConnError, Connection, TlsSetup};
use packet::{Connect, Incoming, Will};
use refusal::Refused;
use report::{Decision, Reporter};
use sparkplug::{Aliases, Form, HostState};
pub(crate) use status::{MqttState, MqttStatus, SparkplugStatus};

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
/// Live data messages published and not yet confirmed, at most.
const MAX_UNCONFIRMED: usize = 8192;
/// Replayed messages published and not yet confirmed, at most.
const REPLAY_WINDOW: usize = 32;
/// How often the replay's budget is refilled.
const REPLAY_EVERY: Duration = Duration::from_millis(10);

/// What the front-end needs from the files its section names, read once at start.
pub(crate) struct Prepared {
    config: MqttConfig,
    password: Option<Vec<u8>>,
    tls: Option<TlsSetup>,
}

impl Prepared {
    /// Whether the front-end may do `operation`, by the one role rule: its role is `write`
    /// with `mqtt.writes: true`, else `read`.
    fn may(&self, operation: Operation) -> bool {
        let role = match self.config.writes {
            true => Role::Write,
            false => Role::Read,
        };
        operation.allowed_to(role).is_ok()
    }
}

/// Reads the password and TLS files; a problem is named with its file.
pub(crate) fn prepare(config: &MqttConfig, base: &std::path::Path) -> Result<Prepared, String> {
    let password = match &config.password {
        None => None,
        Some(Password::File(path)) => {
            let path = base.join(path);
            let text = std::fs::read(&path)
                .map_err(|e| format!("mqtt.password_file {}: {e}", path.display()))?;
            // A trailing newline is the file's, not the password's.
            let end = text
                .iter()
                .rposition(|&b| b != b'\n' && b != b'\r')
                .map_or(0, |i| i + 1);
            Some(text[..end].to_vec())
        }
        Some(Password::Env(name)) => Some(
            std::env::var_os(name)
                .ok_or_else(|| format!("mqtt.password_env: the environment has no `{name}`"))?
                .into_encoded_bytes(),
        ),
    };
    let tls = if config.url.tls {
        let mut c = config.clone();
        c.tls.ca = c.tls.ca.map(|p| base.join(p));
        c.tls.cert = c.tls.cert.map(|p| base.join(p));
        c.tls.key = c.tls.key.map(|p| base.join(p));
        Some(TlsSetup::load(&c)?)
    } else {
        None
    };
    let mut config = config.clone();
    config.buffer.dir = config.buffer.dir.map(|d| base.join(d));
    Ok(Prepared {
        config,
        password,
        tls,
    })
}

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

#[derive(Serialize)]
struct SetResult<'a> {
    device: &'a str,
    field: &'a str,
    generation: u64,
    status: &'static str,
    #[serde(skip_serializing_if = "Option::is_none")]
    error: Option<String>,
}

#[derive(Serialize)]
struct SetRefused<'a> {
    device: &'a str,
    field: &'a str,
    error: super::error::ErrorDetail,
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
}

/// Why a session ended.
enum Ended {
    /// The gateway stops.
    Shutdown,
    /// The connection failed.
    Lost(ConnError),
    /// The primary host went offline: NDEATH sent, connect again and wait for it.
    HostOffline,
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

    async fn run(mut self, token: CancellationToken) {
        let config = self.prepared.config.clone();
        let mut devices_changed = self.service.watch_devices();
        let mut changes = self.subscribe();
        let mut wait = Duration::ZERO;
        let mut first = true;
        let mut timer = tokio::time::interval(FOLLOW_EVERY);
        loop {
            // Offline: connect (after the back-off) while changes go to the buffer.
            self.keep_bd_seq();
            let connect = self.connect_packet();
            let tls = self.prepared.tls.clone();
            let delay = jittered(wait);
            let attempt = async {
                tokio::time::sleep(delay).await;
                Connection::open(&config, tls.as_ref(), &connect).await
            };
            tokio::pin!(attempt);
            let opened = loop {
                tokio::select! {
                    _ = token.cancelled() => {
                        self.stop(None).await;
                        return;
                    }
                    r = &mut attempt => break r,
                    change = next_change(&mut changes) => match change {
                        Some(change) => self.on_change(change, None),
                        None => changes = None,
                    },
                    key = self.reporter.due() => self.heartbeat(key, None),
                    _ = devices_changed.changed() => {
                        changes = self.subscribe();
                        self.devices_changed(None);
                    }
                    _ = timer.tick() => self.tick(None),
                }
            };
            match opened {
                Ok(conn) => {
                    if !first {
                        self.status.reconnects += 1;
                    }
                    first = false;
                    wait = RECONNECT_MIN;
                    tracing::info!(broker = %config.url, bd_seq = self.bd_seq, "MQTT connected");
                    self.status.connected = true;
                    self.status.last_error = None;
                    self.publish_status();
                    let mut online = Online {
                        conn,
                        outbox: VecDeque::new(),
                        live: VecDeque::new(),
                        replay: VecDeque::new(),
                        replay_budget: 0.0,
                        node_born: false,
                        born: HashSet::new(),
                        seq: 0,
                        host: None,
                        followed: VecDeque::new(),
                    };
                    let ended = self
                        .session(
                            &mut online,
                            &mut changes,
                            &mut devices_changed,
                            &mut timer,
                            &token,
                        )
                        .await;
                    self.status.connected = false;
                    self.connection_ended(&mut online);
                    match ended {
                        Ended::Shutdown => {
                            self.stop(Some(online)).await;
                            return;
                        }
                        Ended::Lost(e) => {
                            tracing::warn!(broker = %config.url, error = %e, "MQTT connection lost");
                            self.status.last_error = Some(e.to_string());
                        }
                        Ended::HostOffline => {
                            self.node_death(&mut online).await;
                            online.conn.disconnect().await;
                            self.status.last_error =
                                Some("the primary host application went offline".into());
                            wait = Duration::ZERO;
                        }
                    }
                    self.next_bd_seq();
                }
                Err(e) => {
                    wait = (wait * 2).clamp(RECONNECT_MIN, config.reconnect_max);
                    tracing::warn!(broker = %config.url, error = %e, retry_in = ?wait, "cannot connect to the MQTT broker");
                    self.status.last_error = Some(e.to_string());
                    // The CONNECT may have reached the broker (a lost CONNACK): its Will,
                    // published later, must not carry the next session's bdSeq.
                    self.next_bd_seq();
                }
            }
            self.publish_status();
        }
    }

    /// The next connection's `bdSeq` (0-255, wrapping).
    fn next_bd_seq(&mut self) {
        self.bd_seq = self.bd_seq.wrapping_add(1);
    }

    /// Writes the `bdSeq` of the CONNECT about to be sent beside the buffer (replacing the
    /// file at once), so that after a restart, even a kill, the next one differs from it:
    /// a late NDEATH from the Will of a killed connection is never taken for the new one's.
    fn keep_bd_seq(&mut self) {
        let Some(dir) = &self.prepared.config.buffer.dir else {
            return;
        };
        let tmp = dir.join("bdseq.tmp");
        let written = std::fs::write(&tmp, format!("{}\n", self.bd_seq))
            .and_then(|()| std::fs::rename(&tmp, dir.join("bdseq")));
        if let Err(e) = written {
            tracing::warn!(error = %e, dir = %dir.display(), "MQTT: cannot keep bdSeq");
        }
    }

    /// The gateway stops: NDEATH and the offline state, what is unconfirmed kept on disk.
    async fn stop(&mut self, online: Option<Online>) {
        if let Some(mut online) = online {
            self.node_death(&mut online).await;
            if let Some(json) = self.json() {
                let topic = Topics(json).gateway_state();
                let qos = json.qos;
                let _ = online
                    .conn
                    .publish(&topic, &state_payload(false), qos, true, 0)
                    .await;
            }
            online.conn.disconnect().await;
        }
        if let Some(b) = &mut self.buffer {
            let _ = b.sync();
            let _ = b.write_head(true);
        }
        self.status.connected = false;
        self.publish_status();
    }

    /// NDEATH with the connection's `bdSeq`, before a DISCONNECT (which drops the Will).
    async fn node_death(&self, online: &mut Online) {
        if let Some(t) = &self.spark {
            let _ = online
                .conn
                .publish(
                    &t.node("NDEATH"),
                    &sparkplug::death(self.bd_seq, now_ms()),
                    1,
                    false,
                    0,
                )
                .await;
        }
    }

    /// What was published and not confirmed, and what waited to be, goes to the buffer;
    /// the replay starts again from the first record not confirmed.
    fn connection_ended(&mut self, online: &mut Online) {
        let live: Vec<Record> = online
            .live
            .drain(..)
            .filter(|u| !u.confirmed && u.item.1)
            .map(|u| u.item.0)
            .collect();
        let waiting: Vec<Record> = online
            .outbox
            .drain(..)
            .filter_map(|i| match i {
                Item::Data {
                    record,
                    change: true,
                } => Some(record),
                _ => None,
            })
            .collect();
        for r in live.into_iter().chain(waiting) {
            self.keep(r);
        }
        online.replay.clear();
        if let Some(b) = &mut self.buffer {
            b.rewind();
        }
        if let Some(sp) = &mut self.status.sparkplug {
            sp.born = false;
            sp.born_devices = 0;
        }
    }

    /// Keeps a data message for later (or counts it lost when there is no buffer).
    fn keep(&mut self, record: Record) {
        match &mut self.buffer {
            Some(b) => {
                if let Err(e) = b.append(&record) {
                    tracing::warn!(error = %e, "MQTT: a message could not be buffered");
                    self.lost += 1;
                }
            }
            None => self.lost += 1,
        }
    }

    async fn session(
        &mut self,
        online: &mut Online,
        changes: &mut Option<crate::service::Changes>,
        devices_changed: &mut tokio::sync::watch::Receiver<u64>,
        timer: &mut tokio::time::Interval,
        token: &CancellationToken,
    ) -> Ended {
        match self.start_session(online).await {
            Ok(()) => {}
            Err(e) => return Ended::Lost(e),
        }
        let mut replay_timer = tokio::time::interval(REPLAY_EVERY);
        loop {
            // Send what can be sent, then wait for the next event.
            let sent: Result<(), ConnError> = async {
                self.drain(online).await?;
                online.conn.barrier().await
            }
            .await;
            if let Err(e) = sent {
                return Ended::Lost(e);
            }
            let keep_alive = online.conn.keep_alive_due();
            let can_take = online.outbox.len() < MAX_OUTBOX && online.live.len() < MAX_UNCONFIRMED;
            let replaying = self.buffer.as_ref().is_some_and(|b| !b.is_empty());
            let event = tokio::select! {
                biased;
                _ = token.cancelled() => Event::Shutdown,
                packet = online.conn.read() => Event::Packet(packet),
                _ = sleep_until(keep_alive) => Event::KeepAlive,
                change = next_change(changes), if can_take => Event::Change(change),
                key = self.reporter.due(), if can_take => Event::Due(key),
                _ = devices_changed.changed() => Event::Devices,
                _ = replay_timer.tick(), if replaying => Event::Replay,
                _ = timer.tick() => Event::Timer,
            };
            let result: Result<Option<Ended>, ConnError> = match event {
                Event::Shutdown => Ok(Some(Ended::Shutdown)),
                Event::Packet(Ok(p)) => self.incoming(online, p).await,
                Event::Packet(Err(e)) => Err(e),
                Event::KeepAlive => online.conn.keep_alive().await.map(|()| None),
                Event::Change(Some(change)) => {
                    self.on_change(change, Some(online));
                    Ok(None)
                }
                Event::Change(None) => {
                    *changes = None;
                    Ok(None)
                }
                Event::Due(key) => {
                    self.heartbeat(key, Some(online));
                    Ok(None)
                }
                Event::Devices => {
                    *changes = self.subscribe();
                    self.devices_changed(Some(online));
                    Ok(None)
                }
                Event::Replay => self.replay(online).await.map(|()| None),
                Event::Timer => {
                    self.tick(Some(online));
                    Ok(None)
                }
            };
            match result {
                Ok(None) => {}
                Ok(Some(ended)) => return ended,
                Err(e) => return Ended::Lost(e),
            }
            self.take_confirmations(online);
            if replaying
                && online.replay_budget >= 1.0
                && online.replay.len() < REPLAY_WINDOW
                && let Err(e) = self.replay_more(online).await
            {
                return Ended::Lost(e);
            }
        }
    }

    /// Subscriptions (again after every reconnect: a clean session forgets them), then the
    /// births or, while a primary host is awaited, nothing.
    async fn start_session(&mut self, online: &mut Online) -> Result<(), ConnError> {
        let mut filters = Vec::new();
        if let Some(t) = &self.spark {
            filters.push((t.node("NCMD"), 1));
            filters.push((t.node("DCMD") + "/+", 1));
            if let Some(state) = t.host_state() {
                filters.push((state, 1));
            }
        }
        if let Some(json) = self.json()
            && self.prepared.may(Operation::WriteOutputs)
        {
            filters.push((Topics(json).set_filter(), 1));
        }
        if !filters.is_empty() {
            online.conn.subscribe(&filters).await?;
        }
        if let Some(json) = self.json() {
            // Every field's current value on the live (retained) topics: changes made while
            // the broker was away went to the buffer, and a retained topic must not stay
            // behind them.
            let json = json.clone();
            let topics = Topics(&json);
            online.outbox.push_back(Item::Plain(Out {
                topic: topics.gateway_state(),
                payload: state_payload(true),
                qos: json.qos,
                retain: true,
            }));
            for device in self.devices.clone() {
                online.outbox.push_back(Item::Plain(self.device_state(
                    &json,
                    &device,
                    &device.diagnostics(),
                )));
                for idx in 0..device.profile.fields.len() {
                    let view = self.service.field_view_now(&device, idx);
                    let key = self.key(&device, idx);
                    self.reporter
                        .sent(key, view.value.as_ref(), view.quality, Instant::now());
                    online.outbox.push_back(Item::Plain(Out {
                        topic: topics.field(device.name(), &view.field.name),
                        payload: serde_json::to_vec(&field_value(&view)).unwrap_or_default(),
                        qos: json.qos,
                        retain: json.retain,
                    }));
                }
            }
        }
        if let Some(t) = &self.spark
            && t.host_state().is_none()
        {
            self.births(online);
        }
        Ok(())
    }

    fn key(&mut self, device: &Device, idx: usize) -> (usize, usize) {
        let base = self
            .aliases
            .base(device.name(), device.profile.fields.len());
        (base as usize, idx)
    }

    /// NBIRTH and a DBIRTH for every device that answers.
    fn births(&mut self, online: &mut Online) {
        online.node_born = true;
        online.born.clear();
        online.outbox.push_back(Item::NodeBirth);
        for device in self.devices.clone() {
            if device.diagnostics().connected {
                self.device_birth(online, &device);
            }
        }
    }

    fn device_birth(&mut self, online: &mut Online, device: &Device) {
        let now = now_ms();
        let n = device.profile.fields.len();
        let base = self.aliases.base(device.name(), n);
        let mut metrics: Vec<_> = (0..n)
            .map(|idx| {
                let view = self.service.field_view_now(device, idx);
                sparkplug::field_metric(&view, base + idx as u64, Form::Birth, now)
            })
            .collect();
        let d = device.diagnostics();
        metrics.extend(sparkplug::diagnostics_metrics(
            &d,
            base + n as u64,
            true,
            now,
        ));
        self.diag_sent.insert(
            device.name().to_owned(),
            (d.connected, d.error_code.code(), Instant::now()),
        );
        online.born.insert(device.name().to_owned());
        online.outbox.push_back(Item::Spark {
            kind: "DBIRTH",
            device: device.name().to_owned(),
            metrics,
        });
    }

    fn device_death(&mut self, online: &mut Online, device: &str) {
        if online.born.remove(device) {
            online.outbox.push_back(Item::Spark {
                kind: "DDEATH",
                device: device.to_owned(),
                metrics: Vec::new(),
            });
        }
    }

    /// Devices came or went: a DBIRTH for a new one that answers, a DDEATH for one removed.
    fn devices_changed(&mut self, online: Option<&mut Online>) {
        let Some(online) = online.filter(|o| o.node_born) else {
            return;
        };
        let names: HashSet<String> = self.devices.iter().map(|d| d.name().to_owned()).collect();
        let gone: Vec<String> = online
            .born
            .iter()
            .filter(|n| !names.contains(*n))
            .cloned()
            .collect();
        for name in gone {
            self.device_death(online, &name);
        }
        for device in self.devices.clone() {
            if !online.born.contains(device.name()) && device.diagnostics().connected {
                self.device_birth(online, &device);
            }
        }
    }

    fn on_change(&mut self, change: Change, online: Option<&mut Online>) {
        match change {
            Change::Value {
                device,
                idx,
                sample,
                ..
            } => {
                let key = self.key(&device, idx);
                let view = self.service.field_view(&device, idx, &sample);
                let deadband = view.field.deadband;
                let now = Instant::now();
                let first = !self.reporter.has_sent_value(key);
                let decision =
                    self.reporter
                        .change(key, view.value.as_ref(), view.quality, deadband, now);
                match decision {
                    Decision::Send => {
                        self.reporter
                            .sent(key, view.value.as_ref(), view.quality, now);
                        // A field's first value is not a change to keep for later: the
                        // births and the connection's first messages carry it.
                        self.emit(&view, online, !first);
                    }
                    Decision::Skip | Decision::Hold => {}
                }
            }
            Change::Diagnostics {
                device,
                diagnostics,
            } => self.on_diagnostics(&device, &diagnostics, online),
            // A removed device dies when the device set changes.
            Change::Removed { .. } => {}
        }
    }

    /// A held change or a heartbeat is due.
    fn heartbeat(&mut self, key: (usize, usize), online: Option<&mut Online>) {
        let Some(device) = self.by_key.get(&key.0).cloned() else {
            return;
        };
        if key.1 >= device.profile.fields.len() {
            return;
        }
        let view = self.service.field_view_now(&device, key.1);
        let held = self.reporter.is_held(key);
        self.reporter
            .sent(key, view.value.as_ref(), view.quality, Instant::now());
        // Only a held change is kept for later: a heartbeat repeats what the buffer has.
        self.emit(&view, online, held);
    }

    /// A field's value to publish: live when it can be, else kept for the replay when it is
    /// a change (`change`).
    fn emit(&mut self, view: &FieldView<'_>, mut online: Option<&mut Online>, change: bool) {
        let device = view.device.name().to_owned();
        let field = view.field.name.clone();
        let at_ms = now_ms();
        if self.json().is_some() {
            let record = Record {
                at_ms,
                kind: Kind::Json,
                device: device.clone(),
                field: field.clone(),
                payload: serde_json::to_vec(&field_value(view)).unwrap_or_default(),
            };
            match online.as_deref_mut() {
                Some(o) => o.outbox.push_back(Item::Data { record, change }),
                None if change => self.keep(record),
                None => {}
            }
        }
        if self.spark.is_some() {
            let metric = sparkplug::field_metric(view, 0, Form::Data, at_ms);
            let record = Record {
                at_ms,
                kind: Kind::Sparkplug,
                device: device.clone(),
                field,
                payload: sparkplug::kept_metric(&metric),
            };
            match online {
                Some(o) if o.node_born && o.born.contains(&device) => {
                    o.outbox.push_back(Item::Data { record, change });
                }
                // A device that does not answer is dead to the host; its DBIRTH brings the
                // values when it answers again.
                Some(o) if o.node_born => {}
                // Offline, or the primary host awaited.
                _ if change => self.keep(record),
                _ => {}
            }
        }
    }

    fn on_diagnostics(&mut self, device: &Device, d: &Diagnostics, online: Option<&mut Online>) {
        let name = device.name();
        let now = Instant::now();
        let heartbeat = self.prepared.config.report.max_interval;
        let due = match self.diag_sent.get(name) {
            None => true,
            Some(&(connected, code, at)) => {
                connected != d.connected
                    || code != d.error_code.code()
                    || (!heartbeat.is_zero() && now >= at + heartbeat)
            }
        };
        let Some(online) = online else {
            return;
        };
        if !due {
            return;
        }
        self.diag_sent
            .insert(name.to_owned(), (d.connected, d.error_code.code(), now));
        if let Some(json) = self.json().cloned() {
            let out = self.device_state(&json, device, d);
            online.outbox.push_back(Item::Plain(out));
        }
        if self.spark.is_some() && online.node_born {
            let born = online.born.contains(name);
            match (d.connected, born) {
                (true, false) => self.device_birth(online, device),
                (false, true) => self.device_death(online, name),
                (true, true) => {
                    let n = device.profile.fields.len();
                    let base = self.aliases.base(name, n);
                    online.outbox.push_back(Item::Spark {
                        kind: "DDATA",
                        device: name.to_owned(),
                        metrics: sparkplug::diagnostics_metrics(
                            d,
                            base + n as u64,
                            false,
                            now_ms(),
                        ),
                    });
                }
                (false, false) => {}
            }
        }
    }

    fn device_state(&self, json: &JsonConfig, device: &Device, d: &Diagnostics) -> Out {
        Out {
            topic: Topics(json).device_state(device.name()),
            payload: serde_json::to_vec(&DiagnosticsEvent {
                device: device.name().to_owned(),
                connected: d.connected,
                error_code: d.error_code.code(),
                io_cycles: d.io_cycles,
                last_response_ms: d.last_response_ms,
            })
            .unwrap_or_default(),
            qos: json.qos,
            retain: true,
        }
    }

    fn ticket(&mut self) -> u64 {
        let t = self.next_ticket;
        self.next_ticket += 1;
        t
    }

    async fn publish(&mut self, online: &mut Online, out: Out, tag: u64) -> Result<(), ConnError> {
        online
            .conn
            .publish(&out.topic, &out.payload, out.qos, out.retain, tag)
            .await?;
        self.status.messages_out += 1;
        self.status.bytes_out += out.payload.len() as u64;
        Ok(())
    }

    fn next_seq(online: &mut Online) -> u8 {
        let s = online.seq;
        online.seq = online.seq.wrapping_add(1);
        s
    }

    /// The alias of a device's field in this gateway's births.
    fn alias(&mut self, device: &str, field: &str) -> Option<u64> {
        let d = self.service.device(device).ok()?;
        let idx = d.field_index(field).ok()?;
        Some(self.aliases.base(device, d.profile.fields.len()) + idx as u64)
    }

    /// Publishes what waits, as far as the in-flight window allows.
    async fn drain(&mut self, online: &mut Online) -> Result<(), ConnError> {
        while online.conn.can_publish() {
            let Some(item) = online.outbox.pop_front() else {
                break;
            };
            match item {
                Item::Plain(out) => self.publish(online, out, 0).await?,
                Item::NodeBirth => {
                    let Some(t) = &self.spark else { continue };
                    let topic = t.node("NBIRTH");
                    online.seq = 1;
                    let payload = sparkplug::node_birth(
                        self.bd_seq,
                        self.started.elapsed().as_secs(),
                        now_ms(),
                    );
                    self.publish(
                        online,
                        Out {
                            topic,
                            payload,
                            qos: 0,
                            retain: false,
                        },
                        0,
                    )
                    .await?;
                }
                Item::Spark {
                    kind,
                    device,
                    metrics,
                } => {
                    let Some(t) = &self.spark else { continue };
                    let topic = t.device(kind, &device);
                    let seq = Self::next_seq(online);
                    let payload = sparkplug::encode(now_ms(), Some(seq), metrics);
                    self.publish(
                        online,
                        Out {
                            topic,
                            payload,
                            qos: 0,
                            retain: false,
                        },
                        0,
                    )
                    .await?;
                }
                Item::Data { record, change } => {
                    let Some(out) = self.data_out(online, &record, false) else {
                        continue;
                    };
                    let ticket = self.ticket();
                    self.publish(online, out, ticket).await?;
                    online.live.push_back(Unconfirmed {
                        ticket,
                        item: (record, change),
                        confirmed: false,
                    });
                }
            }
        }
        Ok(())
    }

    /// How a data record is published: live, or replayed from the buffer (`historical`).
    /// `None` when it cannot be any more (its device is not born, or its field gone).
    fn data_out(&mut self, online: &mut Online, record: &Record, historical: bool) -> Option<Out> {
        match record.kind {
            Kind::Json => {
                let json = self.json()?;
                let topics = Topics(json);
                Some(if historical {
                    Out {
                        topic: topics.history(&record.device, &record.field),
                        payload: record.payload.clone(),
                        qos: json.qos,
                        retain: false,
                    }
                } else {
                    Out {
                        topic: topics.field(&record.device, &record.field),
                        payload: record.payload.clone(),
                        qos: json.qos,
                        retain: json.retain,
                    }
                })
            }
            Kind::Sparkplug => {
                if !online.node_born || !online.born.contains(&record.device) {
                    return None;
                }
                let alias = self.alias(&record.device, &record.field)?;
                let metric = sparkplug::sendable(&record.payload)?;
                let topic = self.spark.as_ref()?.device("DDATA", &record.device);
                let seq = Self::next_seq(online);
                Some(Out {
                    topic,
                    payload: sparkplug::data_payload(now_ms(), seq, &metric, alias, historical),
                    qos: 0,
                    retain: false,
                })
            }
        }
    }

    /// Sends buffered records, at `replay_rate` and at most [`REPLAY_WINDOW`] unconfirmed,
    /// beside live data (which never waits for the replay).
    async fn replay(&mut self, online: &mut Online) -> Result<(), ConnError> {
        // Sparkplug records wait for the births (and the host).
        if self.spark.is_some() && !online.node_born {
            return Ok(());
        }
        let rate = f64::from(self.prepared.config.buffer.replay_rate.max(1));
        let burst = (rate * REPLAY_EVERY.as_secs_f64()).max(1.0);
        online.replay_budget = (online.replay_budget + burst).min(burst * 2.0);
        self.replay_more(online).await
    }

    /// Sends buffered records while the rate's budget and the window allow (again as soon
    /// as the broker confirms some, not only on the replay timer).
    async fn replay_more(&mut self, online: &mut Online) -> Result<(), ConnError> {
        if self.spark.is_some() && !online.node_born {
            return Ok(());
        }
        while online.replay_budget >= 1.0
            && online.replay.len() < REPLAY_WINDOW
            && online.conn.can_publish()
        {
            let Some(buffer) = &mut self.buffer else {
                break;
            };
            let next = match buffer.next() {
                Ok(Some(next)) => next,
                Ok(None) => break,
                Err(e) => {
                    tracing::warn!(error = %e, "MQTT: the buffer cannot be read");
                    break;
                }
            };
            let (record, end) = next;
            online.replay_budget -= 1.0;
            let ticket = self.ticket();
            match self.data_out(online, &record, true) {
                Some(out) => {
                    self.publish(online, out, ticket).await?;
                    online.replay.push_back(Unconfirmed {
                        ticket,
                        item: end,
                        confirmed: false,
                    });
                }
                None => {
                    // Its device is gone or dead: nothing a host could take it for.
                    self.lost += 1;
                    online.replay.push_back(Unconfirmed {
                        ticket,
                        item: end,
                        confirmed: true,
                    });
                }
            }
        }
        Ok(())
    }

    /// Marks what the broker confirmed, lets go of live records, and acknowledges the
    /// buffer up to the last replayed record confirmed in order.
    fn take_confirmations(&mut self, online: &mut Online) {
        let confirmed = online.conn.take_confirmed();
        for ticket in confirmed {
            self.confirm(online, ticket);
        }
        while online.live.front().is_some_and(|u| u.confirmed) {
            online.live.pop_front();
        }
        let mut acked = None;
        while online.replay.front().is_some_and(|u| u.confirmed) {
            acked = online.replay.pop_front().map(|u| u.item);
            self.status.buffer.replayed += 1;
        }
        if let (Some(end), Some(b)) = (acked, &mut self.buffer) {
            b.ack(end);
        }
    }

    fn confirm(&mut self, online: &mut Online, ticket: u64) {
        if let Ok(i) = online.live.binary_search_by_key(&ticket, |u| u.ticket) {
            let u = &mut online.live[i];
            u.confirmed = true;
            let latency = now_ms().saturating_sub(u.item.0.at_ms);
            self.state.metrics.observe_latency(latency as f64 / 1000.0);
        } else if let Ok(i) = online.replay.binary_search_by_key(&ticket, |u| u.ticket) {
            online.replay[i].confirmed = true;
        }
    }

    /// A packet from the broker.
    async fn incoming(
        &mut self,
        online: &mut Online,
        packet: Incoming,
    ) -> Result<Option<Ended>, ConnError> {
        match packet {
            Incoming::PubAck { pkid, .. } => {
                if let Some(ticket) = online.conn.acked(pkid)
                    && ticket != 0
                {
                    self.confirm(online, ticket);
                }
            }
            Incoming::Publish(p) => {
                self.status.messages_in += 1;
                self.status.bytes_in += p.payload.len() as u64;
                if p.qos > 0 {
                    online.conn.puback(p.pkid).await?;
                }
                return Ok(self.command(online, &p.topic, &p.payload).await);
            }
            Incoming::Dropped { why, topic, .. } => {
                self.status.dropped_in += 1;
                tracing::warn!(error = %why, topic = topic.as_deref().unwrap_or("-"), "a packet from the broker read past and dropped");
            }
            Incoming::SubAck { codes, .. } if codes.iter().any(|&c| c >= 0x80) => {
                tracing::warn!("the broker refused a subscription (commands or writes)");
            }
            _ => {}
        }
        Ok(None)
    }

    /// A message on a subscribed topic: a write, a Sparkplug command, or the host's STATE.
    async fn command(&mut self, online: &mut Online, topic: &str, payload: &[u8]) -> Option<Ended> {
        if let Some(json) = self.json().cloned()
            && let Some(out) = self.set(&Topics(&json), topic, payload, &mut online.followed)
        {
            online.outbox.push_back(Item::Plain(out));
            return None;
        }
        let t = self.spark.as_ref()?;
        if t.host_state().as_deref() == Some(topic) {
            return self.host_state(online, payload);
        }
        match t.command(topic)? {
            None => self.node_command(online, payload),
            Some(device) => {
                let device = device.to_owned();
                self.device_command(&device, payload);
            }
        }
        None
    }

    fn host_state(&mut self, online: &mut Online, payload: &[u8]) -> Option<Ended> {
        let state: HostState = match serde_json::from_slice(payload) {
            Ok(s) => s,
            Err(e) => {
                tracing::warn!(error = %e, "the primary host's STATE is not its JSON: ignored");
                return None;
            }
        };
        // An older STATE (a retained one overtaken by a newer) is not news.
        if online
            .host
            .as_ref()
            .is_some_and(|h| state.timestamp < h.timestamp)
        {
            return None;
        }
        let online_now = state.online;
        online.host = Some(state);
        if let Some(sp) = &mut self.status.sparkplug {
            sp.host_online = Some(online_now);
        }
        match (online_now, online.node_born) {
            (true, false) => {
                tracing::info!("the primary host application is online: births");
                self.births(online);
                None
            }
            (false, true) => {
                tracing::warn!("the primary host application went offline: NDEATH, reconnecting");
                Some(Ended::HostOffline)
            }
            _ => None,
        }
    }

    /// NCMD: `Node Control/Rebirth` re-sends NBIRTH and every DBIRTH, same `bdSeq`, no
    /// death before.
    fn node_command(&mut self, online: &mut Online, payload: &[u8]) {
        let commands = match sparkplug::commands(payload) {
            Ok(c) => c,
            Err(e) => {
                self.refused("NCMD", Refused::invalid_body(e.to_string()));
                return;
            }
        };
        for c in commands {
            let is_rebirth = c.name.as_deref() == Some(sparkplug::REBIRTH)
                || (c.name.is_none() && c.alias == Some(1));
            if is_rebirth && c.value == Some(serde_json::Value::Bool(true)) {
                if online.node_born {
                    tracing::info!("Sparkplug rebirth requested");
                    if let Some(sp) = &mut self.status.sparkplug {
                        sp.rebirths += 1;
                    }
                    self.births(online);
                }
            } else {
                let name = c
                    .name
                    .unwrap_or_else(|| format!("alias {}", c.alias.unwrap_or(0)));
                self.refused("NCMD", Refused::unknown_metric(&name));
            }
        }
    }

    /// DCMD: each metric is a write through the service (the same checks as REST).
    fn device_command(&mut self, device: &str, payload: &[u8]) {
        let commands = match sparkplug::commands(payload) {
            Ok(c) => c,
            Err(e) => {
                self.refused(device, Refused::invalid_body(e.to_string()));
                return;
            }
        };
        if !self.prepared.may(Operation::WriteOutputs) {
            self.refused(device, Refused::not_enabled());
            return;
        }
        let d = match self.service.device(device) {
            Ok(d) => d,
            Err(e) => {
                self.refused(device, e.into());
                return;
            }
        };
        let n = d.profile.fields.len();
        let base = self.aliases.base(device, n);
        for c in commands {
            let field = match (&c.name, c.alias) {
                (Some(name), _) => name.clone(),
                (None, Some(alias)) if alias >= base && alias < base + n as u64 => {
                    d.field((alias - base) as usize).name.clone()
                }
                (None, alias) => {
                    self.refused(device, Refused::unknown_alias(alias.unwrap_or(0)));
                    continue;
                }
            };
            let Some(value) = c.value else {
                let why = format!("{field}: the metric has no value");
                self.refused(device, Refused::invalid_body(why));
                continue;
            };
            let accepted = self
                .service
                .prepare(&d, &field, |ty| convert::json_to_value(ty, &value))
                .map_err(crate::service::ServiceError::from)
                .and_then(|w| self.service.write(w));
            match accepted {
                Ok(a) => {
                    self.status.writes_accepted += 1;
                    tracing::info!(
                        device,
                        field,
                        generation = a.generation,
                        "Sparkplug DCMD write accepted"
                    );
                }
                Err(e) => self.refused(device, e.into()),
            }
        }
    }

    /// A Sparkplug command to `target` (a device, or `NCMD`) refused: counted and logged with
    /// its kind and code (it has no answer topic).
    fn refused(&mut self, target: &str, refused: Refused) {
        self.status.writes_refused += 1;
        tracing::warn!(
            target_ = target,
            kind = refused.kind_name(),
            code = refused.code,
            reason = %refused.message,
            "MQTT command refused"
        );
    }

    /// The timer: followed writes, the buffer's sync, the shared status.
    fn tick(&mut self, online: Option<&mut Online>) {
        if let Some(b) = &mut self.buffer
            && let Err(e) = b.tick()
        {
            tracing::warn!(error = %e, "MQTT: the buffer cannot be synced");
        }
        if let Some(online) = online {
            if let Some(json) = self.json().cloned() {
                let outs = self.followed_outcomes(&Topics(&json), &json, &mut online.followed);
                online.outbox.extend(outs.into_iter().map(Item::Plain));
            }
            if let Some(sp) = &mut self.status.sparkplug {
                sp.born = online.node_born;
                sp.born_devices = online.born.len();
            }
        }
        self.publish_status();
    }

    /// Copies the counters and the buffer's state into the shared status.
    fn publish_status(&mut self) {
        if let Some(b) = &self.buffer {
            let s = b.stats();
            self.status.buffer.messages = s.depth;
            self.status.buffer.bytes = s.bytes;
            self.status.buffer.oldest_age_s = s.oldest_age_s;
            self.status.buffer.dropped = s.dropped + self.lost;
        } else {
            self.status.buffer.dropped = self.lost;
        }
        let connected = self.status.connected;
        if let Some(sp) = &mut self.status.sparkplug {
            sp.bd_seq = self.bd_seq;
            if !connected {
                sp.born = false;
                sp.born_devices = 0;
            }
        }
        let status = self.status.clone();
        self.state.update(|s| *s = status);
    }

    /// A write from `<prefix>/<device>/<field>/set`: the same JSON, checks and answers as
    /// `PUT /api/v1/devices/{device}/fields/{field}`; the answer goes to `.../set/result`.
    fn set(
        &mut self,
        topics: &Topics<'_>,
        topic: &str,
        payload: &[u8],
        followed: &mut VecDeque<(u64, String, String)>,
    ) -> Option<Out> {
        let json = topics.0;
        let (device, field) = topics.parse_set(topic)?;
        let result_topic = format!("{topic}/result");
        let refused = |e: Refused| {
            tracing::info!(device, field, kind = e.kind_name(), code = e.code, error = %e.message, "MQTT write refused");
            Out {
                topic: result_topic.clone(),
                payload: serde_json::to_vec(&SetRefused {
                    device,
                    field,
                    error: super::error::ErrorDetail {
                        code: e.code.to_owned(),
                        message: e.message,
                    },
                })
                .unwrap_or_default(),
                qos: json.qos,
                retain: false,
            }
        };
        if !self.prepared.may(Operation::WriteOutputs) {
            self.status.writes_refused += 1;
            return Some(refused(Refused::not_enabled()));
        }
        let accepted = (|| -> Result<_, Refused> {
            let body: serde_json::Value = serde_json::from_slice(payload)
                .map_err(|e| Refused::invalid_body(format!("the payload is not JSON: {e}")))?;
            let value = super::rest::value_of(body);
            let d = self.service.device(device)?;
            let write = self
                .service
                .prepare(&d, field, |ty| convert::json_to_value(ty, &value))?;
            Ok(self.service.write(write)?)
        })();
        match accepted {
            Err(e) => {
                self.status.writes_refused += 1;
                Some(refused(e))
            }
            Ok(a) => {
                self.status.writes_accepted += 1;
                if followed.len() >= MAX_FOLLOWED_WRITES {
                    followed.pop_front();
                }
                followed.push_back((a.generation, a.device.clone(), a.field.clone()));
                Some(Out {
                    topic: result_topic,
                    payload: serde_json::to_vec(&SetResult {
                        device: &a.device,
                        field: &a.field,
                        generation: a.generation,
                        status: WriteStatus::Pending.name(),
                        error: None,
                    })
                    .unwrap_or_default(),
                    qos: json.qos,
                    retain: false,
                })
            }
        }
    }

    /// The final outcomes of followed writes that have one.
    fn followed_outcomes(
        &self,
        topics: &Topics<'_>,
        json: &JsonConfig,
        followed: &mut VecDeque<(u64, String, String)>,
    ) -> Vec<Out> {
        let mut outs = Vec::new();
        followed.retain(|(generation, device, field)| {
            let Ok(record) = self.service.write_outcome(*generation) else {
                return false;
            };
            if record.status == WriteStatus::Pending {
                return true;
            }
            outs.push(Out {
                topic: format!("{}/result", topics.field(device, field) + "/set"),
                payload: serde_json::to_vec(&SetResult {
                    device,
                    field,
                    generation: *generation,
                    status: record.status.name(),
                    error: record.error.clone(),
                })
                .unwrap_or_default(),
                qos: json.qos,
                retain: false,
            });
            false
        });
        outs
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

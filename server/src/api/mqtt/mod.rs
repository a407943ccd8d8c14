//! The MQTT front-end: the gateway publishes into one broker. Plain JSON topics
//! (`<prefix>/<device>/<field>` with the JSON of `GET .../fields/{field}`, retained;
//! `<prefix>/<device>/$state` with the device's diagnostics; `<prefix>/$state` with the
//! gateway's own, `{"online": false}` as its Will) and writes on `<prefix>/<device>/<field>/set`
//! answered on `.../set/result`. Values are reported by exception (`report.rs`).
//!
//! Like every front-end it only renders the service: the values and views, the write
//! checks and outcomes are the service's; `writes: true` is this front-end's role (write).

mod buffer;
mod conn;
mod packet;
mod report;

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use futures_util::StreamExt;
use serde::Serialize;
use tokio::time::Instant;
use tokio_util::sync::CancellationToken;

use super::convert::{self, DiagnosticsEvent, field_value};
use super::error::ApiError;
use crate::cache::Device;
use crate::config::mqtt::{JsonConfig, MqttConfig, Password};
use crate::service::{Change, Service};
use crate::write_log::WriteStatus;
use conn::{ConnError, Connection, TlsSetup};
use packet::{Connect, Incoming, Will};
use report::{Decision, Reporter};

/// Waits between attempts to connect: doubling from the first to the last.
const RECONNECT_MIN: Duration = Duration::from_millis(500);
const RECONNECT_MAX: Duration = Duration::from_secs(30);
/// Writes from `/set` whose final outcome is still to be published, at most.
const MAX_FOLLOWED_WRITES: usize = 1024;
/// How often followed writes are looked at.
const FOLLOW_EVERY: Duration = Duration::from_millis(50);

/// What `GET /api/v1/mqtt` shows.
#[derive(Debug, Clone, Default, Serialize, utoipa::ToSchema)]
pub(crate) struct MqttStatus {
    pub(crate) broker: String,
    pub(crate) connected: bool,
    /// Why the last connection failed or ended.
    pub(crate) last_error: Option<String>,
    pub(crate) reconnects: u64,
    pub(crate) messages_out: u64,
    pub(crate) bytes_out: u64,
    pub(crate) messages_in: u64,
    /// Writes refused (bad topic, payload or value, or writes not enabled).
    pub(crate) writes_refused: u64,
}

/// The front-end's shared state: its status for the REST API and `/readyz`.
#[derive(Debug, Default)]
pub(crate) struct Mqtt {
    status: Mutex<MqttStatus>,
}

impl Mqtt {
    pub(crate) fn status(&self) -> MqttStatus {
        self.status
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }

    fn update(&self, f: impl FnOnce(&mut MqttStatus)) {
        f(&mut self.status.lock().unwrap_or_else(|e| e.into_inner()));
    }
}

/// What the front-end needs from the files its section names, read once at start.
pub(crate) struct Prepared {
    config: MqttConfig,
    password: Option<Vec<u8>>,
    tls: Option<TlsSetup>,
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
    Ok(Prepared {
        config: config.clone(),
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
    /// The device and field a `/set` topic names.
    fn parse_set<'t>(&self, topic: &'t str) -> Option<(&'t str, &'t str)> {
        let rest = topic
            .strip_prefix(self.0.prefix.as_str())?
            .strip_prefix('/')?;
        let rest = rest.strip_suffix("/set")?;
        let (device, field) = rest.split_once('/')?;
        (!field.contains('/')).then_some((device, field))
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

/// Starts the front-end's task; it runs until the gateway shuts down.
pub(crate) fn spawn(service: Arc<Service>, prepared: Prepared) -> Arc<Mqtt> {
    tracing::info!(broker = %prepared.config.url, "publishing to MQTT");
    let mqtt = Arc::new(Mqtt::default());
    mqtt.update(|s| s.broker = prepared.config.url.to_string());
    let token = service.tasks().token().clone();
    let task = Task {
        service: service.clone(),
        mqtt: mqtt.clone(),
        prepared,
    };
    service.tasks().spawn(task.run(token));
    mqtt
}

struct Task {
    service: Arc<Service>,
    mqtt: Arc<Mqtt>,
    prepared: Prepared,
}

/// A publish the session loop sends.
struct Out {
    topic: String,
    payload: Vec<u8>,
    qos: u8,
    retain: bool,
}

impl Task {
    fn connect_packet(&self) -> Connect {
        let config = &self.prepared.config;
        let will = config.json.as_ref().map(|json| Will {
            topic: Topics(json).gateway_state(),
            payload: state_payload(false),
            qos: json.qos,
            retain: true,
        });
        Connect {
            client_id: config.client_id.clone(),
            keep_alive: config.keep_alive.as_secs().min(u64::from(u16::MAX)) as u16,
            clean_start: config.clean_start,
            username: config.username.clone(),
            password: self.prepared.password.clone(),
            will,
        }
    }

    async fn run(self, token: CancellationToken) {
        let config = self.prepared.config.clone();
        let mut wait = RECONNECT_MIN;
        let mut first = true;
        loop {
            let connect = self.connect_packet();
            let opened = tokio::select! {
                _ = token.cancelled() => return,
                r = Connection::open(&config, self.prepared.tls.as_ref(), &connect) => r,
            };
            match opened {
                Ok(conn) => {
                    if !first {
                        self.mqtt.update(|s| s.reconnects += 1);
                    }
                    first = false;
                    wait = RECONNECT_MIN;
                    tracing::info!(broker = %config.url, "MQTT connected");
                    self.mqtt.update(|s| {
                        s.connected = true;
                        s.last_error = None;
                    });
                    let ended = self.session(conn, &token).await;
                    self.mqtt.update(|s| s.connected = false);
                    match ended {
                        Ok(()) => return,
                        Err(e) => {
                            tracing::warn!(broker = %config.url, error = %e, "MQTT connection lost");
                            self.mqtt.update(|s| s.last_error = Some(e.to_string()));
                        }
                    }
                }
                Err(e) => {
                    tracing::warn!(broker = %config.url, error = %e, retry_in = ?wait, "cannot connect to the MQTT broker");
                    self.mqtt.update(|s| s.last_error = Some(e.to_string()));
                }
            }
            tokio::select! {
                _ = token.cancelled() => return,
                _ = tokio::time::sleep(wait) => {}
            }
            wait = (wait * 2).min(RECONNECT_MAX);
        }
    }

    async fn send(&self, conn: &mut Connection, out: Out) -> Result<(), ConnError> {
        let len = out.payload.len() as u64;
        conn.publish(&out.topic, &out.payload, out.qos, out.retain, 0)
            .await?;
        self.mqtt.update(|s| {
            s.messages_out += 1;
            s.bytes_out += len;
        });
        Ok(())
    }

    /// One connection: subscribe, publish every current value, then each change, until the
    /// connection ends (`Err`) or the gateway shuts down (`Ok`).
    async fn session(
        &self,
        mut conn: Connection,
        token: &CancellationToken,
    ) -> Result<(), ConnError> {
        let config = &self.prepared.config;
        let Some(json) = &config.json else {
            // Sparkplug only: nothing else is published yet.
            token.cancelled().await;
            conn.disconnect().await;
            return Ok(());
        };
        let topics = Topics(json);
        // Commands first, so that a write sent right after the state is not missed; again
        // after every reconnect (a clean session forgets them).
        if config.writes {
            conn.subscribe(&[(topics.set_filter(), 1)]).await?;
        }
        self.send(
            &mut conn,
            Out {
                topic: topics.gateway_state(),
                payload: state_payload(true),
                qos: json.qos,
                retain: true,
            },
        )
        .await?;
        let devices: Vec<Arc<Device>> = self.service.devices();
        let names: Vec<&str> = devices.iter().map(|d| d.name()).collect();
        let selection = self
            .service
            .select::<_, &str>(&names, &[])
            .map_err(|e| ConnError::Io(std::io::Error::other(e.to_string())))?;
        let mut changes = self
            .service
            .subscribe(selection, true)
            .map_err(|e| ConnError::Io(std::io::Error::other(e.to_string())))?;
        let mut reporter = Reporter::new(config.report.clone());
        let mut followed: VecDeque<(u64, String, String)> = VecDeque::new();
        let mut follow = tokio::time::interval(FOLLOW_EVERY);
        loop {
            let keep_alive = conn.keep_alive_due();
            tokio::select! {
                _ = token.cancelled() => {
                    let _ = self.send(&mut conn, Out {
                        topic: topics.gateway_state(),
                        payload: state_payload(false),
                        qos: json.qos,
                        retain: true,
                    }).await;
                    conn.disconnect().await;
                    return Ok(());
                }
                packet = conn.read() => match packet? {
                    Incoming::PubAck { pkid, .. } => { conn.acked(pkid); }
                    Incoming::Publish(p) => {
                        self.mqtt.update(|s| s.messages_in += 1);
                        if p.qos > 0 {
                            conn.puback(p.pkid).await?;
                        }
                        if let Some(out) = self.set(&topics, &p.topic, &p.payload, &mut followed) {
                            self.send(&mut conn, out).await?;
                        }
                    }
                    Incoming::SubAck { codes, .. } => {
                        if codes.iter().any(|&c| c >= 0x80) {
                            tracing::warn!(filter = %topics.set_filter(), "the broker refused the subscription to writes");
                        }
                    }
                    _ => {}
                },
                _ = async { match keep_alive { Some(at) => tokio::time::sleep_until(at).await, None => std::future::pending().await } } => {
                    conn.keep_alive().await?;
                }
                change = changes.next(), if conn.can_publish() => {
                    let Some(change) = change else {
                        // The gateway is shutting down: the token ends the session.
                        token.cancelled().await;
                        continue;
                    };
                    if let Some(out) = self.on_change(&topics, json, &change, &devices, &mut reporter) {
                        self.send(&mut conn, out).await?;
                    }
                }
                key = reporter.due(), if conn.can_publish() => {
                    if let Some(device) = devices.get(key.0) {
                        let out = self.field_out(&topics, json, device, key.1, &mut reporter);
                        self.send(&mut conn, out).await?;
                    }
                }
                _ = follow.tick(), if !followed.is_empty() && conn.can_publish() => {
                    for out in self.followed_outcomes(&topics, json, &mut followed) {
                        self.send(&mut conn, out).await?;
                    }
                }
            }
        }
    }

    fn field_out(
        &self,
        topics: &Topics<'_>,
        json: &JsonConfig,
        device: &Device,
        idx: usize,
        reporter: &mut Reporter,
    ) -> Out {
        let view = self.service.field_view_now(device, idx);
        let key = (self.position(device), idx);
        reporter.sent(key, view.value.as_ref(), view.quality, Instant::now());
        Out {
            topic: topics.field(device.name(), &view.field.name),
            payload: serde_json::to_vec(&field_value(&view)).unwrap_or_default(),
            qos: json.qos,
            retain: json.retain,
        }
    }

    fn position(&self, device: &Device) -> usize {
        self.service
            .devices()
            .iter()
            .position(|d| std::ptr::eq(d.as_ref(), device))
            .unwrap_or(usize::MAX)
    }

    fn on_change(
        &self,
        topics: &Topics<'_>,
        json: &JsonConfig,
        change: &Change,
        devices: &[Arc<Device>],
        reporter: &mut Reporter,
    ) -> Option<Out> {
        match change {
            Change::Value {
                device,
                idx,
                sample,
            } => {
                let position = devices.iter().position(|d| Arc::ptr_eq(d, device))?;
                let view = self.service.field_view(device, *idx, sample);
                let deadband = None;
                match reporter.change(
                    (position, *idx),
                    view.value.as_ref(),
                    view.quality,
                    deadband,
                    Instant::now(),
                ) {
                    Decision::Send => {
                        reporter.sent(
                            (position, *idx),
                            view.value.as_ref(),
                            view.quality,
                            Instant::now(),
                        );
                        Some(Out {
                            topic: topics.field(device.name(), &view.field.name),
                            payload: serde_json::to_vec(&field_value(&view)).unwrap_or_default(),
                            qos: json.qos,
                            retain: json.retain,
                        })
                    }
                    Decision::Skip | Decision::Hold => None,
                }
            }
            Change::Diagnostics {
                device,
                diagnostics: d,
            } => Some(Out {
                topic: topics.device_state(device.name()),
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
            }),
        }
    }

    /// A write from `<prefix>/<device>/<field>/set`: the same JSON, checks and answers as
    /// `PUT /api/v1/devices/{device}/fields/{field}`; the answer goes to `.../set/result`.
    fn set(
        &self,
        topics: &Topics<'_>,
        topic: &str,
        payload: &[u8],
        followed: &mut VecDeque<(u64, String, String)>,
    ) -> Option<Out> {
        let json = topics.0;
        let (device, field) = topics.parse_set(topic)?;
        let result_topic = format!("{topic}/result");
        let refused = |e: ApiError| {
            self.mqtt.update(|s| s.writes_refused += 1);
            tracing::info!(device, field, error = %e.message, "MQTT write refused");
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
        if !self.prepared.config.writes {
            return Some(refused(ApiError::new(
                axum::http::StatusCode::FORBIDDEN,
                "forbidden",
                "writes over MQTT are not enabled (mqtt.writes)",
            )));
        }
        let accepted = (|| -> Result<_, ApiError> {
            let body: serde_json::Value = serde_json::from_slice(payload).map_err(|e| {
                ApiError::bad_request("invalid_body", format!("the payload is not JSON: {e}"))
            })?;
            let value = super::rest::value_of(body);
            let d = self.service.device(device)?;
            let write = self
                .service
                .prepare(&d, field, |ty| convert::json_to_value(ty, &value))?;
            Ok(self.service.write(write)?)
        })();
        match accepted {
            Err(e) => Some(refused(e)),
            Ok(a) => {
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

fn state_payload(online: bool) -> Vec<u8> {
    serde_json::to_vec(&GatewayState {
        online,
        version: env!("CARGO_PKG_VERSION"),
    })
    .unwrap_or_default()
}

//! What the broker brings the MQTT front-end: the primary host's STATE, NCMD and DCMD
//! writes, `/set` writes and their results; every refusal from its one table
//! (`refusal.rs`).

use super::*;

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
    error: crate::api::error::ErrorDetail,
}

impl Task {
    /// A packet from the broker.
    pub(super) async fn incoming(
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
                return Ok(self.command(online, &p.topic, &p.payload, p.retain).await);
            }
            Incoming::Dropped { why, topic, .. } => {
                self.status.dropped_in += 1;
                if self.said.may() {
                    tracing::warn!(error = %why, topic = %crate::text::quote(topic.as_deref().unwrap_or("-")), "a packet from the broker read past and dropped");
                }
            }
            Incoming::SubAck { codes, .. } if codes.iter().any(|&c| c >= 0x80) => {
                tracing::warn!("the broker refused a subscription (commands or writes)");
            }
            _ => {}
        }
        Ok(None)
    }

    /// A message on a subscribed topic: a write, a Sparkplug command, or the host's STATE.
    /// A write or command the broker delivers as retained is a stored message, not a
    /// command now: it is counted and not executed (the host's STATE is retained by design).
    pub(super) async fn command(
        &mut self,
        online: &mut Online,
        topic: &str,
        payload: &[u8],
        retained: bool,
    ) -> Option<Ended> {
        self.said.message();
        let host_state = self
            .spark
            .as_ref()
            .and_then(|t| t.host_state())
            .is_some_and(|s| s == topic);
        if retained && !host_state {
            self.retained(topic);
            return None;
        }
        if let Some(json) = self.json().cloned()
            && let Some(out) = self.set(&Topics(&json), topic, payload, &mut online.followed)
        {
            online.outbox.push_back(Item::Plain(out));
            return None;
        }
        let t = self.spark.as_ref()?;
        if host_state {
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

    /// A retained write or command: counted, the first one logged (with its topic, short).
    fn retained(&mut self, topic: &str) {
        self.status.retained_ignored += 1;
        let topic = crate::text::quote(topic);
        if self.status.retained_ignored == 1 && self.said.may() {
            tracing::warn!(topic = %topic, "a retained command or write is a stored message, not a command now: not executed (the next ones are counted in retained_ignored)");
        } else {
            tracing::debug!(topic = %topic, "a retained command or write: not executed");
        }
    }

    pub(super) fn host_state(&mut self, online: &mut Online, payload: &[u8]) -> Option<Ended> {
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
    /// death before; once per NCMD, and not again while the births are still to be sent.
    pub(super) fn node_command(&mut self, online: &mut Online, payload: &[u8]) {
        let commands = match sparkplug::commands(payload) {
            Ok(c) => c,
            Err(e) => {
                self.refused("NCMD", Refused::invalid_body(e.to_string()));
                return;
            }
        };
        let mut rebirth = false;
        for c in commands {
            let is_rebirth = c.name.as_deref() == Some(sparkplug::REBIRTH)
                || (c.name.is_none() && c.alias == Some(1));
            if is_rebirth && c.value == Some(serde_json::Value::Bool(true)) {
                rebirth = true;
            } else {
                let name = c
                    .name
                    .unwrap_or_else(|| format!("alias {}", c.alias.unwrap_or(0)));
                self.refused("NCMD", Refused::unknown_metric(&name));
            }
        }
        // However many Rebirth metrics, and however many NCMDs come while the births are
        // still to be sent: one rebirth.
        let pending = online.outbox.iter().any(|i| matches!(i, Item::NodeBirth));
        if rebirth && online.node_born && !pending {
            if self.said.may() {
                tracing::info!("Sparkplug rebirth requested");
            }
            if let Some(sp) = &mut self.status.sparkplug {
                sp.rebirths += 1;
            }
            self.births(online);
        }
    }

    /// DCMD: each metric is a write through the service (the same checks as REST).
    pub(super) fn device_command(&mut self, device: &str, payload: &[u8]) {
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
                let why = format!("{}: the metric has no value", crate::text::quote(&field));
                self.refused(device, Refused::invalid_body(why));
                continue;
            };
            let accepted = crate::api::rest::prepare_json(&self.service, &d, &field, &value)
                .map_err(crate::service::ServiceError::from)
                .and_then(|w| self.service.write(w));
            match accepted {
                Ok(a) => {
                    self.status.writes_accepted += 1;
                    if self.said.may() {
                        tracing::info!(
                            device,
                            field = %crate::text::quote(&field),
                            generation = a.generation,
                            "Sparkplug DCMD write accepted"
                        );
                    }
                }
                Err(e) => self.refused(device, e.into()),
            }
        }
    }

    /// A Sparkplug command to `target` (a device, or `NCMD`) refused: counted and logged with
    /// its kind and code (it has no answer topic).
    pub(super) fn refused(&mut self, target: &str, refused: Refused) {
        self.status.writes_refused += 1;
        if !self.said.may() {
            return;
        }
        tracing::warn!(
            target_ = %crate::text::quote(target),
            kind = refused.kind_name(),
            code = refused.code,
            reason = %refused.message,
            "MQTT command refused"
        );
    }

    /// A write from `<prefix>/<device>/<field>/set`: the same JSON, checks and answers as
    /// `PUT /api/v1/devices/{device}/fields/{field}`; the answer goes to `.../set/result`.
    pub(super) fn set(
        &mut self,
        topics: &Topics<'_>,
        topic: &str,
        payload: &[u8],
        followed: &mut VecDeque<(u64, String, String)>,
    ) -> Option<Out> {
        let json = topics.0;
        let (device, field) = topics.parse_set(topic)?;
        let result_topic = format!("{topic}/result");
        let refused = |e: Refused| Out {
            topic: result_topic.clone(),
            payload: serde_json::to_vec(&SetRefused {
                device,
                field,
                error: crate::api::error::ErrorDetail {
                    code: e.code.to_owned(),
                    message: e.message,
                    active: None,
                },
            })
            .unwrap_or_default(),
            qos: json.qos,
            retain: false,
        };
        if !self.prepared.may(Operation::WriteOutputs) {
            self.status.writes_refused += 1;
            self.tell_refused_write(device, field, &Refused::not_enabled());
            return Some(refused(Refused::not_enabled()));
        }
        let accepted = (|| -> Result<_, Refused> {
            let body: serde_json::Value = serde_json::from_slice(payload)
                .map_err(|e| Refused::invalid_body(format!("the payload is not JSON: {e}")))?;
            let value = crate::api::rest::value_of(body);
            let d = self.service.device(device)?;
            let write = crate::api::rest::prepare_json(&self.service, &d, field, &value)?;
            Ok(self.service.write(write)?)
        })();
        match accepted {
            Err(e) => {
                self.status.writes_refused += 1;
                self.tell_refused_write(device, field, &e);
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

    /// Logs a refused `/set` write, within the log's bound for clients' messages.
    fn tell_refused_write(&mut self, device: &str, field: &str, e: &Refused) {
        if self.said.may() {
            tracing::info!(device = %crate::text::quote(device), field = %crate::text::quote(field), kind = e.kind_name(), code = e.code, error = %e.message, "MQTT write refused");
        }
    }

    /// The final outcomes of followed writes that have one.
    pub(super) fn followed_outcomes(
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

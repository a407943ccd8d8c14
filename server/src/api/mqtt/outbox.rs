//! The MQTT front-end's outbox: sequence numbers and aliases, data records as messages (live,
//! or replayed from the buffer beside live data), tickets and the broker's confirmations.

use super::*;

impl Task {
    pub(super) fn ticket(&mut self) -> u64 {
        let t = self.next_ticket;
        self.next_ticket += 1;
        t
    }

    pub(super) async fn publish(
        &mut self,
        online: &mut Online,
        out: Out,
        tag: u64,
    ) -> Result<(), ConnError> {
        online
            .conn
            .publish(&out.topic, &out.payload, out.qos, out.retain, tag)
            .await?;
        self.status.messages_out += 1;
        self.status.bytes_out += out.payload.len() as u64;
        Ok(())
    }

    pub(super) fn next_seq(online: &mut Online) -> u8 {
        let s = online.seq;
        online.seq = online.seq.wrapping_add(1);
        s
    }

    /// The alias of a device's field in this gateway's births.
    pub(super) fn alias(&mut self, device: &str, field: &str) -> Option<u64> {
        let d = self.service.device(device).ok()?;
        let idx = d.field_index(field).ok()?;
        Some(self.aliases.base(device, d.profile.fields.len()) + idx as u64)
    }

    /// Publishes what waits, as far as the in-flight window allows.
    pub(super) async fn drain(&mut self, online: &mut Online) -> Result<(), ConnError> {
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
                    self.publish(online, Out::sparkplug(topic, payload), 0)
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
                    self.publish(online, Out::sparkplug(topic, payload), 0)
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
    pub(super) fn data_out(
        &mut self,
        online: &mut Online,
        record: &Record,
        historical: bool,
    ) -> Option<Out> {
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
                let payload = sparkplug::data_payload(now_ms(), seq, &metric, alias, historical);
                Some(Out::sparkplug(topic, payload))
            }
        }
    }

    /// Sends buffered records, at `replay_rate` and at most [`REPLAY_WINDOW`] unconfirmed,
    /// beside live data (which never waits for the replay).
    pub(super) async fn replay(&mut self, online: &mut Online) -> Result<(), ConnError> {
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
    pub(super) async fn replay_more(&mut self, online: &mut Online) -> Result<(), ConnError> {
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
    pub(super) fn take_confirmations(&mut self, online: &mut Online) {
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

    pub(super) fn confirm(&mut self, online: &mut Online, ticket: u64) {
        if let Ok(i) = online.live.binary_search_by_key(&ticket, |u| u.ticket) {
            let u = &mut online.live[i];
            u.confirmed = true;
            let latency = now_ms().saturating_sub(u.item.0.at_ms);
            self.state.metrics.observe_latency(latency as f64 / 1000.0);
        } else if let Ok(i) = online.replay.binary_search_by_key(&ticket, |u| u.ticket) {
            online.replay[i].confirmed = true;
        }
    }
}

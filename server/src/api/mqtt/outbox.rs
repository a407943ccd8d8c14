//! The MQTT front-end's outbox: sequence numbers and aliases, data records as messages (live,
//! or replayed from the buffer beside live data), tickets and the broker's confirmations.

use super::*;

/// The most live changes taken together into DDATA messages (one a device), and the most
/// bytes of one (less where the broker's Maximum Packet Size is less).
const BATCH: usize = 1000;
const BATCH_BYTES: usize = 64 * 1024;
/// A metric's bytes in a DDATA beyond its record's: its key and length, its alias.
const METRIC_OVERHEAD: usize = 16;

/// A device's changes taken into one DDATA.
struct Group {
    device: String,
    records: Vec<(Record, bool)>,
    bytes: usize,
    room: usize,
    /// A change did not fit: the device's later ones wait for the next message.
    full: bool,
}

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
        let sent = online
            .conn
            .publish(&out.topic, &out.payload, out.qos, out.retain, tag)
            .await?;
        if !sent {
            // Dropped, and counted so, rather than the connection ended for it by the broker.
            self.lost += 1;
            tracing::warn!(topic = %out.topic, bytes = out.payload.len(), most = online.conn.max_packet(), "MQTT: a message larger than the broker's Maximum Packet Size is not sent");
            return Ok(());
        }
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
                    online.births_waiting = online.births_waiting.saturating_sub(1);
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
                    if kind == "DBIRTH" {
                        online.births_waiting = online.births_waiting.saturating_sub(1);
                    }
                    let Some(t) = &self.spark else { continue };
                    let topic = t.device(kind, &device);
                    let seq = Self::next_seq(online);
                    let payload = sparkplug::encode(now_ms(), Some(seq), metrics);
                    self.publish(online, Out::sparkplug(topic, payload), 0)
                        .await?;
                }
                Item::Data { record, change } if record.kind == Kind::Sparkplug => {
                    self.spark_batch(online, (record, change)).await?;
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

    /// The live Sparkplug changes waiting from `first` on (up to [`BATCH`] of them and
    /// [`BATCH_BYTES`]), one DDATA a device (a host takes an edge node's scan of a device as one
    /// message, not one a field; a device's metrics keep their order). Each record is
    /// tracked under its message's ticket; what the in-flight window has no room for goes
    /// back to the outbox's front, in order.
    async fn spark_batch(
        &mut self,
        online: &mut Online,
        first: (Record, bool),
    ) -> Result<(), ConnError> {
        let max_packet = online.conn.max_packet();
        let Some(spark) = self.spark.as_ref() else {
            return Ok(());
        };
        let mut groups: Vec<Group> = Vec::new();
        // Whether a change is taken into its device's message: not once that one is full
        // (then the device's later changes wait too, so a field's changes keep their order).
        let take = |(record, change): (Record, bool), groups: &mut Vec<Group>| {
            let cost = record.payload.len() + METRIC_OVERHEAD;
            let at = match groups.iter().position(|g| g.device == record.device) {
                Some(at) => at,
                None => {
                    let topic = spark.device("DDATA", &record.device).len();
                    groups.push(Group {
                        device: record.device.clone(),
                        records: Vec::new(),
                        bytes: 0,
                        room: BATCH_BYTES.min(max_packet.saturating_sub(topic + 64)),
                        full: false,
                    });
                    groups.len() - 1
                }
            };
            let g = &mut groups[at];
            g.full |= !g.records.is_empty() && g.bytes + cost > g.room;
            if g.full {
                return Some((record, change));
            }
            g.bytes += cost;
            g.records.push((record, change));
            None
        };
        let _ = take(first, &mut groups);
        // The changes behind it, passing over JSON messages (they keep their order) up to
        // a Sparkplug message of another kind (a birth or a death keeps its place).
        let scan = online
            .outbox
            .iter()
            .take(4 * BATCH)
            .position(|i| matches!(i, Item::Spark { .. } | Item::NodeBirth))
            .unwrap_or(online.outbox.len().min(4 * BATCH));
        let mut taken = 1;
        let mut others = Vec::new();
        for item in online.outbox.drain(..scan) {
            match item {
                Item::Data { record, change }
                    if record.kind == Kind::Sparkplug && taken < BATCH =>
                {
                    match take((record, change), &mut groups) {
                        None => taken += 1,
                        Some((record, change)) => others.push(Item::Data { record, change }),
                    }
                }
                other => others.push(other),
            }
        }
        for item in others.into_iter().rev() {
            online.outbox.push_front(item);
        }
        let mut groups = groups.into_iter().map(|g| (g.device, g.records));
        while let Some((device, records)) = groups.next() {
            if !online.conn.can_publish() {
                let back: Vec<(Record, bool)> = std::iter::once(records)
                    .chain(groups.map(|(_, r)| r))
                    .flatten()
                    .collect();
                for (record, change) in back.into_iter().rev() {
                    online.outbox.push_front(Item::Data { record, change });
                }
                break;
            }
            self.device_data(online, &device, records).await?;
        }
        Ok(())
    }

    /// One DDATA of a device's live changes.
    async fn device_data(
        &mut self,
        online: &mut Online,
        device: &str,
        records: Vec<(Record, bool)>,
    ) -> Result<(), ConnError> {
        if !online.node_born || !online.born.contains(device) {
            return Ok(());
        }
        let Some(topic) = self.spark.as_ref().map(|t| t.device("DDATA", device)) else {
            return Ok(());
        };
        // A record whose field is gone is not sent.
        let kept: Vec<((Record, bool), u64)> = records
            .into_iter()
            .filter_map(|(record, change)| {
                let alias = self.alias(&record.device, &record.field)?;
                Some(((record, change), alias))
            })
            .collect();
        let metrics: Vec<_> = kept
            .iter()
            .filter_map(|((r, _), alias)| Some((sparkplug::sendable(&r.payload)?, *alias)))
            .collect();
        if metrics.is_empty() {
            return Ok(());
        }
        let refs: Vec<(&[u8], u64)> = metrics.iter().map(|(m, a)| (m.as_ref(), *a)).collect();
        let seq = Self::next_seq(online);
        let payload = sparkplug::data_payload_of(now_ms(), seq, &refs, false);
        drop(metrics);
        let ticket = self.ticket();
        self.publish(online, Out::sparkplug(topic, payload), ticket)
            .await?;
        for (item, _) in kept {
            online.live.push_back(Unconfirmed {
                ticket,
                item,
                confirmed: false,
            });
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
        // Sparkplug records wait for the births to be sent (and the host).
        if self.spark.is_some() && (!online.node_born || online.births_waiting > 0) {
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
        if self.spark.is_some() && (!online.node_born || online.births_waiting > 0) {
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
        // Every record of the message (a DDATA carries a device's changes together).
        let from = online.live.partition_point(|u| u.ticket < ticket);
        let mut live = false;
        for u in online.live.range_mut(from..) {
            if u.ticket != ticket {
                break;
            }
            u.confirmed = true;
            live = true;
            let latency = now_ms().saturating_sub(u.item.0.at_ms);
            self.state.metrics.observe_latency(latency as f64 / 1000.0);
        }
        if !live && let Ok(i) = online.replay.binary_search_by_key(&ticket, |u| u.ticket) {
            online.replay[i].confirmed = true;
        }
    }
}

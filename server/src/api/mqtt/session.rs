//! The MQTT front-end's connection loop: connect with back-off, a session's start (births,
//! state, subscriptions), changes and packets as they come, the timer, a clean stop; the
//! only part that waits on the broker.

use super::*;

/// What a session waits on beside its connection, kept across connections.
pub(super) struct Inputs {
    changes: Option<crate::service::Changes>,
    devices_changed: tokio::sync::watch::Receiver<u64>,
    /// Followed writes, the buffer's sync and the shared status.
    timer: tokio::time::Interval,
    token: CancellationToken,
    /// The gateway's role in its pair: only the active (or a gateway alone) connects.
    lease: tokio::sync::watch::Receiver<crate::role::Lease>,
}

impl Task {
    pub(super) async fn run(mut self, token: CancellationToken) {
        let mut inputs = Inputs {
            devices_changed: self.service.watch_devices(),
            changes: self.subscribe(),
            timer: tokio::time::interval(FOLLOW_EVERY),
            token,
            lease: self.service.tasks().role().watch(),
        };
        let mut wait = Duration::ZERO;
        let mut first = true;
        loop {
            self.keep_bd_seq();
            let Some(opened) = self.offline(wait, &mut inputs).await else {
                self.stop(None).await;
                return;
            };
            let url = &self.prepared.config.url;
            match opened {
                Ok(conn) => {
                    if !first {
                        self.status.reconnects += 1;
                    }
                    first = false;
                    match self.online(conn, &mut inputs).await {
                        Some(again) => wait = again,
                        None => return,
                    }
                }
                Err(e) => {
                    wait = (wait * 2).clamp(RECONNECT_MIN, self.prepared.config.reconnect_max);
                    tracing::warn!(broker = %url, error = %e, retry_in = ?wait, "cannot connect to the MQTT broker");
                    self.status.last_error = Some(e.to_string());
                    // The CONNECT may have reached the broker (a lost CONNACK): its Will,
                    // published later, must not carry the next session's bdSeq. One that
                    // was never sent (no TCP or TLS connection) takes no number.
                    if e.connect_sent() {
                        self.next_bd_seq();
                    }
                }
            }
            self.publish_status();
        }
    }

    /// Offline: connects after `wait` (with jitter) while changes go to the buffer; `None`
    /// when the gateway stops first.
    async fn offline(
        &mut self,
        wait: Duration,
        inputs: &mut Inputs,
    ) -> Option<Result<Connection, ConnError>> {
        let role = self.service.tasks().role().clone();
        if !role.owns_field() {
            self.meanwhile(role.owning(), inputs).await?;
            // The pair's one edge node: born again with the session after the old active's.
            if let Some(bd_seq) = role.take_heard_edge_session() {
                self.bd_seq = bd_seq.wrapping_add(1);
                self.keep_bd_seq();
            }
        }
        let connect = self.connect_packet();
        let (config, tls) = (self.prepared.config.clone(), self.prepared.tls.clone());
        let delay = jittered(wait);
        let attempt = async {
            tokio::time::sleep(delay).await;
            Connection::open(&config, tls.as_ref(), &connect).await
        };
        self.meanwhile(attempt, inputs).await
    }

    /// Runs `attempt` while changes go to the buffer; `None` when the gateway stops first.
    async fn meanwhile<T>(
        &mut self,
        attempt: impl std::future::Future<Output = T>,
        inputs: &mut Inputs,
    ) -> Option<T> {
        tokio::pin!(attempt);
        loop {
            tokio::select! {
                _ = inputs.token.cancelled() => return None,
                r = &mut attempt => return Some(r),
                change = next_change(&mut inputs.changes) => match change {
                    Some(change) => self.on_change(change, None),
                    None => inputs.changes = None,
                },
                key = self.reporter.due() => self.heartbeat(key, None),
                _ = inputs.devices_changed.changed() => {
                    inputs.changes = self.subscribe();
                    self.devices_changed(None);
                }
                _ = inputs.timer.tick() => self.tick(None),
            }
        }
    }

    /// Connected: the session until it ends; the wait before the next connection, or
    /// `None` when the gateway stops.
    async fn online(&mut self, conn: Connection, inputs: &mut Inputs) -> Option<Duration> {
        let url = self.prepared.config.url.clone();
        tracing::info!(broker = %url, bd_seq = self.bd_seq, "MQTT connected");
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
            births_waiting: 0,
            born: HashSet::new(),
            seq: 0,
            host: None,
            followed: VecDeque::new(),
        };
        let ended = self.session(&mut online, inputs).await;
        self.status.connected = false;
        self.connection_ended(&mut online);
        let wait = match ended {
            Ended::Shutdown => {
                self.stop(Some(online)).await;
                return None;
            }
            Ended::Lost(e) => {
                tracing::warn!(broker = %url, error = %e, "MQTT connection lost");
                self.status.last_error = Some(e.to_string());
                RECONNECT_MIN
            }
            Ended::StoodDown => {
                tracing::info!(broker = %url, "MQTT: the gateway stood down in its pair: NDEATH, disconnected");
                self.node_death(&mut online).await;
                online.conn.disconnect().await;
                self.status.last_error = Some("standby: the active of the pair publishes".into());
                Duration::ZERO
            }
            Ended::HostOffline => {
                self.node_death(&mut online).await;
                online.conn.disconnect().await;
                self.status.last_error = Some("the primary host application went offline".into());
                Duration::ZERO
            }
        };
        self.next_bd_seq();
        Some(wait)
    }

    /// The next connection's `bdSeq` (0-255, wrapping).
    pub(super) fn next_bd_seq(&mut self) {
        self.bd_seq = self.bd_seq.wrapping_add(1);
    }

    /// Writes the `bdSeq` of the CONNECT about to be sent beside the buffer (replacing the
    /// file at once), so that after a restart, even a kill, the next one differs from it:
    /// a late NDEATH from the Will of a killed connection is never taken for the new one's.
    pub(super) fn keep_bd_seq(&mut self) {
        self.service.tasks().role().set_edge_session(self.bd_seq);
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
    pub(super) async fn stop(&mut self, online: Option<Online>) {
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
    pub(super) async fn node_death(&self, online: &mut Online) {
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
    pub(super) fn connection_ended(&mut self, online: &mut Online) {
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
        online.births_waiting = 0;
        if let Some(b) = &mut self.buffer {
            b.rewind();
        }
        if let Some(sp) = &mut self.status.sparkplug {
            sp.born = false;
            sp.born_devices = 0;
        }
    }

    /// Keeps a data message for later (or counts it lost when there is no buffer).
    pub(super) fn keep(&mut self, record: Record) {
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

    pub(super) async fn session(&mut self, online: &mut Online, inputs: &mut Inputs) -> Ended {
        match self.start_session(online).await {
            Ok(()) => {}
            Err(e) => return Ended::Lost(e),
        }
        let mut replay_timer = tokio::time::interval(REPLAY_EVERY);
        loop {
            // Send what can be sent, then wait for the next event.
            let sent: Result<(), ConnError> = async {
                self.drain(online).await?;
                online.conn.barrier().await?;
                online.conn.flush().await
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
                _ = inputs.token.cancelled() => Event::Shutdown,
                // Changes before the broker's packets: a burst's acknowledgements do not
                // hold back its later changes (the window's own bound, `can_take`, lets the
                // acknowledgements in when publishing has to wait for them).
                change = next_change(&mut inputs.changes), if can_take => Event::Change(change),
                packet = online.conn.read() => Event::Packet(packet),
                _ = sleep_until(keep_alive) => Event::KeepAlive,
                key = self.reporter.due(), if can_take => Event::Due(key),
                _ = inputs.devices_changed.changed() => Event::Devices,
                _ = replay_timer.tick(), if replaying => Event::Replay,
                _ = inputs.timer.tick() => Event::Timer,
                _ = inputs.lease.changed() => Event::Role,
            };
            match self.handle(online, inputs, event).await {
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

    /// One event of a session; `Some` when it ends the session.
    async fn handle(
        &mut self,
        online: &mut Online,
        inputs: &mut Inputs,
        event: Event,
    ) -> Result<Option<Ended>, ConnError> {
        match event {
            Event::Shutdown => return Ok(Some(Ended::Shutdown)),
            Event::Packet(Ok(p)) => return self.packets(online, p).await,
            Event::Packet(Err(e)) => return Err(e),
            Event::KeepAlive => online.conn.keep_alive().await?,
            Event::Change(Some(change)) => {
                self.on_change(change, Some(online));
                self.ready_changes(online, inputs).await;
            }
            Event::Change(None) => inputs.changes = None,
            Event::Due(key) => self.heartbeat(key, Some(online)),
            Event::Devices => {
                inputs.changes = self.subscribe();
                self.devices_changed(Some(online));
            }
            Event::Replay => self.replay(online).await?,
            Event::Timer => self.tick(Some(online)),
            Event::Role if !self.service.tasks().role().owns_field() => {
                return Ok(Some(Ended::StoodDown));
            }
            Event::Role => {}
        }
        Ok(None)
    }

    /// `first` and the packets read whole behind it: the broker's acknowledgements of a
    /// burst come together, and are taken together rather than one a turn of the session.
    async fn packets(
        &mut self,
        online: &mut Online,
        first: Incoming,
    ) -> Result<Option<Ended>, ConnError> {
        let mut next = Some(first);
        for _ in 0..PACKETS_AT_ONCE {
            let Some(p) = next.take() else { break };
            if let Some(ended) = self.incoming(online, p).await? {
                return Ok(Some(ended));
            }
            next = online.conn.read_buffered().await?;
        }
        Ok(None)
    }

    /// Takes the changes that are ready now, up to [`CHANGES_AT_ONCE`] and while the outbox
    /// has room, so that a burst of changes is published in a few writes rather than one
    /// each, and the first of a burst leave before the last are encoded.
    async fn ready_changes(&mut self, online: &mut Online, inputs: &mut Inputs) {
        for _ in 1..CHANGES_AT_ONCE {
            if online.outbox.len() >= MAX_OUTBOX || online.live.len() >= MAX_UNCONFIRMED {
                return;
            }
            match ready_change(&mut inputs.changes).await {
                Some(Some(change)) => self.on_change(change, Some(&mut *online)),
                Some(None) => {
                    inputs.changes = None;
                    return;
                }
                None => return,
            }
        }
    }

    /// Subscriptions (again after every reconnect: a clean session forgets them), then the
    /// births or, while a primary host is awaited, nothing.
    pub(super) async fn start_session(&mut self, online: &mut Online) -> Result<(), ConnError> {
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

    /// The timer: followed writes, the buffer's sync, the shared status.
    pub(super) fn tick(&mut self, online: Option<&mut Online>) {
        self.said.flush();
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
    pub(super) fn publish_status(&mut self) {
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
}

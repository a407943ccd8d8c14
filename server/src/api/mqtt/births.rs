//! The MQTT front-end's session state as changes arrive: what is born and dies, which change
//! is reported, each value rendered once into a record; no I/O (what is to be sent goes to
//! the outbox, or to the buffer while offline).

use super::*;

impl Task {
    pub(super) fn key(&mut self, device: &Device, idx: usize) -> (usize, usize) {
        let base = self
            .aliases
            .base(device.name(), device.profile.fields.len());
        (base as usize, idx)
    }

    /// NBIRTH and a DBIRTH for every device that answers.
    pub(super) fn births(&mut self, online: &mut Online) {
        online.node_born = true;
        online.born.clear();
        online.outbox.push_back(Item::NodeBirth);
        online.births_waiting += 1;
        for device in self.devices.clone() {
            if device.diagnostics().connected {
                self.device_birth(online, &device);
            }
        }
    }

    pub(super) fn device_birth(&mut self, online: &mut Online, device: &Device) {
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
        online.births_waiting += 1;
        online.outbox.push_back(Item::Spark {
            kind: "DBIRTH",
            device: device.name().to_owned(),
            metrics,
        });
    }

    pub(super) fn device_death(&mut self, online: &mut Online, device: &str) {
        if online.born.remove(device) {
            online.outbox.push_back(Item::Spark {
                kind: "DDEATH",
                device: device.to_owned(),
                metrics: Vec::new(),
            });
        }
    }

    /// Devices came or went: a DBIRTH for a new one that answers, a DDEATH for one removed.
    pub(super) fn devices_changed(&mut self, online: Option<&mut Online>) {
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

    pub(super) fn on_change(&mut self, change: Change, online: Option<&mut Online>) {
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
    pub(super) fn heartbeat(&mut self, key: (usize, usize), online: Option<&mut Online>) {
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
    pub(super) fn emit(
        &mut self,
        view: &FieldView<'_>,
        mut online: Option<&mut Online>,
        change: bool,
    ) {
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

    pub(super) fn on_diagnostics(
        &mut self,
        device: &Device,
        d: &Diagnostics,
        online: Option<&mut Online>,
    ) {
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

    pub(super) fn device_state(&self, json: &JsonConfig, device: &Device, d: &Diagnostics) -> Out {
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
}

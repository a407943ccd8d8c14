//! A device's writes: checked against its field, requested (last value wins), taken by
//! its link, finished with their outcome, and the value a device holds that is not the
//! one requested.

use super::*;

impl Device {
    /// Checks that `value` can be written to field `idx`: the field is writable and the value
    /// fits the field's type and raw register after scaling.
    pub(crate) fn check_write(&self, idx: usize, value: Value) -> Result<Checked, AccessError> {
        self.check_writable(idx)?;
        self.check_value(idx, &value)?;
        Ok(Checked::new(idx, Some(value)))
    }

    /// Checks that field `idx` can be relinquished: it is writable (whether its protocol
    /// has a relinquish is the driver's to say).
    pub(crate) fn check_relinquish(&self, idx: usize) -> Result<Checked, AccessError> {
        self.check_writable(idx)?;
        Ok(Checked::new(idx, None))
    }

    fn check_writable(&self, idx: usize) -> Result<(), AccessError> {
        let field = self.field(idx);
        if !field.direction.is_writable() {
            return Err(AccessError::NotWritable {
                device: self.name().to_owned(),
                field: field.name.clone(),
            });
        }
        Ok(())
    }

    /// Checks `value` for field `idx`: its type, and that it fits the raw register after
    /// scaling.
    pub(super) fn check_value(&self, idx: usize, value: &Value) -> Result<(), AccessError> {
        let field = self.field(idx);
        let invalid = |reason: CodecError| AccessError::InvalidValue {
            device: self.name().to_owned(),
            field: field.name.clone(),
            ty: field.ty,
            reason: Box::new(reason),
        };
        if !value.is_of(field.ty) {
            return Err(invalid(CodecError::NotOfType { ty: field.ty }));
        }
        if self.is_simulated() || field.register.kind == RegisterKind::Virtual {
            if let Value::String(s) = value
                && s.len() > SIM_STRING_MAX
            {
                return Err(invalid(CodecError::TooLong {
                    len: s.len(),
                    max: SIM_STRING_MAX,
                }));
            }
            return Ok(());
        }
        if field.register.kind == RegisterKind::Point {
            // A point's STRING length counts characters (an S7 STRING holds one byte a
            // Latin-1 character); the protocol checks the rest before sending.
            if let Value::String(s) = value {
                let max = field
                    .point
                    .as_ref()
                    .and_then(|p| p.length)
                    .map_or(usize::from(field.register.word_count) * 2, usize::from);
                let len = s.chars().count();
                if len > max {
                    return Err(invalid(CodecError::TooManyCharacters { len, max }));
                }
                return Ok(());
            }
        }
        field.encoding.encode(value).map_err(invalid)?;
        Ok(())
    }

    /// Requests a write: the newest value replaces any pending one (which is then
    /// superseded). Returns the write's generation.
    #[cfg(test)]
    pub(crate) fn request_write(&self, idx: usize, value: Value) -> Result<u64, AccessError> {
        let checked = self.check_write(idx, value)?;
        Ok(self.request_writes(vec![checked], None).map_or(0, |g| g[0]))
    }

    /// Requests several checked writes of this device as one: the device's task takes them
    /// together (so adjacent registers become one FC16, never an FC06 and an FC16), and is
    /// woken once. A [`Checked`] is the proof of its check: nothing is checked or encoded
    /// again; its registers go on the bus as they are. `writer` is the scan-cycle stream
    /// that asked (its loss may write the fields' safe values).
    pub(crate) fn request_writes(
        &self,
        writes: Vec<Checked>,
        writer: Option<u64>,
    ) -> Result<Vec<u64>, Vec<Checked>> {
        let named = writes
            .into_iter()
            .map(|c| (self.field(c.idx()).name.as_str(), c))
            .collect();
        let generations = self
            .outputs
            .request_all(self.name(), named, Origin::Client, writer)
            .map_err(|back| back.into_iter().map(|(_, c)| c).collect::<Vec<_>>())?;
        lock(&self.wake).notify_one();
        Ok(generations)
    }

    /// Requests a write the gateway asks for itself (`origin`); a device replaced by a
    /// reload passes it on to its successor (when the field is kept there).
    pub(crate) fn request_own(
        self: &Arc<Self>,
        idx: usize,
        value: Value,
        origin: Origin,
    ) -> Option<u64> {
        let mut device = self.clone();
        let mut idx = idx;
        loop {
            let requested = device.outputs.request_from(
                device.name(),
                &device.field(idx).name,
                idx,
                value.clone(),
                origin,
                None,
            );
            if let Some(generation) = requested {
                lock(&device.wake).notify_one();
                return Some(generation);
            }
            let next = device.current();
            if Arc::ptr_eq(&next, &device) {
                return None;
            }
            idx = device.kept_in(idx, &next)?;
            device = next;
        }
    }

    /// The device's requested outputs: pending writes, newest values, generations.
    pub(crate) fn outputs(&self) -> &Outputs {
        &self.outputs
    }

    /// Takes every pending write, for the device's task to put on the bus.
    pub(crate) fn take_writes(&self) -> Vec<TakenWrite> {
        self.outputs.take()
    }

    /// The newest value requested for field `idx`.
    pub(crate) fn latest_value(&self, idx: usize) -> Option<Value> {
        self.outputs.latest(idx)
    }

    /// The generation of the newest write to field `idx`.
    pub(crate) fn last_write(&self, idx: usize) -> Option<u64> {
        self.outputs.last_generation(idx)
    }

    /// Reports the outcome of a taken write.
    pub(crate) fn finish_write(&self, generation: u64, result: Result<(), WriteError>) {
        self.finish_write_after(generation, result, 0);
    }

    /// Reports the outcome of a taken write that took `attempts` transactions. A failed
    /// one wakes the field's subscribers: what the device holds now differs from what was
    /// asked ([`Device::mismatch`]).
    pub(crate) fn finish_write_after(
        &self,
        generation: u64,
        result: Result<(), WriteError>,
        attempts: u32,
    ) {
        let failed = result.is_err();
        let field = self.outputs.finish(generation, result, attempts);
        if let (true, Some(idx)) = (failed, field) {
            self.samples[idx].send_modify(|s| s.retold = s.retold.wrapping_add(1));
        }
    }

    /// The desired value of output `idx` (the newest requested) when the device holds
    /// another: read back good, with no write of it waiting or on the bus. `None` when they
    /// agree, or nothing was requested, or the value is not known now.
    pub(crate) fn mismatch(&self, idx: usize) -> Option<Value> {
        let desired = self.outputs.latest(idx)?;
        if self.outputs.is_due(idx) {
            return None;
        }
        let sample = self.sample(idx);
        if self.quality(&sample, tokio::time::Instant::now()) != Quality::Good {
            return None;
        }
        let actual = sample.value?;
        (!self.agree(idx, &desired, &actual)).then_some(desired)
    }

    /// Whether two values of field `idx` are the same on the device (the same registers,
    /// or the same raw value stored).
    fn agree(&self, idx: usize, a: &Value, b: &Value) -> bool {
        let field = self.field(idx);
        if field.register.kind == RegisterKind::Point {
            return match (field.to_raw(a), field.to_raw(b)) {
                (Ok(x), Ok(y)) => x == y,
                _ => a == b,
            };
        }
        match (field.encoding.encode(a), field.encoding.encode(b)) {
            (Ok(x), Ok(y)) => x == y,
            _ => a == b,
        }
    }

    /// The outputs to write again now that the device is back (`rewrite_outputs:
    /// on_reconnect`): the newest requested value of each, except where the device
    /// acknowledged it and was read holding another value since (someone else wrote it);
    /// those are left, and the write log says so.
    pub(crate) fn replayable(&self) -> Vec<(usize, Value)> {
        let mut again = Vec::new();
        for (idx, desired, reached) in self.outputs.replayable() {
            let held = self.sample(idx).value;
            match held {
                Some(held) if reached && !self.agree(idx, &desired, &held) => {
                    let field = &self.field(idx).name;
                    tracing::info!(device = %self.name(), field = %field, requested = %desired, held = %held, "not written again after the reconnect: another client wrote it since");
                    self.outputs.leave(self.name(), field, idx, &held);
                }
                _ => again.push((idx, desired)),
            }
        }
        again
    }
}

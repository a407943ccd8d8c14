//! One view of a field, as every front-end shows it: value, type, unit, quality as of now,
//! timestamp, why it is bad, mismatch with the desired value, and the latest write. Built
//! here once; REST, the event stream, the map over REST, gRPC, MQTT and OPC UA only render
//! it, none computes a part of it again.

use std::time::SystemTime;

use iogate_types::Quality;

use super::Service;
use crate::cache::{Device, FieldError, Sample};
use crate::codec::Value;
use crate::profile::Field;
use crate::write_log::WriteRecord;

/// A field as of now. Names are borrowed from the device while a response is written.
#[derive(Debug, Clone)]
pub(crate) struct FieldView<'a> {
    pub(crate) device: &'a Device,
    pub(crate) field: &'a Field,
    /// `None` until the field is first read.
    pub(crate) value: Option<Value>,
    /// The sample's quality as of now (a good value not refreshed in time is stale).
    pub(crate) quality: Quality,
    /// When the value was last refreshed.
    pub(crate) timestamp: Option<SystemTime>,
    /// Why the quality is bad.
    pub(crate) error: Option<FieldError>,
    /// The newest value requested for this output, when the device holds another with no
    /// write of it waiting (a mismatch).
    pub(crate) desired: Option<Value>,
    /// The latest write to the field, while the log keeps it.
    pub(crate) last_write: Option<WriteRecord>,
}

impl FieldView<'_> {
    pub(crate) fn unit(&self) -> Option<&str> {
        self.field.register.unit.as_deref()
    }

    pub(crate) fn mismatch(&self) -> bool {
        self.desired.is_some()
    }
}

impl Service {
    /// The view of field `idx` of `device` with `sample` (its newest, or the one a change
    /// carries).
    pub(crate) fn field_view<'a>(
        &self,
        device: &'a Device,
        idx: usize,
        sample: &Sample,
    ) -> FieldView<'a> {
        FieldView {
            device,
            field: device.field(idx),
            value: sample.value.clone(),
            quality: device.quality(sample, tokio::time::Instant::now()),
            timestamp: sample.updated.map(|(_, wall)| wall),
            error: sample.error.as_deref().cloned(),
            desired: device.mismatch(idx),
            last_write: self.last_write(device, idx),
        }
    }

    /// The view of field `idx` of `device` with its newest sample.
    pub(crate) fn field_view_now<'a>(&self, device: &'a Device, idx: usize) -> FieldView<'a> {
        self.field_view(device, idx, &device.sample(idx))
    }
}

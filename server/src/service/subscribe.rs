//! Following changes: each chosen field and each chosen device's diagnostics is a `watch`
//! receiver, merged into one stream. A subscriber first gets every current value, then
//! each change; a slow one skips to the newest value of a field instead of building a
//! backlog. The stream ends when the gateway shuts down.

use std::pin::Pin;
use std::sync::Arc;

use futures_util::{Stream, StreamExt};
use tokio_stream::StreamMap;
use tokio_stream::wrappers::WatchStream;

use super::{Selection, Service, ServiceError};
use crate::cache::{Device, Diagnostics, Sample};

/// A change of a field's value (or quality), or of a device's diagnostics.
#[derive(Debug, Clone)]
pub(crate) enum Change {
    Value {
        device: Arc<Device>,
        idx: usize,
        sample: Sample,
    },
    Diagnostics {
        device: Arc<Device>,
        diagnostics: Diagnostics,
    },
}

/// The stream of a subscription.
pub(crate) type Changes = Pin<Box<dyn Stream<Item = Change> + Send>>;

/// Which watch a change came from: (device, field), the field `usize::MAX` for diagnostics.
type Key = (usize, usize);
const DIAGNOSTICS: usize = usize::MAX;

impl Service {
    /// Current values then changes of `selection`'s fields, and of its devices'
    /// diagnostics when `diagnostics` is set.
    pub(crate) fn subscribe(
        &self,
        selection: Selection,
        diagnostics: bool,
    ) -> Result<Changes, ServiceError> {
        self.accepting()?;
        let slot = self.stream_slot()?;
        let mut streams: StreamMap<Key, Changes> = StreamMap::new();
        let position = |device: &Arc<Device>| {
            selection
                .devices
                .iter()
                .position(|d| Arc::ptr_eq(d, device))
                .unwrap_or(usize::MAX - 1)
        };
        if diagnostics {
            for (n, device) in selection.devices.iter().enumerate() {
                let d = device.clone();
                let diag = WatchStream::new(device.subscribe_diagnostics()).map(move |diag| {
                    Change::Diagnostics {
                        device: d.clone(),
                        diagnostics: diag,
                    }
                });
                streams.insert((n, DIAGNOSTICS), Box::pin(diag));
            }
        }
        for f in selection.fields.iter() {
            let (device, idx) = (f.device.clone(), f.idx);
            let values = WatchStream::new(device.subscribe(idx)).map(move |sample| Change::Value {
                device: device.clone(),
                idx,
                sample,
            });
            streams.insert((position(&f.device), f.idx), Box::pin(values));
        }
        let shutdown = self.tasks().token().clone().cancelled_owned();
        // The slot goes with the stream: freed when the client goes away.
        Ok(Box::pin(
            streams
                .map(move |(_, change)| {
                    let _held = &slot;
                    change
                })
                .take_until(shutdown),
        ))
    }
}

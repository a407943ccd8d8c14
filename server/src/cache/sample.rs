//! What the cache holds per field and per device: the latest sample with its quality, the
//! reason a read failed, and the diagnostics that the device function blocks and the
//! `SerialLink` of source document 000 report.

use std::time::{Duration, SystemTime};

use tokio::time::Instant;

use crate::codec::{CodecError, Value};
use crate::link::frame::Exception;
use crate::link::{LinkCode, LinkFault, TxError};

pub(crate) use iogate_types::Quality;

/// Why a field could not be read.
#[derive(Debug, Clone, thiserror::Error)]
pub(crate) enum FieldError {
    /// The device answered the read with an exception.
    #[error("{0}")]
    Exception(Exception),
    /// The device did not answer properly (timeout, CRC, wrong frame), after the retries.
    #[error("no response: {0}")]
    NoResponse(TxError),
    /// The answer held a value that does not decode as the field's type.
    #[error("{0}")]
    Decode(CodecError),
    /// The answer was shorter than the batch it answers.
    #[error("{0} missing from the response")]
    Missing(&'static str),
    /// The link is down.
    #[error("{0}")]
    Unreachable(LinkFault),
    /// The device's own word on the value (an OPC UA status code's name and what it says).
    #[error("{0}")]
    Device(String),
}

/// A field's latest value.
#[derive(Debug, Clone)]
pub(crate) struct Sample {
    /// The last good value; kept (and marked) when later reads fail.
    pub(crate) value: Option<Value>,
    pub(crate) quality: Quality,
    /// Why the quality is bad (boxed: most samples have none, and a field keeps one
    /// sample).
    pub(crate) error: Option<Box<FieldError>>,
    /// When the value was last refreshed.
    pub(crate) updated: Option<(Instant, SystemTime)>,
    /// Subscribers were woken when this good value went stale (so that live views show it);
    /// the next refresh wakes them again.
    pub(crate) stale_told: bool,
    /// Counts the times subscribers were woken for something beside the sample (a failed
    /// write: the field's mismatch), so that such a wake is never taken for a repeat.
    pub(crate) retold: u64,
    /// The device whose reads are stored here (`Device::place`): a reload that re-plans or
    /// moves the device gives the sample to its successor, and a read of the old device
    /// still on the way is then not stored.
    pub(crate) place: u64,
}

impl Sample {
    pub(super) fn never_read() -> Self {
        Sample {
            value: None,
            quality: Quality::NeverRead,
            error: None,
            updated: None,
            stale_told: false,
            retold: 0,
            place: 0,
        }
    }

    /// Whether `other` tells a subscriber nothing new: the same value, quality and stale
    /// spell (what a change of the sample is woken for; a refresh alone is not).
    pub(crate) fn same_state(&self, other: &Sample) -> bool {
        self.value == other.value
            && self.quality == other.quality
            && self.stale_told == other.stale_told
            && self.retold == other.retold
    }

    /// The quality as of `now`: a good value not refreshed within `stale_after` is stale.
    pub(crate) fn quality_at(&self, now: Instant, stale_after: Duration) -> Quality {
        match (self.quality, self.updated) {
            (Quality::Good, Some((at, _))) if now.saturating_duration_since(at) > stale_after => {
                Quality::Stale
            }
            (q, _) => q,
        }
    }
}

/// A device's error code, as source document 000's device function blocks report it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum DeviceCode {
    Ok = 0,
    NoLink = 1,
    NoSlave = 2,
    CommError = 10,
}

impl DeviceCode {
    /// The number the APIs and metrics show.
    pub(crate) fn code(self) -> i16 {
        self as i16
    }
}

/// Device diagnostics, as source document 000's device function blocks report them.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Diagnostics {
    pub(crate) connected: bool,
    pub(crate) error_code: DeviceCode,
    pub(crate) io_cycles: u64,
    pub(crate) last_response_ms: f64,
}

/// Link diagnostics, as source document 000's `SerialLink` reports them.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct LinkDiagnostics {
    pub(crate) connected: bool,
    pub(crate) error_code: LinkCode,
}

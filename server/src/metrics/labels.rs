//! The label sets of the gateway's own metrics: bounded values only (links, devices,
//! functions, outcomes; never a value).

use prometheus_client::encoding::EncodeLabelSet;

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub(crate) struct LinkLabels {
    pub(crate) link: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub(crate) struct DroppedLabels {
    pub(crate) link: String,
    /// `busy` (the inbox was full), `expired` (its deadline would pass), `abandoned` (its
    /// caller had gone).
    pub(crate) reason: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub(crate) struct ResultLabels {
    pub(crate) result: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub(crate) struct DeviceLabels {
    pub(crate) device: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub(crate) struct RequestLabels {
    pub(crate) device: String,
    pub(crate) function: String,
    pub(crate) outcome: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub(crate) struct ExceptionLabels {
    pub(crate) device: String,
    pub(crate) code: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub(crate) struct ServerRequestLabels {
    pub(crate) function: String,
    pub(crate) outcome: String,
}

/// What became of a frame on a serial port of the Modbus server (its index in
/// [`SerialOutcome::ALL`] is its discriminant).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum SerialOutcome {
    Answered,
    Exception,
    /// Applied, not answered.
    Broadcast,
    /// Ignored: for another unit id.
    OtherUnit,
    /// Ignored: a bad CRC or LRC.
    CrcError,
    /// Ignored: too short, too long, not hexadecimal, no request's function code.
    Malformed,
}

impl SerialOutcome {
    pub(crate) const ALL: [SerialOutcome; 6] = [
        SerialOutcome::Answered,
        SerialOutcome::Exception,
        SerialOutcome::Broadcast,
        SerialOutcome::OtherUnit,
        SerialOutcome::CrcError,
        SerialOutcome::Malformed,
    ];

    /// The metric's and the API's name.
    pub(crate) fn label(self) -> &'static str {
        match self {
            SerialOutcome::Answered => "answered",
            SerialOutcome::Exception => "exception",
            SerialOutcome::Broadcast => "broadcast",
            SerialOutcome::OtherUnit => "other_unit",
            SerialOutcome::CrcError => "crc_error",
            SerialOutcome::Malformed => "malformed",
        }
    }
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub(crate) struct PortLabels {
    pub(crate) port: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub(crate) struct FrameLabels {
    pub(crate) port: String,
    /// `answered`, `exception`, `broadcast`, `other_unit`, `crc_error`, `malformed`.
    pub(crate) outcome: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub(crate) struct TransactionLabels {
    pub(crate) transaction: String,
    pub(crate) outcome: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub(crate) struct CodeLabels {
    pub(crate) code: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub(crate) struct WriteLabels {
    pub(crate) device: String,
    pub(crate) outcome: String,
}

/// A front-end's messages or frames by direction (`out`/`in`, `sent`/`received`).
#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub(crate) struct DirectionLabels {
    pub(crate) direction: &'static str,
}

/// A front-end's writes by outcome (`accepted`, `refused`).
#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub(crate) struct OutcomeLabels {
    pub(crate) outcome: &'static str,
}

//! How good a cached value is, and which way a field goes.

use serde::Serialize;

/// How much a cached value can be trusted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Quality {
    /// Read on the last poll.
    Good,
    /// Not refreshed for longer than the device's stale period.
    Stale,
    /// Nothing read yet.
    NeverRead,
    /// The device answered, but the value could not be decoded, or the read failed.
    Bad,
}

impl Quality {
    /// `good`, `stale`, `never_read` or `bad`.
    pub fn name(self) -> &'static str {
        match self {
            Quality::Good => "good",
            Quality::Stale => "stale",
            Quality::NeverRead => "never_read",
            Quality::Bad => "bad",
        }
    }
}

/// Which way a field goes: read from the device, written to it, or both.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Direction {
    /// Device to client: read from the device.
    Input,
    /// Client to device: written to the device (and read back).
    Output,
    /// Both.
    Inout,
}

impl Direction {
    /// Every direction.
    pub const ALL: [Direction; 3] = [Direction::Input, Direction::Output, Direction::Inout];

    /// `input`, `output` or `inout`.
    pub fn name(self) -> &'static str {
        match self {
            Direction::Input => "input",
            Direction::Output => "output",
            Direction::Inout => "inout",
        }
    }

    /// Whether clients may write the field.
    pub fn is_writable(self) -> bool {
        self != Direction::Input
    }
}

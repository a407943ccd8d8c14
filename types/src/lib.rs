//! iogate's value model, shared by the gateway and its client: the IEC 61131-3 types a
//! field can have ([`IecType`]), a value of such a type ([`Value`]), how good a cached value
//! is ([`Quality`]), which way a field goes ([`Direction`]), IEC duration literals
//! ([`time`]), and each of these to and from the protobuf messages of `iogate.v1` ([`pb`]).
#![forbid(unsafe_code)]
#![warn(missing_docs)]

mod iec;
pub mod located;
pub mod pb;
mod state;
pub mod time;
mod value;

pub use iec::{IecType, int_range};
pub use located::{Area, Location, LocationError, Size};
pub use state::{Direction, Quality};
pub use value::{Value, ValueError};

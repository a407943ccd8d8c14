//! IEC 60870-5-104: the controlling station's side (a link to an RTU or a substation, its
//! devices' fields by information object address) and the wire format both sides share:
//! the APCI (`apci.rs`), the ASDU (`asdu.rs`), its types (`types.rs`) and their elements (`element.rs`), the
//! time tags (`time.rs`).

// The wire format is used by the link and the outstation as they are built on it.
#![allow(dead_code)]

pub(crate) mod apci;
pub(crate) mod asdu;
pub(crate) mod element;
pub(crate) mod time;
pub(crate) mod types;

//! Siemens S7 PLCs (S7comm over ISO-on-TCP): work in progress, not yet a driver. The bytes
//! (`pdu.rs`) and a connection (`conn.rs`), tested against Snap7's server.

pub(crate) mod address;
pub(crate) mod conn;
pub(crate) mod pdu;

#[cfg(test)]
mod tests;

//! Raw Modbus transactions through the gateway, the two function blocks of source documents
//! 002 (a Modbus RTU write) and 004 (modbus-read): parameters checked with their messages
//! (`params`), values packed and read (`codec`), and the outcome as the blocks report it:
//! `actual`, `state`, the value, the error in the read block's words, the frames.

pub(crate) mod codec;
pub(crate) mod params;
pub(crate) mod spec;
pub mod st;

use crate::link::TxError;
use crate::link::frame::Exception;

pub(crate) use params::{Plan, TransactionSpec};

/// The write block's state codes.
pub mod state {
    pub const NOT_ACTIVE: i32 = 0;
    pub const WAITING: i32 = 1;
    pub const ACCESS: i32 = 2;
    pub const IN_PROGRESS: i32 = 3;
    pub const DONE: i32 = 4;
    pub const INTERFACE_UNAVAILABLE: i32 = -1;
    pub const TIMEOUT: i32 = -2;
    pub const UNKNOWN_ERROR: i32 = -3;
}

/// How a transaction ended.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Outcome {
    /// The last command got a correct response.
    pub(crate) actual: bool,
    pub(crate) state: i32,
    /// A read's value.
    pub(crate) value: Option<f64>,
    /// The read block's message for what went wrong.
    pub(crate) error: Option<&'static str>,
    /// The frames in hex, as they go on an RTU line (`11 06 00 01 00 03 9A 9B`).
    pub(crate) request: String,
    pub(crate) response: Option<String>,
    pub(crate) elapsed_ms: f64,
}

/// The read block's message and the write block's state for a failed transaction.
pub(crate) fn failure(e: &TxError) -> (i32, &'static str) {
    match e {
        TxError::Timeout => (state::TIMEOUT, "Slave timeout"),
        TxError::Exception(x) => (state::UNKNOWN_ERROR, exception_message(*x)),
        TxError::Crc | TxError::Invalid(_) => (state::UNKNOWN_ERROR, "RS485 frame error"),
        TxError::Io(_) => (state::UNKNOWN_ERROR, "IO error"),
    }
}

pub(crate) fn exception_message(x: Exception) -> &'static str {
    match x.0 {
        1 => "Function code not supported",
        2 => "Invalid address",
        3 => "Invalid quantity",
        _ => "Unknown modbus exception code",
    }
}

/// Bytes in hex, space-separated, upper case.
pub(crate) fn hex(bytes: &[u8]) -> String {
    bytes
        .iter()
        .map(|b| format!("{b:02X}"))
        .collect::<Vec<_>>()
        .join(" ")
}

/// Checks the config's standing transactions: their parameters, and that their links exist.
pub(crate) fn check_standing(config: &crate::config::Config) -> Result<(), crate::yaml::Problems> {
    let mut report = crate::yaml::Report::new(&config.source);
    for t in &config.transactions {
        let ctx = format!("transaction {}", t.name);
        let mut errors = t.spec.check().err().unwrap_or_default();
        let unreadable = config.unreadable.links.contains(&t.link);
        if !config.links.iter().any(|l| l.name == t.link) && !unreadable {
            errors.push(params::ParamError::MissingRs485);
        }
        if !errors.is_empty() {
            report.push(t.line, &ctx, params::messages(&errors));
        }
    }
    let problems = report.into_problems();
    if problems.is_empty() {
        Ok(())
    } else {
        Err(problems)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(json: serde_json::Value) -> Result<(), Vec<params::ParamError>> {
        let spec: TransactionSpec = serde_json::from_value(json).expect("a spec");
        spec.check().map(|_| ())
    }

    #[test]
    fn a_read_takes_no_values_and_unused_keys_must_still_be_valid() {
        let read = serde_json::json!({"function": 3, "slave": 1.0, "address": 0,
            "value_type": "FLOAT", "byte_order": "BigEndian"});
        assert_eq!(spec(read.clone()), Ok(()), "1.0 is an integer");
        let mut with_values = read.clone();
        with_values["values"] = serde_json::json!([[null, null]]);
        assert_eq!(spec(with_values), Err(vec![params::ParamError::Values]));
        let mut null_values = read;
        null_values["values"] = serde_json::Value::Null;
        assert_eq!(spec(null_values), Ok(()));
        let coil = serde_json::json!({"function": 5, "slave": 1, "address": 0, "values": [true],
            "value_type": "AAA", "precision": -1});
        assert_eq!(
            spec(coil),
            Err(vec![
                params::ParamError::ValueType,
                params::ParamError::Precision
            ])
        );
    }

    #[test]
    fn failures_get_the_read_blocks_messages_and_the_write_blocks_states() {
        assert_eq!(
            failure(&TxError::Timeout),
            (state::TIMEOUT, "Slave timeout")
        );
        for (code, message) in [
            (1, "Function code not supported"),
            (2, "Invalid address"),
            (3, "Invalid quantity"),
            (4, "Unknown modbus exception code"),
            (11, "Unknown modbus exception code"),
        ] {
            assert_eq!(
                failure(&TxError::Exception(Exception(code))),
                (state::UNKNOWN_ERROR, message)
            );
        }
        assert_eq!(failure(&TxError::Crc).1, "RS485 frame error");
        assert_eq!(hex(&[0x11, 0x06, 0x9A]), "11 06 9A");
    }
}

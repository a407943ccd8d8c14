//! What kind of "no" a refusal is, and its stable code: decided here once for every
//! [`ServiceError`], so that each front-end maps kinds to its wire in one small table (HTTP
//! status, gRPC code, Modbus exception, and later MQTT and OPC UA status codes) and none
//! looks at the error's variants.

use super::ServiceError;
use crate::cache::{AccessError, Refusal};
use crate::declare::DeclareError;

fn access(e: &AccessError) -> (Refusal, &'static str) {
    match e {
        AccessError::UnknownDevice(_) => (Refusal::NotFound, "unknown_device"),
        AccessError::UnknownField { .. } => (Refusal::NotFound, "unknown_field"),
        AccessError::UnknownLink(_) => (Refusal::NotFound, "unknown_link"),
        AccessError::UnknownProfile(_) => (Refusal::NotFound, "unknown_profile"),
        AccessError::NotWritable { .. } => (Refusal::Conflict, "not_writable"),
        AccessError::NotAnInput { .. } => (Refusal::Conflict, "not_an_input"),
        AccessError::NotSimulated(_) => (Refusal::Conflict, "not_simulated"),
        AccessError::InvalidValue { .. } => (Refusal::Invalid, "invalid_value"),
    }
}

fn declare(e: &DeclareError) -> (Refusal, &'static str) {
    match e {
        DeclareError::UnknownProfile(_) => (Refusal::NotFound, "unknown_profile"),
        DeclareError::UnknownLink(_) => (Refusal::NotFound, "unknown_link"),
        DeclareError::NotFound(a) => access(a),
        other => {
            let kind = other.refusal();
            let code = match kind {
                Refusal::NotFound => "not_found",
                Refusal::Conflict => "declaration_conflict",
                Refusal::Forbidden => "not_allowed",
                Refusal::TooMany => "too_many_declared",
                _ => "invalid_declaration",
            };
            (kind, code)
        }
    }
}

impl ServiceError {
    /// The kind of refusal and its stable code (the `code` of the REST API's errors).
    pub(crate) fn refusal(&self) -> (Refusal, &'static str) {
        match self {
            ServiceError::Access(a) => access(a),
            ServiceError::NothingWritten(all) => all
                .first()
                .map_or((Refusal::Invalid, "invalid_value"), access),
            ServiceError::UnknownWrite(_) => (Refusal::NotFound, "unknown_write"),
            ServiceError::WriteExpired { .. } => (Refusal::Gone, "write_expired"),
            ServiceError::Declare(d) => declare(d),
            ServiceError::ShuttingDown => (Refusal::Unavailable, "shutting_down"),
            ServiceError::ReadOnly => (Refusal::Forbidden, "read_only"),
            ServiceError::TooManyStreams(_) | ServiceError::TooManyClientStreams(_) => {
                (Refusal::TooMany, "too_many_streams")
            }
            ServiceError::Busy(_) => (Refusal::Busy, "busy"),
            ServiceError::Location(_) => (Refusal::Invalid, "invalid_location"),
            // A well-formed transaction for a link that is not there: the link is what
            // is missing (with the read block's message).
            ServiceError::Transaction(errors)
                if matches!(
                    errors.as_slice(),
                    [crate::transaction::params::ParamError::MissingRs485]
                ) =>
            {
                (Refusal::NotFound, "unknown_link")
            }
            ServiceError::Transaction(_) => (Refusal::Invalid, "invalid_transaction"),
            ServiceError::UnknownTransaction(_) => (Refusal::NotFound, "unknown_transaction"),
            ServiceError::TransactionConflict(_) => (Refusal::Conflict, "declaration_conflict"),
            ServiceError::TransactionDisabled(_) => (Refusal::Conflict, "transaction_disabled"),
            ServiceError::Unbound(_) => (Refusal::NotFound, "unbound_location"),
            ServiceError::Scan(_) => (Refusal::Invalid, "invalid_scan"),
            ServiceError::ScanRunning { .. } => (Refusal::Conflict, "scan_running"),
            ServiceError::UnknownScan(_) => (Refusal::NotFound, "unknown_scan"),
            ServiceError::Standby(_) => (Refusal::Unavailable, "standby"),
        }
    }
}

impl ServiceError {
    /// Whether a value was refused for being outside what its type (or, after scaling, its
    /// register) holds: a finer kind of [`Refusal::Invalid`] that some wires name apart
    /// (OPC UA's `Bad_OutOfRange`, beside `Bad_TypeMismatch`).
    pub(crate) fn out_of_range(&self) -> bool {
        use crate::codec::CodecError;
        use iogate_types::ValueError;
        let ServiceError::Access(AccessError::InvalidValue { reason, .. }) = self else {
            return false;
        };
        matches!(
            reason.as_ref(),
            CodecError::Value(ValueError::OutOfRange { .. } | ValueError::NotFinite { .. })
                | CodecError::RawOutOfRange { .. }
                | CodecError::NotFinite { .. }
                | CodecError::TooLong { .. }
        )
    }
}

impl AccessError {
    /// The kind of refusal and its stable code.
    pub(crate) fn refusal(&self) -> (Refusal, &'static str) {
        access(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_refusal_has_its_kind_and_code() {
        let unknown = ServiceError::Access(AccessError::UnknownDevice("x".into()));
        assert_eq!(unknown.refusal(), (Refusal::NotFound, "unknown_device"));
        let input = AccessError::NotWritable {
            device: "d".into(),
            field: "f".into(),
        };
        assert_eq!(
            ServiceError::NothingWritten(vec![input]).refusal(),
            (Refusal::Conflict, "not_writable")
        );
        assert_eq!(
            ServiceError::Busy("rs485".into()).refusal(),
            (Refusal::Busy, "busy")
        );
        assert_eq!(
            ServiceError::WriteExpired {
                generation: 1,
                kept: 128
            }
            .refusal(),
            (Refusal::Gone, "write_expired")
        );
    }
}

//! The one mapping from domain errors to HTTP status and JSON error bodies.

use axum::Json;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use serde::Serialize;
use utoipa::ToSchema;

use crate::cache::AccessError;
use crate::declare::{DeclareError, Refusal};
use crate::service::ServiceError;

/// An error answer: `{"error": {"code": "...", "message": "..."}}`.
#[derive(Debug)]
pub struct ApiError {
    pub status: StatusCode,
    pub code: &'static str,
    pub message: String,
}

#[derive(Debug, Serialize, ToSchema)]
pub struct ErrorBody {
    pub error: ErrorDetail,
}

#[derive(Debug, Serialize, ToSchema)]
pub struct ErrorDetail {
    /// A stable, machine-readable code, e.g. `unknown_device`.
    pub code: String,
    /// What is wrong, for people.
    pub message: String,
}

impl ApiError {
    pub fn new(status: StatusCode, code: &'static str, message: impl Into<String>) -> Self {
        ApiError {
            status,
            code,
            message: message.into(),
        }
    }

    pub fn bad_request(code: &'static str, message: impl Into<String>) -> Self {
        ApiError::new(StatusCode::BAD_REQUEST, code, message)
    }

    pub fn not_found(code: &'static str, message: impl Into<String>) -> Self {
        ApiError::new(StatusCode::NOT_FOUND, code, message)
    }
}

fn access_status(e: &AccessError) -> (StatusCode, &'static str) {
    match e {
        AccessError::UnknownDevice(_) => (StatusCode::NOT_FOUND, "unknown_device"),
        AccessError::UnknownField { .. } => (StatusCode::NOT_FOUND, "unknown_field"),
        AccessError::UnknownLink(_) => (StatusCode::NOT_FOUND, "unknown_link"),
        AccessError::UnknownProfile(_) => (StatusCode::NOT_FOUND, "unknown_profile"),
        AccessError::NotWritable { .. } => (StatusCode::CONFLICT, "not_writable"),
        AccessError::NotAnInput { .. } => (StatusCode::CONFLICT, "not_an_input"),
        AccessError::NotSimulated(_) => (StatusCode::CONFLICT, "not_simulated"),
        AccessError::InvalidValue { .. } => (StatusCode::BAD_REQUEST, "invalid_value"),
    }
}

impl From<AccessError> for ApiError {
    fn from(e: AccessError) -> Self {
        let (status, code) = access_status(&e);
        ApiError::new(status, code, e.to_string())
    }
}

impl From<ServiceError> for ApiError {
    fn from(e: ServiceError) -> Self {
        let (status, code) = match &e {
            ServiceError::Access(a) => access_status(a),
            ServiceError::NothingWritten(all) => all
                .first()
                .map_or((StatusCode::BAD_REQUEST, "invalid_value"), access_status),
            ServiceError::UnknownWrite(_) => (StatusCode::NOT_FOUND, "unknown_write"),
            ServiceError::WriteExpired { .. } => (StatusCode::GONE, "write_expired"),
            ServiceError::Declare(DeclareError::UnknownProfile(_)) => {
                (StatusCode::NOT_FOUND, "unknown_profile")
            }
            ServiceError::Declare(DeclareError::UnknownLink(_)) => {
                (StatusCode::NOT_FOUND, "unknown_link")
            }
            ServiceError::Declare(d) => match d.refusal() {
                Refusal::Invalid => (StatusCode::BAD_REQUEST, "invalid_declaration"),
                Refusal::NotFound => (StatusCode::NOT_FOUND, "not_found"),
                Refusal::Conflict => (StatusCode::CONFLICT, "declaration_conflict"),
            },
            ServiceError::ShuttingDown => (StatusCode::SERVICE_UNAVAILABLE, "shutting_down"),
            ServiceError::Location(_) => (StatusCode::BAD_REQUEST, "invalid_location"),
            ServiceError::Transaction(_) => (StatusCode::BAD_REQUEST, "invalid_transaction"),
            ServiceError::UnknownTransaction(_) => (StatusCode::NOT_FOUND, "unknown_transaction"),
            ServiceError::TransactionConflict(_) => (StatusCode::CONFLICT, "declaration_conflict"),
            ServiceError::Unbound(_) => (StatusCode::NOT_FOUND, "unbound_location"),
        };
        ApiError::new(status, code, e.to_string())
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let body = ErrorBody {
            error: ErrorDetail {
                code: self.code.to_owned(),
                message: self.message,
            },
        };
        (self.status, Json(body)).into_response()
    }
}

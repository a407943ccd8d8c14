//! The one mapping from domain errors to HTTP status and JSON error bodies.

use axum::Json;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use serde::Serialize;
use utoipa::ToSchema;

use crate::cache::AccessError;
use crate::service::Refusal;
use crate::service::ServiceError;

/// An error answer: `{"error": {"code": "...", "message": "..."}}`.
#[derive(Debug)]
pub(crate) struct ApiError {
    pub(crate) status: StatusCode,
    pub(crate) code: &'static str,
    pub(crate) message: String,
    /// The active node of the pair, when a standby refuses what only the active does.
    pub(crate) active: Option<crate::role::Peer>,
}

#[derive(Debug, Serialize, ToSchema)]
pub(crate) struct ErrorBody {
    pub(crate) error: ErrorDetail,
}

#[derive(Debug, Serialize, ToSchema)]
pub(crate) struct ErrorDetail {
    /// A stable, machine-readable code, e.g. `unknown_device`.
    pub(crate) code: String,
    /// What is wrong, for people.
    pub(crate) message: String,
    /// On a standby's refusal (`standby`): the active node and its servers' addresses, to
    /// ask there.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) active: Option<crate::role::Peer>,
}

impl ApiError {
    pub(crate) fn new(status: StatusCode, code: &'static str, message: impl Into<String>) -> Self {
        ApiError {
            status,
            code,
            message: message.into(),
            active: None,
        }
    }

    pub(crate) fn bad_request(code: &'static str, message: impl Into<String>) -> Self {
        ApiError::new(StatusCode::BAD_REQUEST, code, message)
    }

    pub(crate) fn not_found(code: &'static str, message: impl Into<String>) -> Self {
        ApiError::new(StatusCode::NOT_FOUND, code, message)
    }
}

/// The HTTP status of each kind of refusal: the REST API's one table.
fn http_status(refusal: Refusal) -> StatusCode {
    match refusal {
        Refusal::Invalid => StatusCode::BAD_REQUEST,
        Refusal::NotFound => StatusCode::NOT_FOUND,
        Refusal::Conflict => StatusCode::CONFLICT,
        Refusal::Forbidden => StatusCode::FORBIDDEN,
        Refusal::Gone => StatusCode::GONE,
        Refusal::Unavailable | Refusal::Busy => StatusCode::SERVICE_UNAVAILABLE,
        Refusal::TooMany => StatusCode::TOO_MANY_REQUESTS,
    }
}

impl From<AccessError> for ApiError {
    fn from(e: AccessError) -> Self {
        let (refusal, code) = e.refusal();
        ApiError::new(http_status(refusal), code, e.to_string())
    }
}

impl From<ServiceError> for ApiError {
    fn from(e: ServiceError) -> Self {
        let (refusal, code) = e.refusal();
        let mut error = ApiError::new(http_status(refusal), code, e.to_string());
        if let ServiceError::Standby(active) = e {
            error.active = active;
        }
        error
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        // A standby's refusal says where the active is: in the body, and as the active's
        // HTTP address in `Location` (with `Retry-After`, as for any 503).
        let location = self
            .active
            .as_ref()
            .and_then(|a| a.addresses.get("http"))
            .and_then(|a| axum::http::HeaderValue::from_str(a).ok());
        let body = ErrorBody {
            error: ErrorDetail {
                code: self.code.to_owned(),
                message: self.message,
                active: self.active,
            },
        };
        let mut response = (self.status, Json(body)).into_response();
        if self.code == "standby" {
            let headers = response.headers_mut();
            headers.insert(
                axum::http::header::RETRY_AFTER,
                axum::http::HeaderValue::from_static("1"),
            );
            if let Some(location) = location {
                headers.insert(axum::http::header::LOCATION, location);
            }
        }
        response
    }
}

pub(crate) use crate::text::quote;

/// The stable code of an error status the framework answers before a handler runs.
fn status_code(status: StatusCode) -> &'static str {
    match status {
        StatusCode::BAD_REQUEST => "bad_request",
        StatusCode::NOT_FOUND => "no_route",
        StatusCode::METHOD_NOT_ALLOWED => "method_not_allowed",
        StatusCode::PAYLOAD_TOO_LARGE => "payload_too_large",
        StatusCode::URI_TOO_LONG => "uri_too_long",
        StatusCode::UNSUPPORTED_MEDIA_TYPE => "unsupported_media_type",
        StatusCode::REQUEST_HEADER_FIELDS_TOO_LARGE => "headers_too_large",
        StatusCode::REQUEST_TIMEOUT => "request_timeout",
        StatusCode::TOO_MANY_REQUESTS => "too_many_requests",
        s if s.is_server_error() => "internal",
        _ => "error",
    }
}

/// Every error answer in the API's JSON shape: an error that is not JSON already (a
/// method not allowed, a path that does not decode, a body too large, ...) is answered again
/// as `{"error": {"code", "message"}}`, its status and headers (such as `Allow`) kept.
pub(crate) async fn json_errors(response: Response) -> Response {
    let status = response.status();
    let is_json = response
        .headers()
        .get(axum::http::header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.starts_with("application/json"));
    if !(status.is_client_error() || status.is_server_error()) || is_json {
        return response;
    }
    let (mut parts, body) = response.into_parts();
    let text = axum::body::to_bytes(body, 4096)
        .await
        .map(|b| String::from_utf8_lossy(&b).into_owned())
        .unwrap_or_default();
    // A body that did not arrive within `listen.body_timeout` fails the extractor that
    // buffers it; that is the client's lateness, not a malformed request.
    if status == StatusCode::BAD_REQUEST && text.contains("was not received within") {
        let mut out = ApiError::new(
            StatusCode::REQUEST_TIMEOUT,
            "request_timeout",
            "the request body did not arrive within listen.body_timeout",
        )
        .into_response();
        out.headers_mut().insert(
            axum::http::header::CONNECTION,
            axum::http::HeaderValue::from_static("close"),
        );
        return out;
    }
    let message = if text.trim().is_empty() {
        status.canonical_reason().unwrap_or("error").to_owned()
    } else {
        quote(text.trim())
    };
    parts.headers.remove(axum::http::header::CONTENT_LENGTH);
    parts.headers.remove(axum::http::header::CONTENT_TYPE);
    let body = ErrorBody {
        error: ErrorDetail {
            code: status_code(status).to_owned(),
            message,
            active: None,
        },
    };
    let mut out = (status, Json(body)).into_response();
    for (name, value) in parts.headers.iter() {
        out.headers_mut().insert(name.clone(), value.clone());
    }
    out
}

/// Ends every JSON answer with a newline, as command-line tools expect (`curl` otherwise
/// runs the answer and the next prompt together). Errors made JSON by [`json_errors`] pass
/// through here after it.
pub(crate) async fn json_newline(response: Response) -> Response {
    let is_json = response
        .headers()
        .get(axum::http::header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.starts_with("application/json"));
    if !is_json {
        return response;
    }
    let (mut parts, body) = response.into_parts();
    let Ok(bytes) = axum::body::to_bytes(body, usize::MAX).await else {
        return Response::from_parts(parts, axum::body::Body::empty());
    };
    let mut text = Vec::with_capacity(bytes.len() + 1);
    text.extend_from_slice(&bytes);
    if text.last() != Some(&b'\n') {
        text.push(b'\n');
    }
    parts.headers.remove(axum::http::header::CONTENT_LENGTH);
    Response::from_parts(parts, axum::body::Body::from(text))
}

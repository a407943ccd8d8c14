//! Scans of configured links over REST: start one, read or follow its state, cancel it.

use std::sync::Arc;

use axum::Json;
use axum::body::Bytes;
use axum::extract::{Path, State};
use axum::http::{StatusCode, header};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use futures_util::Stream;
use serde::Deserialize;
use utoipa::ToSchema;

use super::error::{ApiError, ErrorBody};
use crate::service::Service;
use crate::service::scan::ScanState;

/// What to scan on the link: slave ids and one probe's slot.
#[derive(Debug, Default, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub(crate) struct ScanRequest {
    /// Slave ids: `1-247` (the default), `1,5,10-20`.
    ids: Option<String>,
    /// One probe's slot (silence, request and answer), e.g. `50ms` (the default).
    timeout: Option<String>,
}

/// Starts a scan of the link at its own line setting, between its polls (one probe at a
/// time). The answer is the scan's first state, with how long the search takes at most
/// (`estimate_ms`); follow it at `/api/v1/scans/{id}` or its events.
#[utoipa::path(post, path = "/api/v1/links/{link}/scan", tag = "links",
    params(("link" = String, Path, description = "link name")),
    request_body(content = ScanRequest, description = "optional; an empty body scans 1-247 with 50 ms slots"),
    responses((status = 202, description = "the scan started", body = ScanState),
              (status = 400, description = "bad ids or timeout, or a link that does not carry RTU frames", body = ErrorBody),
              (status = 404, description = "no such link", body = ErrorBody),
              (status = 409, description = "a scan is running on the link", body = ErrorBody)))]
pub(crate) async fn post_scan(
    State(service): State<Arc<Service>>,
    Path(link): Path<String>,
    body: Bytes,
) -> Result<Response, ApiError> {
    let request: ScanRequest = if body.iter().all(u8::is_ascii_whitespace) {
        ScanRequest::default()
    } else {
        serde_json::from_slice(&body).map_err(|e| {
            ApiError::bad_request(
                "invalid_body",
                format!("the scan request is not valid: {e}"),
            )
        })?
    };
    let timeout = request
        .timeout
        .as_deref()
        .map(crate::duration::parse)
        .transpose()
        .map_err(|e| ApiError::bad_request("invalid_scan", format!("timeout: {e}")))?;
    let state = service.start_scan(&link, request.ids.as_deref(), timeout)?;
    let location = format!("/api/v1/scans/{}", state.id);
    Ok((
        StatusCode::ACCEPTED,
        [(header::LOCATION, location)],
        Json(state),
    )
        .into_response())
}

/// The scan id of a path, or a 400 naming it.
fn scan_id(text: &str) -> Result<u64, ApiError> {
    text.parse().map_err(|_| {
        ApiError::bad_request(
            "invalid_scan_id",
            format!("`{text}` is not a scan id (a positive integer)"),
        )
    })
}

/// A scan's state: progress (`probed` of `total`), devices found so far, and when done the
/// `devices:` entries for them.
#[utoipa::path(get, path = "/api/v1/scans/{id}", tag = "links",
    params(("id" = u64, Path, description = "the scan's id")),
    responses((status = 200, description = "the scan", body = ScanState),
              (status = 400, description = "the id is not a number", body = ErrorBody),
              (status = 404, description = "no such scan", body = ErrorBody)))]
pub(crate) async fn get_scan(
    State(service): State<Arc<Service>>,
    Path(id): Path<String>,
) -> Result<Json<ScanState>, ApiError> {
    Ok(Json(service.scan(scan_id(&id)?)?.borrow().clone()))
}

/// Stops a running scan between two probes (its state becomes `cancelled`).
#[utoipa::path(delete, path = "/api/v1/scans/{id}", tag = "links",
    params(("id" = u64, Path, description = "the scan's id")),
    responses((status = 204, description = "the scan stops"),
              (status = 400, description = "the id is not a number", body = ErrorBody),
              (status = 404, description = "no such scan", body = ErrorBody)))]
pub(crate) async fn delete_scan(
    State(service): State<Arc<Service>>,
    Path(id): Path<String>,
) -> Result<StatusCode, ApiError> {
    service.cancel_scan(scan_id(&id)?)?;
    Ok(StatusCode::NO_CONTENT)
}

/// The scan's state as Server-Sent Events: `event: scan` with the whole state at once and
/// on every change (each id probed, each device found); the stream ends with the last state.
#[utoipa::path(get, path = "/api/v1/scans/{id}/events", tag = "links",
    params(("id" = u64, Path, description = "the scan's id")),
    responses((status = 200, description = "`event: scan` with a ScanState as `data`", content_type = "text/event-stream"),
              (status = 400, description = "the id is not a number", body = ErrorBody),
              (status = 404, description = "no such scan", body = ErrorBody),
              (status = 429, description = "too many open streams (`listen.max_streams`)", body = ErrorBody)))]
pub(crate) async fn scan_events(
    State(service): State<Arc<Service>>,
    client: Option<axum::Extension<super::ClientAddr>>,
    Path(id): Path<String>,
) -> Result<Sse<impl Stream<Item = Result<Event, axum::Error>>>, ApiError> {
    let states = service.scan(scan_id(&id)?)?;
    // An open stream holds one of the gateway's places for streams, as every stream does.
    let slot = service.stream_slot_for(client.and_then(|c| c.0.0))?;
    // The state now, then at each change, until a state that is not `running` has been sent.
    let events = futures_util::stream::unfold(Some((states, slot, true)), |next| async move {
        let (mut states, slot, first) = next?;
        if !first {
            states.changed().await.ok()?;
        }
        let state = states.borrow_and_update().clone();
        let event = Event::default().event("scan").json_data(&state);
        Some((
            event,
            (state.state == "running").then_some((states, slot, false)),
        ))
    });
    Ok(Sse::new(events).keep_alive(KeepAlive::default()))
}

//! `GET /api/v1/events`: the service's change stream as Server-Sent Events. A client first
//! gets every current value, then each change; a slow client skips to the newest value of a
//! field instead of building a backlog; the stream ends on shutdown.

use std::collections::HashMap;
use std::convert::Infallible;
use std::sync::Arc;
use std::time::Duration;

use axum::extract::rejection::QueryRejection;
use axum::extract::{Query, State};
use axum::response::sse::{Event, KeepAlive, Sse};
use futures_util::{Stream, StreamExt};
use serde::Serialize;

use super::convert::{DiagnosticsEvent, field_value};
use super::error::{ApiError, ErrorBody};
use crate::service::{Change, Service};

pub(crate) const EVENT_VALUE: &str = "value";
pub(crate) const EVENT_DIAGNOSTICS: &str = "diagnostics";
pub(crate) const EVENT_TRANSACTION: &str = "transaction";
/// A field or device the stream followed was removed (its last event).
pub(crate) const EVENT_REMOVED: &str = "removed";

/// The data of a `removed` event: the device, the field (none: the whole device), why.
#[derive(Debug, Serialize)]
struct RemovedEvent {
    device: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    field: Option<String>,
    reason: &'static str,
}
const KEEP_ALIVE: Duration = Duration::from_secs(15);

fn event(name: &str, data: &impl Serialize) -> Event {
    Event::default()
        .event(name)
        .json_data(data)
        .unwrap_or_else(|_| Event::default().comment("unserializable event"))
}

/// Changes of values and diagnostics, as `value` and `diagnostics` events whose data is
/// the JSON of `GET .../fields/{field}` and of a device's diagnostics; without `device`,
/// also `transaction` events (the JSON of `GET /api/v1/transactions/{name}`). With
/// `values=false`, no `value` events (an overview of many devices).
#[utoipa::path(get, path = "/api/v1/events", tag = "devices",
    params(("device" = Option<String>, Query, description = "only this device"),
           ("values" = Option<bool>, Query, description = "`false`: no `value` events, only diagnostics (and transactions)")),
    responses((status = 200, description = "a stream of `value` and `diagnostics` events: current values first, then each change", content_type = "text/event-stream"),
              (status = 400, description = "an unknown query parameter", body = ErrorBody), (status = 404, description = "unknown device", body = ErrorBody)))]
pub(crate) async fn events(
    State(service): State<Arc<Service>>,
    query: Result<Query<HashMap<String, String>>, QueryRejection>,
) -> Result<Sse<impl Stream<Item = Result<Event, Infallible>>>, ApiError> {
    let Query(query) = query.map_err(|e| ApiError::bad_request("invalid_query", e.body_text()))?;
    if let Some(unknown) = query
        .keys()
        .find(|k| !matches!(k.as_str(), "device" | "values"))
    {
        return Err(ApiError::bad_request(
            "invalid_query",
            format!("unknown query parameter `{unknown}` (expected: device, values)"),
        ));
    }
    let values = match query.get("values").map(String::as_str) {
        None | Some("true") => true,
        Some("false") => false,
        Some(other) => {
            return Err(ApiError::bad_request(
                "invalid_query",
                format!("values must be true or false, not `{other}`"),
            ));
        }
    };
    let devices: Vec<&String> = query.get("device").into_iter().collect();
    let mut selection = service.select::<_, &str>(&devices, &[])?;
    if !values {
        selection = selection.without_values();
    }
    // Standing transactions with everything, not with one device.
    let transactions = if devices.is_empty() {
        service.transaction_changes()
    } else {
        Box::pin(futures_util::stream::empty())
    };
    let transactions = transactions.map(|(standing, status)| {
        Ok(event(
            EVENT_TRANSACTION,
            &super::transactions::standing_info(&standing, &status),
        ))
    });
    let viewer = service.clone();
    let stream = service.subscribe(selection, true)?.map(move |change| {
        Ok(match change {
            Change::Value {
                device,
                idx,
                sample,
            } => event(
                EVENT_VALUE,
                &field_value(&viewer.field_view(&device, idx, &sample)),
            ),
            Change::Diagnostics {
                device,
                diagnostics: d,
            } => event(
                EVENT_DIAGNOSTICS,
                &DiagnosticsEvent {
                    device: device.name().to_owned(),
                    connected: d.connected,
                    error_code: d.error_code.code(),
                    io_cycles: d.io_cycles,
                    last_response_ms: d.last_response_ms,
                },
            ),
            Change::Removed {
                device,
                field,
                reason,
            } => event(
                EVENT_REMOVED,
                &RemovedEvent {
                    device,
                    field,
                    reason,
                },
            ),
        })
    });
    let stream = futures_util::stream::select(stream, transactions);
    Ok(Sse::new(stream).keep_alive(KeepAlive::new().interval(KEEP_ALIVE)))
}

//! `GET /api/v1/events`: a Server-Sent Events stream of value and diagnostics changes.
//!
//! Each field and each device's diagnostics is a `watch` receiver merged into one stream: a
//! client first gets every current value, then each change. A slow client skips to the
//! newest value of a field instead of building a backlog. The stream ends on shutdown.

use std::collections::HashMap;
use std::convert::Infallible;
use std::pin::Pin;
use std::sync::Arc;
use std::time::Duration;

use axum::extract::rejection::QueryRejection;
use axum::extract::{Query, State};
use axum::response::sse::{Event, KeepAlive, Sse};
use futures_util::{Stream, StreamExt};
use serde::Serialize;
use tokio_stream::StreamMap;
use tokio_stream::wrappers::WatchStream;

use super::convert::{DiagnosticsEvent, field_value};
use super::error::{ApiError, ErrorBody};
use crate::app::AppState;

pub const EVENT_VALUE: &str = "value";
pub const EVENT_DIAGNOSTICS: &str = "diagnostics";
const KEEP_ALIVE: Duration = Duration::from_secs(15);

type EventStream = Pin<Box<dyn Stream<Item = Event> + Send>>;

fn event(name: &str, data: &impl Serialize) -> Event {
    Event::default()
        .event(name)
        .json_data(data)
        .unwrap_or_else(|_| Event::default().comment("unserializable event"))
}

/// Changes of values and diagnostics, as `value` and `diagnostics` events whose data is
/// the JSON of `GET .../fields/{field}` and of a device's diagnostics.
#[utoipa::path(get, path = "/api/v1/events", tag = "devices",
    params(("device" = Option<String>, Query, description = "only this device")),
    responses((status = 200, description = "text/event-stream", content_type = "text/event-stream"),
              (status = 400, body = ErrorBody), (status = 404, body = ErrorBody)))]
pub async fn events(
    State(state): State<Arc<AppState>>,
    query: Result<Query<HashMap<String, String>>, QueryRejection>,
) -> Result<Sse<impl Stream<Item = Result<Event, Infallible>>>, ApiError> {
    let Query(query) = query.map_err(|e| ApiError::bad_request("invalid_query", e.body_text()))?;
    if let Some(unknown) = query.keys().find(|k| k.as_str() != "device") {
        return Err(ApiError::bad_request(
            "invalid_query",
            format!("unknown query parameter `{unknown}` (expected: device)"),
        ));
    }
    let devices = match query.get("device") {
        Some(name) => vec![state.cache.device(name)?],
        None => state.cache.devices(),
    };
    let mut streams: StreamMap<(usize, usize), EventStream> = StreamMap::new();
    for (d, device) in devices.iter().enumerate() {
        let diag_device = device.clone();
        let diag = WatchStream::new(device.subscribe_diagnostics()).map(move |diag| {
            event(
                EVENT_DIAGNOSTICS,
                &DiagnosticsEvent {
                    device: diag_device.name().to_owned(),
                    connected: diag.connected,
                    error_code: diag.error_code,
                    io_cycles: diag.io_cycles,
                    last_response_ms: diag.last_response_ms,
                },
            )
        });
        streams.insert((d, usize::MAX), Box::pin(diag));
        for idx in 0..device.profile.fields.len() {
            let device = device.clone();
            let values = WatchStream::new(device.subscribe(idx))
                .map(move |sample| event(EVENT_VALUE, &field_value(&device, idx, &sample)));
            streams.insert((d, idx), Box::pin(values));
        }
    }
    let stream = streams
        .map(|(_, event)| Ok(event))
        .take_until(state.token.clone().cancelled_owned());
    Ok(Sse::new(stream).keep_alive(KeepAlive::new().interval(KEEP_ALIVE)))
}

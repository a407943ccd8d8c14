//! `GET /api/v1/events`: the service's change stream as Server-Sent Events. A client first
//! gets every current value, then each change; a slow client skips to the newest value of a
//! field instead of building a backlog; the stream ends on shutdown. A field's change is
//! written as an event once for all the clients that follow it (the slot's [`SSE_FORM`]).

use std::collections::HashMap;
use std::convert::Infallible;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::Duration;

use axum::body::Body;
use axum::extract::rejection::QueryRejection;
use axum::extract::{Query, State};
use axum::http::header;
use axum::response::{IntoResponse, Response};
use bytes::Bytes;
use futures_util::{Stream, StreamExt};
use serde::Serialize;

use super::error::{ApiError, ErrorBody};
use crate::api::convert::{DiagnosticsEvent, field_value};
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
/// A comment sent after this long without an event, so proxies keep the stream open.
const KEEP_ALIVE: Duration = Duration::from_secs(15);
/// The name of a change's event among a field's wire forms.
const SSE_FORM: &str = "sse";

/// The event `name` with `data` as its one line of JSON.
fn event(name: &str, data: &impl Serialize) -> Bytes {
    let mut text = Vec::with_capacity(160);
    text.extend_from_slice(b"event: ");
    text.extend_from_slice(name.as_bytes());
    text.extend_from_slice(b"\ndata: ");
    if serde_json::to_writer(&mut text, data).is_err() {
        return Bytes::from_static(b": unserializable event\n\n");
    }
    text.extend_from_slice(b"\n\n");
    Bytes::from(text)
}

/// Events with a comment after each [`KEEP_ALIVE`] without one. An event only notes its
/// time; the timer is moved when it fires (not at every event: a timer reset takes the
/// runtime's timer lock, which a thousand streams given the same change would queue on).
struct KeptAlive<S> {
    events: S,
    quiet: Pin<Box<tokio::time::Sleep>>,
    last: tokio::time::Instant,
}

impl<S: Stream<Item = Bytes> + Unpin> Stream for KeptAlive<S> {
    type Item = Result<Bytes, Infallible>;

    fn poll_next(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<Self::Item>> {
        match self.events.poll_next_unpin(cx) {
            Poll::Ready(Some(event)) => {
                self.last = tokio::time::Instant::now();
                Poll::Ready(Some(Ok(event)))
            }
            Poll::Ready(None) => Poll::Ready(None),
            Poll::Pending => loop {
                if self.quiet.as_mut().poll(cx).is_pending() {
                    return Poll::Pending;
                }
                let due = self.last + KEEP_ALIVE;
                if due > self.quiet.deadline() {
                    // An event came since the timer was set: wait from that one.
                    self.quiet.as_mut().reset(due);
                    continue;
                }
                let now = tokio::time::Instant::now();
                self.last = now;
                self.quiet.as_mut().reset(now + KEEP_ALIVE);
                return Poll::Ready(Some(Ok(Bytes::from_static(b":\n\n"))));
            },
        }
    }
}

/// The query's `values` (true unless `false`); any parameter but `device` and `values` is
/// refused.
fn with_values(query: &HashMap<String, String>) -> Result<bool, ApiError> {
    if let Some(unknown) = query
        .keys()
        .find(|k| !matches!(k.as_str(), "device" | "values"))
    {
        return Err(ApiError::bad_request(
            "invalid_query",
            format!("unknown query parameter `{unknown}` (expected: device, values)"),
        ));
    }
    match query.get("values").map(String::as_str) {
        None | Some("true") => Ok(true),
        Some("false") => Ok(false),
        Some(other) => Err(ApiError::bad_request(
            "invalid_query",
            format!("values must be true or false, not `{other}`"),
        )),
    }
}

/// A change as its event; a value's made once for every stream that sends it.
fn change_event(viewer: &Service, change: Change) -> Bytes {
    match change {
        Change::Value {
            device,
            idx,
            sample,
            forms,
        } => forms.get_or_make(SSE_FORM, || {
            event(
                EVENT_VALUE,
                &field_value(&viewer.field_view(&device, idx, &sample)),
            )
        }),
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
    }
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
    client: Option<axum::Extension<super::ClientAddr>>,
    query: Result<Query<HashMap<String, String>>, QueryRejection>,
) -> Result<Response, ApiError> {
    let Query(query) = query.map_err(|e| ApiError::bad_request("invalid_query", e.body_text()))?;
    let values = with_values(&query)?;
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
        event(
            EVENT_TRANSACTION,
            &super::transactions::standing_info(&standing, &status),
        )
    });
    let viewer = service.clone();
    let stream = service
        .subscribe_for(selection, true, client.and_then(|c| c.0.0))?
        .map(move |change| change_event(&viewer, change));
    let stream = KeptAlive {
        events: futures_util::stream::select(stream, transactions),
        quiet: Box::pin(tokio::time::sleep(KEEP_ALIVE)),
        last: tokio::time::Instant::now(),
    };
    Ok((
        [
            (header::CONTENT_TYPE, "text/event-stream"),
            (header::CACHE_CONTROL, "no-cache"),
        ],
        Body::from_stream(stream),
    )
        .into_response())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test(start_paused = true)]
    async fn a_comment_comes_after_fifteen_quiet_seconds_counted_from_the_last_event() {
        let (tx, rx) = tokio::sync::mpsc::unbounded_channel::<Bytes>();
        let mut stream = KeptAlive {
            events: tokio_stream::wrappers::UnboundedReceiverStream::new(rx),
            quiet: Box::pin(tokio::time::sleep(KEEP_ALIVE)),
            last: tokio::time::Instant::now(),
        };
        let start = tokio::time::Instant::now();
        tokio::time::sleep(Duration::from_secs(10)).await;
        tx.send(Bytes::from_static(b"event")).expect("send");
        let first = stream.next().await.and_then(|e| e.ok());
        assert_eq!(first.as_deref(), Some(&b"event"[..]));
        // Quiet since the event at 10 s: the comment at 25 s, not at 15 s.
        let comment = stream.next().await.and_then(|e| e.ok());
        assert_eq!(comment.as_deref(), Some(&b":\n\n"[..]));
        assert_eq!(start.elapsed(), Duration::from_secs(25));
        // And the next after fifteen more.
        let comment = stream.next().await.and_then(|e| e.ok());
        assert_eq!(comment.as_deref(), Some(&b":\n\n"[..]));
        assert_eq!(start.elapsed(), Duration::from_secs(40));
    }
}

//! The HTTP routes: each API route names its operation and the role it needs, health,
//! metrics and the web page's files need no token; request bodies bounded in size and
//! time; the OpenAPI document's source (`ApiDoc`); the server on a listener.

use std::future::Future;
use std::sync::Arc;

use axum::Json;
use axum::Router;
use axum::extract::State;
use axum::http::{HeaderMap, Uri, header};
use axum::response::IntoResponse;
use axum::routing::{get, put};
use tokio::net::TcpListener;
use tower_http::trace::TraceLayer;
use utoipa::OpenApi;

use super::error::{self, ApiError};
use super::{config, declare, events, map, openapi, rest, scan, transactions, ui};
use crate::auth::Operation;
use crate::service::Service;

pub(crate) const API_PREFIX: &str = "/api/v1";
/// The largest request body (a PATCH of every field of a big device fits).
pub(crate) const MAX_BODY: usize = 1024 * 1024;

#[derive(OpenApi)]
#[openapi(
    info(title = "iogate", description = "I/O gateway for industrial devices: cached field values, last-value-wins writes."),
    paths(
        rest::livez, rest::readyz, rest::get_mqtt, rest::get_ha,
        rest::list_links, rest::get_link, rest::get_link_plan,
        rest::list_devices, rest::get_device, rest::get_field, rest::put_field,
        rest::patch_fields, rest::simulate_field, rest::get_write,
        rest::list_profiles, rest::get_profile, rest::get_profile_st,
        events::events, declare::put_link, declare::put_device, declare::delete_link, declare::delete_device, openapi_json, metrics,
        map::get_map, map::get_located, map::put_located, map::get_memory,
        transactions::post_transaction, transactions::list_standing,
        transactions::get_standing, transactions::put_standing, transactions::delete_standing,
        transactions::enable_standing,
        transactions::disable_standing, transactions::trigger_standing,
        transactions::put_standing_values,
        config::get_config, config::reload,
        scan::post_scan, scan::get_scan, scan::delete_scan, scan::scan_events,
    ),
    tags(
        (name = "devices", description = "devices, fields, writes and change events"),
        (name = "links", description = "serial and TCP links"),
        (name = "profiles", description = "device profiles and their function-block layout"),
        (name = "health", description = "liveness and readiness"),
        (name = "transactions", description = "raw Modbus transactions: one-shot and standing"),
        (name = "modbus", description = "the Modbus TCP server's map of IEC located addresses, and its memory"),
        (name = "config", description = "the configuration in force, and reloading it without a restart"),
    )
)]
pub(crate) struct ApiDoc;

/// This document: the REST API in OpenAPI 3.1, with the bearer tokens it needs when the
/// gateway has tokens.
#[utoipa::path(get, path = "/api/v1/openapi.json", tag = "health",
    responses((status = 200, description = "the OpenAPI document", content_type = "application/json")))]
async fn openapi_json(State(service): State<Arc<Service>>) -> Json<&'static serde_json::Value> {
    Json(openapi::document(
        !service.tokens.current().is_empty(),
        &service.described,
    ))
}

/// Prometheus metrics: the Prometheus text format 0.0.4, or OpenMetrics 1.0 when the
/// scraper asks for it in `Accept` (as Prometheus does).
#[utoipa::path(get, path = "/metrics", tag = "health",
    responses((status = 200, description = "every metric family, with states copied from the cache at the scrape",
               content((String = "text/plain"), (String = "application/openmetrics-text")))))]
async fn metrics(State(service): State<Arc<Service>>, headers: HeaderMap) -> impl IntoResponse {
    let accept = headers.get(header::ACCEPT).and_then(|v| v.to_str().ok());
    let format = crate::metrics::Format::negotiate(accept);
    service.count_bounds();
    (
        [(header::CONTENT_TYPE, format.content_type())],
        service.metrics.render(
            &service.cache,
            |out| {
                service.ha().encode_metrics(out)?;
                service.doors.encode_metrics(out)
            },
            format,
        ),
    )
}

async fn not_found(uri: Uri) -> ApiError {
    ApiError::not_found(
        "no_route",
        format!(
            "no such endpoint: {} (see {API_PREFIX}/openapi.json)",
            error::quote(uri.path())
        ),
    )
}

/// Refuses a request without the role its route's operation needs: 401 without a known
/// token, 403 with one whose role is too low, both as the API's JSON.
async fn authorize(
    State((service, operation)): State<(Arc<Service>, Operation)>,
    request: axum::extract::Request,
    next: axum::middleware::Next,
) -> axum::response::Response {
    let header = request
        .headers()
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok());
    let denied = match service.tokens.allows(header, operation) {
        Ok(()) => return next.run(request).await,
        Err(denied) => denied,
    };
    // The body the client is sending is read (at most MAX_BODY, within the body timeout)
    // before the refusal: answered while it still sends, an HTTP/2 client such as curl
    // sees its stream reset and loses the answer.
    let _ = axum::body::to_bytes(request.into_body(), MAX_BODY).await;
    match denied {
        crate::auth::Denied::Unauthenticated => {
            let mut response = ApiError::new(
                axum::http::StatusCode::UNAUTHORIZED,
                "unauthenticated",
                "send a known token: Authorization: Bearer TOKEN",
            )
            .into_response();
            response.headers_mut().insert(
                header::WWW_AUTHENTICATE,
                axum::http::HeaderValue::from_static("Bearer"),
            );
            response
        }
        crate::auth::Denied::Forbidden { needed } => ApiError::new(
            axum::http::StatusCode::FORBIDDEN,
            "forbidden",
            format!("this needs a token with the {} role", needed.name()),
        )
        .into_response(),
    }
}

type Method = axum::routing::MethodRouter<Arc<Service>>;

/// A request whose `Content-Length` is over [`MAX_BODY`] is answered 413 at once, before
/// its body is read (and, over HTTP/1, the connection closed: the body is not wanted).
async fn refuse_large_bodies(
    request: axum::extract::Request,
    next: axum::middleware::Next,
) -> axum::response::Response {
    let declared = request
        .headers()
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.trim().parse::<u64>().ok());
    match declared {
        Some(length) if length > MAX_BODY as u64 => {
            let mut response = ApiError::new(
                axum::http::StatusCode::PAYLOAD_TOO_LARGE,
                "payload_too_large",
                format!("the body is {length} bytes; at most {MAX_BODY} are taken"),
            )
            .into_response();
            if request.version() < axum::http::Version::HTTP_2 {
                response.headers_mut().insert(
                    header::CONNECTION,
                    axum::http::HeaderValue::from_static("close"),
                );
            }
            response
        }
        _ => next.run(request).await,
    }
}

/// `method`, refused to a client without the role `operation` needs: every route names the
/// operation it is, and the role comes from that ([`Operation::role`]).
fn needs(service: &Arc<Service>, operation: Operation, method: Method) -> Method {
    method.layer(axum::middleware::from_fn_with_state(
        (service.clone(), operation),
        authorize,
    ))
}

/// The HTTP routes, each request body to arrive within `body_timeout`. The API's routes
/// each name their operation; health, metrics and the web page's files need no token.
pub(crate) fn router(service: Arc<Service>, body_timeout: std::time::Duration) -> Router {
    let s = &service;
    let api = link_routes(s)
        .merge(device_routes(s))
        .merge(transaction_routes(s));
    Router::new()
        .route("/livez", get(rest::livez))
        .route("/readyz", get(rest::readyz))
        .route("/metrics", get(metrics))
        .nest(API_PREFIX, api)
        .merge(ui::routes())
        .fallback(not_found)
        .layer(axum::extract::DefaultBodyLimit::max(MAX_BODY))
        .layer(tower_http::timeout::RequestBodyTimeoutLayer::new(
            body_timeout,
        ))
        .layer(axum::middleware::from_fn(refuse_large_bodies))
        .layer(axum::middleware::map_response(error::json_errors))
        .layer(axum::middleware::map_response(error::json_newline))
        .layer(TraceLayer::new_for_http().on_failure(failed))
        .with_state(service)
}

/// The document, the configuration, links, their plans and scans.
fn link_routes(s: &Arc<Service>) -> Router<Arc<Service>> {
    use Operation::*;
    use axum::routing::{delete, post};
    Router::new()
        .route("/openapi.json", needs(s, Read, get(openapi_json)))
        .route("/links", needs(s, Read, get(rest::list_links)))
        .route("/config", needs(s, Read, get(config::get_config)))
        .route("/config/reload", needs(s, Reload, post(config::reload)))
        .route("/mqtt", needs(s, Read, get(rest::get_mqtt)))
        .route("/ha", needs(s, Read, get(rest::get_ha)))
        .route(
            "/links/{link}",
            needs(s, Read, get(rest::get_link))
                .merge(needs(s, Declare, put(declare::put_link)))
                .merge(needs(s, Remove, delete(declare::delete_link))),
        )
        .route(
            "/links/{link}/plan",
            needs(s, Read, get(rest::get_link_plan)),
        )
        .route("/links/{link}/scan", needs(s, Scan, post(scan::post_scan)))
        .route(
            "/scans/{id}",
            needs(s, Read, get(scan::get_scan)).merge(needs(s, Scan, delete(scan::delete_scan))),
        )
        .route("/scans/{id}/events", needs(s, Read, get(scan::scan_events)))
        .route(
            "/links/{link}/transactions",
            needs(s, Transact, post(transactions::post_transaction)),
        )
}

/// Devices, their fields and writes, profiles, events and the located addresses.
fn device_routes(s: &Arc<Service>) -> Router<Arc<Service>> {
    use Operation::*;
    use axum::routing::{delete, patch};
    Router::new()
        .route("/devices", needs(s, Read, get(rest::list_devices)))
        .route(
            "/devices/{device}",
            needs(s, Read, get(rest::get_device))
                .merge(needs(s, Declare, put(declare::put_device)))
                .merge(needs(s, Remove, delete(declare::delete_device))),
        )
        .route(
            "/devices/{device}/fields",
            needs(s, WriteOutputs, patch(rest::patch_fields)),
        )
        .route(
            "/devices/{device}/fields/{field}",
            needs(s, Read, get(rest::get_field)).merge(needs(
                s,
                WriteOutputs,
                put(rest::put_field),
            )),
        )
        .route(
            "/devices/{device}/fields/{field}/simulate",
            needs(s, Simulate, put(rest::simulate_field)),
        )
        .route("/writes/{generation}", needs(s, Read, get(rest::get_write)))
        .route("/profiles", needs(s, Read, get(rest::list_profiles)))
        .route(
            "/profiles/{profile}",
            needs(s, Read, get(rest::get_profile)),
        )
        .route(
            "/profiles/{profile}/st",
            needs(s, Read, get(rest::get_profile_st)),
        )
        .route("/events", needs(s, Subscribe, get(events::events)))
        .route("/map", needs(s, Read, get(map::get_map)))
        .route(
            "/map/{at}",
            needs(s, Read, get(map::get_located)).merge(needs(
                s,
                WriteOutputs,
                put(map::put_located),
            )),
        )
        .route("/memory", needs(s, Read, get(map::get_memory)))
}

/// Standing transactions.
fn transaction_routes(s: &Arc<Service>) -> Router<Arc<Service>> {
    use Operation::*;
    use axum::routing::{delete, post};
    Router::new()
        .route(
            "/transactions",
            needs(s, Read, get(transactions::list_standing)),
        )
        .route(
            "/transactions/{name}",
            needs(s, Read, get(transactions::get_standing))
                .merge(needs(s, Declare, put(transactions::put_standing)))
                .merge(needs(s, Remove, delete(transactions::delete_standing))),
        )
        .route(
            "/transactions/{name}/enable",
            needs(s, SwitchTransaction, post(transactions::enable_standing)),
        )
        .route(
            "/transactions/{name}/disable",
            needs(s, SwitchTransaction, post(transactions::disable_standing)),
        )
        .route(
            "/transactions/{name}/trigger",
            needs(s, SwitchTransaction, post(transactions::trigger_standing)),
        )
        .route(
            "/transactions/{name}/values",
            needs(s, SwitchTransaction, put(transactions::put_standing_values)),
        )
}

/// Serves the HTTP API on `listener` until `shutdown` resolves, within the limits of
/// [`super::serve`].
pub(crate) async fn serve_http(
    listener: TcpListener,
    service: Arc<Service>,
    limits: super::Limits,
    tls: Option<Arc<crate::tls::Tls>>,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> std::io::Result<()> {
    super::serve(listener, service, limits, tls, shutdown).await
}

/// A failed response in the log: a standby's refusal (503, with the active's address) is
/// how a pair works, not an error.
fn failed(
    class: tower_http::classify::ServerErrorsFailureClass,
    latency: std::time::Duration,
    _: &tracing::Span,
) {
    use tower_http::classify::ServerErrorsFailureClass::StatusCode;
    match class {
        StatusCode(s) if s == axum::http::StatusCode::SERVICE_UNAVAILABLE => {
            tracing::debug!(latency_ms = latency.as_millis() as u64, "answered 503");
        }
        other => {
            tracing::error!(classification = %other, latency_ms = latency.as_millis() as u64, "response failed")
        }
    }
}

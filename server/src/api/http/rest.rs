//! REST handlers under `/api/v1`.

use std::sync::Arc;

use axum::Json;
use axum::body::Bytes;
use axum::extract::{Path, State};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use serde::Serialize;
use serde_json::Value as Json_;
use utoipa::ToSchema;

use super::error::{ApiError, ErrorBody};
use crate::api::convert::{self, *};
use crate::cache::{AccessError, Device};
use crate::service::{Accepted, Prepared, Service};

type ServiceRef = State<Arc<Service>>;

#[derive(Debug, Serialize, ToSchema)]
pub(crate) struct Health {
    pub(crate) status: String,
    /// Links whose task is stuck in a transaction past its bound (then 503).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub(crate) stalled_links: Vec<String>,
    /// Devices that answer but whose polls get no line time (their values go stale): the
    /// gateway still serves, so this alone does not make it unready.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub(crate) starved_devices: Vec<String>,
    /// Each running front-end's detail, under its name (`mqtt`: connected, messages
    /// buffered, the last error): a front-end never makes the gateway unready.
    #[serde(flatten)]
    pub(crate) doors: std::collections::BTreeMap<String, serde_json::Value>,
    /// The Modbus server's serial ports by state (`open`, `opening`, `lost`), when it has
    /// any: a port away does not make the gateway unready, so this is detail only (the
    /// ports' counters are in `GET /api/v1/map`).
    #[serde(skip_serializing_if = "std::collections::BTreeMap::is_empty")]
    pub(crate) modbus_serial: std::collections::BTreeMap<String, String>,
}

/// The process is alive.
#[utoipa::path(get, path = "/livez", tag = "health", responses((status = 200, description = "the process is alive", body = Health)))]
pub(crate) async fn livez() -> Json<Health> {
    Json(Health {
        status: "ok".into(),
        stalled_links: Vec::new(),
        starved_devices: Vec::new(),
        doors: Default::default(),
        modbus_serial: Default::default(),
    })
}

/// The gateway is serving (not starting, not shutting down, and no link's task stuck).
#[utoipa::path(get, path = "/readyz", tag = "health",
    responses((status = 200, description = "serving", body = Health), (status = 503, description = "starting, shutting down, or a link stalled (named)", body = Health)))]
pub(crate) async fn readyz(State(service): ServiceRef) -> (StatusCode, Json<Health>) {
    let stalled_links: Vec<String> = service
        .links()
        .iter()
        .filter(|l| l.stalled().is_some())
        .map(|l| l.name().to_owned())
        .collect();
    let now = tokio::time::Instant::now();
    let starved_devices: Vec<String> = service
        .devices()
        .iter()
        .filter(|d| d.starved(now))
        .map(|d| d.name().to_owned())
        .collect();
    let ready = service.is_ready() && stalled_links.is_empty();
    (
        if ready {
            StatusCode::OK
        } else {
            StatusCode::SERVICE_UNAVAILABLE
        },
        Json(Health {
            status: if ready { "ready" } else { "not ready" }.into(),
            stalled_links,
            starved_devices,
            doors: service.doors.health(),
            modbus_serial: service
                .serial_ports()
                .into_iter()
                .map(|p| (p.port, p.state.name().to_owned()))
                .collect(),
        }),
    )
}

/// The MQTT front-end: its broker and connection, the store-and-forward buffer, the
/// Sparkplug edge node's session and the counters (404 when no `mqtt:` section is
/// configured).
#[utoipa::path(get, path = "/api/v1/mqtt", tag = "health",
    responses((status = 200, description = "the MQTT front-end's state", body = crate::api::mqtt::MqttStatus),
              (status = 404, description = "no MQTT front-end is configured", body = ErrorBody)))]
pub(crate) async fn get_mqtt(
    State(service): ServiceRef,
) -> Result<Json<crate::api::mqtt::MqttStatus>, ApiError> {
    let mqtt = service.doors.get::<crate::api::mqtt::MqttState>("mqtt");
    mqtt.map(|m| Json(m.status())).ok_or_else(|| {
        ApiError::not_found(
            "no_mqtt",
            "no MQTT front-end is configured (the mqtt: section)",
        )
    })
}

/// This gateway in its active/standby pair: its node, role and epoch, and the active node
/// with its servers' addresses (a gateway alone is active, `paired: false`).
#[utoipa::path(get, path = "/api/v1/ha", tag = "health",
    responses((status = 200, description = "this gateway's place in its pair", body = crate::service::ha::HaView)))]
pub(crate) async fn get_ha(State(service): ServiceRef) -> Json<crate::service::ha::HaView> {
    Json(service.ha())
}

/// Every link with its settings and diagnostics.
#[utoipa::path(get, path = "/api/v1/links", tag = "links", responses((status = 200, description = "every link", body = LinkList)))]
pub(crate) async fn list_links(State(service): ServiceRef) -> Json<LinkList> {
    Json(LinkList {
        links: service.links().iter().map(|l| link_info(l)).collect(),
    })
}

/// One link.
#[utoipa::path(get, path = "/api/v1/links/{link}", tag = "links",
    params(("link" = String, Path, description = "link name")),
    responses((status = 200, description = "the link", body = LinkInfo), (status = 404, description = "an unknown name", body = ErrorBody)))]
pub(crate) async fn get_link(
    State(service): ServiceRef,
    Path(name): Path<String>,
) -> Result<Json<LinkInfo>, ApiError> {
    Ok(Json(link_info(service.link(&name)?.as_ref())))
}

/// A link's poll plan as `iogate plan` prints it (its devices now, declared ones included):
/// each device's read transactions, their wire time, the cycle and the bus utilisation.
#[utoipa::path(get, path = "/api/v1/links/{link}/plan", tag = "links",
    params(("link" = String, Path, description = "link name")),
    responses((status = 200, description = "the plan as text", content_type = "text/plain"), (status = 404, description = "an unknown name", body = ErrorBody)))]
pub(crate) async fn get_link_plan(
    State(service): ServiceRef,
    Path(name): Path<String>,
) -> Result<([(axum::http::HeaderName, &'static str); 1], String), ApiError> {
    let link = service.link(&name)?;
    let members = link.members();
    let peer = link.peer();
    let text = crate::plan::link_plan(
        &link.config(),
        members.iter().map(|d| (&d.config, d.profile.as_ref())),
        &peer,
    );
    Ok((
        [(
            axum::http::header::CONTENT_TYPE,
            "text/plain; charset=utf-8",
        )],
        text,
    ))
}

/// Every device with its diagnostics.
#[utoipa::path(get, path = "/api/v1/devices", tag = "devices", responses((status = 200, description = "every device", body = DeviceList)))]
pub(crate) async fn list_devices(State(service): ServiceRef) -> Json<DeviceList> {
    Json(DeviceList {
        devices: service.devices().iter().map(|d| device_info(d)).collect(),
    })
}

fn field_json<'a>(device: &'a Device, idx: usize, service: &Service) -> FieldValue<'a> {
    field_value(&service.field_view_now(device, idx))
}

/// One device: diagnostics and every field's value.
#[utoipa::path(get, path = "/api/v1/devices/{device}", tag = "devices",
    params(("device" = String, Path, description = "device name")),
    responses((status = 200, description = "the device with every field", body = DeviceDetail), (status = 404, description = "an unknown name", body = ErrorBody)))]
pub(crate) async fn get_device(
    State(service): ServiceRef,
    Path(name): Path<String>,
) -> Result<Response, ApiError> {
    let device = service.device(&name)?;
    let fields = (0..device.profile.fields.len())
        .map(|i| field_json(&device, i, &service))
        .collect::<Vec<_>>();
    // About 130 bytes a field: one buffer, grown rarely.
    let capacity = 512 + 160 * fields.len();
    json_response(
        &DeviceDetail {
            device: device_info(&device),
            fields: FieldMap(fields),
        },
        capacity,
    )
}

/// `value` as a JSON response, written straight into one buffer while it borrows from the
/// cache (names are not copied).
pub(super) fn json_response(
    value: &impl serde::Serialize,
    capacity: usize,
) -> Result<Response, ApiError> {
    let mut body = Vec::with_capacity(capacity);
    serde_json::to_writer(&mut body, value).map_err(|e| {
        ApiError::new(
            StatusCode::INTERNAL_SERVER_ERROR,
            "internal",
            format!("the answer could not be written as JSON: {e}"),
        )
    })?;
    Ok((
        [(
            axum::http::header::CONTENT_TYPE,
            axum::http::HeaderValue::from_static("application/json"),
        )],
        body,
    )
        .into_response())
}

/// One field's value, type, quality and timestamp.
#[utoipa::path(get, path = "/api/v1/devices/{device}/fields/{field}", tag = "devices",
    params(("device" = String, Path, description = "device name"),
           ("field" = String, Path, description = "field name (case-insensitive)")),
    responses((status = 200, description = "the field's value, type, quality and timestamp", body = FieldValue), (status = 404, description = "an unknown name", body = ErrorBody)))]
pub(crate) async fn get_field(
    State(service): ServiceRef,
    Path((name, field)): Path<(String, String)>,
) -> Result<Response, ApiError> {
    let device = service.device(&name)?;
    let idx = device.field_index(&field)?;
    json_response(&field_json(&device, idx, &service), 256)
}

/// The body of a single-field write.
#[derive(Debug, ToSchema)]
#[expect(
    dead_code,
    reason = "documents the request body in the OpenAPI document"
)]
pub(crate) struct WriteRequest {
    /// The value as the JSON of the field's type; `null` relinquishes the output where its
    /// protocol has a relinquish (BACnet), and is refused elsewhere.
    #[schema(value_type = Object)]
    value: Json_,
}

pub(super) fn parse_body(body: &Bytes) -> Result<Json_, ApiError> {
    if body.iter().all(u8::is_ascii_whitespace) {
        return Err(ApiError::bad_request(
            "missing_body",
            "the request has no body; send JSON such as {\"value\": 12.5}",
        ));
    }
    serde_json::from_slice(body).map_err(|e| {
        ApiError::bad_request("invalid_json", format!("the body is not valid JSON: {e}"))
    })
}

fn accepted(a: Accepted) -> WriteAccepted {
    WriteAccepted {
        device: a.device,
        field: a.field,
        generation: a.generation,
        status: "pending".into(),
    }
}

/// The value of a body `{"value": X}`; a bare JSON value is accepted too.
pub(crate) fn value_of(body: Json_) -> Json_ {
    match body {
        Json_::Object(mut map) if map.len() == 1 && map.contains_key("value") => {
            map.remove("value").unwrap_or(Json_::Null)
        }
        other => other,
    }
}

/// A write of `json` to field `field` of `device`, checked; JSON `null` is a relinquish
/// (refused where the field's protocol has none).
pub(crate) fn prepare_json(
    service: &Service,
    device: &Arc<Device>,
    field: &str,
    json: &Json_,
) -> Result<Prepared, AccessError> {
    match json {
        Json_::Null => service.prepare_relinquish(device, field),
        json => service.prepare(device, field, |ty| convert::json_to_value(ty, json)),
    }
}

/// Writes one field (last value wins); `null` relinquishes it (BACnet: NULL at the field's
/// priority). Answers with the write's generation; follow its
/// outcome at `/api/v1/writes/{generation}`.
#[utoipa::path(put, path = "/api/v1/devices/{device}/fields/{field}", tag = "devices",
    params(("device" = String, Path, description = "device name"),
           ("field" = String, Path, description = "field name (case-insensitive)")),
    request_body = WriteRequest,
    responses((status = 202, description = "accepted: pending, follow it by its generation", body = WriteAccepted),
              (status = 400, description = "wrong type or out of range", body = ErrorBody),
              (status = 404, description = "an unknown name", body = ErrorBody),
              (status = 409, description = "the field is an input", body = ErrorBody)))]
pub(crate) async fn put_field(
    State(service): ServiceRef,
    Path((name, field)): Path<(String, String)>,
    body: Bytes,
) -> Result<(StatusCode, Json<WriteAccepted>), ApiError> {
    let device = service.device(&name)?;
    let json = value_of(parse_body(&body)?);
    let write = prepare_json(&service, &device, &field, &json)?;
    Ok((StatusCode::ACCEPTED, Json(accepted(service.write(write)?))))
}

/// Writes several fields of one device: `{"DO_0": true, "AO_1": 3}`. Every value is checked
/// first; if any is refused, none is written and every problem is listed.
#[utoipa::path(patch, path = "/api/v1/devices/{device}/fields", tag = "devices",
    params(("device" = String, Path, description = "device name")),
    request_body(content = Object, description = "field name to value"),
    responses((status = 202, description = "every write accepted: pending", body = WritesAccepted),
              (status = 400, description = "a malformed request or a value the field does not take", body = ErrorBody), (status = 404, description = "an unknown name", body = ErrorBody),
              (status = 409, description = "the field is an input (or the device not simulated)", body = ErrorBody)))]
pub(crate) async fn patch_fields(
    State(service): ServiceRef,
    Path(name): Path<String>,
    body: Bytes,
) -> Result<(StatusCode, Json<WritesAccepted>), ApiError> {
    let device = service.device(&name)?;
    let Json_::Object(map) = parse_body(&body)? else {
        return Err(ApiError::bad_request(
            "invalid_body",
            "send a JSON object of field names to values, e.g. {\"DO_0\": true}",
        ));
    };
    if map.is_empty() {
        return Err(ApiError::bad_request("invalid_body", "no fields given"));
    }
    let writes = map
        .iter()
        .map(|(field, json)| prepare_json(&service, &device, field, json))
        .collect();
    let writes = service
        .write_all(writes)?
        .into_iter()
        .map(accepted)
        .collect();
    Ok((StatusCode::ACCEPTED, Json(WritesAccepted { writes })))
}

/// What a simulated input was set to.
#[derive(Debug, Serialize, ToSchema)]
pub(crate) struct Simulated {
    pub(crate) device: String,
    pub(crate) field: String,
    #[schema(value_type = Object)]
    pub(crate) value: Json_,
}

/// Sets an input of a simulated device, as if the device had read it; it shows on the
/// device's next cycle.
#[utoipa::path(put, path = "/api/v1/devices/{device}/fields/{field}/simulate", tag = "devices",
    params(("device" = String, Path, description = "simulated device name"),
           ("field" = String, Path, description = "an input or inout field")),
    request_body = WriteRequest,
    responses((status = 202, description = "the input is set; it shows on the next cycle", body = Simulated), (status = 400, description = "a malformed request or a value the field does not take", body = ErrorBody),
              (status = 404, description = "an unknown name", body = ErrorBody),
              (status = 409, description = "not a simulated device, or an output", body = ErrorBody)))]
pub(crate) async fn simulate_field(
    State(service): ServiceRef,
    Path((name, field)): Path<(String, String)>,
    body: Bytes,
) -> Result<(StatusCode, Json<Simulated>), ApiError> {
    let device = service.device(&name)?;
    device.field_index(&field)?;
    let json = value_of(parse_body(&body)?);
    let (idx, value) = service.simulate(&device, &field, |ty| convert::json_to_value(ty, &json))?;
    Ok((
        StatusCode::ACCEPTED,
        Json(Simulated {
            device: device.name().to_owned(),
            field: device.field(idx).name.clone(),
            value: convert::value_to_json(&value),
        }),
    ))
}

/// The outcome of a write: `pending`, `written`, `superseded` or `failed`.
#[utoipa::path(get, path = "/api/v1/writes/{generation}", tag = "devices",
    params(("generation" = u64, Path, description = "the generation a write returned")),
    responses((status = 200, description = "where the write stands", body = WriteInfo), (status = 400, description = "a malformed request or a value the field does not take", body = ErrorBody),
              (status = 404, description = "an unknown name", body = ErrorBody),
              (status = 410, description = "too old: no longer kept", body = ErrorBody)))]
pub(crate) async fn get_write(
    State(service): ServiceRef,
    Path(generation): Path<String>,
) -> Result<Json<WriteInfo>, ApiError> {
    let generation: u64 = generation.parse().map_err(|_| {
        ApiError::bad_request(
            "invalid_generation",
            format!("`{generation}` is not a write generation (a positive integer)"),
        )
    })?;
    Ok(Json(WriteInfo::from(&service.write_outcome(generation)?)))
}

/// Every loaded profile.
#[utoipa::path(get, path = "/api/v1/profiles", tag = "profiles", responses((status = 200, description = "every loaded profile", body = ProfileList)))]
pub(crate) async fn list_profiles(State(service): ServiceRef) -> Json<ProfileList> {
    Json(ProfileList {
        profiles: service
            .profiles()
            .iter()
            .map(|p| profile_summary(p))
            .collect(),
    })
}

/// The profile's function block as an IEC 61131-3 ST declaration (text/plain).
#[utoipa::path(get, path = "/api/v1/profiles/{profile}/st", tag = "profiles",
    params(("profile" = String, Path, description = "profile name")),
    responses((status = 200, description = "the declaration", content_type = "text/plain"),
              (status = 404, description = "an unknown name", body = ErrorBody)))]
pub(crate) async fn get_profile_st(
    State(service): ServiceRef,
    Path(name): Path<String>,
) -> Result<([(axum::http::HeaderName, &'static str); 1], String), ApiError> {
    let profile = service.profile(&name)?;
    Ok((
        [(
            axum::http::header::CONTENT_TYPE,
            "text/plain; charset=utf-8",
        )],
        crate::profile::st_declaration(&profile),
    ))
}

/// One profile: its fields and its generated function-block layout.
#[utoipa::path(get, path = "/api/v1/profiles/{profile}", tag = "profiles",
    params(("profile" = String, Path, description = "profile name")),
    responses((status = 200, description = "the profile, its fields and FB layout", body = ProfileDetail), (status = 404, description = "an unknown name", body = ErrorBody)))]
pub(crate) async fn get_profile(
    State(service): ServiceRef,
    Path(name): Path<String>,
) -> Result<Json<ProfileDetail>, ApiError> {
    let profile = service.profile(&name)?;
    Ok(Json(profile_detail(&profile)))
}

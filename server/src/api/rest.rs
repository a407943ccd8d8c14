//! REST handlers under `/api/v1`.

use std::sync::Arc;

use axum::Json;
use axum::body::Bytes;
use axum::extract::{Path, State};
use axum::http::StatusCode;
use serde::Serialize;
use serde_json::Value as Json_;
use utoipa::ToSchema;

use super::convert::{self, *};
use super::error::{ApiError, ErrorBody};
use crate::app::AppState;
use crate::cache::{AccessError, Device};
use crate::codec::Value;
use crate::writes::Lookup;

type AppStateRef = State<Arc<AppState>>;

#[derive(Debug, Serialize, ToSchema)]
pub struct Health {
    pub status: String,
}

/// The process is alive.
#[utoipa::path(get, path = "/livez", tag = "health", responses((status = 200, body = Health)))]
pub async fn livez() -> Json<Health> {
    Json(Health {
        status: "ok".into(),
    })
}

/// The gateway is serving (not starting and not shutting down).
#[utoipa::path(get, path = "/readyz", tag = "health",
    responses((status = 200, body = Health), (status = 503, body = Health)))]
pub async fn readyz(State(state): AppStateRef) -> (StatusCode, Json<Health>) {
    if state.is_ready() {
        (
            StatusCode::OK,
            Json(Health {
                status: "ready".into(),
            }),
        )
    } else {
        (
            StatusCode::SERVICE_UNAVAILABLE,
            Json(Health {
                status: "not ready".into(),
            }),
        )
    }
}

/// Every link with its settings and diagnostics.
#[utoipa::path(get, path = "/api/v1/links", tag = "links", responses((status = 200, body = LinkList)))]
pub async fn list_links(State(state): AppStateRef) -> Json<LinkList> {
    Json(LinkList {
        links: state.cache.links().iter().map(|l| link_info(l)).collect(),
    })
}

/// One link.
#[utoipa::path(get, path = "/api/v1/links/{link}", tag = "links",
    params(("link" = String, Path, description = "link name")),
    responses((status = 200, body = LinkInfo), (status = 404, body = ErrorBody)))]
pub async fn get_link(
    State(state): AppStateRef,
    Path(name): Path<String>,
) -> Result<Json<LinkInfo>, ApiError> {
    Ok(Json(link_info(state.cache.link(&name)?.as_ref())))
}

/// Every device with its diagnostics.
#[utoipa::path(get, path = "/api/v1/devices", tag = "devices", responses((status = 200, body = DeviceList)))]
pub async fn list_devices(State(state): AppStateRef) -> Json<DeviceList> {
    Json(DeviceList {
        devices: state
            .cache
            .devices()
            .iter()
            .map(|d| device_info(d))
            .collect(),
    })
}

fn field_json(device: &Device, idx: usize, state: &AppState) -> FieldValue {
    let mut value = field_value(device, idx, &device.sample(idx));
    if let Some(Lookup::Found(record)) = device.last_write(idx).map(|g| state.cache.writes.get(g)) {
        value.last_write = Some(WriteInfo::from(&record));
    }
    value
}

/// One device: diagnostics and every field's value.
#[utoipa::path(get, path = "/api/v1/devices/{device}", tag = "devices",
    params(("device" = String, Path, description = "device name")),
    responses((status = 200, body = DeviceDetail), (status = 404, body = ErrorBody)))]
pub async fn get_device(
    State(state): AppStateRef,
    Path(name): Path<String>,
) -> Result<Json<DeviceDetail>, ApiError> {
    let device = state.cache.device(&name)?;
    let fields = (0..device.profile.fields.len())
        .map(|i| {
            let value = field_json(&device, i, &state);
            let json = serde_json::to_value(&value).unwrap_or(Json_::Null);
            (value.field, json)
        })
        .collect();
    Ok(Json(DeviceDetail {
        device: device_info(&device),
        fields,
    }))
}

/// One field's value, type, quality and timestamp.
#[utoipa::path(get, path = "/api/v1/devices/{device}/fields/{field}", tag = "devices",
    params(("device" = String, Path, description = "device name"),
           ("field" = String, Path, description = "field name (case-insensitive)")),
    responses((status = 200, body = FieldValue), (status = 404, body = ErrorBody)))]
pub async fn get_field(
    State(state): AppStateRef,
    Path((name, field)): Path<(String, String)>,
) -> Result<Json<FieldValue>, ApiError> {
    let device = state.cache.device(&name)?;
    let idx = device.field_index(&field)?;
    Ok(Json(field_json(&device, idx, &state)))
}

/// The body of a single-field write.
#[derive(Debug, ToSchema)]
#[expect(
    dead_code,
    reason = "documents the request body in the OpenAPI document"
)]
pub struct WriteRequest {
    /// The value as the JSON of the field's type.
    #[schema(value_type = Object)]
    value: Json_,
}

fn parse_body(body: &Bytes) -> Result<Json_, ApiError> {
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

/// The JSON as a value of field `idx`'s type.
fn typed(device: &Device, idx: usize, json: &Json_) -> Result<Value, ApiError> {
    let f = device.field(idx);
    convert::json_to_value(f.ty, json).map_err(|reason| {
        ApiError::from(AccessError::InvalidValue {
            device: device.name().to_owned(),
            field: f.name.clone(),
            ty: f.ty,
            reason,
        })
    })
}

/// Converts and checks one value for a write; nothing is written.
fn prepare(device: &Device, field: &str, json: &Json_) -> Result<(usize, Value), ApiError> {
    let idx = device.field_index(field)?;
    let value = typed(device, idx, json)?;
    device.check_write(idx, &value)?;
    Ok((idx, value))
}

fn accept(device: &Device, idx: usize, value: Value) -> Result<WriteAccepted, ApiError> {
    let generation = device.request_write(idx, value)?;
    Ok(WriteAccepted {
        device: device.name().to_owned(),
        field: device.field(idx).name.clone(),
        generation,
        status: "pending".into(),
    })
}

/// The value of a body `{"value": X}`; a bare JSON value is accepted too.
fn value_of(body: Json_) -> Json_ {
    match body {
        Json_::Object(mut map) if map.len() == 1 && map.contains_key("value") => {
            map.remove("value").unwrap_or(Json_::Null)
        }
        other => other,
    }
}

/// Writes one field (last value wins). Answers with the write's generation; follow its
/// outcome at `/api/v1/writes/{generation}`.
#[utoipa::path(put, path = "/api/v1/devices/{device}/fields/{field}", tag = "devices",
    params(("device" = String, Path, description = "device name"),
           ("field" = String, Path, description = "field name (case-insensitive)")),
    request_body = WriteRequest,
    responses((status = 202, body = WriteAccepted),
              (status = 400, description = "wrong type or out of range", body = ErrorBody),
              (status = 404, body = ErrorBody),
              (status = 409, description = "the field is an input", body = ErrorBody)))]
pub async fn put_field(
    State(state): AppStateRef,
    Path((name, field)): Path<(String, String)>,
    body: Bytes,
) -> Result<(StatusCode, Json<WriteAccepted>), ApiError> {
    let device = state.cache.device(&name)?;
    let json = value_of(parse_body(&body)?);
    let (idx, value) = prepare(&device, &field, &json)?;
    Ok((StatusCode::ACCEPTED, Json(accept(&device, idx, value)?)))
}

/// Writes several fields of one device: `{"DO_0": true, "AO_1": 3}`. Every value is checked
/// first; if any is refused, none is written and every problem is listed.
#[utoipa::path(patch, path = "/api/v1/devices/{device}/fields", tag = "devices",
    params(("device" = String, Path, description = "device name")),
    request_body(content = Object, description = "field name to value"),
    responses((status = 202, body = WritesAccepted),
              (status = 400, body = ErrorBody), (status = 404, body = ErrorBody),
              (status = 409, body = ErrorBody)))]
pub async fn patch_fields(
    State(state): AppStateRef,
    Path(name): Path<String>,
    body: Bytes,
) -> Result<(StatusCode, Json<WritesAccepted>), ApiError> {
    let device = state.cache.device(&name)?;
    let Json_::Object(map) = parse_body(&body)? else {
        return Err(ApiError::bad_request(
            "invalid_body",
            "send a JSON object of field names to values, e.g. {\"DO_0\": true}",
        ));
    };
    if map.is_empty() {
        return Err(ApiError::bad_request("invalid_body", "no fields given"));
    }
    let mut prepared = Vec::with_capacity(map.len());
    let mut errors: Vec<ApiError> = Vec::new();
    for (field, json) in &map {
        match prepare(&device, field, json) {
            Ok(p) => prepared.push(p),
            Err(e) => errors.push(e),
        }
    }
    if let Some(first) = errors.first() {
        let message = errors
            .iter()
            .map(|e| e.message.as_str())
            .collect::<Vec<_>>()
            .join("; ");
        return Err(ApiError::new(
            first.status,
            first.code,
            format!("nothing was written: {message}"),
        ));
    }
    let writes = prepared
        .into_iter()
        .map(|(idx, value)| accept(&device, idx, value))
        .collect::<Result<_, _>>()?;
    Ok((StatusCode::ACCEPTED, Json(WritesAccepted { writes })))
}

/// What a simulated input was set to.
#[derive(Debug, Serialize, ToSchema)]
pub struct Simulated {
    pub device: String,
    pub field: String,
    #[schema(value_type = Object)]
    pub value: Json_,
}

/// Sets an input of a simulated device, as if the device had read it; it shows on the
/// device's next cycle.
#[utoipa::path(put, path = "/api/v1/devices/{device}/fields/{field}/simulate", tag = "devices",
    params(("device" = String, Path, description = "simulated device name"),
           ("field" = String, Path, description = "an input or inout field")),
    request_body = WriteRequest,
    responses((status = 202, body = Simulated), (status = 400, body = ErrorBody),
              (status = 404, body = ErrorBody),
              (status = 409, description = "not a simulated device, or an output", body = ErrorBody)))]
pub async fn simulate_field(
    State(state): AppStateRef,
    Path((name, field)): Path<(String, String)>,
    body: Bytes,
) -> Result<(StatusCode, Json<Simulated>), ApiError> {
    let device = state.cache.device(&name)?;
    let idx = device.field_index(&field)?;
    let value = typed(&device, idx, &value_of(parse_body(&body)?))?;
    let shown = convert::value_to_json(&value);
    device.simulate(idx, value)?;
    Ok((
        StatusCode::ACCEPTED,
        Json(Simulated {
            device: device.name().to_owned(),
            field: device.field(idx).name.clone(),
            value: shown,
        }),
    ))
}

/// The outcome of a write: `pending`, `written`, `superseded` or `failed`.
#[utoipa::path(get, path = "/api/v1/writes/{generation}", tag = "devices",
    params(("generation" = u64, Path, description = "the generation a write returned")),
    responses((status = 200, body = WriteInfo), (status = 400, body = ErrorBody),
              (status = 404, body = ErrorBody),
              (status = 410, description = "too old: no longer kept", body = ErrorBody)))]
pub async fn get_write(
    State(state): AppStateRef,
    Path(generation): Path<String>,
) -> Result<Json<WriteInfo>, ApiError> {
    let generation: u64 = generation.parse().map_err(|_| {
        ApiError::bad_request(
            "invalid_generation",
            format!("`{generation}` is not a write generation (a positive integer)"),
        )
    })?;
    match state.cache.writes.get(generation) {
        Lookup::Found(record) => Ok(Json(WriteInfo::from(&record))),
        Lookup::Expired => Err(ApiError::new(
            StatusCode::GONE,
            "write_expired",
            format!(
                "write {generation} is older than the last {} writes kept",
                crate::writes::WRITE_LOG_CAPACITY
            ),
        )),
        Lookup::Unknown => Err(ApiError::not_found(
            "unknown_write",
            format!("no write has generation {generation}"),
        )),
    }
}

/// Every loaded profile.
#[utoipa::path(get, path = "/api/v1/profiles", tag = "profiles", responses((status = 200, body = ProfileList)))]
pub async fn list_profiles(State(state): AppStateRef) -> Json<ProfileList> {
    Json(ProfileList {
        profiles: state
            .cache
            .catalog
            .iter()
            .map(|p| profile_summary(p))
            .collect(),
    })
}

/// The profile's function block as an IEC 61131-3 ST declaration (text/plain).
#[utoipa::path(get, path = "/api/v1/profiles/{profile}/st", tag = "profiles",
    params(("profile" = String, Path, description = "profile name")),
    responses((status = 200, description = "the declaration", content_type = "text/plain"),
              (status = 404, body = ErrorBody)))]
pub async fn get_profile_st(
    State(state): AppStateRef,
    Path(name): Path<String>,
) -> Result<([(axum::http::HeaderName, &'static str); 1], String), ApiError> {
    let profile = state.cache.profile(&name)?;
    Ok((
        [(
            axum::http::header::CONTENT_TYPE,
            "text/plain; charset=utf-8",
        )],
        crate::profile::st_declaration(profile),
    ))
}

/// One profile: its fields and its generated function-block layout.
#[utoipa::path(get, path = "/api/v1/profiles/{profile}", tag = "profiles",
    params(("profile" = String, Path, description = "profile name")),
    responses((status = 200, body = ProfileDetail), (status = 404, body = ErrorBody)))]
pub async fn get_profile(
    State(state): AppStateRef,
    Path(name): Path<String>,
) -> Result<Json<ProfileDetail>, ApiError> {
    Ok(Json(profile_detail(state.cache.profile(&name)?)))
}

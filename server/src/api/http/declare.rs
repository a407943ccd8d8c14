//! `PUT /api/v1/links/{link}` and `PUT /api/v1/devices/{device}`: the REST form of the
//! run-time declarations (gRPC `EnsureLink` / `EnsureDevice`). Idempotent: declaring what
//! exists answers 200, creating answers 201; a contradiction is 409 naming it. `DELETE` on
//! the same paths removes what was declared (gRPC `RemoveLink` / `RemoveDevice`).

use std::sync::Arc;
use std::time::Duration;

use axum::Json;
use axum::body::Bytes;
use axum::extract::{Path, State};
use axum::http::StatusCode;
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use super::error::{ApiError, ErrorBody};
use crate::api::convert::{DeviceInfo, LinkInfo, device_info, link_info};
use crate::config::rules;
use crate::declare::{DeviceDeclaration, Endpoint, LinkDeclaration};
use crate::service::Service;

/// A serial line as a `SerialLink` instance declares it. An empty or missing `port` is
/// accepted: the link reports error 1 (no port configured) until it is declared again with
/// one.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub(crate) struct SerialDeclaration {
    #[serde(default)]
    pub(crate) port: String,
    pub(crate) baud: u64,
    /// `N` (default), `E` or `O`.
    #[serde(default)]
    pub(crate) parity: String,
    /// 7 or 8 (default).
    #[serde(default)]
    pub(crate) data_bits: u64,
    /// 1 (default) or 2.
    #[serde(default)]
    pub(crate) stop_bits: u64,
    /// `rtu` (default) or `ascii`.
    #[serde(default)]
    pub(crate) framing: String,
}

/// A Modbus TCP endpoint (or RTU frames over TCP).
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub(crate) struct TcpDeclaration {
    pub(crate) host: String,
    /// Default 502.
    #[serde(default)]
    pub(crate) port: u64,
    /// `mbap` (default) or `rtu`.
    #[serde(default)]
    pub(crate) framing: String,
}

/// The body of `PUT /api/v1/links/{link}`: `serial` or `tcp`.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub(crate) struct LinkDeclarationBody {
    pub(crate) serial: Option<SerialDeclaration>,
    pub(crate) tcp: Option<TcpDeclaration>,
    /// Extra silence between frames, 0-1000 ms.
    #[serde(default)]
    pub(crate) guard_time_ms: u64,
}

/// The body of `PUT /api/v1/devices/{device}`. A Modbus device declared without `link` (or
/// with `slave_id` 0) is accepted and reports error 1 (or 2) until declared again with it.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub(crate) struct DeviceDeclarationBody {
    pub(crate) profile: String,
    /// A link name, or a serial port path as a `SerialLink`'s `port`; none for simulated
    /// devices.
    #[serde(default)]
    pub(crate) link: String,
    #[serde(default)]
    pub(crate) slave_id: u32,
    /// Default 100.
    pub(crate) refresh_rate_ms: Option<u64>,
    /// Default 200.
    pub(crate) timeout_ms: Option<u64>,
}

#[derive(Debug, Serialize, ToSchema)]
pub(crate) struct LinkDeclared {
    pub(crate) link: LinkInfo,
    /// Whether the declaration created the link (else it existed, or was given its port).
    pub(crate) created: bool,
}

#[derive(Debug, Serialize, ToSchema)]
pub(crate) struct DeviceDeclared {
    pub(crate) device: DeviceInfo,
    /// Whether the declaration created the device (else it existed, or was bound).
    pub(crate) created: bool,
}

fn body_of<T: serde::de::DeserializeOwned>(body: &Bytes) -> Result<T, ApiError> {
    let invalid = |e: serde_json::Error| {
        ApiError::bad_request("invalid_body", format!("the declaration is not valid: {e}"))
    };
    let mut value: serde_json::Value = serde_json::from_slice(body).map_err(invalid)?;
    whole_numbers(&mut value);
    serde_json::from_value(value).map_err(invalid)
}

/// `9600.0` is the integer 9600, as JSON Schema counts integers (a declaration's numbers
/// are all counts, milliseconds and ids); a fraction stays a fraction and is refused.
fn whole_numbers(value: &mut serde_json::Value) {
    match value {
        serde_json::Value::Number(n) if n.is_f64() => {
            if let Some(whole) = crate::config::transactions::whole_number(n) {
                *value = serde_json::Value::from(whole);
            }
        }
        serde_json::Value::Array(items) => items.iter_mut().for_each(whole_numbers),
        serde_json::Value::Object(map) => map.values_mut().for_each(whole_numbers),
        _ => {}
    }
}

fn status(created: bool) -> StatusCode {
    if created {
        StatusCode::CREATED
    } else {
        StatusCode::OK
    }
}

/// Declares a link (idempotent): an existing link with the same endpoint and settings is
/// answered as it is; different settings on its port are refused, naming each mismatch.
#[utoipa::path(put, path = "/api/v1/links/{link}", tag = "links",
    params(("link" = String, Path, description = "link name")),
    request_body = LinkDeclarationBody,
    responses((status = 200, description = "the link existed with these settings", body = LinkDeclared),
              (status = 201, description = "the link was created and is being opened", body = LinkDeclared),
              (status = 400, description = "a setting breaks a rule", body = ErrorBody),
              (status = 403, description = "the port or endpoint is not allowed by `security.declare`", body = ErrorBody),
              (status = 409, description = "the port or name is in use with other settings", body = ErrorBody)))]
pub(crate) async fn put_link(
    State(service): State<Arc<Service>>,
    Path(name): Path<String>,
    body: Bytes,
) -> Result<(StatusCode, Json<LinkDeclared>), ApiError> {
    let body: LinkDeclarationBody = body_of(&body)?;
    let endpoint = match (body.serial, body.tcp) {
        (Some(s), None) => Endpoint::Serial {
            port: s.port,
            baud: s.baud,
            parity: s.parity,
            data_bits: s.data_bits,
            stop_bits: s.stop_bits,
            framing: s.framing,
        },
        (None, Some(t)) => Endpoint::Tcp {
            host: t.host,
            port: t.port,
            framing: t.framing,
        },
        _ => {
            return Err(ApiError::bad_request(
                "invalid_body",
                "a link needs `serial` or `tcp` settings (one of them)",
            ));
        }
    };
    let ensured = service.ensure_link(LinkDeclaration {
        name: Some(name),
        endpoint,
        guard_time: Duration::from_millis(body.guard_time_ms),
    })?;
    Ok((
        status(ensured.created),
        Json(LinkDeclared {
            link: link_info(&ensured.value),
            created: ensured.created,
        }),
    ))
}

/// Declares a device (idempotent): a device of that name with the same settings is answered
/// as it is; a new one is polled at once by its link.
#[utoipa::path(put, path = "/api/v1/devices/{device}", tag = "devices",
    params(("device" = String, Path, description = "device name")),
    request_body = DeviceDeclarationBody,
    responses((status = 200, description = "the device existed with these settings (or was bound)", body = DeviceDeclared),
              (status = 201, description = "the device was created", body = DeviceDeclared),
              (status = 400, description = "a setting breaks a rule", body = ErrorBody),
              (status = 403, description = "its serial port or endpoint is not allowed by `security.declare`", body = ErrorBody),
              (status = 404, description = "unknown profile or link", body = ErrorBody),
              (status = 409, description = "the device exists with other settings", body = ErrorBody)))]
pub(crate) async fn put_device(
    State(service): State<Arc<Service>>,
    Path(name): Path<String>,
    body: Bytes,
) -> Result<(StatusCode, Json<DeviceDeclared>), ApiError> {
    let body: DeviceDeclarationBody = body_of(&body)?;
    let ensured = service.ensure_device(DeviceDeclaration {
        name,
        profile: body.profile,
        link: body.link,
        slave_id: body.slave_id,
        refresh_rate: body
            .refresh_rate_ms
            .map_or(rules::DEFAULT_REFRESH, Duration::from_millis),
        timeout: body.timeout_ms.map(Duration::from_millis),
    })?;
    Ok((
        status(ensured.created),
        Json(DeviceDeclared {
            device: device_info(&ensured.value),
            created: ensured.created,
        }),
    ))
}

/// Removes a link declared at run time: its task stops and its port or socket is closed.
/// Devices and standing transactions on it must be removed first; a link from the config
/// file stays.
#[utoipa::path(delete, path = "/api/v1/links/{link}", tag = "links",
    params(("link" = String, Path, description = "link name")),
    responses((status = 204, description = "the link was removed"),
              (status = 404, description = "unknown link", body = ErrorBody),
              (status = 409, description = "the link comes from the config file, or devices or transactions still use it", body = ErrorBody)))]
pub(crate) async fn delete_link(
    State(service): State<Arc<Service>>,
    Path(name): Path<String>,
) -> Result<StatusCode, ApiError> {
    service.remove_link(&name)?;
    Ok(StatusCode::NO_CONTENT)
}

/// Removes a device declared at run time: it is no longer polled and writes still waiting
/// for it fail; a device from the config file stays.
#[utoipa::path(delete, path = "/api/v1/devices/{device}", tag = "devices",
    params(("device" = String, Path, description = "device name")),
    responses((status = 204, description = "the device was removed"),
              (status = 404, description = "unknown device", body = ErrorBody),
              (status = 409, description = "the device comes from the config file", body = ErrorBody)))]
pub(crate) async fn delete_device(
    State(service): State<Arc<Service>>,
    Path(name): Path<String>,
) -> Result<StatusCode, ApiError> {
    service.remove_device(&name)?;
    Ok(StatusCode::NO_CONTENT)
}

//! The Modbus server's map over REST: `GET /api/v1/map` (every binding), a field by its
//! located address (`GET`/`PUT /api/v1/map/{at}`), and the gateway memory
//! (`GET /api/v1/memory`).

use std::collections::BTreeMap;
use std::sync::Arc;

use axum::Json;
use axum::body::Bytes;
use axum::extract::{Path, State};
use axum::http::StatusCode;
use serde::Serialize;
use utoipa::ToSchema;

use super::error::{ApiError, ErrorBody};
use crate::api::convert::{self, FieldValue, WriteAccepted};
use crate::map::{Binding, Table};
use crate::service::Service;

/// One binding: a located address, its Modbus table and address, and what it shows.
#[derive(Debug, Serialize, ToSchema)]
pub(crate) struct BindingInfo {
    /// The IEC located address, e.g. `%QX2.6`.
    pub(crate) at: String,
    /// `coil`, `discrete input`, `input register` or `holding register`.
    pub(crate) table: String,
    /// The first Modbus data address (0-based).
    pub(crate) address: u16,
    pub(crate) device: String,
    /// The field, or the diagnostic (`connected`, `error_code`, ...).
    pub(crate) field: String,
    #[serde(rename = "type")]
    pub(crate) ty: String,
    /// `rw` or `r`.
    pub(crate) access: String,
    /// Bound by `auto: true`.
    pub(crate) auto: bool,
}

impl From<&Binding> for BindingInfo {
    fn from(b: &Binding) -> Self {
        BindingInfo {
            at: b.at.to_string(),
            table: b.slot.table.name().to_owned(),
            address: b.slot.address,
            device: b.device.clone(),
            field: b.name.clone(),
            ty: b.ty.name().to_owned(),
            access: if b.writable { "rw" } else { "r" }.to_owned(),
            auto: b.auto,
        }
    }
}

#[derive(Debug, Serialize, ToSchema)]
pub(crate) struct MapInfo {
    /// `linux`, `esp32` or `atmega`.
    pub(crate) address_space: String,
    /// The unit id of the TCP server.
    pub(crate) unit_id: u8,
    pub(crate) read_only: bool,
    /// The TCP address it listens on (the port bound, when the config said 0), when it
    /// listens on one.
    #[schema(nullable = true)]
    pub(crate) listen: Option<String>,
    /// The serial ports it answers on as a slave.
    pub(crate) serial: Vec<SerialPortInfo>,
    pub(crate) bindings: Vec<BindingInfo>,
}

/// A serial port the Modbus server answers on as a slave.
#[derive(Debug, Serialize, ToSchema)]
pub(crate) struct SerialPortInfo {
    pub(crate) port: String,
    /// `rtu` or `ascii`.
    pub(crate) framing: String,
    /// Baud rate and character, e.g. `19200 8E1`.
    pub(crate) line: String,
    pub(crate) unit_id: u8,
    /// `opening` (not open yet, or it cannot be: see `error`), `open`, or `lost` (it
    /// failed and is being reopened).
    pub(crate) state: String,
    #[schema(nullable = true)]
    pub(crate) error: Option<String>,
    /// Openings after the port was lost.
    pub(crate) reopens: u64,
    /// Frames received, by outcome: `answered`, `exception`, `broadcast` (applied, not
    /// answered), `other_unit`, `crc_error`, `malformed` (the last three ignored).
    pub(crate) frames: BTreeMap<String, u64>,
}

/// The gateway memory: set coils and non-zero registers by located address.
#[derive(Debug, Serialize, ToSchema)]
pub(crate) struct MemoryInfo {
    pub(crate) coils: BTreeMap<String, bool>,
    /// `%QW`/`%MW` as 16-bit, `%MD` as 32-bit and `%ML` as 64-bit unsigned numbers.
    pub(crate) registers: BTreeMap<String, u64>,
}

fn no_server() -> ApiError {
    ApiError::not_found(
        "no_modbus_server",
        "no Modbus TCP server is configured (add `modbus_server:` to the config)",
    )
}

/// Every binding of the Modbus TCP server, in table and address order.
#[utoipa::path(get, path = "/api/v1/map", tag = "modbus",
    responses((status = 200, description = "the bindings", body = MapInfo),
              (status = 404, description = "no Modbus server is configured", body = ErrorBody)))]
pub(crate) async fn get_map(
    State(service): State<Arc<Service>>,
) -> Result<Json<MapInfo>, ApiError> {
    let image = service.modbus().ok_or_else(no_server)?;
    Ok(Json(MapInfo {
        address_space: image.space.kind.name().to_owned(),
        unit_id: image.config.unit_id,
        read_only: image.config.read_only,
        // Where it listens: the bound address (port 0 in the config takes a free one).
        listen: (image.config.listen)
            .map(|l| service.listening.bound("modbus").unwrap_or(l).to_string()),
        serial: service
            .serial_ports()
            .into_iter()
            .map(|p| SerialPortInfo {
                port: p.port,
                framing: p.framing.to_owned(),
                line: p.line,
                unit_id: p.unit_id,
                state: p.state.name().to_owned(),
                error: p.error,
                reopens: p.reopens,
                frames: crate::metrics::SerialOutcome::ALL
                    .iter()
                    .zip(&p.frames)
                    .map(|(o, n)| (o.label().to_owned(), n.get()))
                    .collect(),
            })
            .collect(),
        bindings: image
            .bound
            .iter()
            .map(|b| BindingInfo::from(&b.binding))
            .collect(),
    }))
}

/// The field bound to a located address, as `GET .../fields/{field}` answers it.
#[utoipa::path(get, path = "/api/v1/map/{at}", tag = "modbus",
    params(("at" = String, Path, description = "a located address, e.g. %QX2.6 (URL-encoded: %25QX2.6)")),
    responses((status = 200, description = "the field's value", body = FieldValue),
              (status = 400, description = "not a located address", body = ErrorBody),
              (status = 404, description = "no field is bound there", body = ErrorBody)))]
pub(crate) async fn get_located(
    State(service): State<Arc<Service>>,
    Path(at): Path<String>,
) -> Result<axum::response::Response, ApiError> {
    let (device, idx) = service.located(&at)?;
    super::rest::json_response(
        &convert::field_value(&service.field_view_now(&device, idx)),
        256,
    )
}

/// Writes the field bound to a located address (last value wins), as `PUT .../fields/{f}`.
#[utoipa::path(put, path = "/api/v1/map/{at}", tag = "modbus",
    params(("at" = String, Path, description = "a located address, e.g. %QW2")),
    request_body(content = Object, description = "{\"value\": X}"),
    responses((status = 202, description = "accepted: pending", body = WriteAccepted),
              (status = 400, description = "not a located address, or a value the field does not take", body = ErrorBody),
              (status = 404, description = "no field is bound there", body = ErrorBody),
              (status = 409, description = "the field is an input", body = ErrorBody)))]
pub(crate) async fn put_located(
    State(service): State<Arc<Service>>,
    Path(at): Path<String>,
    body: Bytes,
) -> Result<(StatusCode, Json<WriteAccepted>), ApiError> {
    let (device, idx) = service.located(&at)?;
    let json = super::rest::value_of(super::rest::parse_body(&body)?);
    let name = device.field(idx).name.clone();
    let write = super::rest::prepare_json(&service, &device, &name, &json)?;
    let a = service.write(write)?;
    Ok((
        StatusCode::ACCEPTED,
        Json(WriteAccepted {
            device: a.device,
            field: a.field,
            generation: a.generation,
            status: "pending".into(),
        }),
    ))
}

/// The gateway memory behind the unbound `%QX`, `%QW`, `%MW`, `%MD` and `%ML` locations.
#[utoipa::path(get, path = "/api/v1/memory", tag = "modbus",
    responses((status = 200, description = "set coils and non-zero registers", body = MemoryInfo),
              (status = 404, description = "no Modbus server is configured", body = ErrorBody)))]
pub(crate) async fn get_memory(
    State(service): State<Arc<Service>>,
) -> Result<Json<MemoryInfo>, ApiError> {
    let image = service.modbus().ok_or_else(no_server)?;
    let (coils, registers) = image.memory.contents();
    let coils = coils
        .into_iter()
        .filter_map(|a| image.space.location_at(Table::Coils, a))
        .map(|l| (l.to_string(), true))
        .collect();
    let mut out = BTreeMap::new();
    for (address, _) in &registers {
        // Each location once, at its first register, with all its registers.
        let start = (0..4u16).find_map(|back| {
            let a = address.checked_sub(back)?;
            let l = image.space.location_at(Table::HoldingRegisters, a)?;
            let width = image.space.slot(&l).ok()?.width;
            (back < width).then_some((l, a, width))
        });
        if let Some((location, a, width)) = start {
            let value = (0..width).fold(0u64, |acc, k| {
                (acc << 16) | u64::from(image.memory.register(a + k))
            });
            out.insert(location.to_string(), value);
        }
    }
    Ok(Json(MemoryInfo {
        coils,
        registers: out,
    }))
}

//! `POST /api/v1/links/{link}/transactions`: one raw Modbus transaction on a link, queued
//! between polls, answered as the write and read function blocks report it.

use std::sync::Arc;
use std::time::Duration;

use axum::Json;
use axum::body::Bytes;
use axum::extract::{Path, State};
use serde::Serialize;
use utoipa::ToSchema;

use super::error::{ApiError, ErrorBody};
use crate::config::transactions::StandingConfig;
use crate::service::{Service, Standing, StandingStatus};
use crate::transaction::{Outcome, TransactionSpec};

/// How a transaction ended.
#[derive(Debug, Serialize, ToSchema)]
pub(crate) struct TransactionResult {
    /// The command got a correct response.
    pub(crate) actual: bool,
    /// 4 done; -1 interface unavailable; -2 response timeout; -3 unknown error.
    pub(crate) state: i32,
    /// A read's value after divisor and precision; null for writes and failures.
    pub(crate) value: Option<f64>,
    /// What went wrong, in the read block's words (`Slave timeout`, `Invalid address`, ...).
    pub(crate) error: Option<String>,
    /// The request frame in hex (`11 06 00 01 00 03 9A 9B`).
    pub(crate) request: String,
    /// The response frame in hex; null when none came.
    pub(crate) response: Option<String>,
    pub(crate) elapsed_ms: f64,
}

impl From<Outcome> for TransactionResult {
    fn from(o: Outcome) -> Self {
        TransactionResult {
            actual: o.actual,
            state: o.state,
            value: o.value,
            error: o.error.map(str::to_owned),
            request: o.request,
            response: o.response,
            elapsed_ms: o.elapsed_ms,
        }
    }
}

/// Runs one transaction: a read (FC01-04) or a write (FC05/06/15/16). A transaction that ran
/// and failed is still 200 (`actual: false`, its `state` and `error`); parameters that fail
/// are 400 naming every problem.
#[utoipa::path(post, path = "/api/v1/links/{link}/transactions", tag = "links",
    params(("link" = String, Path, description = "link name")),
    request_body = TransactionSpec,
    responses((status = 200, description = "the transaction ran (check `actual`)", body = TransactionResult),
              (status = 400, description = "every parameter problem, in the read block's messages", body = ErrorBody),
              (status = 404, description = "no such link (`unknown_link`, the read block's `Missing RS485 configuration.`)", body = ErrorBody),
              (status = 503, description = "the link's queue is full, or the gateway is stopping", body = ErrorBody)))]
pub(crate) async fn post_transaction(
    State(service): State<Arc<Service>>,
    Path(link): Path<String>,
    body: Bytes,
) -> Result<Json<TransactionResult>, ApiError> {
    let spec: TransactionSpec = serde_json::from_slice(&body).map_err(|e| {
        ApiError::bad_request("invalid_body", format!("the transaction is not valid: {e}"))
    })?;
    Ok(Json(service.transact(&link, &spec).await?.into()))
}

/// A standing transaction: its settings and its latest outcome (the fields of a one-shot's
/// answer) with `name`, `enabled` and a timestamp.
#[derive(Debug, Serialize, ToSchema)]
pub(crate) struct StandingInfo {
    pub(crate) name: String,
    pub(crate) link: String,
    /// `read` or `write`.
    pub(crate) kind: String,
    pub(crate) enabled: bool,
    /// `refresh_interval` of a read (after the previous finished) or `polling_period` of a
    /// write (from the start of the previous); 0: only when triggered.
    pub(crate) period_ms: u64,
    pub(crate) actual: bool,
    /// 0 not active (not run yet); while a run is under way 1 waiting for the link, 2 the
    /// link taken, 3 on the line; then 4 done, -1 interface unavailable, -2 response timeout,
    /// -3 unknown error.
    pub(crate) state: i32,
    pub(crate) value: Option<f64>,
    pub(crate) error: Option<String>,
    pub(crate) request: Option<String>,
    pub(crate) response: Option<String>,
    pub(crate) elapsed_ms: Option<f64>,
    pub(crate) runs: u64,
    pub(crate) failures: u64,
    /// When the last run ended (RFC 3339).
    pub(crate) timestamp: Option<String>,
    pub(crate) parameters: TransactionSpec,
}

pub(crate) fn standing_info(s: &Standing, status: &StandingStatus) -> StandingInfo {
    let last = status.last.as_ref();
    StandingInfo {
        name: s.name.clone(),
        link: s.link.clone(),
        kind: if s.is_write { "write" } else { "read" }.to_owned(),
        enabled: status.enabled,
        period_ms: s.period.as_millis() as u64,
        actual: last.is_some_and(|o| o.actual),
        state: status.state(),
        value: last.and_then(|o| o.value),
        error: last.and_then(|o| o.error).map(str::to_owned),
        request: last.map(|o| o.request.clone()),
        response: last.and_then(|o| o.response.clone()),
        elapsed_ms: last.map(|o| o.elapsed_ms),
        runs: status.runs,
        failures: status.failures,
        timestamp: status.updated.map(crate::api::convert::rfc3339),
        parameters: s.spec(),
    }
}

#[derive(Debug, Serialize, ToSchema)]
pub(crate) struct StandingList {
    pub(crate) transactions: Vec<StandingInfo>,
}

/// The body of `PUT /api/v1/transactions/{name}`: the one-shot's keys plus `link` and a
/// period.
#[derive(Debug, serde::Deserialize, ToSchema)]
pub(crate) struct StandingDeclaration {
    pub(crate) link: String,
    /// Reads: milliseconds between the end of one run and the next (0: only triggered).
    #[serde(default, deserialize_with = "whole_ms")]
    pub(crate) refresh_interval_ms: u64,
    /// Writes: milliseconds between the starts of runs (0: only triggered).
    #[serde(default, deserialize_with = "whole_ms")]
    pub(crate) polling_period_ms: u64,
    #[serde(default = "enabled_by_default")]
    pub(crate) enabled: bool,
    #[serde(flatten)]
    pub(crate) parameters: TransactionSpec,
}

/// Milliseconds as a JSON number: `1000` or `1000.0` (as JSON Schema's integers), never a
/// fraction or a negative number.
fn whole_ms<'de, D: serde::Deserializer<'de>>(d: D) -> Result<u64, D::Error> {
    let n = <serde_json::Number as serde::Deserialize>::deserialize(d)?;
    crate::config::transactions::whole_number(&n)
        .and_then(|ms| u64::try_from(ms).ok())
        .ok_or_else(|| {
            serde::de::Error::custom(format!("{n} is not a whole number of milliseconds"))
        })
}

fn enabled_by_default() -> bool {
    true
}

/// The values a standing write sends.
#[derive(Debug, serde::Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub(crate) struct StandingValues {
    #[schema(value_type = Vec<Object>)]
    pub(crate) values: Vec<serde_json::Value>,
}

type Answer = Result<Json<StandingInfo>, ApiError>;

fn answer(s: &Standing) -> Answer {
    Ok(Json(standing_info(s, &s.status())))
}

/// Every standing transaction.
#[utoipa::path(get, path = "/api/v1/transactions", tag = "transactions",
    responses((status = 200, description = "every standing transaction", body = StandingList)))]
pub(crate) async fn list_standing(State(service): State<Arc<Service>>) -> Json<StandingList> {
    Json(StandingList {
        transactions: service
            .standing()
            .all()
            .iter()
            .map(|s| standing_info(s, &s.status()))
            .collect(),
    })
}

/// One standing transaction with its latest outcome.
#[utoipa::path(get, path = "/api/v1/transactions/{name}", tag = "transactions",
    params(("name" = String, Path, description = "transaction name")),
    responses((status = 200, description = "the transaction", body = StandingInfo),
              (status = 404, description = "no such transaction", body = ErrorBody)))]
pub(crate) async fn get_standing(
    State(service): State<Arc<Service>>,
    Path(name): Path<String>,
) -> Answer {
    answer(service.transaction(&name)?.as_ref())
}

/// Declares a standing transaction (idempotent); it starts at once when enabled.
#[utoipa::path(put, path = "/api/v1/transactions/{name}", tag = "transactions",
    params(("name" = String, Path, description = "transaction name")),
    request_body = StandingDeclaration,
    responses((status = 200, description = "declared (or existed with these settings)", body = StandingInfo),
              (status = 400, description = "every parameter problem", body = ErrorBody),
              (status = 404, description = "no such link (`unknown_link`)", body = ErrorBody),
              (status = 409, description = "exists with other settings", body = ErrorBody)))]
pub(crate) async fn put_standing(
    State(service): State<Arc<Service>>,
    Path(name): Path<String>,
    body: Bytes,
) -> Answer {
    let d: StandingDeclaration = serde_json::from_slice(&body).map_err(|e| {
        ApiError::bad_request("invalid_body", format!("the transaction is not valid: {e}"))
    })?;
    let period = Duration::from_millis(d.refresh_interval_ms.max(d.polling_period_ms));
    if period > Duration::from_secs(3600) {
        return Err(ApiError::bad_request(
            "invalid_transaction",
            crate::transaction::params::ParamError::Refresh.to_string(),
        ));
    }
    let (s, _) = service.ensure_transaction(StandingConfig {
        name,
        link: d.link,
        spec: d.parameters,
        period,
        enabled: d.enabled,
        line: 0,
    })?;
    answer(&s)
}

/// Removes a standing transaction declared at run time: it runs no more, and its link can
/// then be removed; one from the config file stays.
#[utoipa::path(delete, path = "/api/v1/transactions/{name}", tag = "transactions",
    params(("name" = String, Path, description = "transaction name")),
    responses((status = 204, description = "the transaction was removed"),
              (status = 404, description = "no such transaction", body = ErrorBody),
              (status = 409, description = "the transaction comes from the config file", body = ErrorBody)))]
pub(crate) async fn delete_standing(
    State(service): State<Arc<Service>>,
    Path(name): Path<String>,
) -> Result<axum::http::StatusCode, ApiError> {
    service.remove_transaction(&name)?;
    Ok(axum::http::StatusCode::NO_CONTENT)
}

/// Enables a standing transaction.
#[utoipa::path(post, path = "/api/v1/transactions/{name}/enable", tag = "transactions",
    params(("name" = String, Path, description = "transaction name")),
    responses((status = 200, description = "enabled", body = StandingInfo),
              (status = 404, description = "no such transaction", body = ErrorBody)))]
pub(crate) async fn enable_standing(
    State(service): State<Arc<Service>>,
    Path(name): Path<String>,
) -> Answer {
    answer(service.enable_transaction(&name, true)?.as_ref())
}

/// Disables a standing transaction.
#[utoipa::path(post, path = "/api/v1/transactions/{name}/disable", tag = "transactions",
    params(("name" = String, Path, description = "transaction name")),
    responses((status = 200, description = "disabled", body = StandingInfo),
              (status = 404, description = "no such transaction", body = ErrorBody)))]
pub(crate) async fn disable_standing(
    State(service): State<Arc<Service>>,
    Path(name): Path<String>,
) -> Answer {
    answer(service.enable_transaction(&name, false)?.as_ref())
}

/// Runs a standing transaction now (ignored while one of its runs is in flight).
#[utoipa::path(post, path = "/api/v1/transactions/{name}/trigger", tag = "transactions",
    params(("name" = String, Path, description = "transaction name")),
    responses((status = 200, description = "triggered", body = StandingInfo),
              (status = 404, description = "no such transaction", body = ErrorBody),
              (status = 409, description = "the transaction is disabled: a trigger would run nothing", body = ErrorBody)))]
pub(crate) async fn trigger_standing(
    State(service): State<Arc<Service>>,
    Path(name): Path<String>,
) -> Answer {
    answer(service.trigger_transaction(&name)?.as_ref())
}

/// Sets the values a standing write sends from its next run.
#[utoipa::path(put, path = "/api/v1/transactions/{name}/values", tag = "transactions",
    params(("name" = String, Path, description = "transaction name")),
    request_body = StandingValues,
    responses((status = 200, description = "set", body = StandingInfo),
              (status = 400, description = "values the write does not take", body = ErrorBody),
              (status = 404, description = "no such transaction", body = ErrorBody)))]
pub(crate) async fn put_standing_values(
    State(service): State<Arc<Service>>,
    Path(name): Path<String>,
    body: Bytes,
) -> Answer {
    let v: StandingValues = serde_json::from_slice(&body).map_err(|e| {
        ApiError::bad_request("invalid_body", format!("send {{\"values\": [...]}}: {e}"))
    })?;
    answer(service.set_transaction_values(&name, v.values)?.as_ref())
}

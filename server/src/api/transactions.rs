//! `POST /api/v1/links/{link}/transactions`: one raw Modbus transaction on a link, queued
//! between polls, answered as the write and read function blocks report it.

use std::sync::Arc;

use axum::Json;
use axum::body::Bytes;
use axum::extract::{Path, State};
use serde::Serialize;
use utoipa::ToSchema;

use super::error::{ApiError, ErrorBody};
use crate::service::Service;
use crate::transaction::{Outcome, TransactionSpec};

/// How a transaction ended.
#[derive(Debug, Serialize, ToSchema)]
pub struct TransactionResult {
    /// The command got a correct response.
    pub actual: bool,
    /// 4 done; -1 interface unavailable; -2 response timeout; -3 unknown error.
    pub state: i32,
    /// A read's value after divisor and precision; null for writes and failures.
    pub value: Option<f64>,
    /// What went wrong, in the read block's words (`Slave timeout`, `Invalid address`, ...).
    pub error: Option<String>,
    /// The request frame in hex (`11 06 00 01 00 03 9A 9B`).
    pub request: String,
    /// The response frame in hex; null when none came.
    pub response: Option<String>,
    pub elapsed_ms: f64,
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
              (status = 400, description = "every parameter problem, in the read block's messages", body = ErrorBody)))]
pub async fn post_transaction(
    State(service): State<Arc<Service>>,
    Path(link): Path<String>,
    body: Bytes,
) -> Result<Json<TransactionResult>, ApiError> {
    let spec: TransactionSpec = serde_json::from_slice(&body).map_err(|e| {
        ApiError::bad_request("invalid_body", format!("the transaction is not valid: {e}"))
    })?;
    Ok(Json(service.transact(&link, &spec).await?.into()))
}

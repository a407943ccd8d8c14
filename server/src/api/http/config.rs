//! `GET /api/v1/config` (the configuration in force and the last reload's report) and
//! `POST /api/v1/config/reload` (load the files again and apply what changed).

use std::collections::HashMap;
use std::sync::Arc;

use axum::Json;
use axum::extract::rejection::QueryRejection;
use axum::extract::{Query, State};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use serde::Serialize;
use utoipa::ToSchema;

use super::error::{ApiError, ErrorBody};
use crate::service::{ConfigStatus, ReloadError, Report, Service, Trigger};

/// The answer of an applied (or dry-run) reload.
#[derive(Debug, Serialize, ToSchema)]
pub(crate) struct ReloadAnswer {
    /// Whether the changes were applied (`false` for a dry run).
    applied: bool,
    report: Report,
}

/// One problem of a refused configuration.
#[derive(Debug, Serialize, ToSchema)]
pub(crate) struct ConfigProblem {
    file: String,
    line: u64,
    message: String,
}

#[derive(Debug, Serialize, ToSchema)]
pub(crate) struct InvalidConfigDetail {
    /// `invalid_config`.
    code: &'static str,
    message: String,
    problems: Vec<ConfigProblem>,
}

/// `{"error": {"code": "invalid_config", "message", "problems": [{file, line, message}]}}`.
#[derive(Debug, Serialize, ToSchema)]
pub(crate) struct InvalidConfig {
    error: InvalidConfigDetail,
}

fn refused(e: ReloadError) -> Response {
    match e {
        ReloadError::Invalid(problems) => {
            let body = InvalidConfig {
                error: InvalidConfigDetail {
                    code: "invalid_config",
                    message: format!(
                        "{} problem{} found; nothing was changed",
                        problems.len(),
                        if problems.len() == 1 { "" } else { "s" }
                    ),
                    problems: problems
                        .0
                        .iter()
                        .map(|p| ConfigProblem {
                            file: p.file.clone(),
                            line: p.line,
                            message: p.what(),
                        })
                        .collect(),
                },
            };
            (StatusCode::BAD_REQUEST, Json(body)).into_response()
        }
        ReloadError::NoFile => {
            ApiError::new(StatusCode::CONFLICT, "no_config_file", e.to_string()).into_response()
        }
        ReloadError::Failed(_) => {
            ApiError::new(StatusCode::CONFLICT, "reload_failed", e.to_string()).into_response()
        }
    }
}

/// Loads the config file and profiles again, checks them as `iogate check` does and
/// applies only what changed; with `dry_run=true` only reports it. Any problem and nothing
/// changes.
#[utoipa::path(post, path = "/api/v1/config/reload", tag = "config",
    params(("dry_run" = Option<bool>, Query, description = "`true`: report what would change, apply nothing")),
    responses((status = 200, description = "applied (or compared): what changed", body = ReloadAnswer),
              (status = 400, description = "the new configuration has problems: nothing changed", body = InvalidConfig),
              (status = 409, description = "the gateway runs its built-in demo (`no_config_file`), or a listener could not be bound (`reload_failed`): nothing changed", body = ErrorBody)))]
pub(crate) async fn reload(
    State(service): State<Arc<Service>>,
    query: Result<Query<HashMap<String, String>>, QueryRejection>,
) -> Response {
    let dry_run = match query.as_ref().map(|q| q.get("dry_run").map(String::as_str)) {
        Err(e) => return ApiError::bad_request("invalid_query", e.body_text()).into_response(),
        Ok(None | Some("false")) => false,
        Ok(Some("true")) => true,
        Ok(Some(other)) => {
            return ApiError::bad_request(
                "invalid_query",
                format!(
                    "dry_run must be true or false, not `{}`",
                    crate::text::quote(other)
                ),
            )
            .into_response();
        }
    };
    if let Ok(Query(q)) = &query
        && let Some(unknown) = q.keys().find(|k| *k != "dry_run")
    {
        return ApiError::bad_request(
            "invalid_query",
            format!(
                "unknown query parameter `{}` (expected: dry_run)",
                crate::text::quote(unknown)
            ),
        )
        .into_response();
    }
    match service.reload(Trigger::Api, dry_run).await {
        Ok(report) => Json(ReloadAnswer {
            applied: !dry_run,
            report,
        })
        .into_response(),
        Err(e) => refused(e),
    }
}

/// The configuration in force: its file, hash and load time, whether it is watched, and
/// the last reload's report (or the problems of the last refused one).
#[utoipa::path(get, path = "/api/v1/config", tag = "config",
    responses((status = 200, description = "the configuration in force", body = ConfigStatus)))]
pub(crate) async fn get_config(State(service): State<Arc<Service>>) -> Json<ConfigStatus> {
    let mut status = service.config_status().unwrap_or_else(|| ConfigStatus {
        file: "built-in demo".to_owned(),
        profiles: None,
        hash: String::new(),
        loaded_at_unix_ms: 0,
        watch: false,
        last_report: None,
        last_problems: Vec::new(),
        listening: Vec::new(),
    });
    status.listening = service.listening.list();
    Json(status)
}

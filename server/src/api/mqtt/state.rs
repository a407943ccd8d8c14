//! The MQTT front-end's shared state: its status, which its task writes and readers copy,
//! and its metric families; through its [`Door`], what `/readyz` and `/metrics` show of it.

use std::sync::{Arc, Mutex};

use serde::Serialize;

use super::metrics::MqttMetrics;
use super::status::MqttStatus;
use crate::service::doors::Door;

/// The front-end's shared state.
#[derive(Debug)]
pub(crate) struct MqttState {
    status: Mutex<MqttStatus>,
    /// Its metric families, kept by the gateway's metrics across restarts.
    pub(crate) metrics: Arc<MqttMetrics>,
}

/// The MQTT front-end in `/readyz`.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub(crate) struct MqttHealth {
    pub(crate) connected: bool,
    /// Messages waiting in the buffer for the broker.
    pub(crate) buffered: u64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) last_error: Option<String>,
}

impl Door for MqttState {
    fn name(&self) -> &'static str {
        "mqtt"
    }

    fn health(&self) -> Option<serde_json::Value> {
        let s = self.status();
        serde_json::to_value(MqttHealth {
            connected: s.connected,
            buffered: s.buffer.messages,
            last_error: s.last_error,
        })
        .ok()
    }

    fn encode_metrics(&self, out: &mut String) -> std::fmt::Result {
        self.metrics.encode(&self.status(), out)
    }
}

impl MqttState {
    pub(crate) fn new(metrics: Arc<MqttMetrics>) -> MqttState {
        MqttState {
            status: Mutex::default(),
            metrics,
        }
    }

    pub(crate) fn status(&self) -> MqttStatus {
        self.status
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }

    pub(crate) fn update(&self, f: impl FnOnce(&mut MqttStatus)) {
        f(&mut self.status.lock().unwrap_or_else(|e| e.into_inner()));
    }
}

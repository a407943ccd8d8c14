//! The MQTT front-end's status as the rest of the gateway shows it (`GET /api/v1/mqtt`,
//! `/readyz`, the web page, the metrics): a copy of what its task counts (`state.rs`).

use serde::Serialize;

/// What `GET /api/v1/mqtt` shows.
#[derive(Debug, Clone, Default, Serialize, utoipa::ToSchema)]
pub(crate) struct MqttStatus {
    /// The broker's URL.
    pub(crate) broker: String,
    pub(crate) client_id: String,
    pub(crate) connected: bool,
    /// Why the last connection failed or ended.
    pub(crate) last_error: Option<String>,
    /// Connections made after the first.
    pub(crate) reconnects: u64,
    pub(crate) messages_out: u64,
    pub(crate) bytes_out: u64,
    pub(crate) messages_in: u64,
    pub(crate) bytes_in: u64,
    /// Packets from the broker read past and dropped: over the 1 MiB accepted, malformed,
    /// or of a type a client does not receive (each logged with its reason).
    pub(crate) dropped_in: u64,
    /// Writes refused (bad topic, payload or value, or writes not enabled).
    pub(crate) writes_refused: u64,
    /// Commands (`/set`, NCMD, DCMD) the broker delivered as retained: stored messages, not
    /// commands now, so not executed (the first logged).
    pub(crate) retained_ignored: u64,
    /// Writes accepted from `/set`, DCMD.
    pub(crate) writes_accepted: u64,
    pub(crate) buffer: BufferStatus,
    /// Present when the Sparkplug B edge node is configured.
    pub(crate) sparkplug: Option<SparkplugStatus>,
    /// Present when the plain JSON topics are configured.
    pub(crate) json_prefix: Option<String>,
}

/// The store-and-forward buffer.
#[derive(Debug, Clone, Default, Serialize, utoipa::ToSchema)]
pub(crate) struct BufferStatus {
    /// The directory, when messages are kept on disk while the broker is away.
    pub(crate) dir: Option<String>,
    /// Messages kept and not yet acknowledged by the broker.
    pub(crate) messages: u64,
    pub(crate) bytes: u64,
    /// Age of the oldest message kept, in seconds.
    pub(crate) oldest_age_s: u64,
    /// Messages dropped: over `max_bytes` or `max_age`, torn by a crash, or with no buffer.
    pub(crate) dropped: u64,
    /// Messages replayed from the buffer (and acknowledged).
    pub(crate) replayed: u64,
}

/// The Sparkplug B edge node.
#[derive(Debug, Clone, Default, Serialize, utoipa::ToSchema)]
pub(crate) struct SparkplugStatus {
    pub(crate) group_id: String,
    pub(crate) edge_node_id: String,
    /// The birth/death sequence number of the current (or last) connection.
    pub(crate) bd_seq: u8,
    /// NBIRTH published on this connection (and not dead since).
    pub(crate) born: bool,
    /// Devices with a DBIRTH and no DDEATH since.
    pub(crate) born_devices: usize,
    pub(crate) rebirths: u64,
    /// The primary host application, when one is configured.
    pub(crate) primary_host: Option<String>,
    /// Whether its STATE says online (`None` until one is seen).
    pub(crate) host_online: Option<bool>,
}

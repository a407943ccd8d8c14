//! The metrics' names, as consts (counters get `_total` from the encoder).

// Counter names get `_total` appended by the encoder.
pub const LINK_UP: &str = "iogate_link_up";
pub const LINK_ERROR_CODE: &str = "iogate_link_error_code";
pub const LINK_STALLED: &str = "iogate_link_stalled";
pub const LINK_RECONNECTS: &str = "iogate_link_reconnects";
pub const LINK_SENT_BYTES: &str = "iogate_link_sent_bytes";
pub const LINK_RECEIVED_BYTES: &str = "iogate_link_received_bytes";
pub const LINK_DISCARDED_BYTES: &str = "iogate_link_discarded_bytes";
pub const LINK_PLANNED_UTILISATION: &str = "iogate_link_planned_utilisation_ratio";
pub const LINK_UTILISATION: &str = "iogate_link_utilisation_ratio";
pub const LINK_INBOX_DEPTH: &str = "iogate_link_inbox_requests";
pub const LINK_INBOX_OLDEST: &str = "iogate_link_inbox_oldest_seconds";
pub const LINK_INBOX_DROPPED: &str = "iogate_link_inbox_dropped";
pub const DEVICE_CONNECTED: &str = "iogate_device_connected";
pub const DEVICE_ERROR_CODE: &str = "iogate_device_error_code";
pub const DEVICE_IO_CYCLES: &str = "iogate_device_io_cycles";
pub const DEVICE_MISMATCHED_OUTPUTS: &str = "iogate_device_mismatched_outputs";
pub const DEVICE_SAFE_WRITES: &str = "iogate_device_safe_value_writes";
/// Counted by result (`_total` is added by the registry).
pub const CONFIG_RELOADS: &str = "iogate_config_reloads";
pub const DEVICE_RESPONSE_TIME: &str = "iogate_device_response_time_seconds";
pub const DEVICE_REQUESTS: &str = "iogate_device_requests";
pub const DEVICE_TIMEOUTS: &str = "iogate_device_timeouts";
pub const DEVICE_CRC_ERRORS: &str = "iogate_device_crc_errors";
pub const DEVICE_EXCEPTIONS: &str = "iogate_device_exceptions";
pub const DEVICE_WRITES: &str = "iogate_device_writes";
pub const TRANSACTION_RUNS: &str = "iogate_transaction_runs";
pub const MODBUS_SERVER_CONNECTIONS: &str = "iogate_modbus_server_connections";
pub const MODBUS_SERVER_REFUSED: &str = "iogate_modbus_server_refused_connections";
pub const MODBUS_SERVER_EVICTED: &str = "iogate_modbus_server_evicted_connections";
pub const MODBUS_SERVER_REQUESTS: &str = "iogate_modbus_server_requests";
pub const MODBUS_SERVER_EXCEPTIONS: &str = "iogate_modbus_server_exceptions";
pub const MODBUS_SERIAL_PORT_UP: &str = "iogate_modbus_serial_port_up";
pub const MODBUS_SERIAL_REOPENS: &str = "iogate_modbus_serial_port_reopens";
pub const MODBUS_SERIAL_FRAMES: &str = "iogate_modbus_serial_frames";
pub const BOUND_LIMIT: &str = "iogate_bound_limit";
pub const BOUND_USED: &str = "iogate_bound_used";
pub const BOUND_REFUSED: &str = "iogate_bound_refused";

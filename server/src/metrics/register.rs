//! Every metric of the gateway's own registered once, with its help text.

use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::registry::Registry;

use super::*;

impl Metrics {
    /// The registry with every metric registered.
    pub(crate) fn new() -> Self {
        let mut registry = Registry::default();
        let m = Metrics {
            link_up: Family::default(),
            link_error_code: Family::default(),
            link_stalled: Family::default(),
            link_reconnects: Family::default(),
            link_sent: Family::default(),
            link_received: Family::default(),
            link_discarded: Family::default(),
            link_planned: Family::default(),
            link_utilisation: Family::default(),
            inbox_depth: Family::default(),
            inbox_oldest: Family::default(),
            inbox_dropped: Family::default(),
            device_connected: Family::default(),
            device_error_code: Family::default(),
            device_io_cycles: Family::default(),
            device_mismatched: Family::default(),
            safe_writes: Family::default(),
            config_reloads: Family::default(),
            response_time: Family::new_with_constructor(response_histogram),
            requests: Family::default(),
            timeouts: Family::default(),
            crc_errors: Family::default(),
            exceptions: Family::default(),
            writes: Family::default(),
            transaction_runs: Family::default(),
            server_connections: Gauge::default(),
            server_refused: Counter::default(),
            server_evicted: Counter::default(),
            server_requests: Family::default(),
            server_exceptions: Family::default(),
            serial_up: Family::default(),
            serial_reopens: Family::default(),
            serial_frames: Family::default(),
            bound_limit: Family::default(),
            bound_used: Family::default(),
            bound_refused: Family::default(),
            kept: std::sync::Mutex::default(),
            registry: Registry::default(),
        };
        register_links_state(&mut registry, &m);
        register_link_traffic(&mut registry, &m);
        register_devices(&mut registry, &m);
        register_modbus_server(&mut registry, &m);
        register_bounds(&mut registry, &m);
        Metrics { registry, ..m }
    }
}

/// The links' and devices' state, and the configuration reloads.
fn register_links_state(registry: &mut Registry, m: &Metrics) {
    registry.register(
        LINK_UP,
        "1 while the link's port or connection is open",
        m.link_up.clone(),
    );
    registry.register(
        LINK_ERROR_CODE,
        "SerialLink error code: 0 OK, 1 no port configured, 2 open failed, 3 port lost",
        m.link_error_code.clone(),
    );
    registry.register(
        LINK_STALLED,
        "1 while the link's task is stuck in a transaction past its bound (timeout, wire time and 5 s)",
        m.link_stalled.clone(),
    );
    registry.register(
        DEVICE_MISMATCHED_OUTPUTS,
        "Outputs the device was read holding another value in than the newest requested, with no write of it waiting",
        m.device_mismatched.clone(),
    );
    registry.register(
        DEVICE_SAFE_WRITES,
        "Safe values written because the scan-cycle client that wrote the output was lost (on_client_loss)",
        m.safe_writes.clone(),
    );
    registry.register(
        CONFIG_RELOADS,
        "Configuration reloads by result: applied, unchanged, invalid (nothing changed), failed (nothing changed)",
        m.config_reloads.clone(),
    );
    for result in ["applied", "unchanged", "invalid", "failed"] {
        let _ = m.config_reloads.get_or_create(&ResultLabels {
            result: result.to_owned(),
        });
    }
}

/// What the links carry and how busy they are.
fn register_link_traffic(registry: &mut Registry, m: &Metrics) {
    registry.register(
        LINK_RECONNECTS,
        "Times the link was reopened after it was lost",
        m.link_reconnects.clone(),
    );
    registry.register(
        LINK_SENT_BYTES,
        "Bytes sent on the link",
        m.link_sent.clone(),
    );
    registry.register(
        LINK_RECEIVED_BYTES,
        "Bytes received on the link",
        m.link_received.clone(),
    );
    registry.register(
        LINK_DISCARDED_BYTES,
        "Received bytes that answered no request (late replies, noise)",
        m.link_discarded.clone(),
    );
    registry.register(
        LINK_PLANNED_UTILISATION,
        "Share of the line's time the refresh rates demand (serial links)",
        m.link_planned.clone(),
    );
    registry.register(
        LINK_INBOX_DEPTH,
        "Requests (forwarded Modbus, raw transactions) waiting in the link's inbox",
        m.inbox_depth.clone(),
    );
    registry.register(
        LINK_INBOX_OLDEST,
        "How long the oldest request in the link's inbox has waited",
        m.inbox_oldest.clone(),
    );
    registry.register(
        LINK_INBOX_DROPPED,
        "Requests never sent: the inbox was full (busy), the caller's deadline would pass (expired), or the caller had gone (abandoned)",
        m.inbox_dropped.clone(),
    );
    registry.register(
        LINK_UTILISATION,
        "Share of the last interval the link spent in transactions",
        m.link_utilisation.clone(),
    );
}

/// The devices' requests, answers and writes, and standing transactions.
fn register_devices(registry: &mut Registry, m: &Metrics) {
    registry.register(
        DEVICE_CONNECTED,
        "1 while the device answers",
        m.device_connected.clone(),
    );
    registry.register(
        DEVICE_ERROR_CODE,
        "Device error code: 0 OK, 1 no link, 2 no slave, 10 communication error",
        m.device_error_code.clone(),
    );
    registry.register(
        DEVICE_IO_CYCLES,
        "Successful I/O cycles",
        m.device_io_cycles.clone(),
    );
    registry.register(
        DEVICE_RESPONSE_TIME,
        "Time from request to good response",
        m.response_time.clone(),
    );
    registry.register(
        DEVICE_REQUESTS,
        "Modbus requests by function and outcome",
        m.requests.clone(),
    );
    registry.register(
        DEVICE_TIMEOUTS,
        "Requests that got no answer in time",
        m.timeouts.clone(),
    );
    registry.register(
        DEVICE_CRC_ERRORS,
        "Responses with a bad CRC",
        m.crc_errors.clone(),
    );
    registry.register(
        DEVICE_EXCEPTIONS,
        "Modbus exception responses by code",
        m.exceptions.clone(),
    );
    registry.register(
        DEVICE_WRITES,
        "Writes by final outcome: written, superseded, failed",
        m.writes.clone(),
    );
    registry.register(
        TRANSACTION_RUNS,
        "Runs of standing transactions, by name and outcome (ok: a correct response)",
        m.transaction_runs.clone(),
    );
}

/// The Modbus server (TCP and serial).
fn register_modbus_server(registry: &mut Registry, m: &Metrics) {
    registry.register(
        MODBUS_SERVER_CONNECTIONS,
        "Open connections of Modbus TCP masters",
        m.server_connections.clone(),
    );
    registry.register(
        MODBUS_SERVER_REFUSED,
        "Modbus TCP connections refused (max_connections reached, every connection being answered)",
        m.server_refused.clone(),
    );
    registry.register(
        MODBUS_SERVER_EVICTED,
        "Modbus TCP connections closed for a new master (max_connections reached; the one waiting longest on its master)",
        m.server_evicted.clone(),
    );
    registry.register(
        MODBUS_SERVER_REQUESTS,
        "Requests the Modbus server answered (over TCP and its serial ports), by function and outcome (ok, exception)",
        m.server_requests.clone(),
    );
    registry.register(
        MODBUS_SERVER_EXCEPTIONS,
        "Exception responses of the Modbus server (TCP and serial), by code",
        m.server_exceptions.clone(),
    );
    registry.register(
        MODBUS_SERIAL_PORT_UP,
        "Whether a serial port of the Modbus server is open (1) or lost and being reopened (0)",
        m.serial_up.clone(),
    );
    registry.register(
        MODBUS_SERIAL_REOPENS,
        "Times a serial port of the Modbus server was opened again after it was lost",
        m.serial_reopens.clone(),
    );
    registry.register(
        MODBUS_SERIAL_FRAMES,
        "Frames a serial port of the Modbus server received, by outcome: answered, exception, broadcast (applied, not answered), other_unit (ignored), crc_error (CRC or LRC, ignored), malformed (ignored)",
        m.serial_frames.clone(),
    );
}

/// The bounds on what clients can make the gateway hold.
fn register_bounds(registry: &mut Registry, m: &Metrics) {
    registry.register(
        BOUND_LIMIT,
        "The limit of a bound on what clients can make the gateway hold (the README's table of bounds)",
        m.bound_limit.clone(),
    );
    registry.register(
        BOUND_USED,
        "How much of a bound clients hold now",
        m.bound_used.clone(),
    );
    registry.register(
        BOUND_REFUSED,
        "Clients refused at a bound (or, where the bound makes room, the oldest closed)",
        m.bound_refused.clone(),
    );
}

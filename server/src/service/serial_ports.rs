//! The Modbus server's serial ports as the overview shows them: state, settings and frame
//! counts, kept by each port's task.

use std::collections::BTreeMap;
use std::sync::Mutex;

use super::Service;

/// Whether a port is served.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(crate) enum PortState {
    /// Not open yet (or it cannot be opened: see the error).
    #[default]
    Opening,
    Open,
    /// Was open and failed; being reopened.
    Lost,
}

impl PortState {
    pub(crate) fn name(self) -> &'static str {
        match self {
            PortState::Opening => "opening",
            PortState::Open => "open",
            PortState::Lost => "lost",
        }
    }
}

/// One serial port of the Modbus server.
#[derive(Debug, Clone, Default)]
pub(crate) struct PortStatus {
    pub(crate) port: String,
    /// `rtu` or `ascii`.
    pub(crate) framing: &'static str,
    /// As in `19200 8E1`.
    pub(crate) line: String,
    pub(crate) unit_id: u8,
    pub(crate) state: PortState,
    /// Why it is not open, when it is not.
    pub(crate) error: Option<String>,
    /// Openings after the port was lost.
    pub(crate) reopens: u64,
    /// Frames by outcome, indexed as [`crate::metrics::SerialOutcome::ALL`]: the port's
    /// metric counters themselves.
    pub(crate) frames: [prometheus_client::metrics::counter::Counter; 6],
}

/// The ports by name.
#[derive(Debug, Default)]
pub(crate) struct SerialPorts(Mutex<BTreeMap<String, PortStatus>>);

impl Service {
    /// Every serial port of the Modbus server, by port name.
    pub(crate) fn serial_ports(&self) -> Vec<PortStatus> {
        let ports = self
            .serial_ports
            .0
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        ports.values().cloned().collect()
    }

    /// Changes what the overview shows of `port` (added when new).
    pub(crate) fn serial_port_update(&self, port: &str, change: impl FnOnce(&mut PortStatus)) {
        let mut ports = self
            .serial_ports
            .0
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        let status = ports.entry(port.to_owned()).or_insert_with(|| PortStatus {
            port: port.to_owned(),
            ..PortStatus::default()
        });
        change(status);
    }

    /// `port` is no longer served.
    pub(crate) fn serial_port_removed(&self, port: &str) {
        let mut ports = self
            .serial_ports
            .0
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        ports.remove(port);
        self.metrics.serial_port_removed(port);
    }
}

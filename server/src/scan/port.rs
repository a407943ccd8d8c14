//! A scan's probes on a serial port of its own (`iogate scan --port`): the port is opened
//! at each setting, nothing else uses it.

use std::time::Duration;

use tokio::time::Instant;

use super::{Prober, ScanError, Setting};
use crate::link::rtu::RtuTransport;
use crate::link::timing::LineTiming;

pub struct PortProber {
    port: String,
    timeout: Duration,
    transport: Option<RtuTransport>,
}

impl PortProber {
    pub fn new(port: &str, timeout: Duration) -> Self {
        PortProber {
            port: port.to_owned(),
            timeout,
            transport: None,
        }
    }
}

#[async_trait::async_trait]
impl Prober for PortProber {
    async fn set(&mut self, setting: &Setting) -> Result<(), ScanError> {
        // Closed first: a port is opened once at a time.
        self.transport = None;
        let settings = setting.serial(&self.port);
        let stream =
            crate::link::open_serial(&settings).map_err(|e| ScanError::Port(e.to_string()))?;
        self.transport = Some(RtuTransport::new(
            Box::new(stream),
            Some(LineTiming::new(&settings)),
            Duration::ZERO,
        ));
        Ok(())
    }

    async fn probe(&mut self, slave: u8, pdu: &[u8], early: bool) -> Result<Vec<u8>, ScanError> {
        let until = Instant::now() + self.timeout;
        let Some(transport) = self.transport.as_mut() else {
            return Err(ScanError::Port(format!("{} is not open", self.port)));
        };
        transport
            .probe(slave, pdu, until, early)
            .await
            .map_err(|e| ScanError::Port(format!("{}: {e}", self.port)))
    }
}

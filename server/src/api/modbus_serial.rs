//! The Modbus server as a slave on serial lines (`modbus_server.serial`): the same map,
//! memory, rules and exceptions as the TCP server (every request is answered by
//! [`super::modbus_server::answer`]), in RTU or ASCII frames.
//!
//! - RTU: a frame ends when the line has been silent for 3.5 characters (1.75 ms above
//!   19200 baud); a frame with a bad CRC, too short or too long is ignored.
//! - ASCII: a frame runs from `:` to CR LF; a bad LRC or a character that is no hex digit
//!   ignores it; a frame left unfinished for a second (the specification's default
//!   inter-character timeout) is dropped.
//! - Only frames for the port's `unit_id` are answered, after `turnaround_delay`; other
//!   units' frames (requests to other slaves, their answers) are ignored; broadcasts (unit
//!   0) are applied when they are writes, never answered.
//! - A port that cannot be opened or fails is opened again every second, its state shown
//!   in `GET /api/v1/map` and the metrics. A reload that changes the ports restarts the
//!   changed ones within a second.

pub(crate) mod front_end;

use std::collections::HashMap;
use std::sync::Arc;
use std::time::Duration;

use prometheus_client::metrics::counter::Counter;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::time::Instant;
use tokio_util::sync::CancellationToken;

use super::modbus_server::{Counters, answer};
use crate::config::Framing;
use crate::config::modbus_server::SerialServer;
use crate::link::rtu_frame::{self, Unframed};
use crate::link::timing::LineTiming;
use crate::link::{ByteStream, ascii, open_serial, precise};
use crate::metrics::SerialOutcome as Outcome;
use crate::service::Service;
use crate::service::serial_ports::PortState;

/// How often the ports are compared with the configuration, and a failed one reopened.
const RETRY: Duration = Duration::from_secs(1);
/// The longest RTU frame: address, 253-byte PDU, CRC.
const MAX_RTU: usize = 256;
/// ASCII's inter-character timeout (Modbus over serial line V1.02, 2.5.2.1: "1 second by
/// default").
const ASCII_GAP: Duration = Duration::from_secs(1);
/// The longest an answer may take to be written (a port that does not take it is lost).
const WRITE_WAIT: Duration = Duration::from_secs(1);

/// Serves every configured serial port until `shutdown`, following reloads.
pub(crate) async fn serve_serial(service: Arc<Service>, shutdown: CancellationToken) {
    let mut running: HashMap<String, (SerialServer, CancellationToken)> = HashMap::new();
    loop {
        let wanted = service
            .modbus()
            .map(|image| image.config.serial.clone())
            .unwrap_or_default();
        running.retain(|port, (entry, stop)| {
            let keep = wanted.iter().any(|w| w.same_as(entry));
            if !keep {
                stop.cancel();
                service.serial_port_removed(port);
            }
            keep
        });
        for entry in wanted {
            if running.contains_key(&entry.line.port) {
                continue;
            }
            let stop = shutdown.child_token();
            running.insert(entry.line.port.clone(), (entry.clone(), stop.clone()));
            service
                .clone()
                .tasks()
                .spawn(port_task(service.clone(), entry, stop));
        }
        tokio::select! {
            _ = shutdown.cancelled() => return,
            _ = tokio::time::sleep(RETRY) => {}
        }
    }
}

/// Opens the port, serves it, and opens it again when it fails, until `stop`.
async fn port_task(service: Arc<Service>, entry: SerialServer, stop: CancellationToken) {
    let port = entry.line.port.clone();
    let s = &entry.line;
    let line = format!(
        "{} {}{}{}",
        s.baud,
        s.data_bits,
        s.parity.letter(),
        s.stop_bits
    );
    service.serial_port_update(&port, |status| {
        status.framing = s.framing.name();
        status.line = line;
        status.unit_id = entry.unit_id;
        status.frames = service.metrics.serial_frames(&port);
    });
    let mut was_open = false;
    let mut last_error: Option<String> = None;
    loop {
        match open_serial(&entry.line) {
            Ok(stream) => {
                tracing::info!(%port, framing = s.framing.name(), unit_id = entry.unit_id, "Modbus server answering on a serial port");
                service.metrics.serial_port(&port, true, was_open);
                service.serial_port_update(&port, |status| {
                    status.state = PortState::Open;
                    status.error = None;
                    status.reopens += u64::from(was_open);
                });
                was_open = true;
                last_error = None;
                let served = Port::new(&service, &entry)
                    .serve(Box::new(stream), &stop)
                    .await;
                let Err(e) = served else {
                    return; // stopped
                };
                tracing::warn!(%port, error = %e, "Modbus server's serial port lost; reopening");
                service.metrics.serial_port(&port, false, false);
                service.serial_port_update(&port, |status| {
                    status.state = PortState::Lost;
                    status.error = Some(e.to_string());
                });
            }
            Err(e) => {
                let error = e.to_string();
                // Said once, not every second.
                if last_error.as_ref() != Some(&error) {
                    tracing::warn!(%port, %error, "Modbus server cannot open its serial port; trying again every second");
                }
                service.metrics.serial_port(&port, false, false);
                service.serial_port_update(&port, |status| {
                    status.state = if was_open {
                        PortState::Lost
                    } else {
                        PortState::Opening
                    };
                    status.error = Some(error.clone());
                });
                last_error = Some(error);
            }
        }
        tokio::select! {
            _ = stop.cancelled() => return,
            _ = tokio::time::sleep(RETRY) => {}
        }
    }
}

/// One open port.
struct Port<'a> {
    service: &'a Service,
    entry: &'a SerialServer,
    timing: LineTiming,
    counters: Counters,
    frames: [Counter; 6],
    timer: precise::Timer,
}

impl<'a> Port<'a> {
    fn new(service: &'a Service, entry: &'a SerialServer) -> Self {
        let port = &entry.line.port;
        Port {
            service,
            entry,
            timing: LineTiming::new(&entry.line),
            counters: Counters::default(),
            frames: service.metrics.serial_frames(port),
            timer: precise::Timer::new(),
        }
    }

    /// Serves until `stop` (`Ok`) or the port fails.
    async fn serve(
        mut self,
        mut io: Box<dyn ByteStream>,
        stop: &CancellationToken,
    ) -> std::io::Result<()> {
        match self.entry.line.framing {
            Framing::Ascii => self.serve_ascii(&mut io, stop).await,
            _ => self.serve_rtu(&mut io, stop).await,
        }
    }

    async fn serve_rtu(
        &mut self,
        io: &mut Box<dyn ByteStream>,
        stop: &CancellationToken,
    ) -> std::io::Result<()> {
        let silence = self.timing.silence();
        let mut frame: Vec<u8> = Vec::with_capacity(MAX_RTU);
        let mut too_long = false;
        let mut chunk = [0u8; 512];
        loop {
            let n = tokio::select! {
                _ = stop.cancelled() => return Ok(()),
                r = io.read(&mut chunk) => r?,
            };
            if n == 0 {
                return Err(std::io::ErrorKind::UnexpectedEof.into());
            }
            take(&mut frame, &mut too_long, &chunk[..n]);
            // The frame runs until the line has been silent for 3.5 characters.
            let mut last = Instant::now();
            loop {
                let read = tokio::select! {
                    biased;
                    _ = stop.cancelled() => return Ok(()),
                    r = io.read(&mut chunk) => r?,
                    _ = self.timer.sleep_until(last + silence) => break,
                };
                if read == 0 {
                    return Err(std::io::ErrorKind::UnexpectedEof.into());
                }
                take(&mut frame, &mut too_long, &chunk[..read]);
                last = Instant::now();
            }
            let reply = if too_long {
                self.count(Outcome::Malformed);
                None
            } else {
                self.rtu_frame(&frame).await
            };
            frame.clear();
            too_long = false;
            if let Some(reply) = reply {
                self.reply(io, &reply).await?;
            }
        }
    }

    /// The answer to an RTU frame, if it calls for one.
    async fn rtu_frame(&mut self, frame: &[u8]) -> Option<Vec<u8>> {
        let body = match rtu_frame::open(frame) {
            Ok(_) => &frame[..frame.len() - 2],
            Err(Unframed::Short) => {
                self.count(Outcome::Malformed);
                return None;
            }
            Err(Unframed::Crc) => {
                self.count(Outcome::CrcError);
                return None;
            }
        };
        let pdu = self.request(body).await?;
        Some(rtu_frame::seal(self.entry.unit_id, &pdu))
    }

    async fn serve_ascii(
        &mut self,
        io: &mut Box<dyn ByteStream>,
        stop: &CancellationToken,
    ) -> std::io::Result<()> {
        let mut assembler = ascii::Assembler::default();
        let mut chunk = [0u8; 512];
        loop {
            let read = tokio::select! {
                _ = stop.cancelled() => return Ok(()),
                r = io.read(&mut chunk) => Some(r?),
                _ = tokio::time::sleep(ASCII_GAP), if assembler.in_frame() => None,
            };
            let Some(n) = read else {
                assembler.reset();
                self.count(Outcome::Malformed);
                continue;
            };
            if n == 0 {
                return Err(std::io::ErrorKind::UnexpectedEof.into());
            }
            for &c in &chunk[..n] {
                let Some(frame) = assembler.push(c) else {
                    continue;
                };
                let reply = match frame {
                    Ok(body) => self.request(&body).await.map(|pdu| {
                        let mut body = Vec::with_capacity(pdu.len() + 1);
                        body.push(self.entry.unit_id);
                        body.extend_from_slice(&pdu);
                        ascii::encode(&body)
                    }),
                    Err(ascii::AsciiError::Lrc { .. }) => {
                        self.count(Outcome::CrcError);
                        None
                    }
                    Err(_) => {
                        self.count(Outcome::Malformed);
                        None
                    }
                };
                if let Some(reply) = reply {
                    self.reply(io, &reply).await?;
                }
            }
        }
    }

    /// The response PDU to a request frame's address and PDU (CRC or LRC already checked),
    /// when it calls for one.
    async fn request(&mut self, body: &[u8]) -> Option<Vec<u8>> {
        let (&unit, pdu) = body.split_first()?;
        if unit != 0 && unit != self.entry.unit_id {
            self.count(Outcome::OtherUnit);
            return None;
        }
        // No master sends function 0 or 128-255 (those are exception answers, maybe
        // another slave's): nothing to answer.
        match pdu.first() {
            None => {
                self.count(Outcome::Malformed);
                return None;
            }
            Some(&code) if code == 0 || code >= 0x80 => {
                self.count(Outcome::Malformed);
                return None;
            }
            Some(_) => {}
        }
        let response = answer(self.service, None, pdu, &mut self.counters).await;
        if unit == 0 {
            // A broadcast is applied (when it is a write: a read has no one to answer)
            // and never answered.
            self.count(Outcome::Broadcast);
            return None;
        }
        let exception = response.first().is_some_and(|c| c & 0x80 != 0);
        self.count(if exception {
            Outcome::Exception
        } else {
            Outcome::Answered
        });
        Some(response)
    }

    /// Writes an answer after the turnaround delay.
    async fn reply(&mut self, io: &mut Box<dyn ByteStream>, frame: &[u8]) -> std::io::Result<()> {
        if !self.entry.turnaround_delay.is_zero() {
            self.timer
                .sleep_until(Instant::now() + self.entry.turnaround_delay)
                .await;
        }
        let written = tokio::time::timeout(WRITE_WAIT, async {
            io.write_all(frame).await?;
            io.flush().await
        })
        .await;
        match written {
            Ok(result) => result,
            Err(_) => Err(std::io::Error::new(
                std::io::ErrorKind::TimedOut,
                format!("an answer was not taken by the port within {WRITE_WAIT:?}"),
            )),
        }
    }

    fn count(&self, outcome: Outcome) {
        self.frames[outcome as usize].inc();
    }
}

/// Adds received bytes to an RTU frame, up to the longest one (beyond it the frame is
/// marked too long and its bytes dropped).
fn take(frame: &mut Vec<u8>, too_long: &mut bool, bytes: &[u8]) {
    if frame.len() + bytes.len() > MAX_RTU {
        *too_long = true;
        return;
    }
    frame.extend_from_slice(bytes);
}

//! Siemens S7 PLCs as devices (`protocol: s7`): S7comm over ISO-on-TCP, written here (the
//! crates read were synchronous or a first release). A link is a PLC (`s7:` with `host`,
//! rack and slot or TSAPs); a field names its `address` as S7 users write it. A device's
//! fields are read in the fewest jobs the negotiated PDU allows; a BOOL is written as a
//! bit, never by rewriting its byte.

mod clock;
mod config;
mod conn;
pub(crate) mod pdu;
mod szl;
mod value;
mod write;

use std::sync::Arc;
use std::time::Duration;

use tokio::time::Instant;

use super::{Driver, Read, Session};
use crate::cache::{Device, FieldError, Link, Progress};
use crate::config::{LinkConfig, Transport};
use crate::link::LinkFault;
use crate::metrics::Metrics;
use crate::plan::WriteItem;
use crate::plan::s7::{self as plan, Batch, Place};
use conn::{Connection, S7Error};
use szl::Mode;

/// The S7 driver.
pub(crate) struct S7;

/// Its links' key and its profiles' protocol.
pub(crate) const PROTOCOL: &str = "s7";

/// What is kept of a device: its fields' places and the jobs planned for a PDU size.
pub(crate) struct Plan {
    places: Vec<Result<Place, String>>,
    batches: Vec<Batch>,
    /// The PDU size the batches were planned for (0: not yet).
    pdu: u16,
    /// Fields read in items of their own (their range, merged, was out of range).
    alone: std::collections::BTreeSet<usize>,
}

/// An open PLC connection.
pub(crate) struct Plc {
    conn: Connection,
    link: Arc<Link>,
    progress: Arc<Progress>,
    timeout: Duration,
    /// The PLC's operating state as last read, and when to read it again.
    mode: Option<Mode>,
    next_mode: Instant,
    /// The PLC's last refusal of a whole job, told once in the log.
    refused: Option<String>,
}

/// How often the operating state is read while the PLC is polled.
const MODE_EVERY: Duration = Duration::from_secs(2);

/// What a PLC in STOP does to its values.
const IN_STOP: &str =
    "the PLC is in STOP: its program does not run and these values do not change; switch it to RUN";

/// The connection's end.
fn lost(e: S7Error) -> LinkFault {
    LinkFault::Lost(Arc::new(std::io::Error::other(e.to_string())))
}

/// An error of a job: the connection's end, or (`Ok`) the PLC's refusal of the job.
fn fault(e: S7Error) -> Result<String, LinkFault> {
    match e {
        S7Error::Malformed(m @ pdu::Malformed::Refused { .. }) => Ok(m.to_string()),
        e => Err(lost(e)),
    }
}

impl Driver for S7 {
    type Plan = Plan;
    type Session = Plc;
    const NAME: &'static str = PROTOCOL;

    fn serves(config: &LinkConfig) -> bool {
        matches!(&config.transport, Transport::Driver(d) if d.protocol == PROTOCOL)
    }

    fn check(config: &LinkConfig, report: &mut crate::yaml::Report) {
        if let Transport::Driver(d) = &config.transport {
            config::read(&config.name, d, report);
        }
    }

    fn plan(device: &Device) -> Plan {
        Plan {
            places: plan::places(&device.profile),
            batches: Vec::new(),
            pdu: 0,
            alone: Default::default(),
        }
    }

    async fn open(
        config: &LinkConfig,
        link: &Arc<Link>,
        _metrics: &Arc<Metrics>,
    ) -> Result<Plc, LinkFault> {
        let Transport::Driver(d) = &config.transport else {
            return Err(LinkFault::NoPort);
        };
        let mut report = crate::yaml::Report::new("config");
        let Some(s) = config::read(&config.name, d, &mut report) else {
            return Err(LinkFault::OpenFailed {
                port: d.endpoint.clone(),
                reason: report.into_problems().to_string(),
            });
        };
        let conn = Connection::open(
            (s.host.as_str(), s.port),
            s.local_tsap,
            s.remote_tsap,
            s.pdu,
            s.timeout,
        )
        .await
        .map_err(|e| LinkFault::ConnectFailed {
            endpoint: format!("{}:{}", s.host, s.port),
            reason: Arc::new(std::io::Error::other(e.to_string())),
        })?;
        let mut plc = Plc {
            conn,
            link: link.clone(),
            progress: link.progress.clone(),
            timeout: s.timeout,
            mode: None,
            next_mode: Instant::now(),
            refused: None,
        };
        link.set_peer("pdu_size", plc.conn.pdu.to_string());
        plc.identify().await.map_err(|e| LinkFault::ConnectFailed {
            endpoint: format!("{}:{}", s.host, s.port),
            reason: Arc::new(std::io::Error::other(e.to_string())),
        })?;
        Ok(plc)
    }
}

impl Plc {
    fn started(&self) {
        self.progress.started(Instant::now() + self.timeout);
    }

    /// One SZL record's text: `None` where the PLC does not answer it (a refusal), an error
    /// where the connection failed.
    async fn szl_text(
        &mut self,
        (id, index, len): (u16, u16, usize),
    ) -> Result<Option<String>, S7Error> {
        self.started();
        let answered = self.conn.szl(id, index).await;
        self.progress.ended();
        match answered {
            Ok(records) => Ok(records.first().and_then(|r| szl::text(r, len))),
            Err(S7Error::Malformed(e)) => {
                tracing::debug!(link = %self.link.name(), "SZL {id:#06x}/{index}: {e}");
                Ok(None)
            }
            Err(e) => Err(e),
        }
    }

    /// Reads the PLC's identity and operating state into the link's state.
    async fn identify(&mut self) -> Result<(), S7Error> {
        let facts = [
            ("order_number", (szl::MODULE_ID, 1, szl::ORDER_LEN)),
            (
                "module",
                (szl::COMPONENT_ID, szl::MODULE_NAME, szl::NAME_LEN),
            ),
            (
                "serial_number",
                (szl::COMPONENT_ID, szl::SERIAL, szl::NAME_LEN),
            ),
        ];
        for (key, record) in facts {
            if let Some(text) = self.szl_text(record).await? {
                self.link.set_peer(key, text);
            }
        }
        self.read_mode().await
    }

    /// Reads the operating state; a change is told in the link's state and the log.
    async fn read_mode(&mut self) -> Result<(), S7Error> {
        self.next_mode = Instant::now() + MODE_EVERY;
        self.started();
        let answered = self.conn.szl(szl::CPU_STATE, 0).await;
        self.progress.ended();
        let mode = match answered {
            Ok(records) => records.first().and_then(|r| szl::mode(r)),
            Err(S7Error::Malformed(_)) => None,
            Err(e) => return Err(e),
        };
        if mode != self.mode {
            let name = self.link.name();
            match mode {
                Some(Mode::Stop) => tracing::warn!(link = %name, "{IN_STOP}"),
                Some(m) => tracing::info!(link = %name, "the PLC is in {m}"),
                None => {}
            }
            if let Some(m) = mode {
                self.link.set_peer("cpu_state", m.to_string());
            }
            self.mode = mode;
        }
        Ok(())
    }

    /// Tells a refusal of a whole job in the log once (until another comes).
    fn tell_refused(&mut self, why: &str) {
        if self.refused.as_deref() != Some(why) {
            tracing::warn!(link = %self.link.name(), "{why}");
            self.refused = Some(why.to_owned());
        }
    }
}

/// Publishes one answered item's fields (stale with `doubt` where the PLC vouches for them
/// only in part).
fn publish_item(
    device: &Device,
    plan: &Plan,
    fields: &[(usize, u32)],
    answer: &Result<Vec<u8>, u8>,
    doubt: Option<&FieldError>,
    now: Instant,
) {
    for &(idx, offset) in fields {
        let Some(Ok(place)) = plan.places.get(idx) else {
            continue;
        };
        let value = match answer {
            Ok(bytes) => {
                let at = usize::try_from(offset).unwrap_or(usize::MAX);
                let mine = bytes.get(at..).unwrap_or_default();
                let field = device.field(idx);
                value::decode(place.form, place.stored, mine)
                    .and_then(|raw| value::scaled(field, raw))
                    .map_err(FieldError::Device)
            }
            Err(code) => Err(FieldError::Device(pdu::item_error(*code).to_owned())),
        };
        device.publish_from(idx, value, doubt.cloned(), None, now);
    }
}

/// Plans the device's jobs for the PDU the PLC granted, telling each field that has no place
/// (or does not fit one item) why.
fn replan(device: &Device, plan: &mut Plan, pdu: u16) {
    plan.batches = plan::batches(&plan.places, pdu, &plan.alone);
    plan.pdu = pdu;
    let room = plan::max_item(pdu);
    for (idx, p) in plan.places.iter().enumerate() {
        let why = match p {
            Err(why) => why.clone(),
            Ok(p) if u32::from(p.bytes) > room => format!(
                "{} bytes do not fit one item of the PLC's PDU ({room} bytes)",
                p.bytes
            ),
            Ok(_) => continue,
        };
        device.publish(idx, Err(FieldError::Device(why)));
    }
}

impl Session for Plc {
    type Plan = Plan;

    async fn read(&mut self, device: &Arc<Device>, plan: &mut Plan) -> Result<Read, LinkFault> {
        if plan.pdu != self.conn.pdu {
            replan(device, plan, self.conn.pdu);
        }
        let started = Instant::now();
        if started >= self.next_mode
            && let Err(e) = self.read_mode().await
        {
            fault(e)?;
        }
        let doubt = (self.mode == Some(Mode::Stop)).then(|| FieldError::Device(IN_STOP.into()));
        let jobs: Vec<&[pdu::Item]> = plan.batches.iter().map(|b| b.items.as_slice()).collect();
        let (progress, timeout) = (self.progress.clone(), self.timeout);
        let answered = self
            .conn
            .read_jobs(&jobs, || progress.started(Instant::now() + timeout))
            .await;
        self.progress.ended();
        let answers = answered.map_err(lost)?;
        let now = Instant::now();
        let mut split = Vec::new();
        for (batch, answer) in plan.batches.iter().zip(answers) {
            match answer {
                Ok(items) => {
                    for (fields, item) in batch.fields.iter().zip(&items) {
                        publish_item(device, plan, fields, item, doubt.as_ref(), now);
                        if fields.len() > 1 && *item == Err(pdu::OUT_OF_RANGE) {
                            split.extend(fields.iter().map(|&(idx, _)| idx));
                        }
                    }
                }
                Err(refused) => {
                    let why = refused.to_string();
                    self.tell_refused(&why);
                    for &(idx, _) in batch.fields.iter().flatten() {
                        device.publish(idx, Err(FieldError::Device(why.clone())));
                    }
                }
            }
        }
        if !split.is_empty() {
            // A range past the end of its block: its fields are read alone from now on, so
            // that those within it are read.
            plan.alone.extend(split);
            plan.pdu = 0;
        }
        Ok(Read::Answered(started.elapsed()))
    }

    async fn write(
        &mut self,
        device: &Arc<Device>,
        plan: &mut Plan,
        items: Vec<WriteItem>,
    ) -> Result<Option<FieldError>, LinkFault> {
        write::write(self, device, plan, items).await
    }
}

#[cfg(test)]
mod tests;

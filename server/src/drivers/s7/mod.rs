//! Siemens S7 PLCs as devices (`protocol: s7`): S7comm over ISO-on-TCP, written here (the
//! crates read were synchronous or a first release). A link is a PLC (`s7:` with `host`,
//! rack and slot or TSAPs); a field names its `address` as S7 users write it. A device's
//! fields are read in the fewest jobs the negotiated PDU allows; a BOOL is written as a
//! bit, never by rewriting its byte.

pub(crate) mod address;
mod clock;
mod config;
mod conn;
mod describe;
pub(crate) mod form;
pub(crate) mod pdu;
pub(crate) mod plan;
mod read;
mod szl;
mod value;
mod write;

use std::sync::Arc;
use std::time::Duration;

use tokio::time::Instant;

use super::WriteItem;
use super::{Driver, Read, Session};
use crate::cache::{Device, FieldError, Link, Progress};
use crate::config::LinkConfig;
use crate::link::LinkFault;
use crate::metrics::Metrics;
use crate::profile::Words;
use conn::{Connection, S7Error};
use plan::{Place, ReadPlan};
use szl::Mode;

/// The S7 driver.
pub(crate) struct S7;

/// Its links' key and its profiles' protocol.
pub(crate) const PROTOCOL: &str = "s7";

/// Its words in configuration.
const WORDS: Words = Words {
    protocol: PROTOCOL,
    point_key: "address",
    point_alternative: None,
    link_key: PROTOCOL,
    link_at: "host",
    check_point: form::check,
    point_identity: |p| form::point_identity(&p.address),
    default_length: 64,
    example: "DB10.DBD6",
    scaled: true,
    field_keys: &[],
    device_keys: &[],
};

/// The link's fact of the PDU size the PLC granted (its view, its plan).
const PDU_SIZE: &str = "pdu_size";

/// What is kept of a device: its fields' places and the jobs planned for a PDU size.
pub(crate) struct Plan {
    places: Vec<Result<Place, String>>,
    reads: ReadPlan,
    /// The PDU size the reads were planned for (0: not yet).
    pdu: u16,
    /// The link's `max_gap` they were planned with.
    gap: u32,
    /// Fields read in items of their own (their range, merged, was out of range).
    alone: std::collections::BTreeSet<usize>,
}

/// An open PLC connection.
pub(crate) struct Plc {
    conn: Connection,
    /// The link's `max_gap`.
    gap: u32,
    link: Arc<Link>,
    progress: Arc<Progress>,
    timeout: Duration,
    /// The PLC's operating state as last read, and when to read it again.
    mode: Option<Mode>,
    next_mode: Instant,
    /// The PLC's last refusal of a whole job, told once in the log.
    refused: Option<String>,
    /// Whether the PLC left an SZL read unanswered (S7-200, LOGO!): not asked again on this
    /// connection.
    szl_silent: bool,
    /// Whether the PLC's identity was read on this connection.
    identified: bool,
}

/// How often the operating state is read while the PLC is polled.
const MODE_EVERY: Duration = Duration::from_secs(2);

/// What a PLC in STOP does to its values.
const IN_STOP: &str =
    "the PLC is in STOP: its program does not run and these values do not change; switch it to RUN";

/// The connection's end.
fn lost(e: S7Error) -> LinkFault {
    LinkFault::lost(e)
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
    const READS_BACK_TO_BACK: bool = true;
    /// A connection, its COTP connection and its setup: three exchanges of at most the
    /// link's `timeout` (4 s at most) each. The PLC's identity is read with the first read,
    /// so that a PLC silent to SZL reads (S7-200, LOGO!) opens all the same.
    const OPEN_TIMEOUT: Duration = Duration::from_secs(15);

    const WORDS: Option<&'static Words> = Some(&WORDS);
    type Settings = config::Settings;

    const READ_SETTINGS: super::ReadSettings<config::Settings> = config::read;

    fn check_value(device: &Device, idx: usize, value: &crate::codec::Value) -> Result<(), String> {
        write::check_value(device, idx, value)
    }

    fn describe(
        link: &LinkConfig,
        devices: &super::Planned<'_>,
        peer: &super::Facts,
        out: &mut String,
    ) {
        describe::link(link, devices, peer, out);
    }

    fn plan(device: &Device) -> Plan {
        Plan {
            places: plan::places(&device.profile),
            reads: ReadPlan::default(),
            pdu: 0,
            gap: 0,
            alone: Default::default(),
        }
    }

    async fn open(
        config: &LinkConfig,
        link: &Arc<Link>,
        _metrics: &Arc<Metrics>,
    ) -> Result<Plc, LinkFault> {
        let s = Self::settings(config)?;
        let conn = Connection::open(
            (s.host.as_str(), s.port),
            s.local_tsap,
            s.remote_tsap,
            s.pdu,
            s.timeout,
        )
        .await
        .map_err(|e| LinkFault::connect_failed(format!("{}:{}", s.host, s.port), e))?;
        let plc = Plc {
            conn,
            gap: s.max_gap,
            link: link.clone(),
            progress: link.progress.clone(),
            timeout: s.timeout,
            mode: None,
            next_mode: Instant::now(),
            refused: None,
            szl_silent: false,
            identified: false,
        };
        link.set_peer(PDU_SIZE, plc.conn.pdu.to_string());
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
            Err(S7Error::Timeout(_)) => {
                tracing::debug!(link = %self.link.name(), "SZL {id:#06x}/{index}: no answer");
                self.szl_silent = true;
                Ok(None)
            }
            Err(e) => Err(e),
        }
    }

    /// Reads the PLC's identity and operating state into the link's state.
    async fn identify(&mut self) -> Result<(), S7Error> {
        self.identified = true;
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
            if self.szl_silent {
                break;
            }
            if let Some(text) = self.szl_text(record).await? {
                self.link.set_peer(key, text);
            }
        }
        self.read_mode().await
    }

    /// Reads the operating state; a change is told in the link's state and the log.
    async fn read_mode(&mut self) -> Result<(), S7Error> {
        self.next_mode = Instant::now() + MODE_EVERY;
        if self.szl_silent {
            return Ok(());
        }
        self.started();
        let answered = self.conn.szl(szl::CPU_STATE, 0).await;
        self.progress.ended();
        let mode = match answered {
            Ok(records) => records.first().and_then(|r| szl::mode(r)),
            Err(S7Error::Malformed(_)) => None,
            Err(S7Error::Timeout(_)) => {
                self.szl_silent = true;
                None
            }
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

impl Session for Plc {
    type Plan = Plan;

    async fn read(&mut self, device: &Arc<Device>, plan: &mut Plan) -> Result<Read, LinkFault> {
        read::read(self, device, plan).await
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

/// An S7 PLC's answer as every parser meets it, and the bytes of an item by every form.
#[cfg(any(fuzzing, test))]
pub(crate) fn fuzz_answer(data: &[u8]) {
    use crate::codec::IecType;
    use crate::drivers::s7::form::Form;
    let asked = usize::from(data.first().copied().unwrap_or(0) % 24);
    if let Ok(a) = pdu::answer(data) {
        let _ = pdu::read_items(&a, &pdu::fuzz_items(asked));
        let _ = pdu::write_items(&a, asked);
        let _ = pdu::granted(&a);
        for record in szl::records(&a).unwrap_or_default() {
            let _ = (szl::text(&record, szl::NAME_LEN), szl::mode(&record));
        }
    }
    let _ = pdu::connect_confirm(data);
    let forms = [
        Form::Bit(3),
        Form::Number,
        Form::Char,
        Form::WChar,
        Form::String(20),
        Form::WString(10),
        Form::Dt,
        Form::Dtl,
        Form::Timer,
        Form::Counter,
    ];
    for form in forms {
        for ty in IecType::ALL {
            let _ = value::decode(form, ty, data);
        }
    }
}

#[cfg(test)]
mod tests;

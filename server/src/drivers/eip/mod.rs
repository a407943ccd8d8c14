//! Allen-Bradley Logix controllers as devices (`protocol: ab-eip`): EtherNet/IP explicit
//! messages, written here (ARCHITECTURE.md says why). A link is a controller (`eip:` with
//! `host` and the `path` to it); a field names its `tag` as Logix users write it. A device's
//! tags are read in Multiple Service Packets as large as an unconnected message allows; each
//! tag's CIP status is its own field's error; a bit of an integer is written with
//! Read-Modify-Write Tag, never by writing the whole integer.

mod cip;
mod config;
mod conn;
mod describe;
mod directory;
pub mod import;
mod manager;
pub(crate) mod plan;
mod read;
pub(crate) mod tag;
mod value;
mod write;

use std::sync::Arc;
use std::time::Duration;

use tokio::time::Instant;

use super::WriteItem;
use super::{Driver, Read, Session, finish, written};
use crate::cache::{Device, FieldError, Link, Progress};
use crate::config::LinkConfig;
use crate::link::LinkFault;
use crate::metrics::Metrics;
use crate::profile::Words;
use conn::{Connection, EipError};
use tag::Tag;

/// The EtherNet/IP driver.
pub(crate) struct Eip;

/// Its links' key.
pub(crate) const LINK_KEY: &str = "eip";

/// Its words in configuration.
const WORDS: Words = Words {
    protocol: "ab-eip",
    point_key: "tag",
    point_alternative: None,
    link_key: LINK_KEY,
    link_at: "host",
    check_point: tag::check,
    // Logix tag names are not case-sensitive.
    point_identity: |p| p.address.to_ascii_lowercase(),
    // A Logix STRING holds 82 characters.
    default_length: 82,
    example: "Program:Main.Speed",
    scaled: false,
    field_keys: &[],
    device_keys: &[],
};

/// What is kept of a device: each field's tag (or why it has none) and the type the
/// controller answered for it (a bit's integer, for its writes).
pub(crate) struct Plan {
    tags: Vec<Result<Tag, String>>,
    codes: Vec<Option<u16>>,
    /// A Logix STRING's structure handle and size, as last read (for its writes).
    layouts: Vec<Option<(u16, usize)>>,
    /// Elements read on their own: a read of them together with their neighbours failed.
    alone: Vec<bool>,
    /// Reads of elements (by their first field) the controller answered only in part:
    /// read fragmented.
    fragment: Vec<bool>,
    /// The reads packed, kept while what they depend on stays the same.
    packed: Option<read::Packed>,
    /// Set when a read changed what the packing depends on.
    repack: bool,
    /// Why a bit of an integer is not written: the controller has no Read-Modify-Write Tag
    /// (it refused it, or closed the connection when asked). Kept across reconnects.
    no_bit_writes: Option<String>,
}

impl Plan {
    /// The type the controller answered for field `idx`: a new one changes the packing.
    fn set_code(&mut self, idx: usize, code: u16) {
        if self.codes[idx] != Some(code) {
            self.codes[idx] = Some(code);
            self.repack = true;
        }
    }
}

/// Connection serial numbers, one for each Forward Open this gateway makes.
static SERIAL: std::sync::atomic::AtomicU16 = std::sync::atomic::AtomicU16::new(1);

/// An open connection to a controller.
pub(crate) struct Controller {
    conn: Connection,
    progress: Arc<Progress>,
    timeout: Duration,
    /// One read a request: the controller has no Multiple Service Packets.
    single: bool,
    link: Arc<Link>,
}

/// The link's word that its controller has no Multiple Service Packets (shown in the
/// link's view and its plan; learned again, in the same cycle, on each connection).
const NO_MULTIPLE: (&str, &str) = (
    "multiple_service_packets",
    "unsupported: one Read Tag a request",
);

fn lost(e: EipError) -> LinkFault {
    LinkFault::lost(e)
}

impl Driver for Eip {
    type Plan = Plan;
    type Session = Controller;
    const NAME: &'static str = "ab-eip";
    const READS_BACK_TO_BACK: bool = true;

    const WORDS: Option<&'static Words> = Some(&WORDS);
    type Settings = config::Settings;

    const READ_SETTINGS: super::ReadSettings<config::Settings> = config::read;

    const IMPORT: Option<super::Import> = Some(super::Import {
        from: LINK_KEY,
        options: &["--path"],
        source: "one controller, HOST or HOST:PORT",
    });

    fn import(host: &str, options: &super::ImportOptions<'_>, out: Option<&std::path::Path>) -> u8 {
        let path = super::option(options, "--path");
        import::run(host, path, out)
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
        let tags = plan::tags(&device.profile);
        Plan {
            codes: vec![None; tags.len()],
            layouts: vec![None; tags.len()],
            alone: vec![false; tags.len()],
            fragment: vec![false; tags.len()],
            packed: None,
            repack: false,
            no_bit_writes: None,
            tags,
        }
    }

    async fn open(
        config: &LinkConfig,
        link: &Arc<Link>,
        _metrics: &Arc<Metrics>,
    ) -> Result<Controller, LinkFault> {
        let s = Self::settings(config)?;
        let failed = |e: EipError| LinkFault::connect_failed(format!("{}:{}", s.host, s.port), e);
        let mut conn = Connection::open((s.host.as_str(), s.port), s.route.clone(), s.timeout)
            .await
            .map_err(failed)?;
        let serial = SERIAL.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        if s.connected {
            conn.forward_open(serial).await.map_err(failed)?;
        }
        link.set_peer(
            "connection_size",
            match conn.connection_size() {
                0 => "unconnected".to_owned(),
                n => n.to_string(),
            },
        );
        // The identity is only shown: a controller that refuses List Identity, or does not
        // answer it, is read on with its identity unknown.
        match conn.identity().await {
            Ok(Some((vendor, product, revision, serial, name))) => {
                link.set_peer("vendor", vendor.to_string());
                link.set_peer("product_code", product.to_string());
                link.set_peer("product_name", name);
                link.set_peer("revision", revision);
                link.set_peer("serial_number", format!("{serial:#010x}"));
            }
            Ok(None) => {}
            Err(e @ (EipError::Malformed(_) | EipError::Timeout(_))) => {
                tracing::info!(link = %link.name(), error = %e, "the controller does not tell its identity (List Identity); read on without it");
                link.set_peer("identity", format!("unknown: {e}"));
            }
            Err(e) => return Err(failed(e)),
        }
        Ok(Controller {
            conn,
            progress: link.progress.clone(),
            timeout: s.timeout,
            single: false,
            link: link.clone(),
        })
    }
}

impl Controller {
    /// Learns that the controller has no Multiple Service Packets (CIP status 0x08).
    fn no_multiple(&mut self) {
        tracing::warn!(link = %self.link.name(), "the controller does not support Multiple Service Packets (CIP status 0x08): one Read Tag a request from now on");
        self.single = true;
        self.link.set_peer(NO_MULTIPLE.0, NO_MULTIPLE.1.to_owned());
    }

    /// A request's reply; `Ok(Err)` when the controller refused it whole (an
    /// encapsulation status, or the route's refusal: the connection stays in step), `Err` when the link failed.
    async fn request(&mut self, message: &[u8]) -> Result<Result<Vec<u8>, String>, LinkFault> {
        self.progress.started(Instant::now() + self.timeout);
        let answer = self.conn.request(message).await;
        self.progress.ended();
        match answer {
            Ok(reply) => Ok(Ok(reply)),
            Err(EipError::Malformed(m @ cip::Malformed::Encapsulation(_))) => {
                Ok(Err(format!("the controller refused the request: {m}")))
            }
            Err(EipError::Malformed(m @ cip::Malformed::Route { .. })) => Ok(Err(m.to_string())),
            Err(e) => Err(lost(e)),
        }
    }
}

impl Session for Controller {
    type Plan = Plan;

    async fn close(self) {
        self.conn.close().await;
    }

    async fn read(&mut self, device: &Arc<Device>, plan: &mut Plan) -> Result<Read, LinkFault> {
        let started = Instant::now();
        for (idx, tag) in plan.tags.iter().enumerate() {
            if let Err(why) = tag {
                device.publish(idx, Err(FieldError::Device(why.clone())));
            }
        }
        self.read_device(device, plan).await?;
        Ok(Read::Answered(started.elapsed()))
    }

    async fn write(
        &mut self,
        device: &Arc<Device>,
        plan: &mut Plan,
        items: Vec<WriteItem>,
    ) -> Result<Option<FieldError>, LinkFault> {
        self.write_items(device, plan, &items).await?;
        Ok(None)
    }
}

/// A controller's answer as every parser meets it.
#[cfg(any(fuzzing, test))]
pub(crate) fn fuzz_answer(data: &[u8]) {
    use crate::codec::IecType;
    let asked = usize::from(data.first().copied().unwrap_or(0) % 40);
    let _ = cip::header(data);
    let _ = cip::identity(data);
    let _ = directory::symbols(data);
    let _ = directory::template_attributes(data);
    let _ = directory::template(data, u16::from(data.first().copied().unwrap_or(0)));
    if let Ok(mr) = cip::rr_data_reply(data)
        && let Ok(r) = cip::reply(mr)
        && let Ok(parts) = cip::multiple_replies(r.data, asked)
    {
        for p in parts {
            if let Ok(one) = cip::reply(p) {
                for ty in IecType::ALL {
                    let _ = value::decode(one.data, ty, None);
                    let _ = value::decode(one.data, ty, Some(asked as u8));
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn every_answer_is_taken_apart_without_a_panic() {
        for data in [
            &b""[..],
            b"\x00\x00\x00\x00\x00\x00\x02\x00\x00\x00\x00\x00\xb2\x00\x04\x00\xcc\x00\x00\x00",
            &[0xFF; 64],
        ] {
            super::fuzz_answer(data);
        }
    }
}

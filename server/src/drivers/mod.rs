//! Field protocols. A driver is one folder behind one contract: [`Driver`] opens a link
//! and plans each device's reads; the open [`Session`] reads a device, probes one that
//! stopped answering, writes its outputs and answers what waits in the link's inbox. The
//! link's task (`crate::poller`) does the rest, whatever the protocol: the schedule (writes
//! first, the most overdue device next, each on the drift-free grid of its refresh rate),
//! reopening with back-off, backing off a silent device, the bounded inbox, the watchdog,
//! write outcomes, quality and staleness. [`with_driver`] lists the drivers: adding one is
//! its folder here and its line there.
//!
//! A driver reports what it reads into the cache itself (`Device::publish`, one value or
//! field error per field) and finishes each write it takes with its outcome
//! (`Device::finish_write_after`); it maps its protocol's failures onto the link codes
//! (`LinkFault`, through the `Result` of each call: an error ends the session) and the
//! device codes (`Read::Silent`: the device is disconnected, error 10) of document 000.

pub mod bacnet;
mod checks;
pub(crate) mod describe;
pub mod eip;
pub(crate) mod iec104;
pub mod import;
pub(crate) mod modbus;
pub mod opcua;
pub(crate) mod s7;
pub mod scan;

use std::future::Future;
use std::sync::Arc;
use std::time::Duration;

use crate::cache::{Device, FieldError, Link, Passthrough, PassthroughError, Probe, WriteError};
use crate::codec::Value;
use crate::config::{DeviceConfig, DriverLink, LinkConfig, Transport};
use crate::link::LinkFault;
use crate::metrics::Metrics;
use crate::profile::{Profile, Protocol, Words};

/// The drivers, one line each: the link tasks choose among them by a link's settings
/// ([`with_driver`]), the profiles' checks by a profile's protocol ([`for_protocol`]), and
/// configuration learns their words from them ([`register`]).
macro_rules! drivers {
    ($($driver:ty),* $(,)?) => {
        /// The drivers: `f` done with the one that serves a link configured so.
        pub(crate) fn with_driver<F: ForDriver>(config: &LinkConfig, f: F) -> Option<F::Output> {
            $(if <$driver as Driver>::serves(config) {
                return Some(f.with::<$driver>());
            })*
            None
        }

        /// The drivers: `f` done with the one whose devices speak `protocol`.
        pub(crate) fn for_protocol<F: ForDriver>(protocol: Protocol, f: F) -> Option<F::Output> {
            $(if <$driver as Driver>::speaks(protocol) {
                return Some(f.with::<$driver>());
            })*
            None
        }

        /// The drivers: `f` done with the one a live import `--from` names.
        pub(crate) fn for_import<F: ForDriver>(from: &str, f: F) -> Option<F::Output> {
            $(if <$driver as Driver>::IMPORT.is_some_and(|i| i.from == from) {
                return Some(f.with::<$driver>());
            })*
            None
        }

        /// The drivers: `f` done with the one whose scan `--from` names.
        pub(crate) fn for_scan<F: ForDriver>(from: &str, f: F) -> Option<F::Output> {
            $(if <$driver as Driver>::SCAN.is_some_and(|i| i.from == from) {
                return Some(f.with::<$driver>());
            })*
            None
        }

        /// The scans of every driver that has one.
        const SCANS: &[Option<Import>] = &[$(<$driver as Driver>::SCAN),*];

        /// The live imports of every driver that has one.
        const IMPORTS: &[Option<Import>] = &[$(<$driver as Driver>::IMPORT),*];

        /// The words each driver adds to configuration.
        const WORDS: &[Option<&'static Words>] = &[$(<$driver as Driver>::WORDS),*];
    };
}

#[rustfmt::skip]
drivers![
    modbus::Modbus,
    opcua::OpcUa,
    s7::S7,
    eip::Eip,
    bacnet::Bacnet,
    iec104::Iec104,
];

/// Makes the drivers' words known to configuration (profiles' `protocol`, their fields'
/// point keys, the links' settings keys), which is read below the drivers and so cannot
/// ask them itself. Done once, before any configuration is read (`Setup::load`, the
/// command line, the fuzz targets); again, it does nothing.
pub fn register() {
    static KNOWN: std::sync::LazyLock<Vec<&'static Words>> =
        std::sync::LazyLock::new(|| WORDS.iter().flatten().copied().collect());
    crate::profile::know(&KNOWN);
}

/// `iogate profile import --from FROM SOURCE`: a driver's import of a live device's
/// profile (a server's variables, a controller's tags).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Import {
    /// The word `--from` names it by.
    pub(crate) from: &'static str,
    /// The options it takes besides `--out` (`--node`).
    pub(crate) options: &'static [&'static str],
    /// What it takes as its one source, for the message when it is given another.
    pub(crate) source: &'static str,
}

/// The options given to an import, by flag (`--node`), each with its value.
pub type ImportOptions<'a> = [(&'static str, &'a str)];

/// The value of an import's option, if given.
pub(crate) fn option<'a>(options: &ImportOptions<'a>, flag: &str) -> Option<&'a str> {
    options.iter().find(|(f, _)| *f == flag).map(|(_, v)| *v)
}

/// How a driver reads a link's settings from its part of the configuration: `None` after
/// reporting every problem.
pub(crate) type ReadSettings<S> =
    fn(link: &str, d: &DriverLink, report: &mut crate::yaml::Report) -> Option<S>;

pub(crate) use checks::{check_links, check_relinquish, check_value, describe, link_warnings};

/// Something done with the driver of a link, whichever it is.
pub(crate) trait ForDriver {
    type Output;
    fn with<D: Driver>(self) -> Self::Output;
}

/// A value to put on a device: a client's write (with its generation) or the latest value
/// written again after a reconnect (without). Each driver makes its protocol's request of
/// it (Modbus its registers, S7 its bytes).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct WriteItem {
    pub(crate) field: usize,
    /// The value; `None` for a relinquish, which only a driver whose
    /// [`Driver::check_relinquish`] allows it is given.
    pub(crate) value: Option<Value>,
    pub(crate) generation: Option<u64>,
}

impl WriteItem {
    /// The value to write; a relinquish is refused (for a driver that has none).
    pub(crate) fn value(&self) -> Result<&Value, String> {
        self.value
            .as_ref()
            .ok_or_else(|| "the protocol has no relinquish; write a value".to_owned())
    }
}

/// A link's devices, each with its profile, as `iogate plan` is given them.
pub type Planned<'a> = [(&'a DeviceConfig, &'a Profile)];

/// What a link's peer told of itself (`Link::peer`): named values.
pub type Facts = [(&'static str, String)];

/// A field protocol: how its links open and how a device's reads are planned.
pub(crate) trait Driver: Send + Sized + 'static {
    /// What the driver keeps of a device between cycles and across reconnects (its
    /// planned reads, what it learned of the device).
    type Plan: Send;
    /// An open link.
    type Session: Session<Plan = Self::Plan>;

    /// The protocol's name, as logs say it.
    const NAME: &'static str;

    /// How long opening a link may take before the attempt counts as failed.
    const OPEN_TIMEOUT: Duration = Duration::from_secs(3);

    /// Whether the values of a device whose link is down stay, stale, until they are read
    /// again (a server that vouches for its values when it is back), rather than turn bad.
    const STALE_WHILE_AWAY: bool = false;

    /// Whether a device at `refresh_rate: 0ms` is read back to back, each cycle as soon as
    /// the last one's answers came: a protocol whose read asks the device each time. One
    /// whose values come by themselves (subscriptions, spontaneous data) reads such a
    /// device every 100 ms instead.
    const READS_BACK_TO_BACK: bool = false;

    /// Its words in configuration: its profiles' `protocol`, its fields' point key, its
    /// links' settings key (`None`: Modbus, whose links are `serial` or `tcp` and whose
    /// fields are registers).
    const WORDS: Option<&'static Words> = None;

    /// A link's settings as the driver reads them from its part of the configuration.
    type Settings;

    /// Reads a link's settings (`None` after reporting every problem in them).
    const READ_SETTINGS: ReadSettings<Self::Settings>;

    /// Whether this driver serves a link configured so: its settings key's.
    fn serves(config: &LinkConfig) -> bool {
        Self::WORDS.is_some_and(
            |w| matches!(&config.transport, Transport::Driver(d) if d.protocol == w.link_key),
        )
    }

    /// Whether devices of a profile's protocol are this driver's.
    fn speaks(protocol: Protocol) -> bool {
        Self::WORDS.is_some() && protocol.words() == Self::WORDS
    }

    /// A link's settings, or why the link cannot open (what `iogate check` says of it
    /// too).
    fn settings(config: &LinkConfig) -> Result<Self::Settings, LinkFault> {
        let Transport::Driver(d) = &config.transport else {
            return Err(LinkFault::NoPort);
        };
        let mut report = crate::yaml::Report::new("config");
        (Self::READ_SETTINGS)(&config.name, d, &mut report).ok_or_else(|| LinkFault::OpenFailed {
            port: d.endpoint.clone(),
            reason: report.into_problems().to_string(),
        })
    }

    /// Reports what is wrong with a link's settings, as `check` does (the settings the
    /// config reader left to the driver, the files they name).
    fn check(config: &LinkConfig, report: &mut crate::yaml::Report) {
        if let Transport::Driver(d) = &config.transport {
            (Self::READ_SETTINGS)(&config.name, d, report);
        }
    }

    /// Reports what is wrong with a device's own keys on a link of this driver
    /// (`DeviceConfig::at`: a BACnet device's `device_instance`), as `check` does; a driver
    /// whose devices have none refuses them.
    fn check_device(device: &DeviceConfig, report: &mut crate::yaml::Report) {
        for (key, _) in &device.at {
            report.push(
                device.line,
                format!("device {}", device.name),
                format!("`{key}` is not a key of a device on a {} link", Self::NAME),
            );
        }
    }

    /// What of the host a link of this driver takes for itself, which no other link may
    /// take too (a BACnet/IP port's UDP port), as a sentence's object, and why.
    fn claims(config: &LinkConfig) -> Option<(String, &'static str)> {
        let _ = config;
        None
    }

    /// What names a device on its link, which no other device of the link may have too (a
    /// BACnet device's instance), as a sentence's object.
    fn device_identity(device: &DeviceConfig) -> Option<String> {
        let _ = device;
        None
    }

    /// Reports what a link's settings allow that a user should know of (a check turned
    /// off), as `check` and `serve` warn.
    fn warn(config: &LinkConfig, report: &mut crate::yaml::Report) {
        let _ = (config, report);
    }

    /// Whether the protocol can hold `value` where field `idx` of a device is (beyond
    /// the field's type, which is checked for every protocol).
    fn check_value(device: &Device, idx: usize, value: &Value) -> Result<(), String> {
        let _ = (device, idx, value);
        Ok(())
    }

    /// Whether field `idx` of a device can be relinquished (a write of no value: the
    /// device's own value, or a lower priority's, takes over); by default not, and the
    /// answer says what to do instead.
    fn check_relinquish(device: &Device, idx: usize) -> Result<(), String> {
        let _ = idx;
        Err(format!(
            "{} has no relinquish; write a value of the field's type",
            device.profile.protocol.name()
        ))
    }

    /// What `iogate plan` prints of a link's devices under its line: by default each
    /// field's point (a protocol the peer samples for the gateway, as OPC UA).
    fn describe(link: &LinkConfig, devices: &Planned<'_>, peer: &Facts, out: &mut String) {
        let _ = (link, peer);
        for (d, profile) in devices {
            describe::points(out, d, profile);
        }
    }

    /// The warnings of `check` and `serve` about a link's plan (refresh rates that need
    /// more than a line carries).
    fn plan_warnings(link: &LinkConfig, devices: &Planned<'_>) -> Vec<String> {
        let _ = (link, devices);
        Vec::new()
    }

    /// Its live import (`iogate profile import --from ...`), where it has one.
    const IMPORT: Option<Import> = None;

    /// Imports a live device's profiles from `source` with the options given (only those
    /// of [`Driver::IMPORT`]); the command's exit code.
    fn import(source: &str, options: &ImportOptions<'_>, out: Option<&std::path::Path>) -> u8 {
        let _ = (source, options, out);
        crate::EXIT_CONFIG as u8
    }

    /// Its scan (`iogate scan --from ...`), where it has one (`source` unused).
    const SCAN: Option<Import> = None;

    /// Finds the devices of a network with the options given (only those of
    /// [`Driver::SCAN`]); the command's exit code.
    fn scan(options: &ImportOptions<'_>, json: bool) -> u8 {
        let _ = (options, json);
        crate::EXIT_CONFIG as u8
    }

    /// Plans a device's reads from its profile.
    fn plan(device: &Device) -> Self::Plan;

    /// The share of its line the devices' refresh rates need, where the protocol knows it
    /// (a serial line).
    fn planned_utilisation<'a>(
        config: &LinkConfig,
        devices: impl Iterator<Item = (&'a Device, &'a Self::Plan)>,
    ) -> Option<f64> {
        let _ = (config, devices.count());
        None
    }

    /// Opens the link (bounded by the task's connect timeout).
    fn open(
        config: &LinkConfig,
        link: &Arc<Link>,
        metrics: &Arc<Metrics>,
    ) -> impl Future<Output = Result<Self::Session, LinkFault>> + Send;
}

/// Finishes a write the driver took with its outcome, after `attempts` requests (a value
/// written again after a reconnect has no write of its own to finish).
pub(crate) fn finish(
    device: &Device,
    item: &WriteItem,
    result: Result<(), WriteError>,
    attempts: u32,
) {
    if let Some(g) = item.generation {
        device.finish_write_after(g, result, attempts);
    }
}

/// A write the device took: its value published as the device holds it (the value
/// through its raw form and back), then its outcome (never a moment that shows the write
/// done and the old value).
pub(crate) fn written(device: &Device, item: &WriteItem, attempts: u32) {
    if let Some(value) = &item.value {
        device.publish(item.field, Ok(device.field(item.field).held(value)));
    }
    finish(device, item, Ok(()), attempts);
}

/// How a device's read ended.
#[derive(Debug)]
pub(crate) enum Read {
    /// The device answered (each field published, good or with its field error); the
    /// time its last answer took.
    Answered(Duration),
    /// The device did not answer (after the retries): it is disconnected and backed off.
    Silent(FieldError),
}

/// How probing a device that stopped answering ended.
#[derive(Debug)]
pub(crate) enum Probed {
    /// It answers again.
    Answers,
    /// Still nothing.
    Silent(FieldError),
    /// There is nothing to ask it (no fields to read).
    Nothing,
}

/// An open link of a driver. Every call's `Err` means the link itself failed: the task
/// reopens it.
pub(crate) trait Session: Send {
    type Plan: Send;

    /// Reads the device's fields (one cycle) and publishes each.
    fn read(
        &mut self,
        device: &Arc<Device>,
        plan: &mut Self::Plan,
    ) -> impl Future<Output = Result<Read, LinkFault>> + Send;

    /// One request, no retries: whether a device that stopped answering is back. A link
    /// that answers for all its devices (a server's session) has nothing more to ask.
    fn probe(
        &mut self,
        device: &Arc<Device>,
        plan: &mut Self::Plan,
    ) -> impl Future<Output = Result<Probed, LinkFault>> + Send {
        let _ = (device, plan);
        std::future::ready(Ok(Probed::Answers))
    }

    /// Writes `items` (clients' writes and the latest values written again), finishing
    /// each write with its outcome; a written value is published before its outcome.
    /// `Some` when the device stopped answering (the items not sent are finished).
    fn write(
        &mut self,
        device: &Arc<Device>,
        plan: &mut Self::Plan,
        items: Vec<WriteItem>,
    ) -> impl Future<Output = Result<Option<FieldError>, LinkFault>> + Send;

    /// Sends a request queued by another master as it is (a Modbus request), and answers
    /// it; `label` names the device it goes to, in the metrics.
    fn pass_through(
        &mut self,
        queued: Passthrough,
        label: &str,
    ) -> impl Future<Output = Result<(), LinkFault>> + Send {
        let _ = label;
        let _ = queued.reply.send(Err(PassthroughError::NotModbus));
        std::future::ready(Ok(()))
    }

    /// Sends a scan's probe (an RTU line's).
    fn scan_probe(&mut self, queued: Probe) -> impl Future<Output = Result<(), LinkFault>> + Send {
        let _ = queued.reply.send(Err(PassthroughError::NotModbus));
        std::future::ready(Ok(()))
    }

    /// Ends the session, telling the other end where the protocol has a request for it
    /// (a CIP connection's Forward Close, an OPC UA session's CloseSession), whether the
    /// link is stopped, reopened with other settings or was lost: whatever the driver
    /// opened on a peer is released, not left to the peer's timeouts. The task bounds it.
    fn close(self) -> impl Future<Output = ()> + Send
    where
        Self: Sized,
    {
        std::future::ready(())
    }

    /// Resolves when the link is lost between requests (a session kept alive by the
    /// protocol); a driver that only talks when asked never resolves it.
    fn lost(&mut self) -> impl Future<Output = LinkFault> + Send {
        std::future::pending()
    }
}

//! BACnet/IP devices (`protocol: bacnet`): a link is the gateway's BACnet/IP port (`bacnet:`
//! with the address it is bound to, a BBMD to register with as a foreign device); a device
//! is a BACnet device on it by its `device_instance` (bound by `address` or found by
//! Who-Is / I-Am, also behind a router: then by its network number and MAC as its I-Am
//! says), and a field is a property of one of its objects (`object: analog-input:3`,
//! `property:` present-value unless it says). A device's fields are read with
//! ReadPropertyMultiple, each present value with its status flags (fault or out of
//! service is not a good value); writes go at the field's `priority`.
//!
//! The protocol is bacnet-client's (rusty-bacnet, MIT): its transaction state machine
//! (timeouts and retries as the standard says, segmented answers, answers checked against
//! their requests), its device table and its BACnet/IP transport with foreign-device
//! registration. The session holds the client as the OPC UA driver holds its session; the
//! link task's back-off and schedule stay shared.

mod client;
mod config;
mod cov;
mod describe;
pub mod import;
mod point;
mod read;
pub mod scan;
mod value;
mod write;

use std::net::SocketAddrV4;
use std::sync::Arc;
use std::time::Duration;

use bacnet_client::client::BACnetClient;
use bacnet_transport::bip::BipTransport;
use bacnet_types::enums::PropertyIdentifier;
use bacnet_types::primitives::ObjectIdentifier;
use tokio::time::Instant;

use super::{Driver, Probed, Read, Session, WriteItem};
use crate::cache::{Device, FieldError, Link, Progress};
use crate::config::{DeviceConfig, LinkConfig};
use crate::link::LinkFault;
use crate::metrics::Metrics;
use crate::profile::Words;

/// The BACnet/IP driver.
pub(crate) struct Bacnet;

/// Its links' key and its profiles' protocol.
const PROTOCOL: &str = "bacnet";

/// Its words in configuration.
const WORDS: Words = Words {
    protocol: PROTOCOL,
    point_key: "object",
    point_alternative: None,
    link_key: PROTOCOL,
    link_at: "bind",
    check_point: point::check_object,
    point_identity,
    default_length: 64,
    example: "analog-input:3",
    scaled: false,
    field_keys: point::FIELD_KEYS,
    device_keys: &[point::DEVICE_INSTANCE, point::ADDRESS, point::COV],
};

/// One point is one object's property, however their names are spelled.
fn point_identity(p: &crate::profile::Point) -> String {
    let object =
        point::object(&p.address).map_or_else(|_| p.address.clone(), |id| format!("{id:?}"));
    let property = p
        .get(point::PROPERTY)
        .map_or(Ok(PropertyIdentifier::PRESENT_VALUE), point::property)
        .map_or_else(|_| String::new(), |id| format!("{id:?}"));
    format!("{object} {property}")
}

/// Where a field is on its device: its object, its property and its writes' priority.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Place {
    object: ObjectIdentifier,
    property: PropertyIdentifier,
    priority: u8,
}

/// What is kept of a device: where it is and where each field is (or why it has none).
pub(crate) struct Plan {
    instance: Result<(u32, Option<SocketAddrV4>), String>,
    places: Vec<Result<Place, String>>,
    /// The device as the client's table last held it (its I-Am heard, or bound by its
    /// address), to put back when the client forgets it.
    row: Option<bacnet_client::discovery::DiscoveredDevice>,
    /// The device rejected ReadPropertyMultiple as a service it does not have: its
    /// properties are read with ReadProperty.
    one_by_one: bool,
    /// Its change-of-value subscriptions on this session.
    cov: cov::Subscriptions,
}

/// The gateway's open BACnet/IP port.
pub(crate) struct Port {
    client: BACnetClient<BipTransport>,
    progress: Arc<Progress>,
    timeout: Duration,
    /// The subscriber processes of the port's change-of-value subscriptions, and the task
    /// that gives each notification to its device.
    cov: Arc<cov::Table>,
    listener: tokio::task::JoinHandle<()>,
}

/// Why the port failed or a request could not be made, as the client says it.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub(crate) struct BacnetError(#[from] bacnet_types::error::Error);

fn places(device: &Device) -> Vec<Result<Place, String>> {
    device
        .profile
        .fields
        .iter()
        .map(|f| {
            let p = f.point.as_ref().ok_or("the field has no object")?;
            Ok(Place {
                object: point::object(&p.address)?,
                property: p
                    .get(point::PROPERTY)
                    .map_or(Ok(PropertyIdentifier::PRESENT_VALUE), point::property)?,
                priority: p
                    .get(point::PRIORITY)
                    .map_or(Ok(point::DEFAULT_PRIORITY), point::priority)?,
            })
        })
        .collect()
}

impl Driver for Bacnet {
    type Plan = Plan;
    type Session = Port;
    const NAME: &'static str = PROTOCOL;
    const WORDS: Option<&'static Words> = Some(&WORDS);
    type Settings = config::Settings;
    const READ_SETTINGS: super::ReadSettings<config::Settings> = config::read;

    const IMPORT: Option<super::Import> = Some(super::Import {
        from: PROTOCOL,
        options: &["--on", "--broadcast", "--bbmd"],
        source: "one device, HOST[:PORT] or its device instance",
    });

    fn import(
        target: &str,
        options: &super::ImportOptions<'_>,
        out: Option<&std::path::Path>,
    ) -> u8 {
        import::run(target, options, out)
    }

    const SCAN: Option<super::Import> = Some(super::Import {
        from: PROTOCOL,
        options: &["--on", "--broadcast", "--bbmd", "--wait"],
        source: "",
    });

    fn scan(options: &super::ImportOptions<'_>, json: bool) -> u8 {
        scan::run(options, json)
    }

    fn check_device(device: &DeviceConfig, report: &mut crate::yaml::Report) {
        let at = device.at(point::DEVICE_INSTANCE);
        let checks = [
            point::device(at, device.at(point::ADDRESS)).map(drop),
            point::cov(device.at(point::COV)).map(drop),
        ];
        for why in checks.into_iter().filter_map(Result::err) {
            report.push(device.line, format!("device {}", device.name), why);
        }
    }

    /// Its port binds every address of the host on its UDP port (to hear broadcasts).
    fn claims(config: &LinkConfig) -> Option<(String, &'static str)> {
        let s = Self::settings(config).ok()?;
        Some((
            format!("UDP port {}", s.bind.port()),
            "a BACnet/IP port is bound on every address of the host, to hear broadcasts: give each link a port of its own",
        ))
    }

    fn device_identity(device: &DeviceConfig) -> Option<String> {
        point::device_instance(device.at(point::DEVICE_INSTANCE)?)
            .ok()
            .map(|i| format!("device_instance {i}"))
    }

    fn describe(_: &LinkConfig, devices: &super::Planned<'_>, _: &super::Facts, out: &mut String) {
        describe::link(devices, out);
    }

    fn check_value(device: &Device, idx: usize, value: &crate::codec::Value) -> Result<(), String> {
        let Some(Ok(place)) = places(device).into_iter().nth(idx) else {
            return Ok(());
        };
        write::value(place, value).map(drop)
    }

    fn check_relinquish(device: &Device, idx: usize) -> Result<(), String> {
        match places(device).into_iter().nth(idx) {
            Some(Ok(place)) => write::relinquishing(place).map(drop),
            Some(Err(why)) => Err(why),
            None => Err("no such field".to_owned()),
        }
    }

    fn plan(device: &Device) -> Plan {
        let config = &device.config;
        Plan {
            instance: point::device(config.at(point::DEVICE_INSTANCE), config.at(point::ADDRESS)),
            places: places(device),
            row: None,
            one_by_one: false,
            cov: cov::Subscriptions {
                wanted: point::cov(config.at(point::COV)).unwrap_or(true),
                ..Default::default()
            },
        }
    }

    async fn open(
        config: &LinkConfig,
        link: &Arc<Link>,
        _metrics: &Arc<Metrics>,
    ) -> Result<Port, LinkFault> {
        let s = Self::settings(config)?;
        let endpoint = s.bind.to_string();
        let client = client::start(&s)
            .await
            .map_err(|e| LinkFault::connect_failed(endpoint, BacnetError(e)))?;
        let table = Arc::new(cov::Table::default());
        let listener = tokio::spawn(cov::listen(table.clone(), client.cov_notifications()));
        Ok(Port {
            client,
            progress: link.progress.clone(),
            timeout: s.timeout * (u32::from(s.retries) + 1),
            cov: table,
            listener,
        })
    }
}

impl Port {
    fn started(&self) {
        self.progress.started(Instant::now() + self.timeout);
    }
}

impl Session for Port {
    type Plan = Plan;

    async fn read(&mut self, device: &Arc<Device>, plan: &mut Plan) -> Result<Read, LinkFault> {
        read::cycle(self, device, plan).await
    }

    async fn probe(&mut self, device: &Arc<Device>, plan: &mut Plan) -> Result<Probed, LinkFault> {
        match read::cycle(self, device, plan).await? {
            Read::Answered(_) => Ok(Probed::Answers),
            Read::Silent(e) => Ok(Probed::Silent(e)),
        }
    }

    async fn write(
        &mut self,
        device: &Arc<Device>,
        plan: &mut Plan,
        items: Vec<WriteItem>,
    ) -> Result<Option<FieldError>, LinkFault> {
        write::outputs(self, device, plan, items).await
    }

    async fn close(mut self) {
        // A silent device's cancellations are not waited for past half a second.
        let _ = tokio::time::timeout(Duration::from_millis(500), cov::cancel(&self)).await;
        self.listener.abort();
        let _ = self.client.stop().await;
    }
}

/// A device's ReadPropertyMultiple answer and change-of-value notification as the driver
/// meets them (each value read as every kind of field, the status flags judged), and the
/// object, property and priority notation of a profile.
#[cfg(any(fuzzing, test))]
pub(crate) fn fuzz_answer(data: &[u8]) {
    use crate::codec::IecType;
    let types = [
        IecType::Bool,
        IecType::Int,
        IecType::Udint,
        IecType::Real,
        IecType::Lreal,
        IecType::String,
    ];
    let values = |bytes: &[u8]| {
        let mut at = 0;
        while let Ok((v, next)) = bacnet_encoding::primitives::decode_application_value(bytes, at) {
            for ty in types {
                let _ = value::reading(ty, &v);
            }
            let _ = value::not_good(&v);
            if next <= at {
                break;
            }
            at = next;
        }
    };
    if let Ok(ack) = bacnet_services::rpm::ReadPropertyMultipleACK::decode(data) {
        for r in &ack.list_of_read_access_results {
            for e in &r.list_of_results {
                values(e.property_value.as_deref().unwrap_or_default());
            }
        }
    }
    if let Ok(n) = bacnet_services::cov::COVNotificationRequest::decode(data) {
        for v in &n.list_of_values {
            values(&v.value);
        }
    }
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = (
            point::object(text),
            point::property(text),
            point::priority(text),
        );
        let _ = point::device(Some(text), Some(text));
    }
}

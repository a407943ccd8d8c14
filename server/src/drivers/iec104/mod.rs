//! IEC 60870-5-104 stations as devices (`protocol: iec104`), the gateway the controlling
//! station: a link is a connection to a station (`iec104:` with its `host`, the standard's
//! timers and windows, a `backup` address: a redundancy group, the second connection held
//! stopped as the standby, `redundancy.rs`), a device is a
//! common address on it (the link's unless the device says), a field is an information
//! object (`ioa:`), its ASDU type taken from the station's answers unless `asdu:` fixes it.
//! The station is interrogated at connect (general, and counter interrogation for devices
//! with counters) and on its period; spontaneous data is taken as it comes, each value with
//! the station's time tag as its timestamp and its quality descriptor judged. An output's
//! write is a command (`C_SC`, `C_DC`, `C_SE_*`, `C_BO`), selected first where the field
//! says `select: true`; its confirmation is its outcome (and its termination, where the
//! field says `termination: true`).
//!
//! The wire format both sides share: the APCI (`apci.rs`), the ASDU (`asdu.rs`), its types
//! (`types.rs`) and elements (`element.rs`), the time tags (`time.rs`). The connection and
//! its timers and windows, `conn.rs`; where received ASDUs go, `route.rs`; values both
//! ways, `value.rs`; interrogations and commands, `session.rs`; fields and devices as
//! profiles write them, `point.rs`; settings, `config.rs`.

pub(crate) mod apci;
pub(crate) mod asdu;
mod command;
pub(crate) mod config;
mod conn;
pub(crate) mod element;
mod point;
mod redundancy;
mod route;
mod session;
pub(crate) mod time;
pub(crate) mod types;
mod value;
pub(crate) mod window;

use std::sync::Arc;
use std::time::Duration;

use super::{Driver, Read, Session, WriteItem};
use crate::cache::{Device, FieldError, Link};
use crate::config::{DeviceConfig, LinkConfig};
use crate::link::LinkFault;
use crate::metrics::Metrics;
use crate::profile::{Direction, Words};
use types::TypeId;

/// The IEC 104 driver.
pub(crate) struct Iec104;

const PROTOCOL: &str = "iec104";

const WORDS: Words = Words {
    protocol: PROTOCOL,
    point_key: "ioa",
    point_alternative: None,
    link_key: PROTOCOL,
    link_at: "host",
    check_point: point::check_ioa,
    point_identity: |p| p.address.trim().to_owned(),
    default_length: 0,
    example: "4001",
    scaled: true,
    field_keys: point::FIELD_KEYS,
    device_keys: &[point::COMMON_ADDRESS],
};

/// Where a field is: its object, the type it is fixed to, whether commands are selected
/// and whether the station terminates them.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Place {
    ioa: u32,
    fixed: Option<TypeId>,
    select: bool,
    termination: bool,
}

/// What is kept of a device.
pub(crate) struct Plan {
    common_address: Result<u16, String>,
    places: Vec<Result<Place, String>>,
    /// The connection its fields were registered with (0: none yet).
    generation: u64,
    /// When it was last interrogated (general, counter) on that connection.
    interrogated: Option<tokio::time::Instant>,
    /// Whether a general interrogation was answered on that connection.
    answered: bool,
    counted: Option<tokio::time::Instant>,
}

fn places(device: &Device) -> Vec<Result<Place, String>> {
    device
        .profile
        .fields
        .iter()
        .map(|f| {
            let p = f.point.as_ref().ok_or("the field has no ioa")?;
            Ok(Place {
                ioa: point::ioa(&p.address)?,
                fixed: p
                    .get(point::ASDU)
                    .map(|t| point::asdu(t, Some(f.stored_type())))
                    .transpose()?,
                select: p.get(point::SELECT).map_or(Ok(false), point::select)?,
                termination: p.get(point::TERMINATION).map_or(Ok(false), point::select)?,
            })
        })
        .collect()
}

/// The connection's error as the link's.
fn lost(e: conn::Iec104Error) -> LinkFault {
    LinkFault::lost(e)
}

impl Driver for Iec104 {
    type Plan = Plan;
    type Session = session::Station;
    const NAME: &'static str = PROTOCOL;
    const WORDS: Option<&'static Words> = Some(&WORDS);
    type Settings = config::Settings;
    const READ_SETTINGS: super::ReadSettings<config::Settings> = config::read;
    /// t0 (30 s by default) bounds the connect; STARTDT waits t1 more.
    const OPEN_TIMEOUT: Duration = Duration::from_secs(60);

    fn check_device(device: &DeviceConfig, report: &mut crate::yaml::Report) {
        for (key, value) in &device.at {
            let why = if *key == point::COMMON_ADDRESS {
                point::common_address(value).err()
            } else {
                Some(format!(
                    "`{key}` is not a key of a device on an iec104 link"
                ))
            };
            if let Some(why) = why {
                report.push(device.line, format!("device {}", device.name), why);
            }
        }
    }

    fn check_value(device: &Device, idx: usize, value: &crate::codec::Value) -> Result<(), String> {
        let field = &device.profile.fields[idx];
        let Some(Ok(place)) = places(device).into_iter().nth(idx) else {
            return Ok(());
        };
        let ty = field.stored_type();
        let command = point::command_for(ty, place.fixed)
            .ok_or_else(|| format!("IEC 104 has no command for a {ty}"))?;
        value::command(command, &field.to_raw(value)?, false).map(drop)
    }

    fn plan(device: &Device) -> Plan {
        Plan {
            common_address: Err(String::new()),
            places: places(device),
            generation: 0,
            interrogated: None,
            answered: false,
            counted: None,
        }
    }

    async fn open(
        config: &LinkConfig,
        link: &Arc<Link>,
        _metrics: &Arc<Metrics>,
    ) -> Result<session::Station, LinkFault> {
        let s = Self::settings(config)?;
        session::Station::open(s, link).await
    }
}

impl Session for session::Station {
    type Plan = Plan;

    async fn read(&mut self, device: &Arc<Device>, plan: &mut Plan) -> Result<Read, LinkFault> {
        let started = tokio::time::Instant::now();
        self.ready().await.map_err(lost)?;
        if plan.generation != self.generation {
            self.register(device, plan);
        }
        let ca = match &plan.common_address {
            Ok(ca) => *ca,
            Err(why) => {
                device.fail_reads(&FieldError::Device(why.clone()));
                return Ok(Read::Answered(started.elapsed()));
            }
        };
        if let Err(fault) = self.interrogate_when_due(device, plan, ca).await {
            // The connection went while it was asked: a standby takes over (its devices
            // asked again at their next read), else the link is lost.
            self.ready().await.map_err(|_| fault)?;
        }
        Ok(Read::Answered(started.elapsed()))
    }

    async fn write(
        &mut self,
        device: &Arc<Device>,
        plan: &mut Plan,
        items: Vec<WriteItem>,
    ) -> Result<Option<FieldError>, LinkFault> {
        self.ready().await.map_err(lost)?;
        if plan.generation != self.generation {
            self.register(device, plan);
        }
        for item in items {
            // A command the closed connection did not take is sent on the standby that
            // took over, if one did; nothing was sent of it.
            if let Err(fault) = self.command(device, plan, item.clone()).await {
                self.ready().await.map_err(|_| fault)?;
                self.command(device, plan, item).await?;
            }
        }
        Ok(None)
    }

    async fn close(self) {
        self.stop().await;
    }

    async fn lost(&mut self) -> LinkFault {
        lost(self.lost_now().await)
    }
}

/// Whether a field takes its values from the station (an input), not a command.
fn is_input(device: &Device, idx: usize) -> bool {
    device.profile.fields[idx].direction != Direction::Output
}

/// A station's bytes as the driver meets them: APDUs one after another, each I-frame's ASDU
/// decoded, encoded again and decoded to the same, each element read as every kind of
/// field and as every command.
#[cfg(any(fuzzing, test))]
pub(crate) fn fuzz_frames(data: &[u8]) {
    use crate::codec::IecType;
    let types = [
        IecType::Bool,
        IecType::Sint,
        IecType::Int,
        IecType::Udint,
        IecType::Real,
        IecType::Lreal,
        IecType::Dword,
    ];
    let mut at = 0;
    while let Ok(Some((frame, used))) = apci::Frame::decode(&data[at..]) {
        at += used;
        if let apci::Frame::I { asdu, .. } = frame
            && let Ok(decoded) = asdu::Asdu::decode(&asdu)
        {
            if let Ok(again) = decoded.encode() {
                assert_eq!(
                    asdu::Asdu::decode(&again).as_ref(),
                    Ok(&decoded),
                    "an ASDU encoded again"
                );
            }
            for o in &decoded.objects {
                for ty in types {
                    let _ = value::reading(&o.element, ty);
                }
            }
        }
    }
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = (
            point::ioa(text),
            point::asdu(text, None),
            point::common_address(text),
            config::address(text),
        );
    }
}

#[cfg(test)]
mod tests {
    /// A c104 station's answer to a general interrogation, every octet of it changed in
    /// turn to every value: no panic, and what decodes encodes back the same.
    #[test]
    fn a_station_answer_changed_anywhere_is_decoded_or_refused() {
        let frames = [
            "680e0000020064010700010000000014",
            "6812040002000d81140001006600000000484100",
            "68150c0002001e8114000100640000016d0e0f07030c1a",
            "68170e000200238114000100670000f9ff006d0e0f07030c1a",
        ];
        for hex in frames {
            let bytes: Vec<u8> = (0..hex.len())
                .step_by(2)
                .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).expect("hex"))
                .collect();
            for at in 0..bytes.len() {
                for octet in 0..=255u8 {
                    let mut changed = bytes.clone();
                    changed[at] = octet;
                    super::fuzz_frames(&changed);
                    super::fuzz_frames(&changed[..at]);
                }
            }
        }
    }
}

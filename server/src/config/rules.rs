//! The rules every link and device obeys, wherever it comes from: `iogate.yaml` (checked by
//! the config loader, each problem with its line) or a run-time declaration (`EnsureLink`,
//! `EnsureDevice`). Limits, defaults, the RS485 "configuration mismatch" checks of source
//! document 004 (the Modbus read block) and the link/slave rules of the device function
//! blocks of source document 000 live here once (ARCHITECTURE.md lists the documents).

use std::ops::RangeInclusive;
use std::time::Duration;

use super::{Framing, Parity, SerialSettings};
use crate::profile::{Profile, Protocol};

pub(crate) const DEFAULT_TCP_PORT: u16 = 502;
pub(crate) const DEFAULT_REFRESH: Duration = Duration::from_millis(100);
pub(crate) const DEFAULT_TIMEOUT: Duration = Duration::from_millis(200);
pub(crate) const DEFAULT_RETRIES: u32 = 1;
pub(crate) const MAX_RETRIES: u32 = 10;
/// Registers per read transaction (the Modbus limit; coils are limited separately to 2000).
pub(crate) const MAX_READ_REGISTERS: u16 = 125;
pub(crate) const DEFAULT_DATA_BITS: u8 = 8;
pub(crate) const DEFAULT_STOP_BITS: u8 = 1;
pub(crate) const BAUD_RATES: RangeInclusive<u32> = 300..=4_000_000;
pub(crate) const DATA_BITS: [u8; 2] = [7, 8];
pub(crate) const STOP_BITS: [u8; 2] = [1, 2];
pub(crate) const SLAVE_IDS: RangeInclusive<u32> = 1..=247;
pub(crate) const TCP_PORTS: RangeInclusive<u32> = 1..=65535;
/// The shortest refresh rate and timeout.
pub(crate) const MIN_PERIOD: Duration = Duration::from_millis(1);
/// The longest extra silence between frames: beyond it a line would do little else.
pub(crate) const MAX_GUARD_TIME: Duration = Duration::from_secs(1);

/// A rule a link or a device breaks. Each names the setting it concerns ([`RuleError::key`]).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RuleError {
    #[error("no port configured (SerialLink error 1): the port is empty")]
    NoPort,
    // Source document 004's messages word for word; iogate's detail after a line break.
    #[error("Invalid baudrate configuration.\n{0} baud is outside 300-4000000")]
    Baud(u64),
    #[error("Invalid parity configuration.\n`{0}` is not N, E or O")]
    Parity(String),
    #[error("{0} is not allowed (expected 7 or 8)")]
    DataBits(u64),
    #[error("Invalid stop bits configuration.\n{0} stop bits: 1 or 2")]
    StopBits(u64),
    #[error(
        "Invalid parity or stop bits configuration.\n{data_bits}{}{stop_bits} makes {} bits per character (start, {data_bits} data, parity, {stop_bits} stop); a Modbus serial character has at most 11, so allowed are 8N1, 8N2, 8E1, 8O1 and, with 7 data bits, 7N1, 7N2, 7E1, 7O1, 7E2, 7O2",
        .parity.letter(),
        character_bits(*.data_bits, *.parity, *.stop_bits)
    )]
    ParityStopBits {
        data_bits: u8,
        parity: Parity,
        stop_bits: u8,
    },
    #[error("the TCP host is empty")]
    NoHost,
    #[error("{0} is outside the allowed range 1-65535")]
    TcpPort(u64),
    #[error("unknown framing `{0}` (expected mbap, rtu or ascii)")]
    Framing(String),
    #[error("`{0}` is no framing of a serial line (expected rtu or ascii; mbap is Modbus TCP's)")]
    SerialFraming(String),

    #[error("{} ms is longer than the {} ms allowed", .0.as_millis(), MAX_GUARD_TIME.as_millis())]
    GuardTime(Duration),
    #[error("must be at least 1ms")]
    TooShort(&'static str),
    #[error("a simulated device has no link (remove `link: {0}`)")]
    SimulatedWithLink(String),
    #[error("a simulated device has no slave_id")]
    SimulatedWithSlave,
    #[error("profile {profile} is {protocol}: the device needs a `link`")]
    NoLink {
        profile: String,
        protocol: &'static str,
    },
    #[error("no slave configured: set slave_id (1-247)")]
    NoSlave,
    #[error("profile {profile} is {protocol}: its devices have no slave_id (remove it)")]
    SlaveOfOther {
        profile: String,
        protocol: &'static str,
    },
    #[error("{0} is outside the allowed range 1-247")]
    SlaveId(u64),
    #[error(
        "`{0}` is not a name: 1-64 letters, digits, `_`, `-` or `.`, starting with a letter, digit or `_`"
    )]
    Name(String),
}

impl RuleError {
    /// The setting the rule is about, as the config file spells it.
    pub(crate) fn key(&self) -> &'static str {
        match self {
            RuleError::NoPort => "port",
            RuleError::Baud(_) => "baud",
            RuleError::Parity(_) => "parity",
            RuleError::DataBits(_) => "data_bits",
            RuleError::StopBits(_) | RuleError::ParityStopBits { .. } => "stop_bits",
            RuleError::NoHost => "host",
            RuleError::TcpPort(_) => "port",
            RuleError::Framing(_) | RuleError::SerialFraming(_) => "framing",
            RuleError::GuardTime(_) => "guard_time",
            RuleError::TooShort(key) => key,
            RuleError::SimulatedWithLink(_) | RuleError::NoLink { .. } => "link",
            RuleError::SimulatedWithSlave
            | RuleError::NoSlave
            | RuleError::SlaveId(_)
            | RuleError::SlaveOfOther { .. } => "slave_id",
            RuleError::Name(_) => "name",
        }
    }
}

/// The longest name of a link, device or transaction.
pub(crate) const MAX_NAME: usize = 64;

/// A link, device or transaction name: 1-64 of `A-Z a-z 0-9 _ - .`, not starting with `-` or
/// `.` (so no `..`, no `/`, nothing a path or a log line could misread).
pub(crate) fn name(text: &str) -> Result<(), RuleError> {
    let ok = !text.is_empty()
        && text.len() <= MAX_NAME
        && text
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'_' | b'-' | b'.'))
        && !text.starts_with(['-', '.']);
    if ok {
        Ok(())
    } else {
        Err(RuleError::Name(crate::text::quote(text)))
    }
}

/// `N`, `E`, `O` (or `none`, `even`, `odd`), in any case.
pub(crate) fn parse_parity(text: &str) -> Result<Parity, RuleError> {
    match text.to_ascii_uppercase().as_str() {
        "N" | "NONE" => Ok(Parity::None),
        "E" | "EVEN" => Ok(Parity::Even),
        "O" | "ODD" => Ok(Parity::Odd),
        _ => Err(RuleError::Parity(text.to_owned())),
    }
}

/// A TCP link's framing: `mbap` (Modbus TCP), `rtu` or `ascii` (serial frames over a raw
/// socket).
pub(crate) fn parse_framing(text: &str) -> Result<Framing, RuleError> {
    match text {
        "mbap" => Ok(Framing::Mbap),
        "rtu" => Ok(Framing::Rtu),
        "ascii" => Ok(Framing::Ascii),
        other => Err(RuleError::Framing(other.to_owned())),
    }
}

/// A serial line's framing: `rtu` or `ascii`.
pub(crate) fn parse_serial_framing(text: &str) -> Result<Framing, RuleError> {
    match text {
        "rtu" => Ok(Framing::Rtu),
        "ascii" => Ok(Framing::Ascii),
        other => Err(RuleError::SerialFraming(other.to_owned())),
    }
}

/// The most bits a character of a Modbus serial line has: a start bit, 8 data bits, a
/// parity bit and a stop bit, or no parity and 2 stop bits (the Modbus serial line
/// specification's 11-bit character).
pub(crate) const MAX_CHARACTER_BITS: u32 = 11;

/// The bits one character takes on the line.
pub(crate) fn character_bits(data_bits: u8, parity: Parity, stop_bits: u8) -> u32 {
    1 + u32::from(data_bits) + u32::from(parity != Parity::None) + u32::from(stop_bits)
}

/// A serial line's settings as given (unchecked numbers, the parity as parsed), checked:
/// every broken rule at once.
pub(crate) fn serial(
    port: String,
    baud: u64,
    parity: Result<Parity, RuleError>,
    data_bits: u64,
    stop_bits: u64,
) -> Result<SerialSettings, Vec<RuleError>> {
    let mut errors = Vec::new();
    if port.trim().is_empty() {
        errors.push(RuleError::NoPort);
    }
    let parity = parity.map_err(|e| errors.push(e)).ok();
    let baud = u32::try_from(baud)
        .ok()
        .filter(|b| BAUD_RATES.contains(b))
        .ok_or(RuleError::Baud(baud));
    let data_bits = u8::try_from(data_bits)
        .ok()
        .filter(|b| DATA_BITS.contains(b))
        .ok_or(RuleError::DataBits(data_bits));
    let stop_bits = u8::try_from(stop_bits)
        .ok()
        .filter(|b| STOP_BITS.contains(b))
        .ok_or(RuleError::StopBits(stop_bits));
    if let (Some(parity), Ok(data_bits), Ok(stop_bits)) = (parity, &data_bits, &stop_bits)
        && character_bits(*data_bits, parity, *stop_bits) > MAX_CHARACTER_BITS
    {
        errors.push(RuleError::ParityStopBits {
            data_bits: *data_bits,
            parity,
            stop_bits: *stop_bits,
        });
    }
    match (baud, parity, data_bits, stop_bits) {
        (Ok(baud), Some(parity), Ok(data_bits), Ok(stop_bits)) if errors.is_empty() => {
            Ok(SerialSettings {
                port,
                baud,
                parity,
                data_bits,
                stop_bits,
                framing: Framing::Rtu,
            })
        }
        (baud, _, data_bits, stop_bits) => {
            errors.extend(
                [baud.err(), data_bits.err(), stop_bits.err()]
                    .into_iter()
                    .flatten(),
            );
            Err(errors)
        }
    }
}

/// A TCP endpoint's host and port, checked.
pub(crate) fn tcp_endpoint(host: &str, port: u64) -> Result<u16, Vec<RuleError>> {
    let mut errors = Vec::new();
    if host.trim().is_empty() {
        errors.push(RuleError::NoHost);
    }
    let port = u16::try_from(port)
        .ok()
        .filter(|p| TCP_PORTS.contains(&u32::from(*p)))
        .ok_or(RuleError::TcpPort(port));
    match port {
        Ok(p) if errors.is_empty() => Ok(p),
        Ok(_) => Err(errors),
        Err(e) => {
            errors.push(e);
            Err(errors)
        }
    }
}

pub(crate) fn guard_time(d: Duration) -> Result<Duration, RuleError> {
    if d > MAX_GUARD_TIME {
        Err(RuleError::GuardTime(d))
    } else {
        Ok(d)
    }
}

/// A refresh rate or timeout (`key` names which), at least [`MIN_PERIOD`].
pub(crate) fn period(key: &'static str, d: Duration) -> Result<Duration, RuleError> {
    if d < MIN_PERIOD {
        Err(RuleError::TooShort(key))
    } else {
        Ok(d)
    }
}

/// How a device of `profile` is bound: a simulated device has neither link nor slave id; a
/// Modbus device needs both, the slave id within 1-247.
pub(crate) fn binding(
    profile: &Profile,
    link: Option<&str>,
    slave_id: Option<u64>,
) -> Vec<RuleError> {
    let mut errors = Vec::new();
    if profile.protocol == Protocol::Simulated {
        if let Some(link) = link {
            errors.push(RuleError::SimulatedWithLink(link.to_owned()));
        }
        if slave_id.is_some() {
            errors.push(RuleError::SimulatedWithSlave);
        }
        return errors;
    }
    if link.is_none() {
        errors.push(RuleError::NoLink {
            profile: profile.name.clone(),
            protocol: profile.protocol.name(),
        });
    }
    if !profile.protocol.is_modbus() {
        if slave_id.is_some() {
            errors.push(RuleError::SlaveOfOther {
                profile: profile.name.clone(),
                protocol: profile.protocol.name(),
            });
        }
        return errors;
    }
    match slave_id.map(self::slave_id) {
        None => errors.push(RuleError::NoSlave),
        Some(Err(e)) => errors.push(e),
        Some(Ok(_)) => {}
    }
    errors
}

/// A Modbus slave address: 1-247 (0 is broadcast, 248-255 reserved).
pub(crate) fn slave_id(id: u64) -> Result<u8, RuleError> {
    u8::try_from(id)
        .ok()
        .filter(|i| SLAVE_IDS.contains(&u32::from(*i)))
        .ok_or(RuleError::SlaveId(id))
}

/// One setting on which two users of one serial port disagree.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Mismatch {
    /// `Baudrate`, `Parity`, `Stop bits` or `Data bits`, as source document 004 words it,
    /// or `Framing` (RTU or ASCII).
    pub(crate) setting: &'static str,
    /// What the port runs with.
    pub(crate) have: String,
    /// What the newcomer asks for.
    pub(crate) want: String,
}

/// Every setting of `want` that differs from `have` on the same port.
pub(crate) fn serial_mismatches(have: &SerialSettings, want: &SerialSettings) -> Vec<Mismatch> {
    [
        ("Baudrate", have.baud.to_string(), want.baud.to_string()),
        (
            "Parity",
            have.parity.letter().to_string(),
            want.parity.letter().to_string(),
        ),
        (
            "Stop bits",
            have.stop_bits.to_string(),
            want.stop_bits.to_string(),
        ),
        (
            "Data bits",
            have.data_bits.to_string(),
            want.data_bits.to_string(),
        ),
        (
            "Framing",
            have.framing.name().to_owned(),
            want.framing.name().to_owned(),
        ),
    ]
    .into_iter()
    .filter(|(_, h, w)| h != w)
    .map(|(setting, have, want)| Mismatch {
        setting,
        have,
        want,
    })
    .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_broken_serial_rule_is_named() {
        let errors =
            serial(" ".into(), 50, Err(RuleError::Parity("X".into())), 9, 3).expect_err("broken");
        assert_eq!(
            errors,
            vec![
                RuleError::NoPort,
                RuleError::Parity("X".into()),
                RuleError::Baud(50),
                RuleError::DataBits(9),
                RuleError::StopBits(3)
            ]
        );
        assert!(serial("/dev/ttyS0".into(), 9600, Ok(Parity::Even), 7, 2).is_ok());
    }

    #[test]
    fn a_character_of_more_than_11_bits_is_refused_with_the_documents_message() {
        for (data, parity, stop, allowed) in [
            (8, Parity::None, 1, true),
            (8, Parity::None, 2, true),
            (8, Parity::Even, 1, true),
            (8, Parity::Odd, 1, true),
            (8, Parity::Even, 2, false),
            (8, Parity::Odd, 2, false),
            (7, Parity::Even, 2, true),
            (7, Parity::None, 1, true),
        ] {
            let checked = serial("/dev/ttyS0".into(), 9600, Ok(parity), data, stop);
            assert_eq!(checked.is_ok(), allowed, "{data}{}{stop}", parity.letter());
            if let Err(errors) = checked {
                let message = errors[0].to_string();
                let (document, detail) = message.split_once('\n').expect("two lines");
                assert_eq!(document, "Invalid parity or stop bits configuration.");
                assert!(
                    detail.starts_with("8E2 makes 12 bits")
                        || detail.starts_with("8O2 makes 12 bits"),
                    "{detail}"
                );
            }
        }
    }

    #[test]
    fn mismatches_are_listed_in_the_documented_order() {
        let a = serial("/dev/x".into(), 9600, Ok(Parity::None), 8, 1).expect("ok");
        let b = serial("/dev/x".into(), 19200, Ok(Parity::None), 8, 2).expect("ok");
        let names: Vec<_> = serial_mismatches(&a, &b)
            .into_iter()
            .map(|m| m.setting)
            .collect();
        assert_eq!(names, ["Baudrate", "Stop bits"]);
        assert!(serial_mismatches(&a, &a).is_empty());
    }

    #[test]
    fn guard_times_and_periods_are_bounded() {
        assert!(guard_time(Duration::from_millis(1000)).is_ok());
        assert_eq!(
            guard_time(Duration::from_millis(1001))
                .expect_err("too long")
                .to_string(),
            "1001 ms is longer than the 1000 ms allowed"
        );
        assert!(period("timeout", Duration::ZERO).is_err());
    }
}

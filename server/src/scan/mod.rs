//! Finding the devices on a line: every slave id at each line setting, one probe in one
//! time slot each; for each id that answers, which reads answer, its identification
//! (FC 43 / MEI 14), collisions (two devices on one id), and the profiles that fit.
//!
//! The scan decides; a [`Prober`] carries its probes: a serial port of its own
//! (`iogate scan`, [`port`]) or a configured link's queue between polls (the service's).

pub mod cli;
mod discover;
pub mod ident;
use discover::{Discovered, discover};
mod judge;
pub mod matching;
pub mod port;
mod probe;
pub mod report;

use std::sync::Arc;
use std::time::Duration;

use serde::Serialize;

use crate::config::Parity;
use crate::profile::Profile;
pub use ident::Identification;

/// One line setting a scan tries: baud rate and parity (8 data bits, 1 stop bit); baud 0
/// for RTU over TCP, which has no line of its own.
#[derive(Debug, Clone, Copy, PartialEq, Eq, utoipa::ToSchema)]
pub struct Setting {
    pub baud: u32,
    /// `N`, `E` or `O`.
    #[schema(value_type = String)]
    pub parity: Parity,
}

impl Setting {
    /// As a line's settings are written: `19200 8E1`.
    pub fn label(&self) -> String {
        format!("{} 8{}1", self.baud, self.parity.letter())
    }

    /// The line settings of `port` at this setting (RTU, 8 data bits, 1 stop bit).
    pub fn serial(&self, port: &str) -> crate::config::SerialSettings {
        crate::config::SerialSettings {
            port: port.to_owned(),
            baud: self.baud,
            parity: self.parity,
            data_bits: 8,
            stop_bits: 1,
            framing: crate::config::Framing::Rtu,
        }
    }
}

impl Serialize for Setting {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeStruct;
        let mut out = s.serialize_struct("Setting", 2)?;
        out.serialize_field("baud", &self.baud)?;
        out.serialize_field("parity", &self.parity.letter().to_string())?;
        out.end()
    }
}

/// The default baud rates, fastest first, and parities.
pub const DEFAULT_BAUDS: [u32; 5] = [115_200, 57_600, 38_400, 19_200, 9_600];
pub const DEFAULT_PARITIES: [Parity; 2] = [Parity::None, Parity::Even];
/// The default time slot of one probe.
pub const DEFAULT_TIMEOUT: Duration = Duration::from_millis(50);

/// What to scan.
#[derive(Debug, Clone)]
pub struct Plan {
    pub settings: Vec<Setting>,
    pub ids: Vec<u8>,
    /// One probe's whole time slot: the line's silence, the request and the answer.
    pub timeout: Duration,
}

impl Plan {
    /// The longest the search takes: one slot per id and setting (each device found adds
    /// its follow-up probes, at most [`MAX_FOLLOW_UPS`] slots plus its profiles' probes).
    pub fn estimate(&self) -> Duration {
        self.timeout * (self.settings.len() * self.ids.len()) as u32
    }

    /// The shortest slot that can carry a probe and its answer at `setting`: the silence,
    /// an 8-byte request, a 7-byte answer and 2 ms for the device to turn round.
    pub fn shortest_slot(setting: &Setting) -> Duration {
        let timing = crate::link::timing::LineTiming::new(&setting.serial(""));
        timing.silence() + timing.frame_time(8) + timing.frame_time(7) + Duration::from_millis(2)
    }

    /// Every problem with the plan, named.
    pub fn check(&self) -> Result<(), String> {
        if self.settings.is_empty() {
            return Err("no line setting to try".to_owned());
        }
        if self.ids.is_empty() {
            return Err("no slave id to try".to_owned());
        }
        for s in &self.settings {
            let least = Plan::shortest_slot(s);
            if self.timeout < least {
                return Err(format!(
                    "timeout {} ms is too short at {} baud: a probe and its answer need {:.1} ms",
                    self.timeout.as_millis(),
                    s.baud,
                    least.as_secs_f64() * 1e3
                ));
            }
        }
        if self.timeout > Duration::from_secs(5) {
            return Err("timeout above 5 s".to_owned());
        }
        Ok(())
    }
}

/// Parses slave ids: `1-247`, `1,3,10-20`.
pub fn parse_ids(text: &str) -> Result<Vec<u8>, String> {
    let mut ids = Vec::new();
    for part in text.split(',').map(str::trim) {
        let (from, to) = part.split_once('-').unwrap_or((part, part));
        let id = |t: &str| {
            t.trim()
                .parse::<u8>()
                .ok()
                .filter(|i| (1..=247).contains(i))
                .ok_or_else(|| format!("`{t}` in `{text}` is not a slave id (1-247)"))
        };
        let (from, to) = (id(from)?, id(to)?);
        if from > to {
            return Err(format!("`{part}` runs backwards"));
        }
        ids.extend(from..=to);
    }
    ids.sort_unstable();
    ids.dedup();
    Ok(ids)
}

/// Parses baud rates: `9600,19200`.
pub fn parse_bauds(text: &str) -> Result<Vec<u32>, String> {
    text.split(',')
        .map(|b| {
            b.trim()
                .parse::<u32>()
                .ok()
                .filter(|b| (300..=4_000_000).contains(b))
                .ok_or_else(|| format!("`{b}` is not a baud rate (300-4000000)"))
        })
        .collect()
}

/// Parses parities: `N,E,O`.
pub fn parse_parities(text: &str) -> Result<Vec<Parity>, String> {
    text.split(',')
        .map(|p| match p.trim() {
            "N" | "n" => Ok(Parity::None),
            "E" | "e" => Ok(Parity::Even),
            "O" | "o" => Ok(Parity::Odd),
            other => Err(format!("`{other}` is not a parity (N, E or O)")),
        })
        .collect()
}

/// Every setting of `bauds` × `parities`, in the order given (each baud with each parity).
pub fn settings(bauds: &[u32], parities: &[Parity]) -> Vec<Setting> {
    bauds
        .iter()
        .flat_map(|&baud| parities.iter().map(move |&parity| Setting { baud, parity }))
        .collect()
}

/// Why a scan could not go on.
#[derive(Debug, Clone, thiserror::Error)]
pub enum ScanError {
    #[error("{0}")]
    Port(String),
    #[error("the scan was cancelled")]
    Cancelled,
}

/// Carries a scan's probes: sets the line and sends one probe in one time slot.
#[async_trait::async_trait]
pub trait Prober: Send {
    /// Sets the line to `setting` (a configured link stays at its own).
    async fn set(&mut self, setting: &Setting) -> Result<(), ScanError>;
    /// Sends `pdu` to `slave` and returns every byte heard within the slot. With `early`,
    /// the slot may end once a whole answer is followed by the line's silence.
    async fn probe(&mut self, slave: u8, pdu: &[u8], early: bool) -> Result<Vec<u8>, ScanError>;
}

/// One read of a device found, and what came of it.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct ReadAnswer {
    pub function: u8,
    pub address: u16,
    pub count: u16,
    /// `data`, `exception`, `no answer` or `garbled`.
    pub answer: &'static str,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub exception: Option<String>,
    /// The registers (or bits as 0/1) read.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub values: Vec<u16>,
}

impl ReadAnswer {
    pub fn answered(&self) -> bool {
        self.answer == "data"
    }
}

/// A profile that fits a device found, and why.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct Suggestion {
    pub profile: String,
    /// Whether the device's identification matched what the profile states.
    pub identified: bool,
    /// The profile's probe reads, each answered.
    pub probes: usize,
    /// Whether the evidence tells this profile from others: an identification, stated
    /// probe values, or a register map answered by a device that refuses registers no map
    /// has (a device that answers every address tells nothing by answering the profile's).
    pub telling: bool,
}

/// A device found: where it answers, what it answered, what it may be.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct Found {
    pub slave_id: u8,
    pub setting: Setting,
    pub reads: Vec<ReadAnswer>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub identification: Option<Identification>,
    /// Two devices on this id: what showed it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub collision: Option<String>,
    /// Its answers could not be read: what the bytes show (one damaged device, or noise or
    /// a collision).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub garbled: Option<String>,
    /// Some of its answers were garbled, others not: what was seen (a noisy line, or a
    /// setting at its edge).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub unsteady: Option<String>,
    pub profiles: Vec<Suggestion>,
}

/// What a scan tells while it runs.
#[derive(Debug, Clone)]
pub enum Progress {
    /// A setting begins: `index` of `of`.
    Setting {
        setting: Setting,
        index: usize,
        of: usize,
    },
    /// Ids tried so far, of all settings.
    Tried {
        done: usize,
        total: usize,
    },
    Found(Box<Found>),
}

/// Follow-up probes of a device found, besides its profiles': FC 04, 01, 02 at address 0
/// and identification (basic, then regular, up to two answers each).
pub const MAX_FOLLOW_UPS: usize = 7;

/// Runs `plan` through `prober`, telling `progress` as it goes; matches each device found
/// against `profiles`. `cancel` stops it between probes.
pub async fn run(
    prober: &mut dyn Prober,
    plan: &Plan,
    profiles: &[Arc<Profile>],
    progress: &mut (dyn FnMut(Progress) + Send),
    cancel: &tokio_util::sync::CancellationToken,
) -> Result<Scanned, ScanError> {
    let total = plan.settings.len() * plan.ids.len();
    let mut done = 0;
    let mut found = Vec::new();
    let mut strangers = Vec::new();
    for (index, setting) in plan.settings.iter().enumerate() {
        progress(Progress::Setting {
            setting: *setting,
            index,
            of: plan.settings.len(),
        });
        prober.set(setting).await?;
        // The ids each id heard answering was asked as, at this setting.
        let mut foreign: std::collections::BTreeMap<u8, Vec<u8>> = Default::default();
        for &id in &plan.ids {
            if cancel.is_cancelled() {
                return Err(ScanError::Cancelled);
            }
            match discover(prober, id, *setting, profiles).await? {
                Discovered::Device(device) => {
                    progress(Progress::Found(device.clone()));
                    found.push(*device);
                }
                Discovered::Foreign(other) => foreign.entry(other).or_default().push(id),
                Discovered::Nothing => {}
            }
            done += 1;
            progress(Progress::Tried { done, total });
        }
        for (answered_as, asked) in foreign {
            // One answer right after its own id's probe is that probe's, late.
            if asked.len() == 1 && u16::from(asked[0]) == u16::from(answered_as) + 1 {
                continue;
            }
            strangers.push(Stranger {
                answered_as,
                setting: *setting,
                asked: report::ranges(&asked),
            });
        }
    }
    Ok(Scanned {
        devices: found,
        strangers,
    })
}

/// A device that answered requests for other ids as its own: the id it answers with, at
/// which setting, and the ids asked.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct Stranger {
    pub answered_as: u8,
    pub setting: Setting,
    /// The ids whose requests it answered, as ranges (`1-247`).
    pub asked: String,
}

/// What a scan found: the devices, and answers given as ids not asked.
#[derive(Debug, Clone, Default)]
pub struct Scanned {
    pub devices: Vec<Found>,
    pub strangers: Vec<Stranger>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_bauds_and_parities_parse_or_are_named() {
        assert_eq!(parse_ids("1-3,7,2").expect("ids"), vec![1, 2, 3, 7]);
        assert_eq!(parse_ids("1-247").expect("ids").len(), 247);
        assert!(parse_ids("0-5").expect_err("0").contains("`0`"));
        assert!(
            parse_ids("9-3")
                .expect_err("backwards")
                .contains("backwards")
        );
        assert!(parse_ids("248").is_err());
        assert_eq!(
            parse_bauds("9600, 19200").expect("bauds"),
            vec![9600, 19200]
        );
        assert!(parse_bauds("fast").is_err());
        assert_eq!(
            parse_parities("N,E").expect("parities"),
            vec![Parity::None, Parity::Even]
        );
        assert!(parse_parities("X").expect_err("X").contains("`X`"));
    }

    #[test]
    fn the_estimate_is_one_slot_per_id_and_setting_and_a_slot_must_fit() {
        let plan = Plan {
            settings: settings(&[19_200, 9_600], &[Parity::None]),
            ids: parse_ids("1-247").expect("ids"),
            timeout: Duration::from_millis(50),
        };
        assert_eq!(plan.estimate(), Duration::from_millis(50 * 2 * 247));
        assert!(plan.check().is_ok());
        let slow = Plan {
            settings: settings(&[1_200], &[Parity::None]),
            timeout: Duration::from_millis(50),
            ..plan
        };
        let e = slow.check().expect_err("too short");
        assert!(e.contains("too short at 1200 baud"), "{e}");
    }
}

//! A scan's result as the terminal shows it and as JSON, with the `links:` and `devices:`
//! entries for `iogate.yaml`.

use std::fmt::Write;

use serde::Serialize;

use super::{Found, Plan, Scanned, Setting, Stranger};

/// A finished (or running) scan's result: what was tried, what was found, and the config.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct Summary {
    pub settings: Vec<Setting>,
    /// The ids tried, as ranges: `1-247`.
    pub ids: String,
    pub timeout_ms: u64,
    /// The longest the search takes (one slot per id and setting).
    pub estimate_ms: u64,
    pub devices: Vec<Found>,
    /// Devices that answered requests for other ids as an id of their own.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub strangers: Vec<Stranger>,
    /// Ready `links:` (for a port) and `devices:` entries.
    pub config: String,
}

impl Summary {
    pub fn new(plan: &Plan, scanned: Scanned, port: Option<&str>, link: &str) -> Self {
        let Scanned { devices, strangers } = scanned;
        Summary {
            strangers,
            settings: plan.settings.clone(),
            ids: ranges(&plan.ids),
            timeout_ms: plan.timeout.as_millis() as u64,
            estimate_ms: plan.estimate().as_millis() as u64,
            config: config(&devices, port, link),
            devices,
        }
    }
}

/// `1,2,3,7` → `1-3,7`.
pub fn ranges(ids: &[u8]) -> String {
    let mut out: Vec<String> = Vec::new();
    let mut i = 0;
    while i < ids.len() {
        let mut j = i;
        while j + 1 < ids.len() && ids[j + 1] == ids[j] + 1 {
            j += 1;
        }
        out.push(if i == j {
            ids[i].to_string()
        } else {
            format!("{}-{}", ids[i], ids[j])
        });
        i = j + 1;
    }
    out.join(",")
}

/// The link a device found at `setting` goes on: `link` when every device is at one setting,
/// else one link per setting.
fn link_name(link: &str, setting: &Setting, many: bool) -> String {
    if many {
        format!(
            "{link}_{}_8{}1",
            setting.baud,
            setting.parity.letter().to_ascii_lowercase()
        )
    } else {
        link.to_owned()
    }
}

/// The `links:` entries (for a port of its own) and `devices:` entries of the devices found:
/// the best profile of each (the others named in a comment); an id two devices answer is
/// a comment, not an entry.
pub fn config(devices: &[Found], port: Option<&str>, link: &str) -> String {
    let mut settings: Vec<Setting> = Vec::new();
    for d in devices {
        if !settings.contains(&d.setting) {
            settings.push(d.setting);
        }
    }
    let many = settings.len() > 1;
    let mut out = String::new();
    if let Some(port) = port
        && !settings.is_empty()
    {
        if many {
            out.push_str("# devices answer at different settings: one port runs at one of them\n");
        }
        out.push_str("links:\n");
        for s in &settings {
            let _ = writeln!(
                out,
                "  - {{ name: {}, serial: {{ port: {port}, baud: {}, parity: {} }} }}",
                link_name(link, s, many),
                s.baud,
                s.parity.letter()
            );
        }
    }
    if devices.is_empty() {
        return out;
    }
    out.push_str("devices:\n");
    let mut names: Vec<String> = Vec::new();
    for d in devices {
        let link = link_name(link, &d.setting, many);
        let _ = writeln!(out, "{}", device_lines(d, &link, &mut names));
    }
    out
}

/// The entry (or the comment saying why there is none) of one device found; `names` are
/// those given so far (a device that answers at two settings gets two names).
fn device_lines(d: &Found, link: &str, names: &mut Vec<String>) -> String {
    let mut out = entry_lines(d, link, names);
    if let Some(why) = &d.unsteady {
        let _ = write!(out, "\n  #   warning: {why}");
    }
    out
}

/// A device's entry, or why it has none.
fn entry_lines(d: &Found, link: &str, names: &mut Vec<String>) -> String {
    let slave = d.slave_id;
    if let Some(why) = &d.collision {
        return format!("  # slave {slave} on {link}: {why}; give one of them another id first");
    }
    if let Some(why) = &d.garbled {
        return format!(
            "  # slave {slave} on {link}: its answers cannot be read: {why}; check the line before adding it"
        );
    }
    let (telling, shape): (Vec<&super::Suggestion>, Vec<&super::Suggestion>) =
        d.profiles.iter().partition(|s| s.telling);
    // Several fit: an identification tells which, else the most probe reads answered; a
    // tie is none offered, each named with what it answered.
    let identified: Vec<&&super::Suggestion> = telling.iter().filter(|s| s.identified).collect();
    let most = telling.iter().map(|s| s.probes).max().unwrap_or(0);
    let top: Vec<&&super::Suggestion> = telling.iter().filter(|s| s.probes == most).collect();
    let best = match (identified.as_slice(), top.as_slice(), telling.as_slice()) {
        ([one], _, _) => Some(**one),
        (_, _, [one]) => Some(*one),
        (_, _, []) => None,
        ([], [one], _) => Some(**one),
        (_, _, several) => {
            let why: Vec<String> = several
                .iter()
                .map(|s| format!("{} ({} probe read(s) answered)", s.profile, s.probes))
                .collect();
            return format!(
                "  # slave {slave} on {link}: {} profiles fit and nothing tells which it is: {}; add the entry of the one it is by hand",
                several.len(),
                why.join(", ")
            );
        }
    };
    let others: Vec<&&super::Suggestion> = telling
        .iter()
        .filter(|s| best.is_some_and(|b| b.profile != s.profile))
        .collect();
    let Some(best) = best else {
        if shape.is_empty() {
            return format!(
                "  # slave {slave} on {link}: no profile fits; import or write one (iogate profile import)"
            );
        }
        let fits: Vec<&str> = shape.iter().map(|s| s.profile.as_str()).collect();
        return format!(
            "  # slave {slave} on {link}: answers where {} expect(s), but also where no map has registers: nothing tells which device it is; add its entry by hand",
            fits.join(", ")
        );
    };
    let mut name = super::matching::entry_name(&best.profile, slave);
    if names.contains(&name) {
        name = format!("{name}_{link}");
    }
    names.push(name.clone());
    let mut out = format!(
        "  {}",
        super::matching::named_entry(&name, &best.profile, link, slave)
    );
    if !others.is_empty() {
        let names: Vec<String> = others
            .iter()
            .map(|s| format!("{} ({} probe read(s) answered)", s.profile, s.probes))
            .collect();
        let _ = write!(
            out,
            "\n  #   also fits: {} (chosen: {} probe read(s) answered{})",
            names.join(", "),
            best.probes,
            if best.identified { ", identified" } else { "" }
        );
    }
    out
}

/// A device that answered as another id, as the terminal shows it.
pub fn stranger_line(s: &Stranger) -> String {
    format!(
        "  at {}: requests for slave {} were answered as slave {}: a device answers with an id other than the one asked (a gateway in between, or a device that ignores the address); no entry is made for it",
        s.setting.label(),
        s.asked,
        s.answered_as
    )
}

/// One device found, as the terminal shows it.
pub fn device_line(d: &Found) -> String {
    let mut out = format!("  slave {:>3} at {}:", d.slave_id, d.setting.label());
    let reads: Vec<String> = d
        .reads
        .iter()
        .map(|r| {
            let what = match (&r.exception, r.answer) {
                (Some(x), _) => format!("exception {x}"),
                (None, "data") => format!("{:?}", r.values),
                (None, other) => other.to_owned(),
            };
            format!("FC{:02} {}+{} {what}", r.function, r.address, r.count)
        })
        .collect();
    let _ = write!(out, " {}", reads.join("; "));
    if let Some(id) = &d.identification {
        let parts: Vec<String> = [
            ("vendor", &id.vendor),
            ("product code", &id.product_code),
            ("revision", &id.revision),
            ("product", &id.product_name),
            ("model", &id.model_name),
        ]
        .iter()
        .filter_map(|(k, v)| v.as_ref().map(|v| format!("{k} {v:?}")))
        .collect();
        let _ = write!(out, "\n      identification: {}", parts.join(", "));
    }
    if let Some(why) = &d.collision {
        let _ = write!(out, "\n      COLLISION: {why}");
    }
    if let Some(why) = &d.garbled {
        let _ = write!(out, "\n      UNREADABLE: {why}");
    }
    if let Some(why) = &d.unsteady {
        let _ = write!(out, "\n      WARNING: {why}");
    }
    if d.profiles.is_empty() {
        out.push_str("\n      profiles: none fits");
    } else {
        let names: Vec<String> = d
            .profiles
            .iter()
            .map(|s| {
                if s.identified {
                    format!("{} (identified)", s.profile)
                } else {
                    s.profile.clone()
                }
            })
            .collect();
        let _ = write!(out, "\n      profiles: {}", names.join(", "));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Parity;
    use crate::scan::Suggestion;

    fn found(id: u8, baud: u32, profile: Option<&str>, collision: Option<&str>) -> Found {
        Found {
            slave_id: id,
            setting: Setting {
                baud,
                parity: Parity::None,
            },
            reads: Vec::new(),
            identification: None,
            collision: collision.map(str::to_owned),
            garbled: None,
            unsteady: None,
            profiles: profile
                .map(|p| Suggestion {
                    profile: p.to_owned(),
                    identified: false,
                    probes: 1,
                    telling: true,
                })
                .into_iter()
                .collect(),
        }
    }

    #[test]
    fn ids_as_ranges() {
        assert_eq!(ranges(&[1, 2, 3, 7, 9, 10]), "1-3,7,9-10");
        assert_eq!(ranges(&[]), "");
    }

    #[test]
    fn config_has_one_link_per_setting_and_no_entry_for_a_collision() {
        let one = config(
            &[
                found(3, 9600, Some("Meter"), None),
                found(5, 9600, None, Some("two answers")),
            ],
            Some("/dev/ttyUSB0"),
            "line",
        );
        assert!(
            one.contains(
                "  - { name: line, serial: { port: /dev/ttyUSB0, baud: 9600, parity: N } }"
            ),
            "{one}"
        );
        assert!(
            one.contains("  - { name: meter_3, profile: Meter, link: line, slave_id: 3 }"),
            "{one}"
        );
        assert!(one.contains("# slave 5 on line: two answers"), "{one}");
        let two = config(
            &[
                found(3, 9600, Some("Meter"), None),
                found(4, 19200, Some("Io"), None),
            ],
            Some("/dev/ttyUSB0"),
            "line",
        );
        assert!(two.contains("name: line_9600_8n1"), "{two}");
        assert!(two.contains("link: line_19200_8n1, slave_id: 4"), "{two}");
    }

    #[test]
    fn one_device_at_two_settings_gets_two_names_and_a_shape_alone_no_entry() {
        let twice = config(
            &[
                found(3, 9600, Some("Meter"), None),
                found(3, 19200, Some("Meter"), None),
            ],
            Some("/dev/ttyUSB0"),
            "line",
        );
        let text = format!(
            "devices:\n{}",
            twice.split("devices:\n").nth(1).unwrap_or("")
        );
        assert!(text.contains("name: meter_3,"), "{twice}");
        assert!(text.contains("name: meter_3_line_19200_8n1,"), "{twice}");
        let mut shape = found(4, 9600, Some("WaveshareAnalogInput"), None);
        shape.profiles[0].telling = false;
        let mut garbled = found(5, 9600, None, None);
        garbled.garbled = Some("answers whose CRC is wrong, each time".to_owned());
        let out = config(&[shape, garbled], None, "line");
        assert!(!out.contains("profile: WaveshareAnalogInput"), "{out}");
        assert!(
            out.contains("# slave 4 on line: answers where WaveshareAnalogInput expect(s), but also where no map has registers"),
            "{out}"
        );
        assert!(
            out.contains(
                "# slave 5 on line: its answers cannot be read: answers whose CRC is wrong"
            ),
            "{out}"
        );
        assert!(
            !out.contains("another id"),
            "no collision is claimed: {out}"
        );
    }

    #[test]
    fn several_profiles_that_fit_alike_are_all_named_and_none_offered() {
        let mut d = found(3, 9600, Some("WaveshareAnalogInput"), None);
        for other in ["GenericIo", "SimIo"] {
            let mut s = d.profiles[0].clone();
            s.profile = other.to_owned();
            d.profiles.push(s);
        }
        let text = config(std::slice::from_ref(&d), Some("/dev/ttyUSB0"), "line");
        assert!(!text.contains("profile: WaveshareAnalogInput"), "{text}");
        assert!(
            text.contains("3 profiles fit and nothing tells which it is")
                && text.contains("GenericIo (1 probe read(s) answered)"),
            "{text}"
        );
        // An identification tells: that one is offered, the others named.
        d.profiles[1].identified = true;
        let text = config(std::slice::from_ref(&d), Some("/dev/ttyUSB0"), "line");
        assert!(text.contains("profile: GenericIo"), "{text}");
        assert!(
            text.contains("also fits: WaveshareAnalogInput (1 probe read(s) answered), SimIo"),
            "{text}"
        );
        // Without it, the most probe reads answered tells.
        d.profiles[1].identified = false;
        d.profiles[2].probes = 3;
        let text = config(std::slice::from_ref(&d), Some("/dev/ttyUSB0"), "line");
        assert!(text.contains("profile: SimIo"), "{text}");
        assert!(
            text.contains("(chosen: 3 probe read(s) answered)"),
            "{text}"
        );
        // A device whose answers were sometimes garbled is offered with a warning.
        d.unsteady = Some("1 of its answers to 5 requests were garbled".to_owned());
        let text = config(std::slice::from_ref(&d), Some("/dev/ttyUSB0"), "line");
        assert!(text.contains("warning: 1 of its answers"), "{text}");
        assert!(device_line(&d).contains("WARNING: 1 of its answers"));
    }
}

//! The profiles that fit a device found: those whose identification (where stated) is the
//! device's and whose probe reads all answer with data (and the stated values); each with
//! a ready `devices:` entry.

use std::collections::HashMap;
use std::sync::Arc;

use super::probe::read;
use super::{Found, Prober, ReadAnswer, ScanError, Suggestion};
use crate::profile::{ProbeRead, Profile, Protocol, RegisterKind};

/// A register no device's map has: a device that answers it answers every address, and its
/// answers to a profile's probes tell nothing.
const CONTROL: u16 = 0xFFF0;

/// The reads a scan tells `profile`'s device by: its `probe:`, else the first field of each
/// register kind it uses, read whole.
pub fn probes(profile: &Profile) -> Vec<ProbeRead> {
    if !profile.probe.is_empty() {
        return profile.probe.clone();
    }
    let mut firsts: Vec<ProbeRead> = Vec::new();
    for f in &profile.fields {
        let kind = f.register.kind;
        if kind == RegisterKind::Virtual {
            continue;
        }
        let count = f.span().min(125) as u16;
        match firsts.iter_mut().find(|p| p.kind == kind) {
            Some(p) if p.address <= f.register.address => {}
            Some(p) => {
                p.address = f.register.address;
                p.count = count;
            }
            None => firsts.push(ProbeRead {
                kind,
                address: f.register.address,
                count,
                values: None,
            }),
        }
    }
    firsts.sort_by_key(|p| p.kind);
    firsts
}

/// Whether `device`'s identification says what `profile` states (each stated object,
/// ignoring case and surrounding blanks).
fn identified(profile: &Profile, device: &Found) -> Option<bool> {
    if profile.identification.is_empty() {
        return None;
    }
    let Some(id) = &device.identification else {
        return Some(false);
    };
    Some(profile.identification.iter().all(|(key, want)| {
        id.get(key)
            .is_some_and(|have| have.trim().eq_ignore_ascii_case(want.trim()))
    }))
}

/// Finds `device`'s profiles among `profiles`, reading each probe once.
pub(super) async fn suggest(
    prober: &mut dyn Prober,
    device: &mut Found,
    profiles: &[Arc<Profile>],
) -> Result<(), ScanError> {
    let mut answers: HashMap<(RegisterKind, u16, u16), ReadAnswer> = HashMap::new();
    let mut suggestions = Vec::new();
    'profiles: for profile in profiles {
        if profile.protocol == Protocol::Simulated {
            continue;
        }
        let identified = identified(profile, device);
        if identified == Some(false) {
            continue;
        }
        let reads = probes(profile);
        for p in &reads {
            let key = (p.kind, p.address, p.count);
            if let std::collections::hash_map::Entry::Vacant(slot) = answers.entry(key) {
                let (answer, two) =
                    read(prober, device.slave_id, p.kind, p.address, p.count).await?;
                if device.collision.is_none() {
                    device.collision = two;
                }
                slot.insert(answer);
            }
            let answered = answers
                .get(&key)
                .is_some_and(|a| a.answered() && p.values.as_ref().is_none_or(|v| *v == a.values));
            if !answered {
                continue 'profiles;
            }
        }
        // Evidence that tells this profile from others: an identification, values the
        // profile states, or its map answered by a device that refuses a register no map
        // has (one that answers every address tells nothing by answering these).
        let valued = reads.iter().any(|r| r.values.is_some());
        let mut mapped = true;
        for kind in reads.iter().map(|r| r.kind) {
            let key = (kind, CONTROL, 1);
            if let std::collections::hash_map::Entry::Vacant(slot) = answers.entry(key) {
                slot.insert(read(prober, device.slave_id, kind, CONTROL, 1).await?.0);
            }
            mapped &= answers.get(&key).is_some_and(|a| !a.answered());
        }
        let telling = identified == Some(true) || valued || mapped;
        // The strongest evidence first: an identification, then probes the profile states
        // (over the default ones), then how many registers answered as it expects.
        let registers: u32 = reads.iter().map(|r| u32::from(r.count)).sum();
        let rank = (
            telling,
            identified == Some(true),
            !profile.probe.is_empty(),
            reads.len(),
            registers,
        );
        suggestions.push((
            rank,
            Suggestion {
                profile: profile.name.clone(),
                identified: identified == Some(true),
                probes: reads.len(),
                telling,
            },
        ));
    }
    suggestions.sort_by(|(a, x), (b, y)| b.cmp(a).then_with(|| x.profile.cmp(&y.profile)));
    let suggestions: Vec<Suggestion> = suggestions.into_iter().map(|(_, s)| s).collect();
    let mut probed: Vec<ReadAnswer> = answers
        .into_values()
        .filter(|a| !device.reads.contains(a))
        .collect();
    probed.sort_by_key(|a| (a.function, a.address, a.count));
    device.reads.extend(probed);
    device.profiles = suggestions;
    Ok(())
}

/// A `devices:` entry for `iogate.yaml`: named after the profile (in snake case) and the id.
pub fn device_entry(profile: &str, link: &str, slave: u8) -> String {
    named_entry(&entry_name(profile, slave), profile, link, slave)
}

/// The name [`device_entry`] gives.
pub(super) fn entry_name(profile: &str, slave: u8) -> String {
    format!("{}_{slave}", snake(profile))
}

/// A `devices:` entry named `name`.
pub(super) fn named_entry(name: &str, profile: &str, link: &str, slave: u8) -> String {
    format!("- {{ name: {name}, profile: {profile}, link: {link}, slave_id: {slave} }}")
}

/// `WaveshareAnalogInput` → `waveshare_analog_input`.
fn snake(name: &str) -> String {
    let mut out = String::new();
    let mut prev_lower = false;
    for c in name.chars() {
        if c.is_ascii_uppercase() && prev_lower {
            out.push('_');
        }
        prev_lower = c.is_ascii_lowercase() || c.is_ascii_digit();
        out.push(c.to_ascii_lowercase());
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn entries_are_named_in_snake_case() {
        assert_eq!(snake("WaveshareAnalogInput"), "waveshare_analog_input");
        assert_eq!(snake("SDM630"), "sdm630");
        assert_eq!(
            device_entry("EastronSDM630", "line", 2),
            "- { name: eastron_sdm630_2, profile: EastronSDM630, link: line, slave_id: 2 }"
        );
    }

    #[test]
    fn default_probes_read_the_first_field_of_each_kind() {
        let profile = crate::profile::load_str(
            "p.yaml",
            "name: P\nfields:\n  - { name: B, type: REAL, direction: input, register: { address: 10, kind: input_register, word_count: 2 } }\n  - { name: A, type: INT, direction: input, register: { address: 4, kind: input_register } }\n  - { name: C, type: BOOL, direction: output, register: { address: 3, kind: coil } }\n",
        )
        .expect("loads");
        let reads = probes(&profile);
        assert_eq!(reads.len(), 2);
        assert_eq!(
            (reads[0].kind, reads[0].address, reads[0].count),
            (RegisterKind::Coil, 3, 1)
        );
        assert_eq!(
            (reads[1].kind, reads[1].address, reads[1].count),
            (RegisterKind::InputRegister, 4, 1)
        );
    }
}

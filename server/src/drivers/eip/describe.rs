//! What `iogate plan` prints of an EtherNet/IP link's devices: each device's packets per
//! cycle on a connection of Large Forward Open's size, each with its tags, and what the
//! controller was found not to support (it changes how it is read).

use std::fmt::Write as _;

use crate::config::{DeviceConfig, LinkConfig};
use crate::drivers::{Facts, Planned};
use crate::profile::Profile;

/// The link's devices, and the controller's missing services where the peer told them.
pub(super) fn link(_link: &LinkConfig, devices: &Planned<'_>, peer: &Facts, out: &mut String) {
    for (d, profile) in devices {
        device(out, d, profile);
    }
    if let Some((_, v)) = peer.iter().find(|(k, _)| *k == super::NO_MULTIPLE.0) {
        let _ = writeln!(out, "multiple service packets: {v}");
    }
}

/// An EtherNet/IP device's packets per cycle on a connection of Large Forward Open's size
/// (a controller that takes only a smaller one gets more packets): each with its tags.
fn device(out: &mut String, d: &DeviceConfig, profile: &Profile) {
    let plan = super::plan::planned(profile);
    let _ = writeln!(
        out,
        "  device {} (profile {}, ab-eip, every {} ms): {} packet(s) per cycle on a connection of {} bytes",
        d.name,
        profile.name,
        d.refresh_rate.as_millis(),
        plan.packets.len(),
        super::plan::LARGE,
    );
    let name = |i: usize| {
        let f = &profile.fields[i];
        let at = f.point.as_ref().map_or("", |p| p.address.as_str());
        format!("{} ({at})", f.name)
    };
    for (n, reads) in plan.packets.iter().enumerate() {
        let mut names = Vec::new();
        for &r in reads {
            match plan.runs[r].as_slice() {
                [one] => names.push(name(*one)),
                [first, .., last] => names.push(format!(
                    "{} to {}, {} elements in one read",
                    name(*first),
                    name(*last),
                    plan.runs[r].len()
                )),
                [] => {}
            }
        }
        let how = match reads.as_slice() {
            [r] if super::plan::fragmented(plan.answers[*r], super::plan::CONNECTED_MESSAGE) => {
                format!(
                    ", read fragmented ({} bytes in {} requests at least)",
                    plan.answers[*r],
                    plan.answers[*r].div_ceil(super::plan::CONNECTED_MESSAGE - 10)
                )
            }
            _ => String::new(),
        };
        let fields: usize = reads.iter().map(|&r| plan.runs[r].len()).sum();
        let _ = writeln!(
            out,
            "    packet {}: {fields} tag(s){how}: {}",
            n + 1,
            names.join(", ")
        );
    }
    for (f, t) in profile.fields.iter().zip(&plan.tags) {
        if let Err(why) = t {
            let _ = writeln!(out, "    {} not read: {why}", f.name);
        }
    }
}

//! What `iogate plan` prints of an S7 link's devices: each device's jobs per cycle for the
//! PDU size the PLC granted (a running link's) or the one its settings ask, each item's
//! area and bytes with the fields it carries.

use std::fmt::Write as _;

use crate::config::{DeviceConfig, LinkConfig, Transport};
use crate::drivers::{Facts, Planned};
use crate::profile::Profile;

/// The link's devices, planned for the PDU granted where the peer told it.
pub(super) fn link(link: &LinkConfig, devices: &Planned<'_>, peer: &Facts, out: &mut String) {
    let Transport::Driver(s) = &link.transport else {
        return;
    };
    let granted = peer
        .iter()
        .find(|(k, _)| *k == super::PDU_SIZE)
        .and_then(|(_, v)| v.parse().ok());
    let pdu = granted.map_or_else(
        || (super::plan::asked_pdu(&s.settings), "asked"),
        |g| (g, "granted"),
    );
    for (d, profile) in devices {
        device(out, d, profile, pdu, super::plan::asked_gap(&s.settings));
    }
}

/// An S7 device's jobs per cycle for a PDU size (and whether the PLC granted it or it is
/// the size asked): each item's area and bytes with the fields it carries.
fn device(
    out: &mut String,
    d: &DeviceConfig,
    profile: &Profile,
    (pdu, how): (u16, &str),
    gap: u32,
) {
    let places = super::plan::places(profile);
    let plan = super::plan::read_plan(&places, pdu, &Default::default(), gap);
    let _ = writeln!(
        out,
        "  device {} (profile {}, s7, every {} ms): {} job(s) per cycle for a PDU of {pdu} bytes ({how})",
        d.name,
        profile.name,
        d.refresh_rate.as_millis(),
        plan.jobs.len(),
    );
    // Each item's fields, and which piece of its span it is where the span has several.
    let mut carried = std::collections::BTreeMap::new();
    for span in &plan.spans {
        let names: Vec<&str> = span
            .fields
            .iter()
            .map(|(i, _)| profile.fields[*i].name.as_str())
            .collect();
        let n = span.pieces.len();
        for (k, piece) in span.pieces.iter().enumerate() {
            let part = if n > 1 {
                format!(" (part {} of {n})", k + 1)
            } else {
                String::new()
            };
            carried.insert(*piece, format!("{}{part}", names.join(", ")));
        }
    }
    for (n, items) in plan.jobs.iter().enumerate() {
        let _ = writeln!(out, "    job {}: {} item(s)", n + 1, items.len());
        for (k, item) in items.iter().enumerate() {
            let fields = carried.get(&(n, k)).map_or("", String::as_str);
            let _ = writeln!(out, "      {}: {fields}", super::plan::describe(item));
        }
    }
    for (f, p) in profile.fields.iter().zip(&places) {
        if let Err(why) = p {
            let _ = writeln!(out, "    {} not read: {why}", f.name);
        }
    }
}

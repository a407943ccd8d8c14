//! `iogate plan`: the poll plan of every link as text, and the warnings `check` and `serve`
//! print when refresh rates need more than a line carries.

use std::fmt::Write as _;
use std::time::Duration;

use super::{ReadBatch, cycle_time, read_batches, transaction_time, utilisation};
use crate::config::{Config, DeviceConfig, LinkConfig, Transport};
use crate::link::timing::LineTiming;
use crate::profile::{Catalog, Profile};

/// A link's devices whose profiles are known, each with its read batches.
type Planned<'a> = Vec<(&'a DeviceConfig, &'a Profile, Vec<ReadBatch>)>;

fn devices_of<'a>(config: &'a Config, catalog: &'a Catalog, link: &LinkConfig) -> Planned<'a> {
    config
        .devices
        .iter()
        .filter(|d| d.link.as_deref() == Some(link.name.as_str()))
        .filter_map(|d| {
            let p = catalog.get(&d.profile)?;
            Some((d, p.as_ref(), read_batches(p, d.max_batch, d.max_gap)))
        })
        .collect()
}

/// The share of a serial link's time its devices' refresh rates demand; `None` over TCP.
fn link_utilisation(link: &LinkConfig, devices: &Planned<'_>) -> Option<f64> {
    let Transport::Serial(s) = &link.transport else {
        return None;
    };
    Some(utilisation(
        devices.iter().map(|(d, _, b)| (*d, b.as_slice())),
        &LineTiming::new(s),
        link.guard_time,
    ))
}

/// Links whose devices' refresh rates need more than the line carries, as warnings.
pub fn warnings(config: &Config, catalog: &Catalog) -> Vec<String> {
    config
        .links
        .iter()
        .filter_map(|link| {
            let u = link_utilisation(link, &devices_of(config, catalog, link))?;
            (u > 1.0).then(|| {
                format!(
                    "link {}: the refresh rates need {:.0}% of what the line carries; devices will be polled less often than configured (see `iogate plan`)",
                    link.name,
                    u * 100.0
                )
            })
        })
        .collect()
}

/// The poll plan of every link, as `iogate plan` prints it.
pub fn render(config: &Config, catalog: &Catalog) -> String {
    let mut out = String::new();
    if config.links.is_empty() {
        out.push_str("No links configured: nothing is polled on a bus.\n");
    }
    for link in &config.links {
        render_link(&mut out, link, &devices_of(config, catalog, link), None);
    }
    out
}

/// The poll plan of one link and its devices (each with its profile), as `iogate plan`
/// prints it: for a running gateway's links, with the devices declared since it started.
///
/// `granted` is the PDU size an S7 PLC granted, where it did (else the size asked).
pub fn link_plan<'a>(
    link: &LinkConfig,
    devices: impl IntoIterator<Item = (&'a DeviceConfig, &'a Profile)>,
    granted: Option<u16>,
) -> String {
    let planned: Planned<'a> = devices
        .into_iter()
        .map(|(d, p)| (d, p, read_batches(p, d.max_batch, d.max_gap)))
        .collect();
    let mut out = String::new();
    render_link(&mut out, link, &planned, granted);
    out
}

fn render_link(out: &mut String, link: &LinkConfig, devices: &Planned<'_>, granted: Option<u16>) {
    let timing = render_line(out, link);
    for (d, profile, batches) in devices {
        if profile.protocol.name() == "s7"
            && let Transport::Driver(s) = &link.transport
        {
            let pdu = granted.map_or_else(
                || (super::s7::asked_pdu(&s.settings), "asked"),
                |g| (g, "granted"),
            );
            render_s7(out, d, profile, pdu, super::s7::asked_gap(&s.settings));
            continue;
        }
        if profile.protocol.name() == "ab-eip" {
            render_eip(out, d, profile);
            continue;
        }
        if profile.protocol.point_key().is_some() {
            render_points(out, d, profile);
            continue;
        }
        render_device(out, link, timing.as_ref(), d, profile, batches);
    }
    if let Some(u) = link_utilisation(link, devices) {
        let _ = writeln!(out, "  bus utilisation: {:.1}% of the line", u * 100.0);
        if u > 1.0 {
            let _ = writeln!(
                out,
                "  WARNING: the refresh rates need {:.0}% of what the line can carry; devices will be polled less often than configured",
                u * 100.0
            );
        }
    }
}

/// The link's line: its settings, and for a serial line its timing (returned).
fn render_line(out: &mut String, link: &LinkConfig) -> Option<LineTiming> {
    match &link.transport {
        Transport::Serial(s) => {
            let t = LineTiming::new(s);
            let _ = writeln!(
                out,
                "link {}: serial {} {} {}{}{} ({} bits per character, {:.3} ms per character, {:.3} ms inter-frame silence{})",
                link.name,
                s.port,
                s.baud,
                s.data_bits,
                s.parity.letter(),
                s.stop_bits,
                t.bits_per_char,
                ms(t.char_time()),
                ms(t.silence()),
                if link.guard_time.is_zero() {
                    String::new()
                } else {
                    format!(" + {:.3} ms guard time", ms(link.guard_time))
                }
            );
            Some(t)
        }
        Transport::Tcp {
            host,
            port,
            framing,
        } => {
            let _ = writeln!(
                out,
                "link {}: tcp {host}:{port} ({}); no wire-time budget",
                link.name,
                framing.name()
            );
            None
        }
        Transport::Driver(d) => {
            let _ = writeln!(
                out,
                "link {}: {} {}; no wire-time budget",
                link.name, d.protocol, d.endpoint
            );
            None
        }
    }
}

/// An S7 device's jobs per cycle for a PDU size (and whether the PLC granted it or it is
/// the size asked): each item's area and bytes with the fields it carries.
fn render_s7(
    out: &mut String,
    d: &DeviceConfig,
    profile: &Profile,
    (pdu, how): (u16, &str),
    gap: u32,
) {
    let places = super::s7::places(profile);
    let plan = super::s7::read_plan(&places, pdu, &Default::default(), gap);
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
            let _ = writeln!(out, "      {}: {fields}", super::s7::describe(item));
        }
    }
    for (f, p) in profile.fields.iter().zip(&places) {
        if let Err(why) = p {
            let _ = writeln!(out, "    {} not read: {why}", f.name);
        }
    }
}

/// An EtherNet/IP device's packets per cycle on a connection of Large Forward Open's size
/// (a controller that takes only a smaller one gets more packets): each with its tags.
fn render_eip(out: &mut String, d: &DeviceConfig, profile: &Profile) {
    let plan = super::eip::planned(profile);
    let _ = writeln!(
        out,
        "  device {} (profile {}, ab-eip, every {} ms): {} packet(s) per cycle on a connection of {} bytes",
        d.name,
        profile.name,
        d.refresh_rate.as_millis(),
        plan.packets.len(),
        super::eip::LARGE,
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
            [r] if super::eip::fragmented(plan.answers[*r], super::eip::CONNECTED_MESSAGE) => {
                format!(
                    ", read fragmented ({} bytes in {} requests at least)",
                    plan.answers[*r],
                    plan.answers[*r].div_ceil(super::eip::CONNECTED_MESSAGE - 10)
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

/// A device of a protocol that names its points: one subscription, a monitored item per
/// field (the server samples each; the gateway asks nothing per cycle).
fn render_points(out: &mut String, d: &DeviceConfig, profile: &Profile) {
    let count = profile.fields.iter().filter(|f| f.point.is_some()).count();
    let how = format!(
        "a subscription publishing every {} ms, {count} monitored item(s); read every refresh where the server has no subscriptions",
        d.refresh_rate.as_millis()
    );
    let _ = writeln!(
        out,
        "  device {} (profile {}, {}): {how}",
        d.name,
        profile.name,
        profile.protocol.name(),
    );
    for f in &profile.fields {
        if let Some(p) = &f.point {
            let sampling = p.sampling.unwrap_or(d.refresh_rate).as_millis();
            let _ = writeln!(
                out,
                "    {} {} ({}, sampled every {sampling} ms)",
                f.name, p.address, f.ty
            );
        }
    }
}

/// A device's transactions per cycle, each with its wire time on a serial line.
fn render_device(
    out: &mut String,
    link: &LinkConfig,
    timing: Option<&LineTiming>,
    d: &DeviceConfig,
    profile: &Profile,
    batches: &[ReadBatch],
) {
    let _ = writeln!(
        out,
        "  device {} (profile {}, slave {}, every {} ms): {} transaction(s) per cycle",
        d.name,
        profile.name,
        d.slave_id.unwrap_or(0),
        d.refresh_rate.as_millis(),
        batches.len()
    );
    for b in batches {
        let request = b.request();
        let names: Vec<&str> = b
            .fields
            .iter()
            .map(|&i| profile.fields[i].name.as_str())
            .collect();
        let wire = timing
            .map(|t| {
                let time = transaction_time(&request, t, link.guard_time);
                format!(" {:>8.3} ms", ms(time))
            })
            .unwrap_or_default();
        let _ = writeln!(
            out,
            "    {} slave {:>3} address {:>5} count {:>4}{wire}  {}",
            request.function(),
            d.slave_id.unwrap_or(0),
            b.address,
            b.count,
            names.join(", ")
        );
    }
    if let Some(t) = timing {
        let _ = writeln!(
            out,
            "    cycle: {:.3} ms of bus time",
            ms(cycle_time(batches, t, link.guard_time))
        );
    }
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1000.0
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::test_profile as profile;

    #[test]
    fn plan_warns_when_the_line_cannot_carry_the_rates() {
        let config = crate::config::parse(
            "c.yaml",
            "links:\n  - { name: slow, serial: { port: /dev/ttyS0, baud: 9600 } }\ndevices:\n  - { name: m, profile: P, link: slow, slave_id: 1, refresh_rate: 20ms }\n",
        )
        .expect("config");
        let p = profile(
            "  - { name: A, type: INT, direction: input, register: { address: 0, kind: input_register } }\n  - { name: B, type: INT, direction: input, register: { address: 10, kind: input_register } }\n",
        );
        let catalog = Catalog::new([p]);
        let text = render(&config, &catalog);
        assert!(
            text.contains("FC04 slave   1 address     0 count    1"),
            "{text}"
        );
        assert!(text.contains("WARNING"), "{text}");
        let warnings = warnings(&config, &catalog);
        assert_eq!(warnings.len(), 1);
        assert!(
            warnings[0].starts_with("link slow: the refresh rates need"),
            "{warnings:?}"
        );
    }
}

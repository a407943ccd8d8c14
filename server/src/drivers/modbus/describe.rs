//! What `iogate plan` prints of a Modbus link's devices: each device's read transactions
//! with their wire time on a serial line, its cycle, and the share of the line the refresh
//! rates need (with the warning `check` and `serve` print when it is more than the line
//! carries).

use std::fmt::Write as _;
use std::time::Duration;

use super::{ReadBatch, cycle_time, read_batches, transaction_time, utilisation};
use crate::config::{DeviceConfig, LinkConfig, Transport};
use crate::drivers::Planned;
use crate::link::timing::LineTiming;
use crate::profile::Profile;

/// Each device with its read batches.
fn batched<'a>(devices: &Planned<'a>) -> Vec<(&'a DeviceConfig, &'a Profile, Vec<ReadBatch>)> {
    devices
        .iter()
        .map(|&(d, p)| (d, p, read_batches(p, d.max_batch, d.max_gap)))
        .collect()
}

/// The share of a serial link's time its devices' refresh rates demand; `None` over TCP.
fn link_utilisation(
    link: &LinkConfig,
    devices: &[(&DeviceConfig, &Profile, Vec<ReadBatch>)],
) -> Option<f64> {
    let Transport::Serial(s) = &link.transport else {
        return None;
    };
    Some(utilisation(
        devices.iter().map(|(d, _, b)| (*d, b.as_slice())),
        &LineTiming::new(s),
        link.guard_time,
    ))
}

/// The link's devices and the bus utilisation.
pub(super) fn link(link: &LinkConfig, devices: &Planned<'_>, out: &mut String) {
    let timing = match &link.transport {
        Transport::Serial(s) => Some(LineTiming::new(s)),
        _ => None,
    };
    let devices = batched(devices);
    for (d, profile, batches) in &devices {
        device(out, link, timing.as_ref(), d, profile, batches);
    }
    if let Some(u) = link_utilisation(link, &devices) {
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

/// A link whose devices' refresh rates need more than the line carries, as a warning.
pub(super) fn warnings(link: &LinkConfig, devices: &Planned<'_>) -> Vec<String> {
    let Some(u) = link_utilisation(link, &batched(devices)) else {
        return Vec::new();
    };
    if u <= 1.0 {
        return Vec::new();
    }
    vec![format!(
        "link {}: the refresh rates need {:.0}% of what the line carries; devices will be polled less often than configured (see `iogate plan`)",
        link.name,
        u * 100.0
    )]
}

/// A device's transactions per cycle, each with its wire time on a serial line.
fn device(
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
    use crate::profile::{Catalog, test_profile as profile};

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
        let text = crate::plan::render(&config, &catalog);
        assert!(
            text.contains("FC04 slave   1 address     0 count    1"),
            "{text}"
        );
        assert!(text.contains("WARNING"), "{text}");
        let warnings = crate::plan::warnings(&config, &catalog);
        assert_eq!(warnings.len(), 1);
        assert!(
            warnings[0].starts_with("link slow: the refresh rates need"),
            "{warnings:?}"
        );
    }
}

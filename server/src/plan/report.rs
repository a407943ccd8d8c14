//! `iogate plan`: the poll plan of every link as text (each link's line, then what its
//! driver says of its devices), and the warnings `check` and `serve` print when refresh
//! rates need more than a line carries.

use std::fmt::Write as _;
use std::time::Duration;

use crate::config::{Config, DeviceConfig, LinkConfig, Transport};
use crate::drivers::Facts;
use crate::link::timing::LineTiming;
use crate::profile::{Catalog, Profile};

fn devices_of<'a>(
    config: &'a Config,
    catalog: &'a Catalog,
    link: &LinkConfig,
) -> Vec<(&'a DeviceConfig, &'a Profile)> {
    config
        .devices
        .iter()
        .filter(|d| d.link.as_deref() == Some(link.name.as_str()))
        .filter_map(|d| Some((d, catalog.get(&d.profile)?.as_ref())))
        .collect()
}

/// Links whose devices' refresh rates need more than the line carries, as warnings.
pub fn warnings(config: &Config, catalog: &Catalog) -> Vec<String> {
    config
        .links
        .iter()
        .flat_map(|link| {
            let devices = devices_of(config, catalog, link);
            crate::drivers::describe(link, &devices, &[], &mut String::new())
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
        render_link(&mut out, link, &devices_of(config, catalog, link), &[]);
    }
    out
}

/// The poll plan of one link and its devices (each with its profile), as `iogate plan`
/// prints it: for a running gateway's links, with the devices declared since it started
/// and what the link's peer told of itself (`peer`: the PDU an S7 PLC granted).
pub fn link_plan<'a>(
    link: &LinkConfig,
    devices: impl IntoIterator<Item = (&'a DeviceConfig, &'a Profile)>,
    peer: &Facts,
) -> String {
    let devices: Vec<_> = devices.into_iter().collect();
    let mut out = String::new();
    render_link(&mut out, link, &devices, peer);
    out
}

fn render_link(
    out: &mut String,
    link: &LinkConfig,
    devices: &[(&DeviceConfig, &Profile)],
    peer: &Facts,
) {
    render_line(out, link);
    crate::drivers::describe(link, devices, peer, out);
}

/// The link's line: its settings, and for a serial line its timing.
fn render_line(out: &mut String, link: &LinkConfig) {
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
        }
        Transport::Driver(d) => {
            let _ = writeln!(
                out,
                "link {}: {} {}; no wire-time budget",
                link.name, d.protocol, d.endpoint
            );
        }
    }
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1000.0
}

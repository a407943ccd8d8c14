//! `iogate scan --from bacnet [--on HOST[:PORT]] [--broadcast ADDR] [--bbmd HOST[:PORT]]`:
//! a global Who-Is from a port of the scan's own, and every I-Am heard within `--wait`
//! (3 s unless it says), each device with where it is (an address, or a network number and
//! MAC behind a router), its vendor, its APDU size and segmentation, as text with the
//! configuration entries to copy, or as JSON.

use std::fmt::Write as _;
use std::time::Duration;

use bacnet_client::client::DeviceEvent;
use bacnet_client::discovery::DiscoveredDevice;
use tokio::sync::broadcast::error::RecvError;

use super::config::{Settings, address};
use crate::drivers::{ImportOptions, option};

/// The most devices one scan lists.
const MAX_DEVICES: usize = 10_000;

/// The scan's settings from its options.
pub(super) fn settings(options: &ImportOptions<'_>) -> Result<(Settings, Duration), String> {
    let on = address(option(options, "--on").unwrap_or("0.0.0.0:47808"))
        .map_err(|e| format!("--on: {e}"))?;
    let broadcast = match option(options, "--broadcast") {
        None => std::net::Ipv4Addr::BROADCAST,
        Some(b) => b
            .parse()
            .map_err(|_| format!("--broadcast: `{b}` is not an IPv4 address"))?,
    };
    let bbmd = option(options, "--bbmd")
        .map(|b| address(b).map_err(|e| format!("--bbmd: {e}")))
        .transpose()?;
    let wait = option(options, "--wait")
        .map(|w| crate::duration::parse(w).map_err(|e| format!("--wait: {e}")))
        .transpose()?
        .unwrap_or(Duration::from_secs(3));
    let settings = Settings {
        bind: on,
        broadcast,
        bbmd: bbmd.map(|b| (b, Duration::from_secs(60))),
        timeout: Duration::from_secs(3),
        retries: 1,
    };
    Ok((settings, wait.min(Duration::from_secs(600))))
}

/// Where a device is, as a configuration entry says it (`None` behind a router: found by
/// Who-Is), and as a person reads it.
fn place(d: &DiscoveredDevice) -> (Option<String>, String) {
    let mac = &d.mac_address;
    let ip = (mac.len() == 6).then(|| {
        let port = u16::from_be_bytes([mac[4], mac[5]]);
        format!("{}.{}.{}.{}:{port}", mac[0], mac[1], mac[2], mac[3])
    });
    match (d.source_network, &d.source_address) {
        (Some(net), Some(sadr)) => {
            let hex: Vec<String> = sadr.iter().map(|b| format!("{b:02x}")).collect();
            let through = ip.unwrap_or_else(|| "a router".into());
            (
                None,
                format!("on network {net}, MAC {}, through {through}", hex.join(":")),
            )
        }
        _ => {
            let at = ip.unwrap_or_else(|| "an unknown address".into());
            (Some(at.clone()), format!("at {at}"))
        }
    }
}

/// The devices as text: one line each, then their configuration entries.
fn text(devices: &[DiscoveredDevice]) -> String {
    let mut out = String::new();
    for d in devices {
        let (_, at) = place(d);
        let _ = writeln!(
            out,
            "device {} {at}: vendor {}, max APDU {}, segmentation {}",
            d.object_identifier.instance_number(),
            d.vendor_id,
            d.max_apdu_length,
            d.segmentation_supported,
        );
    }
    let _ = writeln!(out, "# configuration entries (choose each a profile):");
    for d in devices {
        let instance = d.object_identifier.instance_number();
        let address = place(d)
            .0
            .map(|a| format!(", address: \"{a}\""))
            .unwrap_or_default();
        let _ = writeln!(
            out,
            "  - {{ name: device_{instance}, profile: CHOOSE, link: bacnet, device_instance: {instance}{address} }}"
        );
    }
    out
}

fn json(devices: &[DiscoveredDevice]) -> String {
    let list: Vec<serde_json::Value> = devices
        .iter()
        .map(|d| {
            let (address, _) = place(d);
            serde_json::json!({
                "device_instance": d.object_identifier.instance_number(),
                "address": address,
                "network": d.source_network,
                "mac": d.source_address.as_ref().map(|m| m.iter().map(|b| format!("{b:02x}")).collect::<Vec<_>>().join(":")),
                "vendor": d.vendor_id,
                "max_apdu": d.max_apdu_length,
                "segmentation": d.segmentation_supported.to_string(),
            })
        })
        .collect();
    serde_json::json!({ "devices": list }).to_string()
}

/// Every device that answers a global Who-Is within `wait`, by instance.
async fn listen(s: &Settings, wait: Duration) -> Result<Vec<DiscoveredDevice>, String> {
    let mut client = super::client::start(s).await.map_err(|e| e.to_string())?;
    let mut events = client.device_events();
    let asked = client
        .who_is(None)
        .await
        .map_err(|e| format!("sending the Who-Is: {e}"));
    let mut found: Vec<DiscoveredDevice> = Vec::new();
    if asked.is_ok() {
        let collect = async {
            loop {
                match events.recv().await {
                    // An I-Am names a device object; one that names another is not a device.
                    Ok(DeviceEvent { device, .. })
                        if found.len() < MAX_DEVICES
                            && device.object_identifier.object_type()
                                == bacnet_types::enums::ObjectType::DEVICE =>
                    {
                        let id = device.object_identifier;
                        found.retain(|d| d.object_identifier != id);
                        found.push(device);
                    }
                    Ok(_) | Err(RecvError::Lagged(_)) => {}
                    Err(RecvError::Closed) => return,
                }
            }
        };
        let _ = tokio::time::timeout(wait, collect).await;
    }
    let _ = client.stop().await;
    asked?;
    found.sort_by_key(|d| d.object_identifier.instance_number());
    Ok(found)
}

/// The devices that answer, as JSON (`{"devices": [...]}`), or why the scan could not run.
pub fn find(options: &ImportOptions<'_>) -> Result<String, String> {
    let (settings, wait) = settings(options)?;
    crate::profile::import::emit::on_runtime_with(listen(&settings, wait)).map(|f| json(&f))
}

/// Runs the scan; the exit code: 0 devices found, 1 none (or the port could not open), 64
/// a bad option.
pub(super) fn run(options: &ImportOptions<'_>, as_json: bool) -> u8 {
    let (settings, wait) = match settings(options) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("iogate scan --from bacnet: {e}");
            return crate::EXIT_CONFIG as u8;
        }
    };
    eprintln!(
        "scanning BACnet/IP from {}: a Who-Is to {}{}, answers for {} ms",
        settings.bind,
        settings.broadcast,
        settings
            .bbmd
            .map(|(b, _)| format!(" and through the BBMD {b}"))
            .unwrap_or_default(),
        wait.as_millis()
    );
    crate::profile::import::emit::on_runtime(async {
        match listen(&settings, wait).await {
            Ok(found) => {
                if as_json {
                    println!("{}", json(&found));
                } else {
                    print!("{}", text(&found));
                }
                eprintln!("{} device(s) answered", found.len());
                u8::from(found.is_empty())
            }
            Err(e) => {
                eprintln!("iogate scan --from bacnet: {e}");
                1
            }
        }
    })
}

//! The matrix NG Gateway and NeuronEX publish, row by row: Modbus TCP devices of 1,000
//! holding registers (UINT; ten of them `inout`), 10 devices a channel (one connection to
//! its own server), read every second (10,000, 50,000, 100,000 fields) or every 100 ms
//! (1,000, 5,000, 10,000), and under the 100,000-field load 100 writes through the REST API
//! timed from the request to the device's log. The devices run in a process of their own
//! (this bench started again, `parts/matrix_device.rs`); only the gateway's process is
//! measured: resident memory (the largest seen in the window), CPU (share of one core over
//! 20 s after 5 s of warm-up), Modbus bytes on the wire (counted by the devices), and the
//! share of the planned polls that were answered.
//!
//! Two rows more, the many-connections load EMQ measured Neuron 2.2.1 on: 500 devices of 30
//! registers, each on a connection of its own, every second and every 500 ms, with the
//! writes under each.
//!
//! `cargo bench -p iogate --bench matrix` (`IOGATE_BENCH_ONLY=10k,100k`: the rows named)

use std::io::BufRead;
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

mod common;
#[path = "parts/matrix_device.rs"]
mod matrix_device;
#[path = "parts/matrix_rows.rs"]
mod matrix_rows;

use matrix_rows::{Case, Measured, Writes};

/// Writes as the devices logged them: unit, address, value, Unix time in ns.
type Log = Arc<Mutex<Vec<(u8, u16, u16, u128)>>>;

/// The devices' process: its ports, and what it has told since.
struct Devices {
    child: Child,
    ports: Vec<u16>,
    /// Requests answered and Modbus bytes, as last told.
    stat: Arc<Mutex<(u64, u64)>>,
    log: Log,
}

impl Drop for Devices {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn start_devices(channels: usize) -> anyhow::Result<Devices> {
    let mut child = Command::new(std::env::current_exe()?)
        .env("IOGATE_MATRIX_CHANNELS", channels.to_string())
        .stdout(Stdio::piped())
        .spawn()?;
    let out = child
        .stdout
        .take()
        .ok_or_else(|| anyhow::anyhow!("no stdout"))?;
    let mut lines = std::io::BufReader::new(out).lines();
    let mut ports = Vec::new();
    loop {
        let line = lines
            .next()
            .ok_or_else(|| anyhow::anyhow!("the devices ended"))??;
        match line.split_once(' ') {
            Some(("PORT", p)) => ports.push(p.parse()?),
            _ if line == "READY" => break,
            _ => {}
        }
    }
    let (stat, log) = (Arc::<Mutex<(u64, u64)>>::default(), Log::default());
    let (s, l) = (stat.clone(), log.clone());
    std::thread::spawn(move || {
        for line in lines.map_while(Result::ok) {
            let words: Vec<&str> = line.split(' ').collect();
            match words.as_slice() {
                ["STAT", r, b] => {
                    if let (Ok(r), Ok(b), Ok(mut s)) = (r.parse(), b.parse(), s.lock()) {
                        *s = (r, b);
                    }
                }
                ["W", u, a, v, ns] => {
                    if let (Ok(u), Ok(a), Ok(v), Ok(ns), Ok(mut l)) =
                        (u.parse(), a.parse(), v.parse(), ns.parse(), l.lock())
                    {
                        l.push((u, a, v, ns));
                    }
                }
                _ => {}
            }
        }
    });
    Ok(Devices {
        child,
        ports,
        stat,
        log,
    })
}

/// The profile (the case's UINT holding registers, the first ten `inout`) and the config.
fn config(dir: &std::path::Path, case: &Case, ports: &[u16]) -> anyhow::Result<String> {
    let profiles = dir.join("profiles");
    std::fs::create_dir_all(&profiles)?;
    let mut profile = String::from("name: Matrix\nprotocol: modbus-tcp\nfields:\n");
    for i in 0..case.fields_a_device.min(matrix_device::REGISTERS) {
        let direction = if i < 10 { "inout" } else { "input" };
        profile.push_str(&format!(
            "  - {{ name: R{i}, type: UINT, direction: {direction}, register: {{ address: {i}, kind: holding_register }} }}\n"
        ));
    }
    std::fs::write(profiles.join("matrix.yaml"), profile)?;
    let mut config = format!(
        "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0 }}\nprofiles: {}\nlinks:\n",
        profiles.display()
    );
    for (c, port) in ports.iter().enumerate() {
        config.push_str(&format!(
            "  - {{ name: c{c}, tcp: {{ host: 127.0.0.1, port: {port} }} }}\n"
        ));
    }
    config.push_str("devices:\n");
    for c in 0..ports.len() {
        for u in 1..=case.devices_a_channel {
            config.push_str(&format!(
                "  - {{ name: c{c}u{u}, profile: Matrix, link: c{c}, slave_id: {u}, refresh_rate: {} }}\n",
                case.rate
            ));
        }
    }
    Ok(config)
}

fn stat(devices: &Devices) -> (u64, u64) {
    devices.stat.lock().map(|s| *s).unwrap_or_default()
}

fn unix_ns() -> u128 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos())
}

/// 100 writes, one every 50 ms to a device and `inout` register of the load chosen in
/// turn, each timed from the moment its PUT was sent to the device's log of it.
async fn writes(
    http: std::net::SocketAddr,
    devices: &Devices,
    case: &Case,
) -> anyhow::Result<Writes> {
    let mut api = common::http::Kept::connect(http).await?;
    let mut took = Vec::new();
    for i in 0..100u32 {
        let channel = (i as usize * 7) % devices.ports.len();
        let unit = 1 + (i as usize * 3) % case.devices_a_channel;
        let register = (i * 13) % 10;
        // A value no device holds on its own: above the numbers it makes.
        let value = 60_000 + i as u16;
        let sent = unix_ns();
        api.send(
            "PUT",
            &format!("/api/v1/devices/c{channel}u{unit}/fields/R{register}"),
            &format!("{{\"value\": {value}}}"),
        )
        .await?;
        let until = Instant::now() + Duration::from_secs(5);
        let arrived = loop {
            let seen = devices.log.lock().ok().and_then(|l| {
                l.iter()
                    .find(|w| w.0 as usize == unit && u32::from(w.1) == register && w.2 == value)
                    .map(|w| w.3)
            });
            if let Some(at) = seen {
                break at;
            }
            anyhow::ensure!(Instant::now() < until, "write {i} never reached its device");
            tokio::time::sleep(Duration::from_micros(200)).await;
        };
        took.push(arrived.saturating_sub(sent) as f64 / 1e6);
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    Ok(Writes::of(&took))
}

/// One row: devices and gateway started, warmed up, measured.
fn measure(runtime: &tokio::runtime::Runtime, case: &Case) -> anyhow::Result<Measured> {
    let channels = case.fields / usize::from(case.fields_a_device) / case.devices_a_channel;
    let devices = start_devices(channels)?;
    let dir = common::temp_dir(&format!("matrix-{}", case.name))?;
    let gateway = common::start(&dir, &config(&dir, case, &devices.ports)?)?;
    let pid = gateway.child.id();
    let total = channels * case.devices_a_channel;
    runtime.block_on(async {
        let started = Instant::now();
        while common::http::connected_devices(gateway.http)
            .await
            .unwrap_or(0)
            < total
        {
            anyhow::ensure!(
                started.elapsed() < Duration::from_secs(60),
                "devices never connected"
            );
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        tokio::time::sleep(Duration::from_secs(5)).await;
        let (cpu0, (req0, bytes0), window) =
            (common::cpu_seconds(pid), stat(&devices), Instant::now());
        let mut rss = 0;
        while window.elapsed() < Duration::from_secs(20) {
            tokio::time::sleep(Duration::from_millis(500)).await;
            rss = rss.max(common::rss_kib(pid));
        }
        let secs = window.elapsed().as_secs_f64();
        let (req1, bytes1) = stat(&devices);
        let cpu = (common::cpu_seconds(pid) - cpu0) / secs;
        let planned = total as f64 * case.requests_a_device() / case.period().as_secs_f64();
        let writes = if case.writes {
            Some(writes(gateway.http, &devices, case).await?)
        } else {
            None
        };
        Ok(Measured {
            rss_mib: rss as f64 / 1024.0,
            cpu,
            bytes_a_second: (bytes1 - bytes0) as f64 / secs,
            answered: (req1 - req0) as f64 / secs / planned,
            writes,
        })
    })
}

fn main() -> anyhow::Result<()> {
    if let Ok(channels) = std::env::var("IOGATE_MATRIX_CHANNELS") {
        return matrix_device::serve(channels.parse()?);
    }
    let runtime = tokio::runtime::Runtime::new()?;
    let only = std::env::var("IOGATE_BENCH_ONLY").ok();
    let mut rows = Vec::new();
    for case in matrix_rows::CASES {
        if only
            .as_deref()
            .is_some_and(|o| !o.split(',').any(|n| n == case.name))
        {
            continue;
        }
        eprintln!("measuring {} fields every {}", case.fields, case.rate);
        rows.push((case, measure(&runtime, case)?));
    }
    matrix_rows::print(&rows);
    Ok(())
}

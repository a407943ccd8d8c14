//! MQTT publishing under load, against a real Mosquitto on loopback: 10,000 fields (10 Modbus
//! TCP devices x 1,000 input registers, polled every 100 ms) each changing once a second,
//! published as JSON at QoS 1; each message's latency from the gateway's read of the value
//! to its PUBLISH leaving the gateway's socket (the gateway's own part, seen by a relay between
//! the gateway and the broker) and to its delivery to `mosquitto_sub` (end to end). Then the broker goes away while the
//! fields change ten times faster, until a million messages wait in the buffer, and comes
//! back: the replay rate. The gateway runs in a process of its own (the tests crate's
//! `gateway` binary) so that its CPU time and resident size are its own.
//! Run with `cargo bench -p iogate-tests --bench mqtt`; it prints figures.

use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use iogate_tests::GatewayProcess;
use iogate_tests::devices::{ModbusDevice, input_register_profile, modbus_tcp_server, temp_dir};
use iogate_tests::mqtt::Broker;
use iogate_tests::process::{cpu_seconds, rss_mib};
use mqtt_watch::{Latencies, summary};

mod mqtt_watch;

const DEVICES: usize = 10;
const FIELDS: usize = 1000;
const BUFFERED: u64 = 1_000_000;

/// Every 100 ms, `slices` tenths of every device's registers change (1: each field once a
/// second; 10: ten times a second), until `stop`.
fn change(
    devices: Vec<ModbusDevice>,
    slices: usize,
    stop: Arc<AtomicBool>,
) -> tokio::task::JoinHandle<()> {
    tokio::spawn(async move {
        let mut tick = tokio::time::interval(Duration::from_millis(100));
        let mut k = 0usize;
        while !stop.load(Ordering::Relaxed) {
            tick.tick().await;
            for _ in 0..slices {
                let range = (k % 10) * (FIELDS / 10)..(k % 10 + 1) * (FIELDS / 10);
                for d in &devices {
                    let mut t = d.tables.lock().unwrap_or_else(|e| e.into_inner());
                    for r in range.clone() {
                        t.input[r] = t.input[r].wrapping_add(1);
                    }
                }
                k += 1;
            }
        }
    })
}

async fn buffered(gw: &iogate_tests::TestGateway) -> (u64, bool) {
    let (_, s) = gw.get("/api/v1/mqtt").await.unwrap_or_default();
    (
        s["buffer"]["messages"].as_u64().unwrap_or(0),
        s["connected"] == true,
    )
}

async fn run() -> anyhow::Result<()> {
    let mut broker = Broker::start().await?;
    let dir = temp_dir("bench-mqtt");
    let (relay, own) = mqtt_watch::relay(broker.port)?;
    let (config, devices, servers) = bench_config(&dir, relay).await?;
    let gateway =
        GatewayProcess::start(env!("CARGO_BIN_EXE_gateway"), Path::new(&dir), &config).await?;
    let pid = gateway.pid().ok_or_else(|| anyhow::anyhow!("no pid"))?;
    let gw = &gateway.gateway;

    let (mut sub, delivered) = mqtt_watch::subscriber(broker.port, "bench/+/+").await?;
    steady_state(pid, &devices, &own, &delivered).await?;

    // The broker goes away; the fields change ten times a second until the buffer holds a
    // million messages.
    broker.pause().await;
    broker_away(pid, gw, &devices, &dir).await?;
    let depth = buffered(gw).await.0;
    broker.resume().await?;
    broker_back(pid, gw, depth).await;
    gateway.kill().await?;
    let _ = sub.kill().await;
    broker.stop().await;
    for s in servers {
        s.abort();
    }
    // The buffer (a million messages, some 170 MiB) goes with the run.
    let _ = std::fs::remove_dir_all(&dir);
    Ok(())
}

/// The profile, and the config of `DEVICES` links each with its Modbus TCP device (started
/// here) and the MQTT section; the devices and their servers' tasks.
async fn bench_config(
    dir: &Path,
    port: u16,
) -> anyhow::Result<(String, Vec<ModbusDevice>, Vec<tokio::task::JoinHandle<()>>)> {
    let profiles = dir.join("profiles");
    std::fs::create_dir_all(&profiles)?;
    std::fs::write(
        profiles.join("bench.yaml"),
        input_register_profile("Bench1000", FIELDS),
    )?;
    let mut config = format!("profiles: {}\nlinks:\n", profiles.display());
    let mut devices = Vec::new();
    let mut servers = Vec::new();
    for n in 0..DEVICES {
        let device = ModbusDevice::default();
        let (port, task) = modbus_tcp_server(device.clone()).await;
        devices.push(device);
        servers.push(task);
        config.push_str(&format!(
            "  - {{ name: l{n}, tcp: {{ host: 127.0.0.1, port: {port} }} }}\n"
        ));
    }
    config.push_str("devices:\n");
    for n in 0..DEVICES {
        config.push_str(&format!(
            "  - {{ name: d{n}, profile: Bench1000, link: l{n}, slave_id: 1, refresh_rate: 100ms }}\n"
        ));
    }
    config.push_str(&format!(
        "mqtt:
  url: mqtt://127.0.0.1:{}
  client_id: iogate-bench
  json: {{ prefix: bench, qos: 1, retain: false }}
  buffer: {{ dir: {}, max_bytes: 1GiB, replay_rate: 1000000/s, fsync: second }}
",
        port,
        dir.join("buffer").display()
    ));
    Ok((config, devices, servers))
}

/// Steady state: 10,000 changes a second, written by the gateway and delivered to the
/// subscriber; what was seen.
async fn steady_state(
    pid: u32,
    devices: &[ModbusDevice],
    own: &Latencies,
    delivered: &Latencies,
) -> anyhow::Result<()> {
    let stop = Arc::new(AtomicBool::new(false));
    let changer = change(devices.to_vec(), 1, stop.clone());
    tokio::time::sleep(Duration::from_secs(5)).await;
    own.take();
    delivered.take();
    let (cpu0, t0) = (cpu_seconds(pid), Instant::now());
    let measure = Duration::from_secs(20);
    tokio::time::sleep(measure).await;
    let cpu = (cpu_seconds(pid) - cpu0) / t0.elapsed().as_secs_f64();
    println!(
        "{} fields changing once a second, JSON at QoS 1 into Mosquitto on loopback:",
        DEVICES * FIELDS
    );
    for (what, seen) in [
        ("read to PUBLISH written (the gateway's own part)", own),
        ("read to delivery to mosquitto_sub", delivered),
    ] {
        let (n, p50, p99, max) = summary(seen.take());
        println!(
            "  {what}: {:.0} messages/s, p50 {p50:.1} ms, p99 {p99:.1} ms, max {max:.1} ms",
            n as f64 / measure.as_secs_f64()
        );
    }
    println!(
        "  gateway CPU {:.1} % of one core, resident {:.1} MiB",
        cpu * 100.0,
        rss_mib(pid)
    );
    stop.store(true, Ordering::Relaxed);
    changer.await?;
    Ok(())
}

/// The broker away: the fields change ten times a second until the buffer holds a million
/// messages; what it took.
async fn broker_away(
    pid: u32,
    gw: &iogate_tests::TestGateway,
    devices: &[ModbusDevice],
    dir: &Path,
) -> anyhow::Result<()> {
    let stop = Arc::new(AtomicBool::new(false));
    let changer = change(devices.to_vec(), 10, stop.clone());
    let (cpu0, t0) = (cpu_seconds(pid), Instant::now());
    let start_depth = buffered(gw).await.0;
    let depth = loop {
        tokio::time::sleep(Duration::from_millis(500)).await;
        let (depth, _) = buffered(gw).await;
        if depth >= BUFFERED || t0.elapsed() > Duration::from_secs(300) {
            break depth;
        }
    };
    stop.store(true, Ordering::Relaxed);
    changer.await?;
    let fill = t0.elapsed().as_secs_f64();
    let fill_cpu = (cpu_seconds(pid) - cpu0) / fill;
    let disk: u64 = std::fs::read_dir(dir.join("buffer"))?
        .filter_map(|e| e.ok()?.metadata().ok())
        .map(|m| m.len())
        .sum();
    println!(
        "broker away: {} messages buffered in {fill:.1} s ({:.0}/s, gateway CPU {:.1} %), {:.0} MiB on disk, resident {:.1} MiB",
        depth - start_depth,
        (depth - start_depth) as f64 / fill,
        fill_cpu * 100.0,
        disk as f64 / (1 << 20) as f64,
        rss_mib(pid)
    );
    Ok(())
}

/// The broker back: the buffer replayed; how fast.
async fn broker_back(pid: u32, gw: &iogate_tests::TestGateway, depth: u64) {
    let (cpu0, t0) = (cpu_seconds(pid), Instant::now());
    let mut connected_at = None;
    loop {
        tokio::time::sleep(Duration::from_millis(200)).await;
        let (left, connected) = buffered(gw).await;
        if connected && connected_at.is_none() {
            connected_at = Some(t0.elapsed());
        }
        if (connected && left == 0) || t0.elapsed() > Duration::from_secs(900) {
            break;
        }
    }
    let took = t0.elapsed() - connected_at.unwrap_or_default();
    println!(
        "broker back: {depth} messages replayed in {:.1} s ({:.0}/s, gateway CPU {:.1} %, resident {:.1} MiB)",
        took.as_secs_f64(),
        depth as f64 / took.as_secs_f64(),
        (cpu_seconds(pid) - cpu0) / t0.elapsed().as_secs_f64() * 100.0,
        rss_mib(pid)
    );
}

fn main() -> anyhow::Result<()> {
    tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?
        .block_on(run())
}

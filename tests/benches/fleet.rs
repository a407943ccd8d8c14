//! A fleet: 20 gateways, each in its own process with 10,000 fields (10 Modbus TCP devices of
//! 1,000 input registers on a connection of its own, polled every 500 ms), publishing
//! Sparkplug B into one Mosquitto on loopback; a Sparkplug host (`tests/mqtt/fleet_host.py`,
//! pysparkplug) counts every metric, each edge node's sequence numbers, and every change a
//! metric skipped. Every register is one more each change; the changes come `RATES` (every
//! register once a second; a tenth of them). Printed: metrics a second at the host, gaps and
//! lost changes, CPU and memory a gateway (mean and most), the broker's CPU and memory.
//! Run with `cargo bench -p iogate-tests --bench fleet`.

use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use iogate_tests::GatewayProcess;
use iogate_tests::devices::{ModbusDevice, input_register_profile, modbus_tcp_server, temp_dir};
use iogate_tests::mqtt::Broker;
use iogate_tests::process::{cpu_seconds, rss_mib};
use tokio::io::AsyncBufReadExt;

const GATEWAYS: usize = 20;
const DEVICES: usize = 10;
const FIELDS: usize = 1000;
const MEASURE: Duration = Duration::from_secs(30);

fn config(dir: &Path, g: usize, modbus: u16, broker: u16) -> String {
    let mut c = format!(
        "profiles: {}\nlinks:\n  - {{ name: l, tcp: {{ host: 127.0.0.1, port: {modbus} }} }}\ndevices:\n",
        dir.join("profiles").display()
    );
    for d in 0..DEVICES {
        c.push_str(&format!(
            "  - {{ name: d{d}, profile: Bench1000, link: l, slave_id: {}, refresh_rate: 500ms }}\n",
            d + 1
        ));
    }
    c.push_str(&format!(
        "mqtt:\n  url: mqtt://127.0.0.1:{broker}\n  client_id: fleet-{g}\n  sparkplug: {{ group_id: fleet, edge_node_id: gw{g} }}\n"
    ));
    c
}

/// What the host said last (its totals), and the metrics and messages it counted since
/// `take`.
#[derive(Clone, Default)]
struct Host(Arc<Mutex<(serde_json::Value, u64, u64)>>);

impl Host {
    fn take(&self) -> (serde_json::Value, u64, u64) {
        let mut seen = self.0.lock().unwrap_or_else(|e| e.into_inner());
        let metrics = std::mem::take(&mut seen.1);
        let messages = std::mem::take(&mut seen.2);
        (seen.0.clone(), metrics, messages)
    }
}

async fn host(port: u16) -> anyhow::Result<(tokio::process::Child, Host)> {
    let script = iogate_tests::repo_file("mqtt/fleet_host.py");
    let mut child = tokio::process::Command::new(iogate_tests::python())
        .arg(script)
        .args([port.to_string(), "fleet".into()])
        .stdout(std::process::Stdio::piped())
        .kill_on_drop(true)
        .spawn()?;
    let out = child
        .stdout
        .take()
        .ok_or_else(|| anyhow::anyhow!("no stdout"))?;
    let seen = Host::default();
    let keep = seen.clone();
    tokio::spawn(async move {
        let mut lines = tokio::io::BufReader::new(out).lines();
        while let Ok(Some(line)) = lines.next_line().await {
            let Ok(v) = serde_json::from_str::<serde_json::Value>(&line) else {
                continue;
            };
            if v.get("decode_error").is_some() {
                eprintln!("host: {line}");
            }
            if v.get("gaps").is_some() {
                let mut s = keep.0.lock().unwrap_or_else(|e| e.into_inner());
                s.1 += v["metrics"].as_u64().unwrap_or(0);
                s.2 += v["messages"].as_u64().unwrap_or(0);
                s.0 = v;
            }
        }
    });
    Ok((child, seen))
}

/// Every second, `share` of every register one more (from register 0; 1.0: all).
fn change(device: ModbusDevice, share: f64, stop: Arc<std::sync::atomic::AtomicBool>) {
    let n = (FIELDS as f64 * share) as usize;
    tokio::spawn(async move {
        let mut tick = tokio::time::interval(Duration::from_secs(1));
        while !stop.load(std::sync::atomic::Ordering::Relaxed) {
            tick.tick().await;
            let mut t = device.tables.lock().unwrap_or_else(|e| e.into_inner());
            for r in &mut t.input[..n] {
                *r = r.wrapping_add(1);
            }
        }
    });
}

struct Fleet {
    gateways: Vec<GatewayProcess>,
    pids: Vec<u32>,
}

async fn fleet(dir: &Path, device: &ModbusDevice, broker: u16) -> anyhow::Result<Fleet> {
    std::fs::create_dir_all(dir.join("profiles"))?;
    std::fs::write(
        dir.join("profiles/bench.yaml"),
        input_register_profile("Bench1000", FIELDS),
    )?;
    let mut gateways = Vec::new();
    let mut pids = Vec::new();
    for g in 0..GATEWAYS {
        let (modbus, _task) = modbus_tcp_server(device.clone()).await;
        let own = dir.join(format!("gw{g}"));
        std::fs::create_dir_all(&own)?;
        let gw = GatewayProcess::start(
            env!("CARGO_BIN_EXE_gateway"),
            &own,
            &config(dir, g, modbus, broker),
        )
        .await?;
        pids.push(gw.pid().ok_or_else(|| anyhow::anyhow!("no pid"))?);
        gateways.push(gw);
    }
    Ok(Fleet { gateways, pids })
}

/// One rate: `share` of the registers changing every second, measured for `MEASURE`.
async fn measure(fleet: &Fleet, host: &Host, broker: u32, device: &ModbusDevice, share: f64) {
    let stop = Arc::new(std::sync::atomic::AtomicBool::new(false));
    change(device.clone(), share, stop.clone());
    tokio::time::sleep(Duration::from_secs(5)).await;
    let (before, _, _) = host.take();
    let sent0 = sent(fleet).await;
    let cpu0: Vec<f64> = fleet.pids.iter().map(|&p| cpu_seconds(p)).collect();
    let broker0 = cpu_seconds(broker);
    let t0 = Instant::now();
    tokio::time::sleep(MEASURE).await;
    let secs = t0.elapsed().as_secs_f64();
    let (after, metrics, messages) = host.take();
    let sent = sent(fleet).await - sent0;
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    let cpu: Vec<f64> = (fleet.pids.iter().zip(&cpu0))
        .map(|(&p, c0)| (cpu_seconds(p) - c0) / secs * 100.0)
        .collect();
    let rss: Vec<f64> = fleet.pids.iter().map(|&p| rss_mib(p)).collect();
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let most = |v: &[f64]| v.iter().cloned().fold(0.0, f64::max);
    let delta = |k: &str| after[k].as_u64().unwrap_or(0) - before[k].as_u64().unwrap_or(0);
    let expected = (GATEWAYS * DEVICES) as f64 * (FIELDS as f64 * share);
    println!(
        "{GATEWAYS} gateways x {} fields, {:.0} changes a second expected: host counted {:.0} metrics/s ({} edge nodes), {} sequence gaps, {} changes lost, {} decode errors",
        DEVICES * FIELDS,
        expected,
        metrics as f64 / secs,
        after["nodes"],
        delta("gaps"),
        delta("lost"),
        delta("errors"),
    );
    println!(
        "  messages: {sent} published by the gateways, {messages} taken by the host ({:.0} metrics a message)",
        metrics as f64 / messages.max(1) as f64
    );
    println!(
        "  a gateway: CPU mean {:.1} % of a core (most {:.1}), resident mean {:.1} MiB (most {:.1}); Mosquitto CPU {:.1} %, resident {:.1} MiB",
        mean(&cpu),
        most(&cpu),
        mean(&rss),
        most(&rss),
        (cpu_seconds(broker) - broker0) / secs * 100.0,
        rss_mib(broker),
    );
    tokio::time::sleep(Duration::from_secs(3)).await;
}

/// The messages the gateways have published, all told.
async fn sent(fleet: &Fleet) -> u64 {
    let mut n = 0;
    for gw in &fleet.gateways {
        let (_, s) = gw.gateway.get("/api/v1/mqtt").await.unwrap_or_default();
        n += s["messages_out"].as_u64().unwrap_or(0);
    }
    n
}

/// The rates measured: every register once a second, a tenth of them.
const RATES: [f64; 2] = [0.1, 1.0];

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    iogate_tests::mqtt::install()?;
    let broker = Broker::start().await?;
    let broker_pid = broker
        .pid()
        .ok_or_else(|| anyhow::anyhow!("no broker pid"))?;
    let (mut host_child, host) = host(broker.port).await?;
    let dir = temp_dir("bench-fleet");
    let device = ModbusDevice::default();
    let fleet = fleet(&dir, &device, broker.port).await?;
    for share in RATES {
        measure(&fleet, &host, broker_pid, &device, share).await;
    }
    for gw in fleet.gateways {
        gw.kill().await?;
    }
    let _ = host_child.kill().await;
    broker.stop().await;
    let _ = std::fs::remove_dir_all(&dir);
    Ok(())
}

//! What a gateway costs before anyone asks: `iogate serve` in its own process, started
//! cold (a new process each time), measured from its spawn.
//!
//! - The built-in demo (no config): spawn to the first good value of its Modbus meter
//!   served over REST; median of 5.
//! - 10,000 simulated fields (ten devices of 1,000, read every second): spawn to the last
//!   device's first good value served over REST; median of 5.
//! - Every door configured (HTTP, gRPC, the Modbus TCP server, OPC UA, MQTT to a broker
//!   that is not there, the IEC 104 outstation) and no device: resident memory once
//!   listening, and CPU over 10 s of nobody asking.
//! - The binary's size (the bench profile's build; `docs/benchmarks.md` gives the release
//!   build's too).
//!
//! `cargo bench -p iogate --bench startup`

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

mod common;

const STARTS: usize = 5;

fn main() -> anyhow::Result<()> {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    let mut rows = Vec::new();
    let demo = median((0..STARTS).map(|_| runtime.block_on(demo())).collect())?;
    println!("demo: spawn to the meter's first value {demo:.0} ms");
    rows.push(row(
        "demo: spawn to the first field value served",
        format!("{demo:.0} ms"),
        "",
        0.0,
    ));
    let fields = median(
        (0..STARTS)
            .map(|_| runtime.block_on(ten_thousand()))
            .collect(),
    )?;
    println!("10,000 fields: spawn to the last device's first value {fields:.0} ms");
    rows.push(row(
        "10,000 simulated fields: spawn to every device's first value served",
        format!("{fields:.0} ms"),
        "",
        0.0,
    ));
    let (rss, cpu) = runtime.block_on(every_door())?;
    println!(
        "every door, no device: {rss:.1} MiB, CPU {:.3} % over 10 s",
        cpu * 100.0
    );
    rows.push(row(
        "every door configured, no device: memory, CPU while nobody asks",
        format!("{rss:.1} MiB, {:.2} % of a core", cpu * 100.0),
        "",
        0.0,
    ));
    let size = std::fs::metadata(env!("CARGO_BIN_EXE_iogate"))?.len() as f64 / 1_048_576.0;
    println!("binary: {size:.1} MiB (bench profile)");
    rows.push(row(
        "binary size (bench profile)",
        format!("{size:.1} MiB"),
        "",
        0.0,
    ));
    common::print_table(&rows);
    Ok(())
}

fn row(measure: &str, iogate: String, peer: &str, ratio: f64) -> common::Row {
    common::Row {
        measure: measure.into(),
        iogate,
        peer: peer.into(),
        ratio,
        goal: "measured".into(),
    }
}

fn median(mut runs: Vec<anyhow::Result<f64>>) -> anyhow::Result<f64> {
    let mut ms = Vec::new();
    for r in runs.drain(..) {
        ms.push(r?);
    }
    ms.sort_by(f64::total_cmp);
    Ok(ms[ms.len() / 2])
}

/// Polls `path` every millisecond until its answer holds `want`; the time since `from`.
async fn until(
    addr: std::net::SocketAddr,
    path: &str,
    want: &str,
    from: Instant,
) -> anyhow::Result<f64> {
    let deadline = from + Duration::from_secs(60);
    loop {
        if let Ok((200, body)) = common::http::get_once(addr, path).await
            && String::from_utf8_lossy(&body).contains(want)
        {
            return Ok(from.elapsed().as_secs_f64() * 1000.0);
        }
        anyhow::ensure!(Instant::now() < deadline, "{path}: no {want} within 60 s");
        tokio::time::sleep(Duration::from_millis(1)).await;
    }
}

/// The built-in demo, from a directory with no `iogate.yaml`, on free ports.
async fn demo() -> anyhow::Result<f64> {
    let dir = common::temp_dir("startup-demo")?;
    let http = common::free_port()?;
    let port = |p: u16| format!("127.0.0.1:{p}");
    let started = Instant::now();
    let mut child = Command::new(env!("CARGO_BIN_EXE_iogate"))
        .arg("serve")
        .args(["--http", &port(http), "--grpc", &port(common::free_port()?)])
        .args([
            "--modbus",
            &port(common::free_port()?),
            "--opcua",
            &port(common::free_port()?),
        ])
        .current_dir(&dir)
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()?;
    let addr = std::net::SocketAddr::from(([127, 0, 0, 1], http));
    let took = until(
        addr,
        "/api/v1/devices/meter",
        "\"quality\":\"good\"",
        started,
    )
    .await;
    let _ = child.kill();
    let _ = child.wait();
    took
}

/// Ten simulated devices of 1,000 INT fields each.
async fn ten_thousand() -> anyhow::Result<f64> {
    let dir = common::temp_dir("startup-10k")?;
    std::fs::create_dir_all(dir.join("profiles"))?;
    let mut profile = String::from("name: Big\nprotocol: simulated\nfields:\n");
    for i in 0..1000 {
        profile.push_str(&format!(
            "  - {{ name: f{i}, type: INT, direction: input, register: {{ address: {i}, kind: virtual }} }}\n"
        ));
    }
    std::fs::write(dir.join("profiles/big.yaml"), profile)?;
    let mut config = format!(
        "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0 }}\nprofiles: {}\ndevices:\n",
        dir.join("profiles").display()
    );
    for d in 0..10 {
        config.push_str(&format!(
            "  - {{ name: d{d}, profile: Big, refresh_rate: 1s }}\n"
        ));
    }
    let started = Instant::now();
    let gw = common::start(&dir, &config)?;
    until(
        gw.http,
        "/api/v1/devices/d9/fields/f999",
        "\"quality\":\"good\"",
        started,
    )
    .await
}

/// Every door, no device: memory once listening, CPU over 10 s.
async fn every_door() -> anyhow::Result<(f64, f64)> {
    let dir = common::temp_dir("startup-doors")?;
    let mqtt = common::free_port()?;
    let config = format!(
        "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0 }}\nmodbus_server:\n  listen: 127.0.0.1:0\n  auto: true\nopcua:\n  listen: 127.0.0.1:0\n  pki_dir: {}\nmqtt:\n  url: mqtt://127.0.0.1:{mqtt}\n  client_id: iogate-startup\n  sparkplug: {{ group_id: bench, edge_node_id: idle }}\niec104_server:\n  listen: 127.0.0.1:0\n",
        dir.join("pki").display()
    );
    let gw = common::start(&dir, &config)?;
    let pid = gw.child.id();
    until(gw.http, "/readyz", "", Instant::now()).await?;
    tokio::time::sleep(Duration::from_secs(2)).await;
    let rss = common::rss_kib(pid) as f64 / 1024.0;
    let cpu0 = common::cpu_seconds(pid);
    tokio::time::sleep(Duration::from_secs(10)).await;
    let cpu = (common::cpu_seconds(pid) - cpu0) / 10.0;
    Ok((rss, cpu))
}

//! 100,000 fields: 1,000 simulated devices of 100 fields each, refreshed every 100 ms, in
//! `iogate serve` in its own process. Prints the time from start to ready (`/readyz` 200),
//! resident memory and CPU (from /proc) once running, and how long `GET /api/v1/devices`
//! and `GET /api/v1/links` (what the web page's overview asks for) take.
//!
//! `cargo bench -p iogate --bench scale`

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

mod common;

const DEVICES: usize = 1000;
const FIELDS: usize = 100;

/// One GET over a fresh connection: the status and how long the whole answer took.
async fn get(addr: SocketAddr, path: &str) -> anyhow::Result<(u16, Duration, usize)> {
    let started = Instant::now();
    let mut stream = TcpStream::connect(addr).await?;
    stream
        .write_all(
            format!("GET {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n").as_bytes(),
        )
        .await?;
    let mut body = Vec::new();
    stream.read_to_end(&mut body).await?;
    let elapsed = started.elapsed();
    let status = std::str::from_utf8(body.get(9..12).unwrap_or_default())
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(0);
    Ok((status, elapsed, body.len()))
}

fn percentile(sorted: &[Duration], q: f64) -> Duration {
    sorted[((sorted.len() as f64 * q) as usize).min(sorted.len() - 1)]
}

fn main() -> anyhow::Result<()> {
    let dir = common::temp_dir("scale")?;
    let profiles = dir.join("profiles");
    std::fs::create_dir_all(&profiles)?;
    let mut profile = String::from("name: Hundred\nprotocol: simulated\nfields:\n");
    for i in 0..FIELDS {
        let ty = ["REAL", "INT", "BOOL", "DINT"][i % 4];
        let direction = if i % 5 == 0 { "output" } else { "input" };
        profile.push_str(&format!(
            "  - {{ name: F{i}, type: {ty}, direction: {direction}, register: {{ address: {i}, kind: virtual }} }}\n"
        ));
    }
    std::fs::write(profiles.join("hundred.yaml"), profile)?;
    let mut config = format!(
        "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0 }}\nprofiles: {}\ndevices:\n",
        profiles.display()
    );
    for d in 0..DEVICES {
        config.push_str(&format!(
            "  - {{ name: d{d}, profile: Hundred, refresh_rate: 100ms }}\n"
        ));
    }
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    let started = Instant::now();
    let gateway = common::start(&dir, &config)?;
    let pid = gateway.child.id();
    runtime.block_on(async {
        loop {
            if let Ok((200, _, _)) = get(gateway.http, "/readyz").await {
                break;
            }
            anyhow::ensure!(started.elapsed() < Duration::from_secs(60), "never ready");
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
        let ready = started.elapsed();
        tokio::time::sleep(Duration::from_secs(5)).await;
        let cpu_before = common::cpu_seconds(pid);
        let window = Instant::now();
        tokio::time::sleep(Duration::from_secs(10)).await;
        let cpu = (common::cpu_seconds(pid) - cpu_before) / window.elapsed().as_secs_f64();
        let rss = common::rss_kib(pid);
        let mut answers = Vec::new();
        for path in ["/api/v1/devices", "/api/v1/links"] {
            let mut times = Vec::new();
            let mut bytes = 0;
            for _ in 0..30 {
                let (status, took, len) = get(gateway.http, path).await?;
                anyhow::ensure!(status == 200, "{path}: {status}");
                times.push(took);
                bytes = len;
            }
            times.sort();
            answers.push((
                path,
                percentile(&times, 0.5),
                percentile(&times, 0.99),
                bytes,
            ));
        }
        println!(
            "{} fields ({DEVICES} simulated devices x {FIELDS}, every 100 ms):",
            DEVICES * FIELDS
        );
        println!("| measure | iogate | goal |");
        println!("| --- | --- | --- |");
        println!(
            "| start to ready | {:.0} ms | < 1 s |",
            ready.as_secs_f64() * 1e3
        );
        println!("| resident | {:.1} MiB | < 64 MB |", rss as f64 / 1024.0);
        println!("| CPU | {:.1} % of a core | < 15 % |", cpu * 100.0);
        for (path, p50, p99, bytes) in answers {
            println!(
                "| `GET {path}` ({:.0} KiB) | p50 {:.1} ms, p99 {:.1} ms | < 50 ms |",
                bytes as f64 / 1024.0,
                p50.as_secs_f64() * 1e3,
                p99.as_secs_f64() * 1e3
            );
        }
        anyhow::Ok(())
    })?;
    drop(gateway);
    Ok(())
}

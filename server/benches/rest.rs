//! REST throughput against the same server's `/livez`, in one run: a whole device (10 fields,
//! and the demo's `plant` with 20), one field, and `/livez`, each over 64 kept-alive
//! HTTP/1.1 connections for 3 s, against `iogate serve` in its own process. Prints requests
//! per second and the ratio to `/livez`.
//!
//! `cargo bench -p iogate --bench rest`

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

const CONNECTIONS: usize = 64;
const RUN: Duration = Duration::from_secs(3);

mod common;
use common::Gateway;

fn start() -> anyhow::Result<Gateway> {
    let dir = common::temp_dir("rest")?;
    let profiles = dir.join("profiles");
    std::fs::create_dir_all(&profiles)?;
    let repo = common::profiles();
    std::fs::copy(repo.join("sim_plant.yaml"), profiles.join("sim_plant.yaml"))?;
    // Ten fields: four REAL, three INT, two BOOL, one STRING; inputs and outputs.
    let mut ten = String::from("name: Ten\nprotocol: simulated\nfields:\n");
    for (i, (ty, dir)) in [
        ("REAL", "input"),
        ("REAL", "input"),
        ("REAL", "output"),
        ("REAL", "input"),
        ("INT", "input"),
        ("INT", "output"),
        ("INT", "input"),
        ("BOOL", "input"),
        ("BOOL", "output"),
        ("STRING", "input"),
    ]
    .iter()
    .enumerate()
    {
        ten.push_str(&format!(
            "  - {{ name: F{i}, type: {ty}, direction: {dir}, register: {{ address: {i}, kind: virtual }} }}\n"
        ));
    }
    std::fs::write(profiles.join("ten.yaml"), ten)?;
    common::start(
        &dir,
        &format!(
            "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0 }}\nprofiles: {}\ndevices:\n  - {{ name: plant, profile: SimPlant, refresh_rate: 100ms }}\n  - {{ name: ten, profile: Ten, refresh_rate: 100ms }}\n",
            profiles.display()
        ),
    )
}

/// Requests `path` over one kept-alive connection until `until`; answers the count.
async fn client(addr: SocketAddr, path: &'static str, until: Instant) -> anyhow::Result<u64> {
    let mut stream = TcpStream::connect(addr).await?;
    stream.set_nodelay(true)?;
    let request = format!("GET {path} HTTP/1.1\r\nHost: x\r\n\r\n");
    let mut buf = vec![0u8; 64 * 1024];
    let mut n = 0;
    while Instant::now() < until {
        stream.write_all(request.as_bytes()).await?;
        // Read the head, then the body by its Content-Length.
        let mut have = 0;
        let (head, length) = loop {
            let read = stream.read(&mut buf[have..]).await?;
            anyhow::ensure!(read > 0, "closed");
            have += read;
            if let Some(end) = buf[..have].windows(4).position(|w| w == b"\r\n\r\n") {
                let head = String::from_utf8_lossy(&buf[..end]).to_lowercase();
                anyhow::ensure!(head.starts_with("http/1.1 200"), "{head}");
                let length: usize = head
                    .lines()
                    .find_map(|l| l.strip_prefix("content-length:"))
                    .and_then(|v| v.trim().parse().ok())
                    .ok_or_else(|| anyhow::anyhow!("no content-length: {head}"))?;
                break (end + 4, length);
            }
        };
        while have < head + length {
            let read = stream.read(&mut buf[have..]).await?;
            anyhow::ensure!(read > 0, "closed");
            have += read;
        }
        n += 1;
    }
    Ok(n)
}

async fn rate(addr: SocketAddr, path: &'static str) -> anyhow::Result<f64> {
    let until = Instant::now() + RUN;
    let started = Instant::now();
    let tasks: Vec<_> = (0..CONNECTIONS)
        .map(|_| tokio::spawn(client(addr, path, until)))
        .collect();
    let mut total = 0;
    for t in tasks {
        total += t.await??;
    }
    Ok(total as f64 / started.elapsed().as_secs_f64())
}

fn main() -> anyhow::Result<()> {
    let runtime = tokio::runtime::Runtime::new()?;
    runtime.block_on(async {
        let gw = start()?;
        let addr = gw.http;
        // Ready, and the device read at least once.
        tokio::time::sleep(Duration::from_millis(500)).await;
        let livez = rate(addr, "/livez").await?;
        let ten = rate(addr, "/api/v1/devices/ten").await?;
        let device = rate(addr, "/api/v1/devices/plant").await?;
        let field = rate(addr, "/api/v1/devices/plant/fields/Level").await?;
        let livez_again = rate(addr, "/livez").await?;
        let livez = (livez + livez_again) / 2.0;
        println!("REST over {CONNECTIONS} kept-alive connections, {RUN:?} each, 2 cores shared with the clients");
        println!("{:<44} {:>10}  {:>8}", "request", "req/s", "of /livez");
        for (what, r) in [
            ("GET /livez", livez),
            ("GET /api/v1/devices/ten (10 fields)", ten),
            ("GET /api/v1/devices/plant (20 fields)", device),
            ("GET /api/v1/devices/plant/fields/Level", field),
        ] {
            println!("{what:<44} {r:>10.0}  {:>8.2}", r / livez);
        }
        Ok(())
    })
}

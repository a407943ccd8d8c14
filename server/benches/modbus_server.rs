//! The Modbus TCP server under load: FC03 × 10 registers from 1 and from 16 masters at once
//! (tokio-modbus clients in this process), requests per second and latency percentiles,
//! against `iogate serve` on the demo's devices in its own process, and the same clients
//! against a libmodbus server (a C program built here with `cc` and Debian's
//! libmodbus-dev, when both are installed) in the same run.
//!
//! `cargo bench -p iogate --bench modbus_server`

use std::net::SocketAddr;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use tokio_modbus::prelude::*;

mod common;

const RUN: Duration = Duration::from_secs(3);

struct Figures {
    rps: f64,
    p50: Duration,
    p99: Duration,
}

async fn load(addr: SocketAddr, masters: usize, address: u16) -> anyhow::Result<Figures> {
    let mut tasks = Vec::new();
    let start = Instant::now();
    for _ in 0..masters {
        tasks.push(tokio::spawn(async move {
            let mut ctx = tcp::connect_slave(addr, Slave(1)).await?;
            let mut latencies = Vec::new();
            while start.elapsed() < RUN {
                let t = Instant::now();
                ctx.read_holding_registers(address, 10).await??;
                latencies.push(t.elapsed());
            }
            anyhow::Ok(latencies)
        }));
    }
    let mut all = Vec::new();
    for t in tasks {
        all.extend(t.await??);
    }
    let elapsed = start.elapsed();
    all.sort();
    let pick = |q: f64| all[((all.len() as f64 * q) as usize).min(all.len() - 1)];
    Ok(Figures {
        rps: all.len() as f64 / elapsed.as_secs_f64(),
        p50: pick(0.5),
        p99: pick(0.99),
    })
}

/// Builds and starts the libmodbus server, if the compiler and library are there.
fn libmodbus_server() -> Option<(Child, SocketAddr)> {
    let program = common::build_peer("modbus_server")?;
    let port = common::free_port().ok()?;
    let mut child = Command::new(&program)
        .arg(port.to_string())
        .stdout(Stdio::piped())
        .spawn()
        .ok()?;
    let mut line = String::new();
    let stdout = child.stdout.take()?;
    std::io::BufRead::read_line(&mut std::io::BufReader::new(stdout), &mut line).ok()?;
    Some((child, SocketAddr::from(([127, 0, 0, 1], port))))
}

/// `iogate serve` on the demo's simulated devices, every field bound (`auto: true`).
fn iogate_server() -> anyhow::Result<(common::Gateway, SocketAddr)> {
    let port = common::free_port()?;
    let dir = common::temp_dir("mbs")?;
    let gateway = common::start(
        &dir,
        &format!(
            "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0 }}\nprofiles: {}\ndevices:\n  - {{ name: sim, profile: SimIo, refresh_rate: 100ms }}\n  - {{ name: plant, profile: SimPlant, refresh_rate: 250ms }}\nmodbus_server:\n  listen: 127.0.0.1:{port}\n  auto: true\n  max_connections: 64\n",
            common::profiles().display()
        ),
    )?;
    Ok((gateway, SocketAddr::from(([127, 0, 0, 1], port))))
}

fn row(name: &str, masters: usize, f: &Figures) {
    println!(
        "{name:<10} {masters:>3} masters  {:>9.0} req/s  p50 {:>7.1} µs  p99 {:>7.1} µs",
        f.rps,
        f.p50.as_secs_f64() * 1e6,
        f.p99.as_secs_f64() * 1e6
    );
}

fn main() -> anyhow::Result<()> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    runtime.block_on(async {
        let (gateway, iogate) = iogate_server()?;
        println!(
            "FC03 x 10 registers for {RUN:?} per row; each server in its own process, the masters in this one, 2 cores"
        );
        let peer = libmodbus_server();
        if peer.is_none() {
            println!("(libmodbus not built: install gcc, pkg-config and libmodbus-dev to compare)");
        }
        for masters in [1, 16] {
            // %MD0-%MD4 of the demo: five bound 32-bit fields.
            let ours = load(iogate, masters, 2048).await?;
            row("iogate", masters, &ours);
            if let Some((_, addr)) = &peer {
                let theirs = load(*addr, masters, 2048).await?;
                row("libmodbus", masters, &theirs);
                println!(
                    "           ratio iogate/libmodbus: throughput {:.2}, p99 {:.2}",
                    ours.rps / theirs.rps,
                    ours.p99.as_secs_f64() / theirs.p99.as_secs_f64()
                );
            }
        }
        if let Some((mut child, _)) = peer {
            let _ = child.kill();
        }
        drop(gateway);
        anyhow::Ok(())
    })
}

//! The Modbus TCP server against its peers (see `benches/modbus_server.rs`).

use std::net::SocketAddr;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use tokio_modbus::prelude::*;

use crate::common::{self, Row};

const RUN: Duration = Duration::from_secs(2);
/// Rounds per row: the servers take turns, and each figure is the median of its rounds.
const ROUNDS: usize = 3;

struct Figures {
    rps: f64,
    p50: Duration,
    p99: Duration,
}

async fn load(
    addr: SocketAddr,
    masters: usize,
    address: u16,
    count: u16,
) -> anyhow::Result<Figures> {
    let mut tasks = Vec::new();
    let start = Instant::now();
    for _ in 0..masters {
        tasks.push(tokio::spawn(async move {
            let mut ctx = tcp::connect_slave(addr, Slave(1)).await?;
            let mut latencies = Vec::new();
            while start.elapsed() < RUN {
                let t = Instant::now();
                ctx.read_holding_registers(address, count).await??;
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

/// Starts a peer server `program` on a free loopback port (its one argument) and waits for
/// its first line (`ready`).
fn start_peer(program: &std::path::Path) -> Option<(Child, SocketAddr)> {
    let port = common::free_port().ok()?;
    let mut child = Command::new(program)
        .arg(port.to_string())
        .stdout(Stdio::piped())
        .spawn()
        .ok()?;
    let mut line = String::new();
    let stdout = child.stdout.take()?;
    std::io::BufRead::read_line(&mut std::io::BufReader::new(stdout), &mut line).ok()?;
    Some((child, SocketAddr::from(([127, 0, 0, 1], port))))
}

/// Builds and starts the libmodbus server, if the compiler and library are there.
fn libmodbus_server() -> Option<(Child, SocketAddr)> {
    start_peer(&common::build_peer("modbus_server")?)
}

/// Builds and starts the rodbus server, if cargo can build it (it fetches the crate).
fn rodbus_server() -> Option<(Child, SocketAddr)> {
    let peer = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("benches/peer/rodbus");
    let target = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../target/peer-rodbus");
    let built = Command::new(env!("CARGO"))
        .args(["build", "--release", "--quiet", "--manifest-path"])
        .arg(peer.join("Cargo.toml"))
        .arg("--target-dir")
        .arg(&target)
        .status()
        .ok()?;
    if !built.success() {
        return None;
    }
    start_peer(&target.join("release/rodbus-peer"))
}

/// `iogate serve` on the demo's simulated devices, every field bound (`auto: true`).
fn iogate_server() -> anyhow::Result<(common::Gateway, SocketAddr)> {
    let port = common::free_port()?;
    let dir = common::temp_dir("mbs")?;
    let gateway = common::start(
        &dir,
        &format!(
            "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0 }}\nprofiles: {}\ndevices:\n  - {{ name: sim, profile: SimIo, refresh_rate: 100ms }}\n  - {{ name: plant, profile: SimPlant, refresh_rate: 250ms }}\nmodbus_server:\n  listen: 127.0.0.1:{port}\n  auto: true\n  max_connections: 64\n  max_connections_per_client: 64\n",
            common::profiles().display()
        ),
    )?;
    Ok((gateway, SocketAddr::from(([127, 0, 0, 1], port))))
}

/// A server under test: its name, address and process.
struct Server {
    name: &'static str,
    addr: SocketAddr,
    pid: u32,
}

/// One round of a row on `server`: its figures and its process's CPU seconds per request.
async fn measure(server: &Server, masters: usize, count: u16) -> anyhow::Result<(Figures, f64)> {
    let before = common::cpu_seconds(server.pid);
    let f = load(server.addr, masters, 2048, count).await?;
    let cpu = common::cpu_seconds(server.pid) - before;
    let requests = f.rps * RUN.as_secs_f64();
    Ok((f, cpu / requests))
}

/// The medians of a server's rounds: requests per second, p50, p99, CPU per request.
fn medians(rounds: &[(Figures, f64)]) -> (f64, Duration, Duration, f64) {
    fn median<T: Copy + PartialOrd>(mut v: Vec<T>) -> T {
        v.sort_by(|a, b| a.partial_cmp(b).unwrap_or(std::cmp::Ordering::Equal));
        v[v.len() / 2]
    }
    (
        median(rounds.iter().map(|(f, _)| f.rps).collect()),
        median(rounds.iter().map(|(f, _)| f.p50).collect()),
        median(rounds.iter().map(|(f, _)| f.p99).collect()),
        median(rounds.iter().map(|(_, c)| *c).collect()),
    )
}

fn cell(name: &str, (rps, p50, p99, cpu): (f64, Duration, Duration, f64)) -> String {
    format!(
        "{name} {rps:.0} req/s, p50 {:.0} µs, p99 {:.0} µs, {:.1} µs CPU/req",
        p50.as_secs_f64() * 1e6,
        p99.as_secs_f64() * 1e6,
        cpu * 1e6
    )
}

/// Runs every row against every peer that could be built: prints the figures, answers the
/// suite's rows (iogate's requests per second against the best peer's).
pub fn run(runtime: &tokio::runtime::Runtime) -> anyhow::Result<Vec<Row>> {
    let mut rows = Vec::new();
    runtime.block_on(async {
        let (gateway, iogate) = iogate_server()?;
        let libmodbus = libmodbus_server();
        if libmodbus.is_none() {
            println!("(libmodbus not built: install gcc, pkg-config and libmodbus-dev to compare)");
        }
        let rodbus = rodbus_server();
        if rodbus.is_none() {
            println!("(rodbus not built: cargo could not build benches/peer/rodbus)");
        }
        let ours = Server {
            name: "iogate",
            addr: iogate,
            pid: gateway.child.id(),
        };
        let peers: Vec<Server> = [("libmodbus", &libmodbus), ("rodbus", &rodbus)]
            .into_iter()
            .filter_map(|(name, p)| {
                p.as_ref().map(|(child, addr)| Server {
                    name,
                    addr: *addr,
                    pid: child.id(),
                })
            })
            .collect();
        println!(
            "FC03, {ROUNDS} rounds of {RUN:?} per server and row (medians; the servers take turns); each server in its own process, the tokio-modbus masters in this one"
        );
        println!();
        println!("| request | masters | iogate | peers | iogate / best peer (req/s) |");
        println!("| --- | ---: | --- | --- | ---: |");
        for count in [10u16, 125] {
            for masters in [1, 16] {
                // From %MD0 of the demo: its bound 32-bit fields, then gateway memory.
                let servers: Vec<&Server> = std::iter::once(&ours).chain(&peers).collect();
                let mut rounds: Vec<Vec<(Figures, f64)>> = servers.iter().map(|_| Vec::new()).collect();
                for round in 0..ROUNDS {
                    // Each round in another order, so that no server always goes first.
                    for k in 0..servers.len() {
                        let i = (k + round) % servers.len();
                        rounds[i].push(measure(servers[i], masters, count).await?);
                    }
                }
                let figures: Vec<_> = rounds.iter().map(|r| medians(r)).collect();
                rows.push(row(count, masters, &servers, &figures));
            }
        }
        for (mut child, _) in [libmodbus, rodbus].into_iter().flatten() {
            let _ = child.kill();
        }
        drop(gateway);
        anyhow::Ok(())
    })?;
    println!();
    Ok(rows)
}

/// One row: iogate's medians against the best peer's, printed and answered.
fn row(
    count: u16,
    masters: usize,
    servers: &[&Server],
    figures: &[(f64, Duration, Duration, f64)],
) -> Row {
    let best = figures[1..].iter().map(|f| f.0).fold(0.0f64, f64::max);
    let best_peer = servers[1..]
        .iter()
        .zip(&figures[1..])
        .find(|(_, f)| f.0 == best);
    let row = Row {
        measure: format!(
            "Modbus TCP server, FC03 x {count}, {masters} master{} (req/s, p99)",
            if masters == 1 { "" } else { "s" }
        ),
        iogate: format!(
            "{:.0}, {:.0} µs",
            figures[0].0,
            figures[0].2.as_secs_f64() * 1e6
        ),
        peer: best_peer.map_or_else(
            || "no peer built".to_owned(),
            |(s, f)| format!("{} {:.0}, {:.0} µs", s.name, f.0, f.2.as_secs_f64() * 1e6),
        ),
        ratio: if best > 0.0 { figures[0].0 / best } else { 0.0 },
        goal: ">= 1.00".into(),
    };
    println!(
        "| FC03 x {count} | {masters} | {} | {} | {} |",
        cell("", figures[0]).trim(),
        servers[1..]
            .iter()
            .zip(&figures[1..])
            .map(|(s, f)| cell(s.name, *f))
            .collect::<Vec<_>>()
            .join("; "),
        if best > 0.0 {
            format!("{:.2}", figures[0].0 / best)
        } else {
            "-".to_owned()
        }
    );
    row
}

//! The IEC 104 outstation to a c104 master (`tests/iec104/master.py --count`, lib60870's
//! Python binding, in its own process): 10,000 fields (10 Modbus TCP devices of 1,000
//! holding registers, served by this process, every register changing every second), each
//! read every second and sent spontaneously with its time tag. Measured: the spontaneous
//! objects the master received a second, the time from each object's time tag (when the
//! gateway read it) to its arrival at the master (p50, p99, max), the gateway's CPU and
//! memory (only `iogate serve`'s process); the same to a master that only reads the wire
//! (`tests/iec104/wire_master.py`: what the outstation delivers, without c104's processing
//! of each object); and a general interrogation of the 10,000 points, from asking to the
//! last object received (by a c104 master of its own, first).
//!
//! `cargo bench -p iogate --bench iec104_server`

use std::io::{BufRead, Write};
use std::path::PathBuf;
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicU16, Ordering};
use std::time::{Duration, Instant};

use tokio_modbus::prelude::{ExceptionCode, Request, Response, SlaveRequest};

mod common;

const DEVICES: usize = 10;
const REGISTERS: usize = 1000;
const RUN: Duration = Duration::from_secs(20);

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// Holding registers whose values all move on every second.
#[derive(Clone, Default)]
struct Ticking(Arc<AtomicU16>);

impl tokio_modbus::server::Service for Ticking {
    type Request = SlaveRequest<'static>;
    type Response = Response;
    type Exception = ExceptionCode;
    type Future = std::future::Ready<Result<Response, ExceptionCode>>;

    fn call(&self, req: SlaveRequest<'static>) -> Self::Future {
        let tick = self.0.load(Ordering::Relaxed);
        std::future::ready(match req.request {
            Request::ReadHoldingRegisters(a, n) if usize::from(a) + usize::from(n) <= REGISTERS => {
                Ok(Response::ReadHoldingRegisters(
                    (a..a + n).map(|r| r.wrapping_add(tick)).collect(),
                ))
            }
            Request::ReadHoldingRegisters(..) => Err(ExceptionCode::IllegalDataAddress),
            _ => Err(ExceptionCode::IllegalFunction),
        })
    }
}

/// The master; killed when dropped.
struct Master {
    child: Child,
    stdin: ChildStdin,
    lines: std::io::Lines<std::io::BufReader<std::process::ChildStdout>>,
}

/// Which master measures.
#[derive(Clone, Copy, PartialEq)]
enum Kind {
    /// c104, its points as the interrogation shows them (for interrogations).
    C104,
    /// c104, its points kept in their time-tagged form (spontaneous objects counted).
    C104Tagged,
    /// `tests/iec104/wire_master.py`: the frames read off the socket, nothing more.
    Wire,
}

impl Master {
    fn connect(port: u16, kind: Kind) -> anyhow::Result<Master> {
        let script = match kind {
            Kind::Wire => "tests/iec104/wire_master.py",
            _ => "tests/iec104/master.py",
        };
        let mut child = Command::new(common::python())
            .arg(repo().join(script))
            .args(["127.0.0.1", &port.to_string()])
            .args((kind != Kind::Wire).then_some("--count"))
            .args((kind == Kind::C104Tagged).then_some("--tagged"))
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()?;
        let stdin = child.stdin.take().ok_or_else(|| anyhow::anyhow!("stdin"))?;
        let out = child
            .stdout
            .take()
            .ok_or_else(|| anyhow::anyhow!("stdout"))?;
        let mut lines = std::io::BufReader::new(out).lines();
        let ready = lines.next().ok_or_else(|| anyhow::anyhow!("ended"))??;
        anyhow::ensure!(ready == "ready", "the master said {ready}");
        Ok(Master {
            child,
            stdin,
            lines,
        })
    }

    fn ask(&mut self, line: &str) -> anyhow::Result<Vec<f64>> {
        writeln!(self.stdin, "{line}")?;
        let said = self
            .lines
            .next()
            .ok_or_else(|| anyhow::anyhow!("ended"))??;
        Ok(said
            .split_whitespace()
            .skip(1)
            .filter_map(|w| w.parse().ok())
            .collect())
    }
}

impl Drop for Master {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn gateway(modbus: u16, iec104: u16) -> anyhow::Result<common::Gateway> {
    let dir = common::temp_dir("iec104-server")?;
    let profiles = dir.join("profiles");
    std::fs::create_dir_all(&profiles)?;
    let mut profile = String::from("name: Thousand\nfields:\n");
    for r in 0..REGISTERS {
        profile.push_str(&format!(
            "  - {{ name: R{r}, type: UINT, direction: input, register: {{ address: {r}, kind: holding_register }} }}\n"
        ));
    }
    std::fs::write(profiles.join("thousand.yaml"), profile)?;
    let mut config = format!(
        "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0 }}\nprofiles: {}\nlinks:\n  - {{ name: line, tcp: {{ host: 127.0.0.1, port: {modbus} }} }}\ndevices:\n",
        profiles.display()
    );
    for k in 1..=DEVICES {
        config.push_str(&format!(
            "  - {{ name: d{k}, profile: Thousand, link: line, slave_id: {k}, refresh_rate: 1s }}\n"
        ));
    }
    config.push_str(&format!("iec104_server:\n  listen: 127.0.0.1:{iec104}\n"));
    common::start(&dir, &config)
}

fn main() -> anyhow::Result<()> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()?;
    let device = Ticking::default();
    let modbus = runtime.block_on(common::modbus_device(device.clone()))?;
    let tick = device.0.clone();
    runtime.spawn(async move {
        let mut every = tokio::time::interval(Duration::from_secs(1));
        loop {
            every.tick().await;
            tick.fetch_add(1, Ordering::Relaxed);
        }
    });
    let port = common::free_port()?;
    let gw = gateway(modbus, port)?;
    let pid = gw.child.id();
    let points = DEVICES * REGISTERS;
    let mut master = Master::connect(port, Kind::C104)?;
    // Until every field is read and served (the first interrogation answers them all).
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let gi = master.ask(&format!("gi {points}"))?;
        if gi.first().is_some_and(|ms| *ms < 60_000.0) {
            break;
        }
        anyhow::ensure!(
            Instant::now() < deadline,
            "the points were not interrogated"
        );
    }
    let mut times = Vec::new();
    for _ in 0..5 {
        times.push(master.ask(&format!("gi {points}"))?[0]);
    }
    drop(master);
    let grpc = format!("http://{}", gw.grpc);
    // c104 keeps spontaneous objects only with points of their time-tagged types.
    for (kind, who) in [
        (Kind::C104Tagged, "a c104 master"),
        (Kind::Wire, "a master that only reads the wire"),
    ] {
        let master = Master::connect(port, kind)?;
        spontaneous(&runtime, &grpc, pid, master, who)?;
    }
    times.sort_by(f64::total_cmp);
    println!(
        "IEC 104 outstation, general interrogation of {points} points to the last object at the master: {:.0} ms median of 5 (min {:.0}, max {:.0})",
        times[2], times[0], times[4]
    );
    Ok(())
}

/// Spontaneous objects to `master` for [`RUN`]: their rate and delays, and the gateway's
/// CPU, memory and device reads meanwhile.
fn spontaneous(
    runtime: &tokio::runtime::Runtime,
    grpc: &str,
    pid: u32,
    mut master: Master,
    who: &str,
) -> anyhow::Result<()> {
    let points = DEVICES * REGISTERS;
    std::thread::sleep(Duration::from_secs(3));
    master.ask("stats")?;
    let reads = || {
        runtime.block_on(async {
            let mut client = iogate_client::Client::connect(grpc).await?;
            let devices = client.devices().await?;
            anyhow::Ok(
                devices
                    .iter()
                    .map(|d| d.diagnostics.as_ref().map_or(0, |d| d.io_cycles))
                    .sum::<u64>(),
            )
        })
    };
    let (cpu0, wall, reads0) = (common::cpu_seconds(pid), Instant::now(), reads()?);
    std::thread::sleep(RUN);
    let stats = master.ask("stats")?;
    let device_reads = (reads()? - reads0) as f64;
    let elapsed = wall.elapsed().as_secs_f64();
    let cpu = (common::cpu_seconds(pid) - cpu0) / elapsed;
    let rss = common::rss_kib(pid) as f64 / 1024.0;
    let [n, p50, p99, max] = stats[..] else {
        anyhow::bail!("the master said {stats:?}");
    };
    println!(
        "IEC 104 outstation, {points} points changing every 1 s to {who}: {:.0} spontaneous objects/s, time tag to master p50 {p50:.1} ms, p99 {p99:.1} ms, max {max:.1} ms; gateway CPU {:.1} % of a core, {rss:.1} MiB resident",
        n / elapsed,
        cpu * 100.0
    );
    println!(
        "  (device reads a second: {:.1}, {DEVICES} devices every 1 s asked)",
        device_reads / elapsed
    );
    Ok(())
}

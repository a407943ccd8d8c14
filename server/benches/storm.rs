//! A line fault on a loaded machine, and what the other lines and the faulty one do after:
//! 100 devices on 4 TCP links (25 each, independent tokio-modbus slaves in this process, 10
//! registers per device, polled every 100 ms), 20 SSE clients taking every change, and
//! both cores kept busy by spinning threads; for 15 s the first link's slave stops
//! answering (each request answered only after the fault, too late), then answers again.
//! Each second: poll cycles per device per second on the faulty link and on the others,
//! fields not `good` (as an SSE client sees them), and quality changes told per second.
//! Recovery: how long after the fault clears every field is good again and polling is back
//! at its rate.
//!
//! `cargo bench -p iogate --bench storm`

use std::collections::HashMap;
use std::future::Future;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};
use tokio::net::TcpStream;
use tokio_modbus::prelude::{ExceptionCode, Request, Response, SlaveRequest};

mod common;

const LINKS: usize = 4;
const DEVICES_PER_LINK: usize = 25;
const REGISTERS: u16 = 10;
const SSE_CLIENTS: usize = 20;
const BEFORE: u64 = 10;
const FAULT: u64 = 15;
const AFTER: u64 = 20;

/// A slave answering every unit id; while `silent`, an answer waits until the fault is
/// over (so every request of the fault times out at the gateway).
#[derive(Clone)]
struct Slave {
    silent: Arc<AtomicBool>,
}

impl tokio_modbus::server::Service for Slave {
    type Request = SlaveRequest<'static>;
    type Response = Response;
    type Exception = ExceptionCode;
    type Future = Pin<Box<dyn Future<Output = Result<Response, ExceptionCode>> + Send>>;

    fn call(&self, req: SlaveRequest<'static>) -> Self::Future {
        let silent = self.silent.clone();
        Box::pin(async move {
            while silent.load(Ordering::Relaxed) {
                tokio::time::sleep(Duration::from_millis(10)).await;
            }
            match req.request {
                Request::ReadHoldingRegisters(a, n) => Ok(Response::ReadHoldingRegisters(
                    (a..a.saturating_add(n)).collect(),
                )),
                _ => Err(ExceptionCode::IllegalFunction),
            }
        })
    }
}

async fn slave(silent: Arc<AtomicBool>) -> anyhow::Result<u16> {
    common::modbus_device(Slave { silent }).await
}

/// One GET's JSON body (a new connection each time).
async fn get_json(addr: SocketAddr, path: &str) -> anyhow::Result<serde_json::Value> {
    let (_, answer) = common::http::get_once(addr, path).await?;
    let text = String::from_utf8_lossy(&answer);
    let body = text
        .split_once("\r\n\r\n")
        .map(|(_, b)| b)
        .ok_or_else(|| anyhow::anyhow!("no body"))?;
    Ok(serde_json::from_str(body)?)
}

/// What the observing SSE client saw: every field's quality, and quality changes so far.
#[derive(Default)]
struct Seen {
    quality: std::sync::Mutex<HashMap<String, String>>,
    changes: AtomicU64,
}

impl Seen {
    /// Fields whose last quality told was not good.
    fn not_good(&self) -> usize {
        let quality = self.quality.lock().unwrap_or_else(|e| e.into_inner());
        quality.values().filter(|q| *q != "good").count()
    }
}

async fn sse(addr: SocketAddr, seen: Option<Arc<Seen>>) -> anyhow::Result<()> {
    let mut stream = TcpStream::connect(addr).await?;
    stream
        .write_all(b"GET /api/v1/events HTTP/1.1\r\nHost: x\r\nAccept: text/event-stream\r\n\r\n")
        .await?;
    let mut lines = BufReader::new(stream).lines();
    while let Some(line) = lines.next_line().await? {
        let (Some(seen), Some(data)) = (&seen, line.strip_prefix("data: ")) else {
            continue;
        };
        let Ok(v) = serde_json::from_str::<serde_json::Value>(data) else {
            continue;
        };
        let (Some(device), Some(field), Some(quality)) = (
            v["device"].as_str(),
            v["field"].as_str(),
            v["quality"].as_str(),
        ) else {
            continue;
        };
        let key = format!("{device}.{field}");
        let mut q = seen.quality.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(before) = q.insert(key, quality.to_owned())
            && before != quality
        {
            seen.changes.fetch_add(1, Ordering::Relaxed);
        }
    }
    Ok(())
}

fn main() -> anyhow::Result<()> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    runtime.block_on(run())
}

async fn run() -> anyhow::Result<()> {
    let silent = Arc::new(AtomicBool::new(false));
    let mut ports = Vec::new();
    for i in 0..LINKS {
        let flag = if i == 0 {
            silent.clone()
        } else {
            Arc::new(AtomicBool::new(false))
        };
        ports.push(slave(flag).await?);
    }
    let dir = common::temp_dir("storm")?;
    let config = storm_files(&dir, &ports)?;
    let gw = common::start(&dir, &config)?;
    let addr = gw.http;
    tokio::time::sleep(Duration::from_secs(2)).await;
    let seen = Arc::new(Seen::default());
    tokio::spawn(sse(addr, Some(seen.clone())));
    for _ in 1..SSE_CLIENTS {
        tokio::spawn(sse(addr, None));
    }
    // Both cores busy besides the gateway.
    let spinning = spin_cores();
    println!(
        "{LINKS} links x {DEVICES_PER_LINK} devices x {REGISTERS} registers at 100 ms, {SSE_CLIENTS} SSE clients, 2 spinning threads; link l0's slave silent from {BEFORE} s to {} s",
        BEFORE + FAULT
    );
    println!(
        "| s | phase | cycles/s per device, l0 | cycles/s per device, others | fields not good | quality changes told |"
    );
    println!("| --- | --- | --- | --- | --- | --- |");
    let mut before = cycles(&get_json(addr, "/api/v1/devices").await?);
    let mut changes_before = seen.changes.load(Ordering::Relaxed);
    let start = Instant::now();
    let mut baseline = (0.0, 0.0);
    let mut recovered: Option<u64> = None;
    for s in 1..=(BEFORE + FAULT + AFTER) {
        if s == BEFORE + 1 {
            silent.store(true, Ordering::Relaxed);
        }
        if s == BEFORE + FAULT + 1 {
            silent.store(false, Ordering::Relaxed);
        }
        tokio::time::sleep_until((start + Duration::from_secs(s)).into()).await;
        let now = cycles(&get_json(addr, "/api/v1/devices").await?);
        let (l0, others) = (rate(&now, &before, false), rate(&now, &before, true));
        before = now;
        let not_good = seen.not_good();
        let changes = seen.changes.load(Ordering::Relaxed);
        let told = changes - changes_before;
        changes_before = changes;
        let phase = phase_of(s);
        if s == BEFORE {
            baseline = (l0, others);
        }
        if phase == "after"
            && recovered.is_none()
            && not_good == 0
            && l0 >= 0.8 * baseline.0
            && others >= 0.8 * baseline.1
        {
            recovered = Some(s - BEFORE - FAULT);
        }
        println!("| {s} | {phase} | {l0:.1} | {others:.1} | {not_good} | {told} |");
    }
    spinning.store(false, Ordering::Relaxed);
    match recovered {
        Some(s) => println!(
            "recovered {s} s after the fault cleared (every field good, polling at >= 80 % of its rate before the fault: {:.1} and {:.1} cycles/s per device)",
            baseline.0, baseline.1
        ),
        None => println!("not recovered within {AFTER} s after the fault cleared"),
    }
    drop(gw);
    Ok(())
}

/// The profile (ten registers) and the config (every link and device) in `dir`; the
/// config's text.
fn storm_files(dir: &std::path::Path, ports: &[u16]) -> anyhow::Result<String> {
    std::fs::create_dir_all(dir.join("profiles"))?;
    let mut profile = String::from("name: Ten\nfields:\n");
    for r in 0..REGISTERS {
        profile.push_str(&format!(
            "  - {{ name: R{r}, type: UINT, direction: input, register: {{ address: {r}, kind: holding_register }} }}\n"
        ));
    }
    std::fs::write(dir.join("profiles/ten.yaml"), profile)?;
    let mut config = String::from(
        "profiles: profiles\nlisten: { http: 127.0.0.1:0, grpc: 127.0.0.1:0 }\nlinks:\n",
    );
    for (i, port) in ports.iter().enumerate() {
        config.push_str(&format!(
            "  - {{ name: l{i}, tcp: {{ host: 127.0.0.1, port: {port} }} }}\n"
        ));
    }
    config.push_str("devices:\n");
    for i in 0..LINKS {
        for d in 0..DEVICES_PER_LINK {
            config.push_str(&format!(
                "  - {{ name: d{i}_{d}, profile: Ten, link: l{i}, slave_id: {}, refresh_rate: 100ms, timeout: 50ms, retries: 0 }}\n",
                d + 1
            ));
        }
    }
    Ok(config)
}

/// Two threads that keep both cores busy until the flag is cleared.
fn spin_cores() -> Arc<AtomicBool> {
    let spinning = Arc::new(AtomicBool::new(true));
    for _ in 0..2 {
        let spinning = spinning.clone();
        std::thread::spawn(move || {
            let mut x = 0u64;
            while spinning.load(Ordering::Relaxed) {
                x = x.wrapping_mul(6364136223846793005).wrapping_add(1);
                std::hint::black_box(x);
            }
        });
    }
    spinning
}

/// Each device's I/O cycles in `GET /api/v1/devices`.
fn cycles(devices: &serde_json::Value) -> HashMap<String, u64> {
    devices["devices"]
        .as_array()
        .map(|ds| {
            ds.iter()
                .filter_map(|d| Some((d["name"].as_str()?.to_owned(), d["io_cycles"].as_u64()?)))
                .collect()
        })
        .unwrap_or_default()
}

/// The phase second `s` is in.
fn phase_of(s: u64) -> &'static str {
    if s <= BEFORE {
        "before"
    } else if s <= BEFORE + FAULT {
        "fault"
    } else {
        "after"
    }
}

/// The cycles a second per device of link l0's devices (or, `other`, of the others').
fn rate(now: &HashMap<String, u64>, before: &HashMap<String, u64>, other: bool) -> f64 {
    let (sum, n) = now
        .iter()
        .filter(|(name, _)| name.starts_with("d0_") != other)
        .fold((0u64, 0u64), |(sum, n), (name, c)| {
            (
                sum + c.saturating_sub(*before.get(name).unwrap_or(c)),
                n + 1,
            )
        });
    sum as f64 / n.max(1) as f64
}

//! The gateway under hostile load, in its own process (`iogate serve`):
//!
//! 1. 18,000 idle sockets (9,000 on the HTTP listener, 9,000 on the gRPC listener) and 200
//!    clients sending their request headers one byte a second, while REST requests (each on
//!    a new connection) and gRPC calls (on a channel opened during the flood) keep being
//!    made: how many are answered, and how fast.
//! 2. 5,000 Server-Sent Events clients (at most 2,048 are served, the rest get 429) while an
//!    output changes every 50 ms; the gateway's resident memory before, with them, and 30 s
//!    after they left; twice, to show nothing is left behind each time.
//!
//! Every client comes from this machine's one address, standing for many: the per-client
//! bounds (`listen.max_connections_per_client`, `listen.max_streams_per_client`) are lifted
//! so that only the gateway-wide bounds are tried.
//!
//! `cargo bench -p iogate --bench load` (needs 20,000 file descriptors: `ulimit -n`);
//! `IOGATE_LOAD_SKIP_FLOOD=1` runs the second part only.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use tokio::io::{AsyncBufReadExt, AsyncReadExt, AsyncWriteExt, BufReader};
use tokio::net::TcpStream;

const IDLE_PER_LISTENER: usize = 9_000;
const SLOW: usize = 200;
const SSE_CLIENTS: usize = 5_000;

mod common;
use common::Gateway;

fn start() -> anyhow::Result<Gateway> {
    let dir = common::temp_dir("load")?;
    common::start(
        &dir,
        &format!(
            "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0, max_connections_per_client: 100000, max_streams_per_client: 100000 }}\nprofiles: {}\ndevices:\n  - {{ name: sim, profile: SimIo, refresh_rate: 20ms }}\n",
            common::profiles().display()
        ),
    )
}

fn open_fds(pid: u32) -> usize {
    std::fs::read_dir(format!("/proc/{pid}/fd")).map_or(0, |d| d.count())
}

fn rss_kib(pid: u32) -> u64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmRSS:"))
                .and_then(|l| l.split_whitespace().nth(1).map(str::to_owned))
        })
        .and_then(|kib| kib.parse().ok())
        .unwrap_or(0)
}

/// One HTTP/1.1 request on a new connection; the status, or None when not answered in 5 s.
async fn http(addr: SocketAddr, request: &str) -> Option<u16> {
    let exchange = async {
        let mut stream = TcpStream::connect(addr).await.ok()?;
        stream.write_all(request.as_bytes()).await.ok()?;
        let mut answer = Vec::new();
        stream.read_to_end(&mut answer).await.ok()?;
        let text = String::from_utf8_lossy(&answer);
        text.split_whitespace().nth(1)?.parse().ok()
    };
    tokio::time::timeout(Duration::from_secs(5), exchange)
        .await
        .ok()
        .flatten()
}

fn get(path: &str) -> String {
    format!("GET {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
}

async fn open_idle(addr: SocketAddr, n: usize) -> Vec<TcpStream> {
    let mut all = Vec::with_capacity(n);
    for chunk in (0..n).collect::<Vec<_>>().chunks(500) {
        let batch: Vec<_> = chunk
            .iter()
            .map(|_| tokio::spawn(TcpStream::connect(addr)))
            .collect();
        for b in batch {
            if let Ok(Ok(s)) = b.await {
                all.push(s);
            }
        }
    }
    all
}

fn percentile(sorted: &[Duration], q: f64) -> Duration {
    if sorted.is_empty() {
        return Duration::ZERO;
    }
    sorted[((sorted.len() as f64 * q) as usize).min(sorted.len() - 1)]
}

async fn answered_while_flooded(gw: &Gateway) -> anyhow::Result<()> {
    let started = Instant::now();
    let (http_addr, grpc_addr) = (gw.http, gw.grpc);
    // The flood goes on while the requests below are made.
    let flood = tokio::spawn(async move {
        let mut idle = open_idle(http_addr, IDLE_PER_LISTENER).await;
        idle.extend(open_idle(grpc_addr, IDLE_PER_LISTENER).await);
        idle
    });
    let slow: Vec<_> = (0..SLOW)
        .map(|_| tokio::spawn(slow_client(gw.http)))
        .collect();
    let mut rest = Vec::new();
    let mut rest_failed = 0;
    let channel = tonic::transport::Channel::from_shared(format!("http://{}", gw.grpc))?
        .connect_timeout(Duration::from_secs(5))
        .connect()
        .await;
    let mut grpc = Vec::new();
    let mut grpc_failed = 0;
    let mut client = channel
        .ok()
        .map(iogate_proto::pb::gateway_client::GatewayClient::new);
    let mut flood_done: Option<Instant> = None;
    let mut idle = Vec::new();
    let mut flood = Some(flood);
    loop {
        if flood_done.is_none() && flood.as_ref().is_some_and(|f| f.is_finished()) {
            if let Some(f) = flood.take() {
                idle = f.await?;
            }
            flood_done = Some(Instant::now());
            println!(
                "flood: {} idle sockets opened in {:.1} s, {SLOW} slow clients",
                idle.len(),
                started.elapsed().as_secs_f64()
            );
        }
        if flood_done.is_some_and(|t| t.elapsed() > Duration::from_secs(5)) {
            break;
        }
        let t = Instant::now();
        match http(gw.http, &get("/api/v1/devices")).await {
            Some(200) => rest.push(t.elapsed()),
            _ => rest_failed += 1,
        }
        let t = Instant::now();
        let call = match client.as_mut() {
            Some(c) => tokio::time::timeout(
                Duration::from_secs(5),
                c.list_devices(iogate_proto::pb::ListDevicesRequest::default()),
            )
            .await
            .is_ok_and(|r| r.is_ok()),
            None => false,
        };
        if call {
            grpc.push(t.elapsed());
        } else {
            grpc_failed += 1;
        }
    }
    said(
        "REST GET /api/v1/devices on new connections during the flood",
        rest,
        rest_failed,
    );
    said(
        "gRPC ListDevices on a channel opened during the flood",
        grpc,
        grpc_failed,
    );
    drop(idle);
    for s in slow {
        s.abort();
    }
    Ok(())
}

async fn sse_memory(gw: &Gateway) -> anyhow::Result<()> {
    let pid = gw.child.id();
    tokio::time::sleep(Duration::from_secs(12)).await;
    let before = rss_kib(pid);
    let mut clients = Vec::new();
    let accepted = std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let refused = std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let events = std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(0));
    for _ in 0..SSE_CLIENTS {
        let (addr, accepted, refused, events) =
            (gw.http, accepted.clone(), refused.clone(), events.clone());
        clients.push(tokio::spawn(sse_client(addr, accepted, refused, events)));
    }
    // Changes for every stream: an output toggled every 50 ms for 10 s.
    let mut peak = 0;
    for i in 0..200 {
        let body = format!("{{\"value\": {}}}", i % 2 == 0);
        let request = format!(
            "PUT /api/v1/devices/sim/fields/DO_0 HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
            body.len()
        );
        let _ = http(gw.http, &request).await;
        tokio::time::sleep(Duration::from_millis(50)).await;
        peak = peak.max(rss_kib(pid));
    }
    println!(
        "SSE: {} streams served, {} refused (429), {} events received",
        accepted.load(std::sync::atomic::Ordering::Relaxed),
        refused.load(std::sync::atomic::Ordering::Relaxed),
        events.load(std::sync::atomic::Ordering::Relaxed)
    );
    for c in &clients {
        c.abort();
    }
    for c in clients {
        let _ = c.await;
    }
    let left = Instant::now();
    let after = settle(pid).await;
    println!(
        "resident memory: {} KiB before, {} KiB peak with the streams, {} KiB {:.0} s after they left ({:.2} of before)",
        before,
        peak,
        after,
        left.elapsed().as_secs_f64(),
        after as f64 / before.max(1) as f64
    );
    Ok(())
}

/// A client that sends its request one byte a second.
async fn slow_client(addr: std::net::SocketAddr) {
    let Ok(mut s) = TcpStream::connect(addr).await else {
        return;
    };
    for b in get("/livez").bytes() {
        if s.write_all(&[b]).await.is_err() {
            return;
        }
        tokio::time::sleep(Duration::from_secs(1)).await;
    }
}

/// How many of `what` were answered, how many not, and their p50 and p99.
fn said(what: &str, mut times: Vec<Duration>, failed: usize) {
    times.sort();
    println!(
        "{what}: {} answered, {failed} not; p50 {:.2} ms, p99 {:.2} ms",
        times.len(),
        percentile(&times, 0.5).as_secs_f64() * 1e3,
        percentile(&times, 0.99).as_secs_f64() * 1e3
    );
}

type Count = std::sync::Arc<std::sync::atomic::AtomicUsize>;

/// One SSE client: counted as accepted or refused (429), then its events counted.
async fn sse_client(addr: std::net::SocketAddr, accepted: Count, refused: Count, events: Count) {
    let Ok(mut s) = TcpStream::connect(addr).await else {
        return;
    };
    let request =
        "GET /api/v1/events?device=sim HTTP/1.1\r\nHost: x\r\nAccept: text/event-stream\r\n\r\n";
    if s.write_all(request.as_bytes()).await.is_err() {
        return;
    }
    let mut reader = BufReader::new(s);
    let mut status = String::new();
    if reader.read_line(&mut status).await.is_err() {
        return;
    }
    if status.contains(" 200") {
        accepted.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    } else if status.contains(" 429") {
        refused.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        return;
    } else {
        eprintln!("SSE answered: {}", status.trim());
        return;
    }
    let mut buf = vec![0u8; 4096];
    while let Ok(n) = reader.read(&mut buf).await {
        if n == 0 {
            break;
        }
        let seen = buf[..n].windows(6).filter(|w| w == b"event:").count();
        events.fetch_add(seen, std::sync::atomic::Ordering::Relaxed);
    }
}

/// The resident memory over the 30 s after the streams left, said every 5 s with the open
/// files; the last.
async fn settle(pid: u32) -> u64 {
    let mut after = 0;
    for i in 0..30 {
        tokio::time::sleep(Duration::from_secs(1)).await;
        after = rss_kib(pid);
        if i % 5 == 4 {
            println!(
                "  {:>2} s after: {after} KiB, {} open files",
                i + 1,
                open_fds(pid)
            );
        }
    }
    after
}

fn main() -> anyhow::Result<()> {
    let runtime = tokio::runtime::Runtime::new()?;
    runtime.block_on(async {
        let gw = start()?;
        let pid = gw.child.id();
        let ready = Instant::now() + Duration::from_secs(10);
        while http(gw.http, &get("/readyz")).await != Some(200) {
            anyhow::ensure!(Instant::now() < ready, "the gateway did not get ready");
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        println!("iogate {} resident at start: {} KiB", pid, rss_kib(pid));
        if std::env::var("IOGATE_LOAD_SKIP_FLOOD").is_err() {
            answered_while_flooded(&gw).await?;
            println!("resident after the flood: {} KiB", rss_kib(pid));
        }
        // Twice: the second round shows whether anything is left behind each time.
        for round in 1..=2 {
            println!("SSE round {round}:");
            sse_memory(&gw).await?;
        }
        Ok(())
    })
}

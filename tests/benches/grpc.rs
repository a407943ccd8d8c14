//! gRPC fan-out and read throughput. Run with `cargo bench -p iogate-tests --bench grpc`;
//! it prints figures rather than asserting them.
//!
//! 1. Fan-out: 1,000 concurrent subscribers to one field of a simulated device polled every
//!    millisecond; the field is toggled 100 times and each change is timed until every
//!    subscriber has it.
//! 2. Unary reads: concurrent clients reading one field as fast as they can.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use futures_util::StreamExt;
use iogate_client::{Client, DeviceDeclaration, Selection, Update, Value};

const SUBSCRIBERS: usize = 1000;
const CHANGES: usize = 100;
const CHANNELS: usize = 10;

fn rss_kib() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmRSS:"))
                .and_then(|l| l.split_whitespace().nth(1).and_then(|n| n.parse().ok()))
        })
        .unwrap_or(0)
}

fn percentile(sorted: &[Duration], p: f64) -> Duration {
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

async fn fan_out(url: &str) -> anyhow::Result<()> {
    let mut client = Client::connect(url).await?;
    client
        .ensure_device(&DeviceDeclaration {
            name: "fan".into(),
            profile: "SimIo".into(),
            link: String::new(),
            slave_id: 0,
            refresh_rate: Duration::from_millis(1),
        })
        .await?;
    let rss_before = rss_kib();
    // received[i]: how many subscribers have seen change i.
    let received: Arc<Vec<AtomicUsize>> =
        Arc::new((0..CHANGES).map(|_| AtomicUsize::new(0)).collect());
    let ready = Arc::new(AtomicUsize::new(0));
    let mut channels = Vec::new();
    for _ in 0..CHANNELS {
        channels.push(Client::connect(url).await?);
    }
    let mut tasks = Vec::new();
    for n in 0..SUBSCRIBERS {
        let mut c = channels[n % CHANNELS].clone();
        let received = received.clone();
        let ready = ready.clone();
        tasks.push(tokio::spawn(async move {
            let mut updates = c.subscribe(&Selection::field("fan", "DO_0"), false).await?;
            ready.fetch_add(1, Ordering::Relaxed);
            let mut next = 0;
            while let Some(update) = updates.next().await {
                if let Update::Value(v) = update? {
                    // Change i sets DO_0 to (i is even); the first value is the current one.
                    let want = Value::Bool(next % 2 == 0);
                    if v.value == Some(want) {
                        received[next].fetch_add(1, Ordering::Relaxed);
                        next += 1;
                        if next == CHANGES {
                            break;
                        }
                    }
                }
            }
            anyhow::Ok(())
        }));
    }
    while ready.load(Ordering::Relaxed) < SUBSCRIBERS {
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    tokio::time::sleep(Duration::from_millis(200)).await;
    let rss_subscribed = rss_kib();
    let mut latencies = Vec::with_capacity(CHANGES);
    let started = Instant::now();
    for i in 0..CHANGES {
        let t0 = Instant::now();
        client.write("fan", "DO_0", Value::Bool(i % 2 == 0)).await?;
        while received[i].load(Ordering::Relaxed) < SUBSCRIBERS {
            tokio::task::yield_now().await;
            if t0.elapsed() > Duration::from_secs(10) {
                anyhow::bail!(
                    "change {i} reached {} subscribers",
                    received[i].load(Ordering::Relaxed)
                );
            }
        }
        latencies.push(t0.elapsed());
    }
    let total = started.elapsed();
    for t in tasks {
        t.await??;
    }
    latencies.sort();
    println!(
        "fan-out to {SUBSCRIBERS} subscribers ({CHANNELS} connections), {CHANGES} changes: write to last delivery median {:.1} ms, p99 {:.1} ms, max {:.1} ms",
        percentile(&latencies, 0.5).as_secs_f64() * 1e3,
        percentile(&latencies, 0.99).as_secs_f64() * 1e3,
        latencies[latencies.len() - 1].as_secs_f64() * 1e3
    );
    println!(
        "  {:.0} updates delivered per second; gateway and clients together: {} MiB resident before, {} MiB with {SUBSCRIBERS} subscribers",
        (SUBSCRIBERS * CHANGES) as f64 / total.as_secs_f64(),
        rss_before / 1024,
        rss_subscribed / 1024
    );
    println!("  (each change also waits up to 1 ms for the simulated device's next cycle)");
    Ok(())
}

async fn unary_reads(url: &str) -> anyhow::Result<()> {
    for clients in [1usize, 8, 32] {
        let count = Arc::new(AtomicU64::new(0));
        let deadline = Instant::now() + Duration::from_secs(3);
        let mut tasks = Vec::new();
        for _ in 0..clients {
            let mut c = Client::connect(url).await?;
            let count = count.clone();
            tasks.push(tokio::spawn(async move {
                while Instant::now() < deadline {
                    c.get("plant", "Level").await?;
                    count.fetch_add(1, Ordering::Relaxed);
                }
                anyhow::Ok(())
            }));
        }
        for t in tasks {
            t.await??;
        }
        let n = count.load(Ordering::Relaxed);
        println!(
            "unary Read of one field, {clients:>2} concurrent clients: {:>8.0} reads/s",
            n as f64 / 3.0
        );
    }
    Ok(())
}

fn main() -> anyhow::Result<()> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    runtime.block_on(async {
        let mut setup = iogate::app::Setup::demo().map_err(|p| anyhow::anyhow!("{p}"))?;
        setup.config.http = "127.0.0.1:0".parse()?;
        setup.config.grpc = "127.0.0.1:0".parse()?;
        if let Some(server) = setup.config.modbus_server.as_mut() {
            server.listen = "127.0.0.1:0".parse()?;
        }
        let running = iogate::app::start(setup).await?;
        let url = format!("http://{}", running.grpc_addr);
        println!("gateway and clients share one process and 2 cores");
        fan_out(&url).await?;
        unary_reads(&url).await?;
        running.shutdown().await;
        anyhow::Ok(())
    })
}

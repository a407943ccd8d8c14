//! Fan-out: subscribers of one field over gRPC `Subscribe` or SSE, a change every 100 ms,
//! timed from the write to the last subscriber having it.

use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use futures_util::StreamExt;
use iogate_client::{Client, Selection, Update, Value};
use tokio::io::{AsyncReadExt, AsyncWriteExt};

use super::common::{self, Row};

const CHANGES: usize = 100;

/// How subscribers follow the field.
#[derive(Clone, Copy, PartialEq)]
pub(crate) enum Front {
    /// gRPC `Subscribe`, this many subscribers a channel (HTTP/2 connection).
    Grpc { per_channel: usize },
    /// `GET /api/v1/events`, one HTTP/1.1 connection each.
    Sse,
}

/// Counts, for each change, the subscribers that have it; the last one wakes the writer.
struct Tally {
    received: Vec<AtomicUsize>,
    subscribers: usize,
    ready: AtomicUsize,
    all_seen: tokio::sync::Notify,
}

impl Tally {
    /// A subscriber has change `n`.
    fn seen(&self, n: usize) {
        if self.received[n].fetch_add(1, Ordering::Relaxed) + 1 == self.subscribers {
            self.all_seen.notify_one();
        }
    }
}

/// One SSE subscriber: a raw HTTP/1.1 request, the events' `"value":` read from the bytes
/// (each event is one line of JSON inside one chunk).
async fn sse_subscriber(addr: std::net::SocketAddr, tally: Arc<Tally>) -> anyhow::Result<()> {
    let mut socket = tokio::net::TcpStream::connect(addr).await?;
    socket
        .write_all(b"GET /api/v1/events?device=fan HTTP/1.1\r\nhost: bench\r\n\r\n")
        .await?;
    tally.ready.fetch_add(1, Ordering::Relaxed);
    let mut text: Vec<u8> = Vec::with_capacity(4096);
    let mut chunk = [0u8; 4096];
    let mut next = 0;
    let want = |n: usize| {
        if n % 2 == 1 {
            &b"\"direction\":\"output\",\"value\":true,"[..]
        } else {
            &b"\"direction\":\"output\",\"value\":false,"[..]
        }
    };
    loop {
        let n = socket.read(&mut chunk).await?;
        anyhow::ensure!(n > 0, "the event stream ended");
        text.extend_from_slice(&chunk[..n]);
        // Whole events only: up to the last blank line.
        let Some(end) = text.windows(2).rposition(|w| w == b"\n\n") else {
            continue;
        };
        for event in text[..end].split(|&b| b == b'\n') {
            let has = |needle: &[u8]| event.windows(needle.len()).any(|w| w == needle);
            if event.starts_with(b"data: ") && has(b"\"field\":\"DO_0\"") && has(want(next)) {
                tally.seen(next);
                next += 1;
                if next == CHANGES {
                    return Ok(());
                }
            }
        }
        text.drain(..end + 2);
    }
}

/// Fan-out: `subscribers` follow one field of a simulated device; a change every 100 ms,
/// timed from the write to the last subscriber having it. Answers the row, and the gateway's
/// CPU per change.
pub(crate) async fn fan_out(front: Front, subscribers: usize) -> anyhow::Result<Row> {
    let dir = common::temp_dir("suite-fan")?;
    let gateway = common::start(
        &dir,
        &format!(
            "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0, max_streams: {}, max_connections_per_client: 100000, max_streams_per_client: 100000 }}\nprofiles: {}\ndevices:\n  - {{ name: fan, profile: SimIo, refresh_rate: 1ms }}\n",
            subscribers + 16,
            common::profiles().display()
        ),
    )?;
    let url = format!("http://{}", gateway.grpc);
    let mut client = Client::connect(&url).await?;
    let tally = Arc::new(Tally {
        received: (0..CHANGES).map(|_| AtomicUsize::new(0)).collect(),
        subscribers,
        ready: AtomicUsize::new(0),
        all_seen: tokio::sync::Notify::new(),
    });
    // Start from a known value: change i sets DO_0 to (i is odd), so change 0 is `false`.
    client.write("fan", "DO_0", Value::Bool(true)).await?;
    tokio::time::sleep(Duration::from_millis(100)).await;
    let rss_before = common::rss_kib(gateway.child.id());
    let tasks = subscribe(front, subscribers, &url, gateway.http, &tally).await?;
    while tally.ready.load(Ordering::Relaxed) < subscribers {
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    // Every subscriber has had the current value (false, or true: the first change waits
    // for `false`) once the streams are quiet.
    tokio::time::sleep(Duration::from_millis(300 + subscribers as u64 / 10)).await;
    let rss_with = common::rss_kib(gateway.child.id());
    let idle = common::cpu_seconds(gateway.child.id());
    tokio::time::sleep(Duration::from_secs(1)).await;
    let idle = common::cpu_seconds(gateway.child.id()) - idle;
    let mut latencies = Vec::with_capacity(CHANGES);
    let mut next_change = Instant::now();
    let gateway_cpu = common::cpu_seconds(gateway.child.id());
    let clients_cpu = common::cpu_seconds(std::process::id());
    for (i, seen) in tally.received.iter().enumerate() {
        tokio::time::sleep_until(next_change.into()).await;
        next_change += Duration::from_millis(100);
        let t0 = Instant::now();
        client.write("fan", "DO_0", Value::Bool(i % 2 == 1)).await?;
        // The last subscriber to see the change wakes this task (no polling, which would
        // take a core from the clients and the gateway).
        if tokio::time::timeout(Duration::from_secs(10), tally.all_seen.notified())
            .await
            .is_err()
        {
            anyhow::bail!(
                "change {i} reached {} subscribers",
                seen.load(Ordering::Relaxed)
            );
        }
        latencies.push(t0.elapsed());
    }
    // Less what the gateway spends without changes (the simulated device's 1 ms cycles, the
    // subscribers' keep-alives) over the same time.
    let gateway_cpu =
        common::cpu_seconds(gateway.child.id()) - gateway_cpu - idle * (CHANGES as f64 / 10.0);
    let clients_cpu = common::cpu_seconds(std::process::id()) - clients_cpu;
    for t in tasks {
        t.await??;
    }
    Ok(row(
        front,
        subscribers,
        latencies,
        gateway_cpu,
        clients_cpu,
        (rss_before, rss_with),
    ))
}

/// Starts `subscribers` subscribers of `front`; each counts the changes it sees in `tally`.
async fn subscribe(
    front: Front,
    subscribers: usize,
    url: &str,
    http: std::net::SocketAddr,
    tally: &Arc<Tally>,
) -> anyhow::Result<Vec<tokio::task::JoinHandle<anyhow::Result<()>>>> {
    let mut tasks = Vec::new();
    match front {
        Front::Grpc { per_channel } => {
            let mut channels = Vec::new();
            for _ in 0..subscribers.div_ceil(per_channel) {
                channels.push(Client::connect(url).await?);
            }
            for n in 0..subscribers {
                let mut c = channels[n / per_channel].clone();
                let tally = tally.clone();
                tasks.push(tokio::spawn(async move {
                    let mut updates = c.subscribe(&Selection::field("fan", "DO_0"), false).await?;
                    tally.ready.fetch_add(1, Ordering::Relaxed);
                    let mut next = 0;
                    while let Some(update) = updates.next().await {
                        if let Update::Value(v) = update?
                            && v.value == Some(Value::Bool(next % 2 == 1))
                        {
                            tally.seen(next);
                            next += 1;
                            if next == CHANGES {
                                break;
                            }
                        }
                    }
                    anyhow::Ok(())
                }));
            }
        }
        Front::Sse => {
            for _ in 0..subscribers {
                tasks.push(tokio::spawn(sse_subscriber(http, tally.clone())));
            }
        }
    }
    Ok(tasks)
}

/// The fan-out's row: latencies from the write to the last subscriber, CPU a change, the
/// resident memory a subscriber.
fn row(
    front: Front,
    subscribers: usize,
    mut latencies: Vec<Duration>,
    gateway_cpu: f64,
    clients_cpu: f64,
    (rss_before, rss_with): (u64, u64),
) -> Row {
    latencies.sort();
    let pick = |q: f64| latencies[((latencies.len() - 1) as f64 * q).round() as usize];
    let (p50, p99) = (pick(0.5), pick(0.99));
    let (name, goal_ms) = match (front, subscribers) {
        (Front::Grpc { .. }, n) if n <= 1000 => ("gRPC", 5.0),
        (Front::Grpc { .. }, _) => ("gRPC", 50.0),
        (Front::Sse, n) if n <= 1000 => ("SSE", 5.0),
        (Front::Sse, _) => ("SSE", 50.0),
    };
    let gateway_ms = gateway_cpu * 1e3 / CHANGES as f64;
    let per_subscriber_kib = rss_with.saturating_sub(rss_before) as f64 / subscribers as f64;
    println!(
        "fan-out to {subscribers} {name} subscribers, a change every 100 ms: p50 {:.1} ms, p99 {:.1} ms; CPU per change: gateway {gateway_ms:.2} ms ({:.2} us a subscriber), clients {:.1} ms; gateway resident {} -> {} KiB ({per_subscriber_kib:.1} KiB a subscriber)",
        p50.as_secs_f64() * 1e3,
        p99.as_secs_f64() * 1e3,
        gateway_ms * 1e3 / subscribers as f64,
        clients_cpu * 1e3 / CHANGES as f64,
        rss_before,
        rss_with,
    );
    Row {
        measure: format!(
            "{subscribers} {name} subscribers, write to last delivery p99 (ms); gateway CPU a change"
        ),
        iogate: format!(
            "{:.1} (p50 {:.1}); {gateway_ms:.1} ms",
            p99.as_secs_f64() * 1e3,
            p50.as_secs_f64() * 1e3
        ),
        peer: format!("goal {goal_ms}"),
        ratio: p99.as_secs_f64() * 1e3 / goal_ms,
        goal: "< 1.00".into(),
    }
}

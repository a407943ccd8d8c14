//! What the MQTT benchmark watches: each JSON message's `timestamp` (when the gateway read
//! the value) against the moment the message was seen, at two places: as the gateway's
//! bytes come out of its socket (a relay between the gateway and the broker: the gateway's
//! own part, a value read to its PUBLISH written) and at a subscriber not written by us
//! (Mosquitto's `mosquitto_sub`, end to end). Timestamps carry milliseconds, so each latency
//! is up to 1 ms more than the true one.

use std::process::Stdio;
use std::sync::{Arc, Mutex};
use std::time::SystemTime;

use tokio::io::{AsyncBufReadExt, AsyncReadExt, AsyncWriteExt, BufReader};
use tokio::net::{TcpListener, TcpStream};

const KEY: &[u8] = b"\"timestamp\":\"";

/// Latencies in ms, kept until taken.
#[derive(Clone, Default)]
pub struct Latencies(Arc<Mutex<Vec<f64>>>);

impl Latencies {
    fn add(&self, taken: &mut Vec<f64>) {
        self.0
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .append(taken);
    }

    /// What was seen since the last take.
    pub fn take(&self) -> Vec<f64> {
        std::mem::take(&mut *self.0.lock().unwrap_or_else(|e| e.into_inner()))
    }
}

/// Count, p50, p99 and max of `v` (ms).
pub fn summary(mut v: Vec<f64>) -> (usize, f64, f64, f64) {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    let pick = |q: f64| {
        v.get(((q * n as f64) as usize).min(n.saturating_sub(1)))
            .copied()
    };
    (
        n,
        pick(0.5).unwrap_or(0.0),
        pick(0.99).unwrap_or(0.0),
        v.last().copied().unwrap_or(0.0),
    )
}

/// Every whole `"timestamp":"…"` in `buf`, as a latency from it to `now`; how much of
/// `buf` was looked at (a timestamp cut by the end of the buffer is left for the next read).
fn stamps(buf: &[u8], now: SystemTime, out: &mut Vec<f64>) -> usize {
    let mut at = 0;
    while let Some(k) = find(&buf[at..], KEY) {
        let start = at + k + KEY.len();
        let Some(len) = buf[start..].iter().position(|&b| b == b'"') else {
            return at + k;
        };
        let text = std::str::from_utf8(&buf[start..start + len]).unwrap_or("");
        if let Ok(t) = humantime::parse_rfc3339(text)
            && let Ok(d) = now.duration_since(t)
        {
            out.push(d.as_secs_f64() * 1000.0);
        }
        at = start + len;
    }
    at.max(buf.len().saturating_sub(KEY.len()))
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

/// A relay on a free loopback port to the broker at `broker`: every connection made to it
/// is one to the broker (closed when the broker's is), and the gateway's bytes are looked
/// at as they arrive. It runs on a thread of its own, so that the rest of the benchmark's
/// work (its devices, the subscriber's lines) does not delay what it sees.
pub fn relay(broker: u16) -> anyhow::Result<(u16, Latencies)> {
    let listener = std::net::TcpListener::bind("127.0.0.1:0")?;
    listener.set_nonblocking(true)?;
    let port = listener.local_addr()?.port();
    let seen = Latencies::default();
    let kept = seen.clone();
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    std::thread::spawn(move || {
        runtime.block_on(async move {
            let Ok(listener) = TcpListener::from_std(listener) else {
                return;
            };
            while let Ok((gateway, _)) = listener.accept().await {
                let seen = kept.clone();
                tokio::spawn(async move {
                    if let Ok(upstream) = TcpStream::connect(("127.0.0.1", broker)).await {
                        let _ = gateway.set_nodelay(true);
                        let _ = upstream.set_nodelay(true);
                        pass(gateway, upstream, seen).await;
                    }
                });
            }
        })
    });
    Ok((port, seen))
}

async fn pass(gateway: TcpStream, broker: TcpStream, seen: Latencies) {
    let (mut g_in, mut g_out) = gateway.into_split();
    let (mut b_in, mut b_out) = broker.into_split();
    let down = tokio::io::copy(&mut b_in, &mut g_out);
    let up = async {
        let mut buf = vec![0u8; 1 << 16];
        let mut pending: Vec<u8> = Vec::new();
        let mut taken = Vec::new();
        loop {
            let n = match g_in.read(&mut buf).await {
                Ok(0) | Err(_) => return,
                Ok(n) => n,
            };
            let now = SystemTime::now();
            if b_out.write_all(&buf[..n]).await.is_err() {
                return;
            }
            pending.extend_from_slice(&buf[..n]);
            let used = stamps(&pending, now, &mut taken);
            pending.drain(..used);
            seen.add(&mut taken);
        }
    };
    tokio::select! {
        _ = down => {}
        _ = up => {}
    }
}

/// `mosquitto_sub` subscribed to `filter` at QoS 0, each message stamped on arrival.
pub async fn subscriber(
    port: u16,
    filter: &str,
) -> anyhow::Result<(tokio::process::Child, Latencies)> {
    let mut child = tokio::process::Command::new("mosquitto_sub")
        .args(["-h", "127.0.0.1", "-p", &port.to_string(), "-q", "0"])
        .args(["-t", filter, "-F", "%U %p"])
        .stdout(Stdio::piped())
        .kill_on_drop(true)
        .spawn()?;
    let out = child
        .stdout
        .take()
        .ok_or_else(|| anyhow::anyhow!("mosquitto_sub: no stdout"))?;
    let seen = Latencies::default();
    let kept = seen.clone();
    tokio::spawn(async move {
        let mut lines = BufReader::new(out).lines();
        while let Ok(Some(line)) = lines.next_line().await {
            let Some((at, payload)) = line.split_once(' ') else {
                continue;
            };
            let Ok(at) = at.parse::<f64>() else { continue };
            let now = SystemTime::UNIX_EPOCH + std::time::Duration::from_secs_f64(at);
            let mut taken = Vec::new();
            stamps(payload.as_bytes(), now, &mut taken);
            kept.add(&mut taken);
        }
    });
    Ok((child, seen))
}

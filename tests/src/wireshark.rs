//! Wireshark's dissectors as an independent judge of the gateway's bytes: a TCP proxy that
//! records both directions of every connection through it in the order they passed, the
//! recording written as a capture file (raw IPv4, a TCP handshake and then every chunk
//! as a segment with its sequence and acknowledgement numbers, the server's end on the
//! protocol's port so that tshark's dissector takes it), and tshark's verdict on it: what
//! it decoded, and every malformed packet or expert warning it found. tshark comes from
//! Debian (`tests/wireshark/install.sh`).

use std::sync::{Arc, Mutex};

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::task::AbortHandle;

use crate::run_installer;

/// Which end sent a chunk.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum From {
    Client,
    Server,
}

/// One connection: its chunks, in the order they passed.
pub type Conversation = Vec<(From, Vec<u8>)>;

/// A recording proxy to `127.0.0.1:<upstream>`.
pub struct Recorder {
    pub port: u16,
    conversations: Arc<Mutex<Vec<Arc<Mutex<Conversation>>>>>,
    task: AbortHandle,
}

impl Drop for Recorder {
    fn drop(&mut self) {
        self.task.abort();
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

impl Recorder {
    pub async fn to(upstream: u16) -> anyhow::Result<Recorder> {
        let listener = TcpListener::bind("127.0.0.1:0").await?;
        let port = listener.local_addr()?.port();
        let conversations: Arc<Mutex<Vec<Arc<Mutex<Conversation>>>>> = Arc::default();
        let all = conversations.clone();
        let task = tokio::spawn(async move {
            while let Ok((client, _)) = listener.accept().await {
                let Ok(server) = TcpStream::connect(("127.0.0.1", upstream)).await else {
                    continue;
                };
                let log: Arc<Mutex<Conversation>> = Arc::default();
                lock(&all).push(log.clone());
                let (c_rx, c_tx) = client.into_split();
                let (s_rx, s_tx) = server.into_split();
                tokio::spawn(copy(c_rx, s_tx, From::Client, log.clone()));
                tokio::spawn(copy(s_rx, c_tx, From::Server, log));
            }
        })
        .abort_handle();
        Ok(Recorder {
            port,
            conversations,
            task,
        })
    }

    /// Every connection's chunks so far.
    pub fn conversations(&self) -> Vec<Conversation> {
        lock(&self.conversations)
            .iter()
            .map(|c| lock(c).clone())
            .collect()
    }
}

async fn copy(
    mut from: tokio::net::tcp::OwnedReadHalf,
    mut to: tokio::net::tcp::OwnedWriteHalf,
    side: From,
    log: Arc<Mutex<Conversation>>,
) {
    let mut buf = vec![0u8; 16 * 1024];
    while let Ok(n) = from.read(&mut buf).await {
        if n == 0 {
            break;
        }
        // Recorded before it is passed on: the order is the order of the protocol.
        lock(&log).push((side, buf[..n].to_vec()));
        if to.write_all(&buf[..n]).await.is_err() {
            break;
        }
    }
    let _ = to.shutdown().await;
}

const CLIENT: [u8; 4] = [10, 0, 0, 1];
const SERVER: [u8; 4] = [10, 0, 0, 2];

/// A capture file (pcap, LINKTYPE_RAW) of the conversations, the server on `port`, each
/// conversation from its own client port.
pub fn pcap(conversations: &[Conversation], port: u16) -> Vec<u8> {
    let mut out = Vec::new();
    // Magic, version 2.4, zone, accuracy, snap length, LINKTYPE_RAW (101).
    out.extend_from_slice(&0xa1b2_c3d4u32.to_le_bytes());
    out.extend_from_slice(&2u16.to_le_bytes());
    out.extend_from_slice(&4u16.to_le_bytes());
    out.extend_from_slice(&[0; 8]);
    out.extend_from_slice(&262_144u32.to_le_bytes());
    out.extend_from_slice(&101u32.to_le_bytes());
    let mut time = 1_700_000_000u64 * 1_000_000;
    for (n, conversation) in conversations.iter().enumerate() {
        let client_port = 40_000 + n as u16;
        let mut tcp = Tcp {
            client: (client_port, 1_000),
            server: (port, 9_000),
        };
        let handshake = [
            (From::Client, 0x02u8),
            (From::Server, 0x12),
            (From::Client, 0x10),
        ];
        for (side, flags) in handshake {
            time += 100;
            record(&mut out, time, &tcp.segment(side, flags, &[]));
            if flags & 0x02 != 0 {
                tcp.advance(side, 1);
            }
        }
        for (side, bytes) in conversation {
            for part in bytes.chunks(60_000) {
                time += 100;
                record(&mut out, time, &tcp.segment(*side, 0x18, part));
                tcp.advance(*side, part.len());
            }
        }
    }
    out
}

/// The two ends' ports and next sequence numbers.
struct Tcp {
    client: (u16, u32),
    server: (u16, u32),
}

impl Tcp {
    fn advance(&mut self, side: From, by: usize) {
        let end = match side {
            From::Client => &mut self.client,
            From::Server => &mut self.server,
        };
        end.1 = end.1.wrapping_add(by as u32);
    }

    /// An IPv4 packet of one TCP segment from `side`, acknowledging all of the other's.
    fn segment(&self, side: From, flags: u8, payload: &[u8]) -> Vec<u8> {
        let (from, to, src, dst) = match side {
            From::Client => (self.client, self.server, CLIENT, SERVER),
            From::Server => (self.server, self.client, SERVER, CLIENT),
        };
        let total = (40 + payload.len()) as u16;
        let mut p = Vec::with_capacity(usize::from(total));
        p.extend_from_slice(&[0x45, 0]);
        p.extend_from_slice(&total.to_be_bytes());
        p.extend_from_slice(&[0, 0, 0x40, 0, 64, 6, 0, 0]);
        p.extend_from_slice(&src);
        p.extend_from_slice(&dst);
        let sum = checksum(&p[..20]);
        p[10..12].copy_from_slice(&sum.to_be_bytes());
        p.extend_from_slice(&from.0.to_be_bytes());
        p.extend_from_slice(&to.0.to_be_bytes());
        p.extend_from_slice(&from.1.to_be_bytes());
        let ack = if flags & 0x10 != 0 { to.1 } else { 0 };
        p.extend_from_slice(&ack.to_be_bytes());
        p.extend_from_slice(&[0x50, flags, 0xff, 0xff, 0, 0, 0, 0]);
        p.extend_from_slice(payload);
        p
    }
}

fn checksum(header: &[u8]) -> u16 {
    let mut sum: u32 = header
        .chunks(2)
        .map(|w| u32::from(u16::from_be_bytes([w[0], w[1]])))
        .sum();
    while sum > 0xffff {
        sum = (sum & 0xffff) + (sum >> 16);
    }
    !(sum as u16)
}

fn record(out: &mut Vec<u8>, micros: u64, packet: &[u8]) {
    out.extend_from_slice(&((micros / 1_000_000) as u32).to_le_bytes());
    out.extend_from_slice(&((micros % 1_000_000) as u32).to_le_bytes());
    out.extend_from_slice(&(packet.len() as u32).to_le_bytes());
    out.extend_from_slice(&(packet.len() as u32).to_le_bytes());
    out.extend_from_slice(packet);
}

/// What tshark made of a capture.
#[derive(Debug)]
pub struct Verdict {
    /// Each packet's values of the field asked for, in order (one line a packet).
    pub decoded: Vec<String>,
    /// Every packet tshark found malformed or warned about: its number and messages.
    pub problems: Vec<String>,
}

/// tshark's reading of `capture`, the TCP port `port` decoded as `protocol`, with the
/// values of `field` of each packet that has it.
pub async fn dissect(
    capture: &[u8],
    port: u16,
    protocol: &str,
    field: &str,
) -> anyhow::Result<Verdict> {
    run_installer("wireshark/install.sh")?;
    let file = std::env::temp_dir().join(format!(
        "iogate-capture-{}-{}.pcap",
        std::process::id(),
        rand_suffix()
    ));
    std::fs::write(&file, capture)?;
    let decode = format!("tcp.port=={port},{protocol}");
    let run = |filter: &str, fields: &[&str]| {
        let mut c = tokio::process::Command::new("tshark");
        c.args(["-n", "-r"]).arg(&file);
        c.args(["-d", &decode, "-Y", filter, "-T", "fields"]);
        for f in fields {
            c.args(["-e", f]);
        }
        c.kill_on_drop(true);
        c.output()
    };
    let decoded = run(field, &[field]).await?;
    anyhow::ensure!(
        decoded.status.success(),
        "tshark: {}",
        String::from_utf8_lossy(&decoded.stderr)
    );
    let problems = run(
        "_ws.malformed || _ws.expert.severity >= 0x00600000",
        &["frame.number", "_ws.expert.message", "_ws.col.Info"],
    )
    .await?;
    let _ = std::fs::remove_file(&file);
    let lines = |b: &[u8]| -> Vec<String> {
        String::from_utf8_lossy(b)
            .lines()
            .map(str::to_owned)
            .collect()
    };
    Ok(Verdict {
        decoded: lines(&decoded.stdout),
        problems: lines(&problems.stdout),
    })
}

fn rand_suffix() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The judge can say no: an APDU whose length runs past its ASDU is found malformed.
    #[tokio::test]
    async fn a_malformed_apdu_is_found() -> anyhow::Result<()> {
        // STARTDT act, then an I-frame of an M_ME_NC_1 that says it has five objects and
        // carries one.
        let good = vec![0x68, 4, 0x07, 0, 0, 0];
        let mut bad = vec![0x68, 18, 0, 0, 0, 0, 13, 5, 3, 0, 1, 0, 1, 0, 0];
        bad.extend_from_slice(&[0, 0, 0x48, 0x41, 0]);
        let conversation = vec![(From::Client, good), (From::Client, bad)];
        let verdict = dissect(
            &pcap(&[conversation], 2404),
            2404,
            "iec60870_104",
            "iec60870_104.apdulen",
        )
        .await?;
        assert!(!verdict.decoded.is_empty(), "{verdict:?}");
        assert!(!verdict.problems.is_empty(), "{verdict:?}");
        Ok(())
    }
}

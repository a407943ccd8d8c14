//! A TCP tap between a client and its server: it forwards both ways, records when each
//! connection opened and closed and what the client sent on it (for a Modbus slave's write
//! log by connection), and can cut the network without closing anything (a partition:
//! the bytes go nowhere, both ends think the connection is up) and restore it (the cut
//! connections are closed then, as a real network's would have timed out; new ones pass).

use std::sync::{Arc, Mutex};
use std::time::Instant;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::watch;
use tokio::task::JoinHandle;

/// One connection through the tap.
#[derive(Debug, Clone)]
pub struct Passage {
    pub id: usize,
    pub opened: Instant,
    /// When either end closed it (or the tap did, on a restore).
    pub closed: Option<Instant>,
    /// What the client sent, chunk by chunk, each when it passed.
    pub sent: Vec<(Instant, Vec<u8>)>,
}

#[derive(Default)]
struct Log(Mutex<Vec<Passage>>);

impl Log {
    fn with<T>(&self, f: impl FnOnce(&mut Vec<Passage>) -> T) -> T {
        f(&mut self.0.lock().unwrap_or_else(|e| e.into_inner()))
    }
}

/// The tap; its task ends when dropped.
pub struct Tap {
    pub port: u16,
    log: Arc<Log>,
    /// The generation of the network: odd while cut.
    network: watch::Sender<u64>,
    task: JoinHandle<()>,
}

impl Drop for Tap {
    fn drop(&mut self) {
        self.task.abort();
    }
}

impl Tap {
    /// A tap on a free loopback port in front of `127.0.0.1:target`.
    pub async fn start(target: u16) -> anyhow::Result<Tap> {
        let listener = TcpListener::bind("127.0.0.1:0").await?;
        let port = listener.local_addr()?.port();
        let log = Arc::new(Log::default());
        let (network, _) = watch::channel(0u64);
        let (l, n) = (log.clone(), network.clone());
        let task = tokio::spawn(async move {
            while let Ok((client, _)) = listener.accept().await {
                let Ok(server) = TcpStream::connect(("127.0.0.1", target)).await else {
                    continue;
                };
                let id = l.with(|p| {
                    p.push(Passage {
                        id: p.len(),
                        opened: Instant::now(),
                        closed: None,
                        sent: Vec::new(),
                    });
                    p.len() - 1
                });
                tokio::spawn(pass(client, server, id, l.clone(), n.subscribe()));
            }
        });
        Ok(Tap {
            port,
            log,
            network,
            task,
        })
    }

    /// Cuts the network: nothing passes, nothing is closed.
    pub fn cut(&self) {
        self.network.send_modify(|g| {
            if *g % 2 == 0 {
                *g += 1;
            }
        });
    }

    /// Restores it: the connections that were cut are closed, new ones pass.
    pub fn restore(&self) {
        self.network.send_modify(|g| {
            if *g % 2 == 1 {
                *g += 1;
            }
        });
    }

    /// Every connection so far.
    pub fn passages(&self) -> Vec<Passage> {
        self.log.with(|p| p.clone())
    }
}

/// Forwards one connection until either end closes it, or the network it was opened on
/// is restored after a cut.
async fn pass(
    mut client: TcpStream,
    mut server: TcpStream,
    id: usize,
    log: Arc<Log>,
    mut network: watch::Receiver<u64>,
) {
    let born = *network.borrow_and_update();
    if born % 2 == 1 {
        // Opened while cut: it goes nowhere until the restore closes it.
        let _ = network.wait_for(|g| *g > born).await;
        log.with(|p| p[id].closed = Some(Instant::now()));
        return;
    }
    let (mut up, mut down) = ([0u8; 4096], [0u8; 4096]);
    // While cut, nothing passes: not bytes, not a close (a FIN is lost as the rest is).
    let (mut up_open, mut down_open) = (true, true);
    loop {
        let cut = *network.borrow() != born;
        if !cut && (!up_open || !down_open) {
            break;
        }
        tokio::select! {
            r = client.read(&mut up), if up_open => match r {
                Ok(0) | Err(_) => up_open = false,
                Ok(n) if !cut => {
                    log.with(|p| p[id].sent.push((Instant::now(), up[..n].to_vec())));
                    if server.write_all(&up[..n]).await.is_err() {
                        break;
                    }
                }
                Ok(_) => {}
            },
            r = server.read(&mut down), if down_open => match r {
                Ok(0) | Err(_) => down_open = false,
                Ok(n) if !cut => {
                    if client.write_all(&down[..n]).await.is_err() {
                        break;
                    }
                }
                Ok(_) => {}
            },
            changed = network.changed() => {
                if changed.is_err() || *network.borrow() > born + 1 {
                    break;
                }
            }
        }
    }
    log.with(|p| p[id].closed = Some(Instant::now()));
}

/// The Modbus TCP write requests (FC06, FC16) a client sent on a connection: each with when
/// it passed and its (address, values). Requests are taken whole from the bytes sent, in
/// order (a chunk may carry several, or part of one).
pub fn modbus_writes(passage: &Passage) -> Vec<(Instant, u16, Vec<u16>)> {
    let mut out = Vec::new();
    let mut buf: Vec<u8> = Vec::new();
    for (at, chunk) in &passage.sent {
        buf.extend_from_slice(chunk);
        while buf.len() >= 7 {
            let len = usize::from(u16::from_be_bytes([buf[4], buf[5]]));
            if buf.len() < 6 + len {
                break;
            }
            let frame: Vec<u8> = buf.drain(..6 + len).collect();
            let pdu = &frame[7..];
            let word = |i: usize| u16::from_be_bytes([pdu[i], pdu[i + 1]]);
            match pdu.first() {
                Some(6) if pdu.len() >= 5 => out.push((*at, word(1), vec![word(3)])),
                Some(16) if pdu.len() >= 6 => {
                    let count = usize::from(word(3));
                    let values = (0..count)
                        .filter(|i| 6 + 2 * i + 1 < pdu.len())
                        .map(|i| word(6 + 2 * i))
                        .collect();
                    out.push((*at, word(1), values));
                }
                _ => {}
            }
        }
    }
    out
}

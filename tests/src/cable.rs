//! A cable between the gateway and a peer: a TCP proxy on a free loopback port that can be
//! cut (every connection through it closed at once, as a pulled plug or a switch's restart
//! would) or hushed (the open connections pass nothing more, either way: a peer gone
//! silent), that counts the connections the gateway made through it and keeps what the
//! gateway sent on each; or a peer that opens and then fails (the proxy passes the first
//! requests of each connection, then closes it).

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::task::AbortHandle;

/// What the cable does to the peer's answers (every read from the peer, which for these
/// protocols is an answer or a part of one).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum Mangle {
    /// Passes them.
    Pass,
    /// Drops them (the peer seems silent; the connection stays).
    Silent,
    /// Flips the bits of their first 8 bytes (headers, lengths, ids).
    Garble,
    /// Sends their first half, then closes the connection.
    Truncate,
    /// Sends each with 64 zero bytes after it.
    Oversize,
    /// Sends them a byte every 2 ms.
    Drip,
}

impl Mangle {
    const ALL: [Mangle; 6] = [
        Mangle::Pass,
        Mangle::Silent,
        Mangle::Garble,
        Mangle::Truncate,
        Mangle::Oversize,
        Mangle::Drip,
    ];
}

/// What a cable makes of each of the peer's answers.
pub type Rewrite = fn(&[u8]) -> Vec<u8>;

/// What the gateway sent on one connection.
type Record = Arc<std::sync::Mutex<Vec<u8>>>;

/// A proxy to `127.0.0.1:<upstream>`.
pub struct Cable {
    /// The port the gateway connects to.
    pub port: u16,
    accepted: Arc<AtomicUsize>,
    open: Arc<AtomicUsize>,
    plugged: Arc<AtomicBool>,
    connections: Arc<std::sync::Mutex<Vec<AbortHandle>>>,
    /// Raised to hush the connections open now.
    hushed: Arc<tokio::sync::watch::Sender<u64>>,
    /// What the gateway sent, a list of byte strings per connection.
    sent: Arc<std::sync::Mutex<Vec<Record>>>,
    /// What is done to the peer's answers now (a [`Mangle`]), and how many were changed.
    mangle: Arc<std::sync::atomic::AtomicU8>,
    mangled: Arc<AtomicUsize>,
    task: AbortHandle,
}

impl Drop for Cable {
    fn drop(&mut self) {
        self.task.abort();
        self.cut();
    }
}

/// A connection's count of open connections, given back when it ends however it ends.
struct Held(Arc<AtomicUsize>);

impl Drop for Held {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::SeqCst);
    }
}

impl Cable {
    /// A cable that passes everything.
    pub async fn to(upstream: u16) -> anyhow::Result<Cable> {
        Cable::failing_after(upstream, None).await
    }

    /// A cable that passes everything, each of the peer's answers (a read from it) first
    /// changed by `rewrite`: a peer of another make, written from its captures.
    pub async fn rewriting(upstream: u16, rewrite: Rewrite) -> anyhow::Result<Cable> {
        Cable::with(upstream, None, Some(rewrite)).await
    }

    /// A cable whose every connection passes the gateway's first `requests` reads (its
    /// opening handshake) and their answers, then closes at the next one: a peer that
    /// opens and then fails every answer. `None` passes everything.
    pub async fn failing_after(upstream: u16, requests: Option<usize>) -> anyhow::Result<Cable> {
        Cable::with(upstream, requests, None).await
    }

    async fn with(
        upstream: u16,
        requests: Option<usize>,
        rewrite: Option<Rewrite>,
    ) -> anyhow::Result<Cable> {
        let listener = TcpListener::bind("127.0.0.1:0").await?;
        let port = listener.local_addr()?.port();
        let accepted = Arc::new(AtomicUsize::new(0));
        let open = Arc::new(AtomicUsize::new(0));
        let plugged = Arc::new(AtomicBool::new(true));
        let connections: Arc<std::sync::Mutex<Vec<AbortHandle>>> = Arc::default();
        let hushed = Arc::new(tokio::sync::watch::Sender::new(0u64));
        let sent: Arc<std::sync::Mutex<Vec<Record>>> = Arc::default();
        let (count, live, on, held) = (
            accepted.clone(),
            open.clone(),
            plugged.clone(),
            connections.clone(),
        );
        let (hush, records) = (hushed.clone(), sent.clone());
        let mangle = Arc::new(std::sync::atomic::AtomicU8::new(Mangle::Pass as u8));
        let mangled = Arc::new(AtomicUsize::new(0));
        let mangling = (mangle.clone(), mangled.clone());
        let task = tokio::spawn(async move {
            while let Ok((client, _)) = listener.accept().await {
                count.fetch_add(1, Ordering::SeqCst);
                if !on.load(Ordering::SeqCst) {
                    continue;
                }
                live.fetch_add(1, Ordering::SeqCst);
                let guard = Held(live.clone());
                let record: Record = Arc::default();
                if let Ok(mut all) = records.lock() {
                    all.push(record.clone());
                }
                let mut hush = hush.subscribe();
                hush.borrow_and_update();
                let mangle = mangling.clone();
                let task = tokio::spawn(async move {
                    let _guard = guard;
                    if let Ok(up) = TcpStream::connect(("127.0.0.1", upstream)).await {
                        let ends = Ends { client, up };
                        pass(ends, requests, record, hush, mangle, rewrite).await;
                    }
                });
                if let Ok(mut list) = held.lock() {
                    list.retain(|h| !h.is_finished());
                    list.push(task.abort_handle());
                }
            }
        })
        .abort_handle();
        Ok(Cable {
            port,
            accepted,
            open,
            plugged,
            connections,
            hushed,
            sent,
            mangle,
            mangled,
            task,
        })
    }

    /// Closes every connection through the cable now; new ones are taken.
    pub fn cut(&self) {
        if let Ok(mut list) = self.connections.lock() {
            for h in list.drain(..) {
                h.abort();
            }
        }
    }

    /// The connections open now pass nothing more, either way (kept open, what the gateway
    /// sends kept); new ones pass as before.
    pub fn hush(&self) {
        self.hushed.send_modify(|n| *n += 1);
    }

    /// What the gateway sent on each connection, in the order they were made.
    pub fn sent(&self) -> Vec<Vec<u8>> {
        self.sent
            .lock()
            .map(|all| {
                all.iter()
                    .map(|r| r.lock().map(|b| b.clone()).unwrap_or_default())
                    .collect()
            })
            .unwrap_or_default()
    }

    /// From now on, does `m` to the peer's answers, on every connection.
    pub fn mangle(&self, m: Mangle) {
        self.mangle.store(m as u8, Ordering::SeqCst);
    }

    /// Answers changed (or dropped) so far.
    pub fn mangled(&self) -> usize {
        self.mangled.load(Ordering::SeqCst)
    }

    /// Pulls the plug: every connection closed, new ones closed as they come.
    pub fn pull(&self) {
        self.plugged.store(false, Ordering::SeqCst);
        self.cut();
    }

    /// Plugs it in again.
    pub fn plug(&self) {
        self.plugged.store(true, Ordering::SeqCst);
    }

    /// Connections the gateway made through the cable so far.
    pub fn accepted(&self) -> usize {
        self.accepted.load(Ordering::SeqCst)
    }

    /// Connections open through the cable now.
    pub fn open(&self) -> usize {
        self.open.load(Ordering::SeqCst)
    }
}

/// Copies both ways, keeping what the client sends in `record`; with `requests`, the
/// connection closes at the client's read after that many; once `hush` changes, nothing
/// passes (the client's bytes are still kept) until the client closes.
/// A connection's two sockets: the gateway's and the peer's.
struct Ends {
    client: TcpStream,
    up: TcpStream,
}

async fn pass(
    Ends { client, up }: Ends,
    requests: Option<usize>,
    record: Record,
    mut hush: tokio::sync::watch::Receiver<u64>,
    (mangle, mangled): (Arc<std::sync::atomic::AtomicU8>, Arc<AtomicUsize>),
    rewrite: Option<Rewrite>,
) {
    let (mut client_rx, mut client_tx) = client.into_split();
    let (mut up_rx, mut up_tx) = up.into_split();
    let mut quiet = hush.clone();
    let down = tokio::spawn(async move {
        let mut buf = vec![0u8; 64 * 1024];
        loop {
            tokio::select! {
                _ = quiet.changed() => return,
                n = up_rx.read(&mut buf) => match n {
                    Ok(n) if n > 0 => {
                        let mut bytes = match rewrite {
                            Some(rewrite) => rewrite(&buf[..n]),
                            None => buf[..n].to_vec(),
                        };
                        let m = Mangle::ALL
                            .get(usize::from(mangle.load(Ordering::SeqCst)))
                            .copied()
                            .unwrap_or(Mangle::Pass);
                        if m != Mangle::Pass {
                            mangled.fetch_add(1, Ordering::SeqCst);
                        }
                        if !answer(&mut client_tx, &mut bytes, m).await {
                            return;
                        }
                    }
                    _ => return,
                },
            }
        }
    });
    // Cut (this task aborted), the peer's direction ends with it: both sockets close.
    let _down = Downstream(down.abort_handle());
    let mut buf = vec![0u8; 64 * 1024];
    let (mut seen, mut hushed) = (0, false);
    loop {
        let n = tokio::select! {
            _ = hush.changed(), if !hushed => {
                hushed = true;
                continue;
            }
            n = client_rx.read(&mut buf) => n,
        };
        let Ok(n) = n else { break };
        if n == 0 || requests == Some(seen) {
            break;
        }
        seen += 1;
        if let Ok(mut r) = record.lock() {
            r.extend_from_slice(&buf[..n]);
        }
        if !hushed && up_tx.write_all(&buf[..n]).await.is_err() {
            break;
        }
    }
    down.abort();
}

/// The peer-to-gateway half of a connection, ended with the other.
struct Downstream(AbortHandle);

impl Drop for Downstream {
    fn drop(&mut self) {
        self.0.abort();
    }
}

/// Sends an answer of the peer to the gateway as `m` says; `false` when the connection is
/// to end.
async fn answer(to: &mut tokio::net::tcp::OwnedWriteHalf, bytes: &mut [u8], m: Mangle) -> bool {
    match m {
        Mangle::Pass => to.write_all(bytes).await.is_ok(),
        Mangle::Silent => true,
        Mangle::Garble => {
            for b in bytes.iter_mut().take(8) {
                *b ^= 0x5A;
            }
            to.write_all(bytes).await.is_ok()
        }
        Mangle::Truncate => {
            let _ = to.write_all(&bytes[..bytes.len() / 2]).await;
            let _ = to.shutdown().await;
            false
        }
        Mangle::Oversize => {
            to.write_all(bytes).await.is_ok() && to.write_all(&[0u8; 64]).await.is_ok()
        }
        Mangle::Drip => {
            for b in bytes.iter() {
                if to.write_all(&[*b]).await.is_err() {
                    return false;
                }
                tokio::time::sleep(std::time::Duration::from_millis(2)).await;
            }
            true
        }
    }
}

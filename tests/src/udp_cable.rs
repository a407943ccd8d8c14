//! A cable for a datagram protocol (BACnet/IP): a UDP relay on a free loopback port between
//! the gateway and a peer, passing each datagram on, and doing to the peer's (answers and
//! notifications alike) what a `Mangle` says: dropped, garbled, cut in half, with junk after
//! it, or sent twice. It counts what it mangled.

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicU8, AtomicUsize, Ordering};

use tokio::net::UdpSocket;
use tokio::task::AbortHandle;

/// What the relay does to the peer's datagrams.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum Mangle {
    /// Passes them.
    Pass,
    /// Drops them (the peer seems silent).
    Silent,
    /// Flips the bits of their first 8 bytes (headers, lengths, ids).
    Garble,
    /// Sends their first half.
    Truncate,
    /// Sends each with 64 zero bytes after it.
    Oversize,
    /// Sends each twice (an answer taken twice, or a late copy taken as the next answer).
    Twice,
}

impl Mangle {
    const ALL: [Mangle; 6] = [
        Mangle::Pass,
        Mangle::Silent,
        Mangle::Garble,
        Mangle::Truncate,
        Mangle::Oversize,
        Mangle::Twice,
    ];
}

/// A relay to `127.0.0.1:<upstream>`.
pub struct UdpCable {
    /// The port the gateway sends to.
    pub port: u16,
    mangle: Arc<AtomicU8>,
    mangled: Arc<AtomicUsize>,
    task: AbortHandle,
}

impl UdpCable {
    /// Relays to the peer at `upstream`, passing everything.
    pub async fn to(upstream: u16) -> anyhow::Result<UdpCable> {
        let front = UdpSocket::bind("127.0.0.1:0").await?;
        let back = UdpSocket::bind("127.0.0.1:0").await?;
        back.connect(("127.0.0.1", upstream)).await?;
        let port = front.local_addr()?.port();
        let (mangle, mangled) = (Arc::new(AtomicU8::new(0)), Arc::new(AtomicUsize::new(0)));
        let (m, count) = (mangle.clone(), mangled.clone());
        let task = tokio::spawn(async move {
            let mut gateway: Option<SocketAddr> = None;
            let (mut a, mut b) = (vec![0u8; 2048], vec![0u8; 2048]);
            loop {
                tokio::select! {
                    Ok((n, from)) = front.recv_from(&mut a) => {
                        gateway = Some(from);
                        let _ = back.send(&a[..n]).await;
                    }
                    Ok(n) = back.recv(&mut b) => {
                        let Some(to) = gateway else { continue };
                        let how = Mangle::ALL[usize::from(m.load(Ordering::Relaxed))];
                        if how != Mangle::Pass {
                            count.fetch_add(1, Ordering::Relaxed);
                        }
                        let mut d = b[..n].to_vec();
                        match how {
                            Mangle::Pass => {}
                            Mangle::Silent => continue,
                            Mangle::Garble => d.iter_mut().take(8).for_each(|x| *x = !*x),
                            Mangle::Truncate => d.truncate(n / 2),
                            Mangle::Oversize => d.extend_from_slice(&[0; 64]),
                            Mangle::Twice => {
                                let _ = front.send_to(&d, to).await;
                            }
                        }
                        let _ = front.send_to(&d, to).await;
                    }
                }
            }
        });
        Ok(UdpCable {
            port,
            mangle,
            mangled,
            task: task.abort_handle(),
        })
    }

    /// From now on, does `m` to the peer's datagrams.
    pub fn mangle(&self, m: Mangle) {
        self.mangle.store(m as u8, Ordering::Relaxed);
    }

    /// How many of the peer's datagrams it mangled.
    pub fn mangled(&self) -> usize {
        self.mangled.load(Ordering::Relaxed)
    }
}

impl Drop for UdpCable {
    fn drop(&mut self) {
        self.task.abort();
    }
}

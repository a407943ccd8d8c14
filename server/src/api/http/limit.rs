//! A listener's connections within a limit, for the HTTP and gRPC listeners: at most the
//! bound's limit at once (more are closed as soon as they are accepted, each counted as a
//! refusal), TCP_NODELAY set, accept errors (out of file descriptors) waited out.

use std::io;
use std::pin::Pin;
use std::task::{Context, Poll};
use std::time::Duration;

use futures_util::Stream;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tonic::transport::server::{Connected, TcpConnectInfo};

use crate::metrics::{Bound, ClientHeld, Held, PerClient};

/// An accepted connection holding one of the listener's places, and one of its client's,
/// until it closes.
pub(crate) struct Limited {
    stream: TcpStream,
    _slot: Held,
    _client: ClientHeld,
}

/// The connections accepted on `listener`, at most `slots`' limit open at once and
/// `clients`' limit from one client address.
pub(crate) fn incoming(
    listener: TcpListener,
    slots: Bound,
    clients: PerClient,
) -> impl Stream<Item = io::Result<Limited>> + Send + 'static {
    let state = (listener, slots, clients);
    futures_util::stream::unfold(state, |(listener, slots, clients)| async move {
        loop {
            let (stream, peer) = match listener.accept().await {
                Ok(a) => a,
                Err(e) => {
                    tracing::warn!(error = %e, "cannot accept a connection");
                    tokio::time::sleep(Duration::from_millis(50)).await;
                    continue;
                }
            };
            let Some(client) = clients.take(peer.ip()) else {
                tracing::debug!(%peer, "connection refused: too many from this client");
                continue;
            };
            let Some(slot) = slots.take() else {
                tracing::debug!(%peer, "connection refused: too many connections");
                continue;
            };
            let _ = stream.set_nodelay(true);
            let limited = Limited {
                stream,
                _slot: slot,
                _client: client,
            };
            return Some((Ok(limited), (listener, slots, clients)));
        }
    })
}

impl Limited {
    /// The peer's address, when the socket still knows it.
    pub(crate) fn peer(&self) -> Option<std::net::SocketAddr> {
        self.stream.peer_addr().ok()
    }

    /// Waits until the peer has sent its first byte (which stays to be read) or closed.
    pub(crate) async fn first_byte(&self) -> io::Result<()> {
        self.stream.peek(&mut [0u8; 1]).await.map(|_| ())
    }
}

impl Connected for Limited {
    type ConnectInfo = TcpConnectInfo;

    fn connect_info(&self) -> TcpConnectInfo {
        self.stream.connect_info()
    }
}

impl AsyncRead for Limited {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        Pin::new(&mut self.stream).poll_read(cx, buf)
    }
}

impl AsyncWrite for Limited {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        Pin::new(&mut self.stream).poll_write(cx, buf)
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.stream).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.stream).poll_shutdown(cx)
    }

    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        Pin::new(&mut self.stream).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.stream.is_write_vectored()
    }
}

#[cfg(test)]
mod tests {
    use futures_util::StreamExt;
    use tokio::io::AsyncReadExt;

    use super::*;

    fn test_bound(n: usize) -> Bound {
        crate::metrics::Metrics::new().bound("test", n)
    }

    fn test_per_client(n: usize) -> PerClient {
        crate::metrics::Metrics::new().per_client("test_per_client", n)
    }

    #[tokio::test]
    async fn accepted_sockets_have_tcp_nodelay() {
        let listener = TcpListener::bind("127.0.0.1:0").await.expect("bind");
        let addr = listener.local_addr().expect("addr");
        let mut accepted = Box::pin(incoming(listener, test_bound(2), test_per_client(8)));
        let _client = TcpStream::connect(addr).await.expect("connect");
        let connection = accepted.next().await.expect("one").expect("ok");
        assert!(
            connection.stream.nodelay().expect("nodelay"),
            "Nagle is off"
        );
    }

    #[tokio::test]
    async fn connections_beyond_the_limit_are_closed_until_a_slot_frees() {
        let listener = TcpListener::bind("127.0.0.1:0").await.expect("bind");
        let addr = listener.local_addr().expect("addr");
        let mut accepted = Box::pin(incoming(listener, test_bound(2), test_per_client(8)));
        let _a = TcpStream::connect(addr).await.expect("a");
        let _b = TcpStream::connect(addr).await.expect("b");
        let first = accepted.next().await.expect("first").expect("ok");
        let _second = accepted.next().await.expect("second").expect("ok");
        // Both slots held: the third is accepted and closed while the stream waits on.
        let mut c = TcpStream::connect(addr).await.expect("c");
        let next = tokio::spawn(async move { accepted.next().await.is_some_and(|r| r.is_ok()) });
        let mut byte = [0u8; 1];
        assert_eq!(c.read(&mut byte).await.expect("closed, not reset"), 0);
        // A slot freed: the next connection is served.
        drop(first);
        let _d = TcpStream::connect(addr).await.expect("d");
        assert!(next.await.expect("task"), "d accepted");
    }

    #[tokio::test]
    async fn one_client_cannot_take_another_clients_places() {
        let listener = TcpListener::bind("0.0.0.0:0").await.expect("bind");
        let port = listener.local_addr().expect("addr").port();
        let mut accepted = Box::pin(incoming(listener, test_bound(8), test_per_client(2)));
        // 127.0.0.1 holds its two places; a third from it is closed at once.
        let _a = TcpStream::connect(("127.0.0.1", port)).await.expect("a");
        let _b = TcpStream::connect(("127.0.0.1", port)).await.expect("b");
        let first = accepted.next().await.expect("first").expect("ok");
        let _second = accepted.next().await.expect("second").expect("ok");
        let mut c = TcpStream::connect(("127.0.0.1", port)).await.expect("c");
        let next = tokio::spawn(async move {
            let n = accepted.next().await;
            (n.and_then(Result::ok).and_then(|l| l.peer()), accepted)
        });
        let mut byte = [0u8; 1];
        assert_eq!(c.read(&mut byte).await.expect("closed"), 0);
        // Another client address (127.0.0.2, also this machine) is served.
        let other = tokio::net::TcpSocket::new_v4().expect("socket");
        other
            .bind(([127, 0, 0, 2], 0).into())
            .expect("bind 127.0.0.2");
        let _d = other
            .connect(([127, 0, 0, 1], port).into())
            .await
            .expect("d");
        let (peer, _) = next.await.expect("task");
        assert_eq!(peer.map(|p| p.ip()), Some([127, 0, 0, 2].into()));
        drop(first);
    }
}

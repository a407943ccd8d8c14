//! Accepted connections made ready to serve, for the HTTP and gRPC listeners: within the
//! listener's connection limit ([`super::limit`]), each connection must complete its TLS
//! handshake (with `security.tls`) or send its first byte (without) within the header
//! timeout, or it is closed. Connections are prepared side by side: a slow one holds no
//! other. At most [`MAX_PREPARING`] wait to be ready; a new one then closes the oldest
//! waiting, so a flood of idle sockets cannot fill the listener: a client that speaks at
//! once is still served.

use std::io;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::Duration;

use futures_util::{Stream, StreamExt};
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::TcpListener;
use tokio_rustls::server::TlsStream;
use tonic::transport::server::{Connected, TcpConnectInfo};

use super::limit::{self, Limited};
use crate::metrics::{Bound, Metrics, PerClient};
use crate::tls::Tls;

/// Connections waiting for their first byte or TLS handshake at once, per listener.
pub(crate) const MAX_PREPARING: usize = 1024;

/// A connection ready for HTTP: plain, or TLS after its handshake.
pub(crate) enum Conn {
    Plain(Limited),
    Tls(Box<TlsStream<Limited>>),
}

impl Conn {
    /// The peer's address, when the socket still knows it.
    pub(crate) fn peer(&self) -> Option<std::net::SocketAddr> {
        match self {
            Conn::Plain(c) => c.peer(),
            Conn::Tls(c) => c.get_ref().0.peer(),
        }
    }
}

/// A listener's bounds: its open connections, each client's, and those waiting to be
/// ready.
#[derive(Clone, Debug)]
pub(crate) struct Bounds {
    pub(crate) connections: Bound,
    pub(crate) per_client: PerClient,
    pub(crate) waiting: Bound,
}

impl Bounds {
    /// The bounds of the HTTP (`grpc` false) or gRPC listener, serving at most
    /// `[max, max_per_client]` connections at once, in all and from one client.
    pub(crate) fn of(metrics: &Metrics, grpc: bool, [max, max_per_client]: [usize; 2]) -> Self {
        let (connections, per_client, waiting) = if grpc {
            (
                "grpc_connections",
                "grpc_connections_per_client",
                "grpc_waiting_connections",
            )
        } else {
            (
                "http_connections",
                "http_connections_per_client",
                "http_waiting_connections",
            )
        };
        Bounds {
            connections: metrics.bound(connections, max),
            per_client: metrics.per_client(per_client, max_per_client),
            waiting: metrics.bound(waiting, MAX_PREPARING),
        }
    }
}

/// The listener's connections, within `bounds`, each ready to serve: its TLS handshake done
/// (when `tls` is given) or its first byte arrived, within `ready_within`.
pub(crate) fn ready(
    listener: TcpListener,
    bounds: Bounds,
    tls: Option<Arc<Tls>>,
    ready_within: Duration,
) -> impl Stream<Item = io::Result<Conn>> + Send + 'static {
    let (tx, rx) = tokio::sync::mpsc::channel::<Conn>(64);
    tokio::spawn(async move {
        let incoming = limit::incoming(listener, bounds.connections, bounds.per_client);
        let waiting = bounds.waiting;
        tokio::pin!(incoming);
        let mut preparing = std::collections::VecDeque::<tokio::task::AbortHandle>::new();
        loop {
            // The server dropping the stream (at shutdown) ends the accepting too.
            let connection = tokio::select! {
                _ = tx.closed() => return,
                next = incoming.next() => match next {
                    Some(Ok(connection)) => connection,
                    Some(Err(_)) => continue,
                    None => return,
                },
            };
            preparing.retain(|h| !h.is_finished());
            if preparing.len() >= waiting.limit()
                && let Some(oldest) = preparing.pop_front()
            {
                tracing::debug!("connection closed: the oldest of too many waiting to be ready");
                waiting.refused();
                oldest.abort();
            }
            let (tx, tls) = (tx.clone(), tls.clone());
            // Held while it waits: freed when it is ready, closed or evicted.
            let held = waiting.hold();
            let task = tokio::spawn(async move {
                let peer = connection.peer();
                match tokio::time::timeout(ready_within, prepare(connection, tls)).await {
                    Ok(Ok(conn)) => {
                        drop(held);
                        let _ = tx.send(conn).await;
                    }
                    Ok(Err(e)) => {
                        tracing::debug!(?peer, error = %e, "connection closed before it was ready")
                    }
                    Err(_) => tracing::debug!(
                        ?peer,
                        "connection closed: not ready within the header timeout"
                    ),
                }
            });
            preparing.push_back(task.abort_handle());
        }
    });
    tokio_stream::wrappers::ReceiverStream::new(rx).map(Ok)
}

async fn prepare(connection: Limited, tls: Option<Arc<Tls>>) -> io::Result<Conn> {
    match tls {
        Some(tls) => {
            let stream = tls.acceptor().accept(connection).await?;
            Ok(Conn::Tls(Box::new(stream)))
        }
        None => {
            connection.first_byte().await?;
            Ok(Conn::Plain(connection))
        }
    }
}

impl Connected for Conn {
    type ConnectInfo = TcpConnectInfo;

    fn connect_info(&self) -> TcpConnectInfo {
        match self {
            Conn::Plain(c) => c.connect_info(),
            Conn::Tls(c) => c.get_ref().0.connect_info(),
        }
    }
}

impl AsyncRead for Conn {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        match self.get_mut() {
            Conn::Plain(c) => Pin::new(c).poll_read(cx, buf),
            Conn::Tls(c) => Pin::new(c.as_mut()).poll_read(cx, buf),
        }
    }
}

impl AsyncWrite for Conn {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        match self.get_mut() {
            Conn::Plain(c) => Pin::new(c).poll_write(cx, buf),
            Conn::Tls(c) => Pin::new(c.as_mut()).poll_write(cx, buf),
        }
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        match self.get_mut() {
            Conn::Plain(c) => Pin::new(c).poll_flush(cx),
            Conn::Tls(c) => Pin::new(c.as_mut()).poll_flush(cx),
        }
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        match self.get_mut() {
            Conn::Plain(c) => Pin::new(c).poll_shutdown(cx),
            Conn::Tls(c) => Pin::new(c.as_mut()).poll_shutdown(cx),
        }
    }

    fn poll_write_vectored(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        match self.get_mut() {
            Conn::Plain(c) => Pin::new(c).poll_write_vectored(cx, bufs),
            Conn::Tls(c) => Pin::new(c.as_mut()).poll_write_vectored(cx, bufs),
        }
    }

    fn is_write_vectored(&self) -> bool {
        match self {
            Conn::Plain(c) => c.is_write_vectored(),
            Conn::Tls(c) => c.is_write_vectored(),
        }
    }
}

#[cfg(test)]
mod tests {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    use tokio::net::TcpStream;

    use super::*;

    fn bounds(connections: usize) -> Bounds {
        let metrics = Metrics::new();
        Bounds {
            connections: metrics.bound("connections", connections),
            per_client: metrics.per_client("per_client", connections),
            waiting: metrics.bound("waiting", MAX_PREPARING),
        }
    }

    #[tokio::test]
    async fn a_silent_connection_is_closed_and_holds_no_other() {
        let listener = TcpListener::bind("127.0.0.1:0").await.expect("bind");
        let addr = listener.local_addr().expect("addr");
        let mut ready = Box::pin(ready(listener, bounds(8), None, Duration::from_millis(200)));
        let mut silent = TcpStream::connect(addr).await.expect("silent");
        let mut talking = TcpStream::connect(addr).await.expect("talking");
        talking.write_all(b"G").await.expect("write");
        // The talking one is ready first although it came second.
        let first = ready.next().await.expect("one").expect("ok");
        assert_eq!(
            first.peer().map(|p| p.port()),
            talking.local_addr().ok().map(|a| a.port())
        );
        // The silent one is closed when its time is up.
        let mut byte = [0u8; 1];
        let read = tokio::time::timeout(Duration::from_secs(5), silent.read(&mut byte))
            .await
            .expect("closed in time");
        assert!(matches!(read, Ok(0) | Err(_)), "closed: {read:?}");
    }

    #[tokio::test]
    async fn a_flood_of_idle_sockets_closes_the_oldest_and_a_speaking_client_gets_in() {
        let listener = TcpListener::bind("127.0.0.1:0").await.expect("bind");
        let addr = listener.local_addr().expect("addr");
        // A slot limit above the waiting limit, and a long header timeout: only eviction
        // can make room.
        let mut ready = Box::pin(ready(
            listener,
            bounds(MAX_PREPARING + 16),
            None,
            Duration::from_secs(600),
        ));
        let mut idle = Vec::new();
        for _ in 0..MAX_PREPARING + 8 {
            idle.push(TcpStream::connect(addr).await.expect("idle"));
        }
        let mut talking = TcpStream::connect(addr).await.expect("talking");
        talking.write_all(b"G").await.expect("write");
        let first = tokio::time::timeout(Duration::from_secs(10), ready.next())
            .await
            .expect("the speaking client is served")
            .expect("one")
            .expect("ok");
        assert_eq!(
            first.peer().map(|p| p.port()),
            talking.local_addr().ok().map(|a| a.port())
        );
        // The oldest idle socket was closed to make room.
        let mut byte = [0u8; 1];
        let read = tokio::time::timeout(Duration::from_secs(5), idle[0].read(&mut byte))
            .await
            .expect("the oldest is closed");
        assert!(matches!(read, Ok(0) | Err(_)), "closed: {read:?}");
    }
}

//! Accepted connections made ready to serve, for the HTTP and gRPC listeners: within the
//! listener's connection limit ([`super::limit`]), each connection must complete its TLS
//! handshake (with `security.tls`) or send its first byte (without) within the header
//! timeout, or it is closed. Connections are prepared side by side: a slow one holds no
//! other.

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
use crate::tls::Tls;

/// A connection ready for HTTP: plain, or TLS after its handshake.
pub enum Conn {
    Plain(Limited),
    Tls(Box<TlsStream<Limited>>),
}

impl Conn {
    /// The peer's address, when the socket still knows it.
    pub fn peer(&self) -> Option<std::net::SocketAddr> {
        match self {
            Conn::Plain(c) => c.peer(),
            Conn::Tls(c) => c.get_ref().0.peer(),
        }
    }
}

/// The listener's connections, at most `max` open at once, each ready to serve: its TLS
/// handshake done (when `tls` is given) or its first byte arrived, within `ready_within`.
pub fn ready(
    listener: TcpListener,
    max: usize,
    tls: Option<Arc<Tls>>,
    ready_within: Duration,
) -> impl Stream<Item = io::Result<Conn>> + Send + 'static {
    let (tx, rx) = tokio::sync::mpsc::channel::<Conn>(64);
    tokio::spawn(async move {
        let incoming = limit::incoming(listener, max);
        tokio::pin!(incoming);
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
            let (tx, tls) = (tx.clone(), tls.clone());
            tokio::spawn(async move {
                let peer = connection.peer();
                match tokio::time::timeout(ready_within, prepare(connection, tls)).await {
                    Ok(Ok(conn)) => {
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

    #[tokio::test]
    async fn a_silent_connection_is_closed_and_holds_no_other() {
        let listener = TcpListener::bind("127.0.0.1:0").await.expect("bind");
        let addr = listener.local_addr().expect("addr");
        let mut ready = Box::pin(ready(listener, 8, None, Duration::from_millis(200)));
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
}

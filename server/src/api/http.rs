//! The HTTP listener: each accepted connection served by hyper with the router, within
//! limits: at most `listen.max_connections` at once (more are closed at once), TLS handshake or
//! first byte and then request headers read within `listen.header_timeout` (a client
//! sending one byte a second is dropped), request bodies read within `listen.body_timeout`,
//! TCP_NODELAY set; at shutdown the server stops accepting and finishes its requests.

use std::future::Future;
use std::sync::Arc;
use std::time::Duration;

use hyper_util::rt::{TokioExecutor, TokioIo, TokioTimer};
use hyper_util::server::conn::auto::Builder;
use hyper_util::server::graceful::GracefulShutdown;
use hyper_util::service::TowerToHyperService;
use tokio::net::TcpListener;
use tokio_stream::StreamExt;

use crate::service::Service;

pub(crate) mod accept;
pub(crate) mod config;
pub(crate) mod declare;
pub(crate) mod error;
pub(crate) mod events;
pub(crate) mod front_end;
pub(crate) mod limit;
pub(crate) mod map;
pub(crate) mod openapi;
pub(crate) mod rest;
mod router;
pub(crate) mod scan;
pub(crate) mod transactions;
pub(crate) mod ui;

pub(crate) use router::{ApiDoc, router, serve_http};

/// The HTTP listener's timeouts (`listen.header_timeout`, `listen.body_timeout`).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Limits {
    /// For the TLS handshake or first byte, then for each request's headers (and the wait
    /// for the next request on a kept-alive connection).
    pub(crate) header_timeout: Duration,
    /// For a request's body (at most [`router::MAX_BODY`]).
    pub(crate) body_timeout: Duration,
    /// Connections served at once (`listen.max_connections`).
    pub(crate) max_connections: usize,
    /// Connections served at once from one client address
    /// (`listen.max_connections_per_client`).
    pub(crate) max_connections_per_client: usize,
}

/// The address of the client a request came from, when its connection knows it (an
/// extension of every request).
#[derive(Debug, Clone, Copy)]
pub(crate) struct ClientAddr(pub(crate) Option<std::net::IpAddr>);

impl Limits {
    /// Connections served at once: in all, and from one client address.
    pub(crate) fn connections(&self) -> [usize; 2] {
        [self.max_connections, self.max_connections_per_client]
    }
}

/// Serves the HTTP API on `listener` until `shutdown` resolves, then finishes the requests
/// in flight (at most the gateway's shutdown grace).
pub(crate) async fn serve(
    listener: TcpListener,
    service: Arc<Service>,
    limits: Limits,
    tls: Option<Arc<crate::tls::Tls>>,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> std::io::Result<()> {
    let bounds = accept::Bounds::of(&service.metrics, false, limits.connections());
    let router = router(service, limits.body_timeout);
    let incoming = accept::ready(listener, bounds, tls, limits.header_timeout);
    tokio::pin!(incoming);
    let graceful = GracefulShutdown::new();
    let mut builder = Builder::new(TokioExecutor::new());
    builder
        .http1()
        .timer(TokioTimer::new())
        .header_read_timeout(limits.header_timeout);
    tokio::pin!(shutdown);
    loop {
        let connection = tokio::select! {
            _ = &mut shutdown => break,
            next = incoming.next() => match next {
                Some(Ok(connection)) => connection,
                _ => break,
            },
        };
        let peer = connection.peer();
        let client = ClientAddr(peer.map(|p| p.ip()));
        let tagged = tower::ServiceBuilder::new()
            .map_request(move |mut r: axum::http::Request<hyper::body::Incoming>| {
                r.extensions_mut().insert(client);
                r
            })
            .service(router.clone());
        let service = TowerToHyperService::new(tagged);
        let connection = builder
            .serve_connection_with_upgrades(TokioIo::new(connection), service)
            .into_owned();
        let connection = graceful.watch(connection);
        tokio::spawn(async move {
            if let Err(e) = connection.await {
                tracing::trace!(?peer, error = %e, "HTTP connection ended");
            }
        });
    }
    graceful.shutdown().await;
    Ok(())
}

//! The listeners' servers (HTTP, gRPC, Modbus TCP), each stopped by its own token, so that a
//! configuration reload that moves one listener, or turns TLS on or off, serves that one
//! again and leaves the others running.

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use tokio::net::TcpListener;
use tokio_util::sync::CancellationToken;
use tokio_util::task::TaskTracker;

use crate::api;
use crate::config::Config;
use crate::service::Service;

/// The listeners' servers and the TLS configuration they serve with.
pub(crate) struct Servers {
    token: CancellationToken,
    tracker: TaskTracker,
    tls: std::sync::Mutex<Option<Arc<crate::tls::Tls>>>,
    running: tokio::sync::Mutex<Served>,
}

/// Each server's address and the token that stops it.
struct Served {
    http: Option<(SocketAddr, CancellationToken, api::http::Limits)>,
    grpc: Option<(SocketAddr, CancellationToken)>,
    modbus: Option<(SocketAddr, CancellationToken)>,
}

/// Listeners bound for a reload before anything else is applied.
#[derive(Default)]
pub(crate) struct Bound {
    http: Option<TcpListener>,
    grpc: Option<TcpListener>,
    modbus: Option<TcpListener>,
}

async fn bind(addr: SocketAddr, key: &str) -> Result<TcpListener, String> {
    TcpListener::bind(addr)
        .await
        .map_err(|e| format!("cannot listen on {addr} ({key}): {e}"))
}

impl Servers {
    /// No server yet; each started one is a task of `tracker`, stopped with `token`.
    pub(crate) fn new(
        token: CancellationToken,
        tracker: TaskTracker,
        tls: Option<Arc<crate::tls::Tls>>,
    ) -> Self {
        Servers {
            token,
            tracker,
            tls: std::sync::Mutex::new(tls),
            running: tokio::sync::Mutex::new(Served {
                http: None,
                grpc: None,
                modbus: None,
            }),
        }
    }

    fn tls(&self) -> Option<Arc<crate::tls::Tls>> {
        self.tls.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }

    pub(crate) async fn serve_modbus(
        &self,
        service: &Arc<Service>,
        listener: TcpListener,
    ) -> anyhow::Result<SocketAddr> {
        let addr = listener.local_addr()?;
        let stop = self.token.child_token();
        self.tracker.spawn(api::modbus_server::serve_modbus(
            listener,
            service.clone(),
            stop.clone(),
        ));
        service.listening.set("modbus", addr, addr.to_string());
        self.running.lock().await.modbus = Some((addr, stop));
        Ok(addr)
    }

    pub(crate) async fn serve_grpc(
        &self,
        service: &Arc<Service>,
        listener: TcpListener,
        limits: api::http::Limits,
    ) -> anyhow::Result<SocketAddr> {
        let addr = listener.local_addr()?;
        service.listening.set("grpc", addr, addr.to_string());
        let stop = self.token.child_token();
        let (service, shutdown, tls) = (service.clone(), stop.clone(), self.tls());
        self.tracker.spawn(async move {
            let served = api::serve_grpc(
                listener,
                service,
                limits.header_timeout,
                tls,
                shutdown.cancelled_owned(),
            )
            .await;
            if let Err(e) = served {
                tracing::error!(error = %e, "gRPC server failed");
            }
        });
        self.running.lock().await.grpc = Some((addr, stop));
        Ok(addr)
    }

    pub(crate) async fn serve_http(
        &self,
        service: &Arc<Service>,
        listener: TcpListener,
        limits: api::http::Limits,
    ) -> anyhow::Result<SocketAddr> {
        let addr = listener.local_addr()?;
        let stop = self.token.child_token();
        let scheme = if self.tls().is_some() {
            "https"
        } else {
            "http"
        };
        service
            .listening
            .set("http", addr, format!("{scheme}://{addr}"));
        let (service, shutdown, tls) = (service.clone(), stop.clone(), self.tls());
        self.tracker.spawn(async move {
            let served =
                api::serve_http(listener, service, limits, tls, shutdown.cancelled_owned()).await;
            if let Err(e) = served {
                tracing::error!(error = %e, "HTTP server failed");
            }
        });
        self.running.lock().await.http = Some((addr, stop, limits));
        Ok(addr)
    }

    /// Binds the listeners a reload moves to another address, before anything is applied:
    /// one that cannot be bound refuses the reload.
    pub(crate) async fn bind(
        &self,
        config: &Config,
        diff: ListenerChanges,
    ) -> Result<Bound, String> {
        let running = self.running.lock().await;
        let moved = |now: Option<SocketAddr>, to: SocketAddr| now.is_some_and(|a| a != to);
        let mut bound = Bound::default();
        if diff.http && moved(running.http.as_ref().map(|h| h.0), config.http) {
            bound.http = Some(bind(config.http, "listen.http").await?);
        }
        if diff.grpc && moved(running.grpc.as_ref().map(|g| g.0), config.grpc) {
            bound.grpc = Some(bind(config.grpc, "listen.grpc").await?);
        }
        if let Some(listen) = config.modbus_server.as_ref().and_then(|s| s.listen)
            && diff.modbus
        {
            let now = running.modbus.as_ref().map(|m| m.0);
            if now.is_none() || moved(now, listen) {
                bound.modbus = Some(bind(listen, "modbus_server.listen").await?);
            }
        }
        Ok(bound)
    }

    /// Applies a reload's listener changes: a moved listener serves on its new address
    /// (bound by [`Servers::bind`]) and the old one stops; one whose TLS or timeouts
    /// changed is served again on its address; TLS files that changed serve the next
    /// connections.
    pub(crate) async fn apply(
        &self,
        service: &Arc<Service>,
        config: &Config,
        diff: ListenerChanges,
        bound: Bound,
        tls: Option<Arc<crate::tls::Tls>>,
    ) {
        let limits = api::http::Limits {
            header_timeout: config.header_timeout,
            body_timeout: config.body_timeout,
        };
        let toggled = diff.tls && self.tls().is_some() != config.security.tls.is_some();
        match (self.tls(), tls) {
            (Some(current), Some(new)) if !toggled => current.replace(&new),
            (_, new) if toggled => {
                if let Some(new) = &new {
                    self.token_spawn_watch(new.clone());
                }
                *self.tls.lock().unwrap_or_else(|e| e.into_inner()) = new;
            }
            _ => {}
        }
        let mut running = self.running.lock().await;
        let old_http = running.http.take();
        let old_grpc = running.grpc.take();
        let old_modbus = running.modbus.take();
        drop(running);
        // HTTP.
        let http = match (bound.http, old_http) {
            (Some(listener), old) => {
                if let Some((_, stop, _)) = old {
                    stop.cancel();
                }
                Some(listener)
            }
            (None, Some((addr, stop, _))) if toggled || diff.limits => {
                stop.cancel();
                rebind(addr, "listen.http").await
            }
            (None, old) => {
                self.running.lock().await.http = old;
                None
            }
        };
        if let Some(listener) = http
            && let Err(e) = self.serve_http(service, listener, limits).await
        {
            tracing::error!(error = %e, "HTTP server not started");
        }
        // gRPC.
        let grpc = match (bound.grpc, old_grpc) {
            (Some(listener), old) => {
                if let Some((_, stop)) = old {
                    stop.cancel();
                }
                Some(listener)
            }
            (None, Some((addr, stop))) if toggled || diff.limits => {
                stop.cancel();
                rebind(addr, "listen.grpc").await
            }
            (None, old) => {
                self.running.lock().await.grpc = old;
                None
            }
        };
        if let Some(listener) = grpc
            && let Err(e) = self.serve_grpc(service, listener, limits).await
        {
            tracing::error!(error = %e, "gRPC server not started");
        }
        // Modbus TCP.
        match (bound.modbus, old_modbus) {
            (Some(listener), old) => {
                if let Some((_, stop)) = old {
                    stop.cancel();
                }
                if let Err(e) = self.serve_modbus(service, listener).await {
                    tracing::error!(error = %e, "Modbus TCP server not started");
                }
            }
            (None, Some((_, stop)))
                if config
                    .modbus_server
                    .as_ref()
                    .is_none_or(|s| s.listen.is_none()) =>
            {
                service.listening.remove("modbus");
                stop.cancel()
            }
            (None, old) => self.running.lock().await.modbus = old,
        }
    }

    fn token_spawn_watch(&self, tls: Arc<crate::tls::Tls>) {
        self.tracker.spawn(tls.watch(self.token.clone()));
    }
}

/// What a reload changed of the listeners, as the servers need to know it.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct ListenerChanges {
    /// `listen.http`, `listen.grpc`, `modbus_server.listen` changed.
    pub(crate) http: bool,
    pub(crate) grpc: bool,
    pub(crate) modbus: bool,
    /// TLS turned on or off, or its files changed.
    pub(crate) tls: bool,
    /// The header or body timeouts changed.
    pub(crate) limits: bool,
}

/// Binds `addr` again after its server was stopped (TLS turned on or off, timeouts
/// changed); the old listener may take a moment to close.
async fn rebind(addr: SocketAddr, key: &str) -> Option<TcpListener> {
    for _ in 0..50 {
        if let Ok(listener) = TcpListener::bind(addr).await {
            return Some(listener);
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    tracing::error!(%addr, key, "cannot listen again after a reload");
    None
}

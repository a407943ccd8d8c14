//! What the front-ends that listen on a TCP port share: the address bound when they are
//! prepared (a reload that cannot bind it changes nothing), or bound again once the one
//! running there has stopped (TLS turned on or off, timeouts changed); and, running, the
//! address and the token that stops them.

use std::future::Future;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use futures_util::future::BoxFuture;
use tokio::net::TcpListener;
use tokio_util::sync::CancellationToken;

use super::{Carried, Prepare, Running};
use crate::service::Service;

/// Where a listening front-end will serve.
pub(crate) enum Listen {
    /// A new address, bound already.
    Bound(TcpListener),
    /// The address the running one holds, bound again once it has stopped.
    Again(SocketAddr),
}

impl Listen {
    /// `to` (`key` in the config, `option` of `serve`), as `prepare` finds it: bound now,
    /// unless the running one was configured with it or holds it.
    pub(crate) async fn prepare(
        prepare: &Prepare<'_>,
        to: SocketAddr,
        was: Option<SocketAddr>,
        key: &str,
        option: &str,
    ) -> Result<Listen, String> {
        if let Some(now) = prepare.now
            && (was == Some(to) || now == to)
        {
            return Ok(Listen::Again(now));
        }
        match TcpListener::bind(to).await {
            Ok(listener) => Ok(Listen::Bound(listener)),
            Err(e) if prepare.old.is_none() => Err(format!(
                "cannot listen on {to} ({key}, or serve {option} ADDR; port 0 takes any free one): {e}"
            )),
            Err(e) => Err(format!("cannot listen on {to} ({key}): {e}")),
        }
    }

    /// Serves on it: the listener bound (or bound again), recorded as `name` in the
    /// listening table, reached at `address(addr)`, and `serve` spawned on it with the
    /// token that stops it.
    pub(crate) async fn serve<F, Fut>(
        self,
        key: &str,
        name: &'static str,
        service: &Arc<Service>,
        address: impl FnOnce(SocketAddr) -> String,
        serve: F,
    ) -> Result<Box<dyn Running>, String>
    where
        F: FnOnce(TcpListener, CancellationToken) -> Fut,
        Fut: Future<Output = ()> + Send + 'static,
    {
        let listener = self.listener(key).await?;
        let addr = listener.local_addr().map_err(|e| e.to_string())?;
        service.listening.set(name, addr, address(addr));
        let stop = service.tasks().token().child_token();
        service.tasks().spawn(serve(listener, stop.clone()));
        Ok(Box::new(Listening { name, addr, stop }))
    }

    /// The listener to serve on; one bound again is retried while the old one closes.
    async fn listener(self, key: &str) -> Result<TcpListener, String> {
        let addr = match self {
            Listen::Bound(listener) => return Ok(listener),
            Listen::Again(addr) => addr,
        };
        for _ in 0..50 {
            if let Ok(listener) = TcpListener::bind(addr).await {
                return Ok(listener);
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        tracing::error!(%addr, key, "cannot listen again after a reload");
        Err(format!("cannot listen on {addr} again ({key})"))
    }
}

/// A listening front-end that runs: its name in the listening table, its address, and
/// what stops it.
struct Listening {
    name: &'static str,
    addr: SocketAddr,
    stop: CancellationToken,
}

impl Running for Listening {
    fn stop(
        self: Box<Self>,
        service: std::sync::Arc<Service>,
    ) -> BoxFuture<'static, Result<Carried, String>> {
        service.listening.remove(self.name);
        self.stop.cancel();
        Box::pin(std::future::ready(Ok(None)))
    }

    fn address(&self) -> Option<SocketAddr> {
        Some(self.addr)
    }
}

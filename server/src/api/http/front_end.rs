//! HTTP (REST, Server-Sent Events, `/metrics`, the web page) as one of the front-ends:
//! `listen.http` bound when prepared, served again when it moves, when TLS is turned on or
//! off or when its timeouts change.

use futures_util::future::BoxFuture;

use super::Limits;
use tokio_util::sync::CancellationToken;

use crate::api::front_end::{FrontEnd, Listen, Prepare, Running, Start, Starting};
use crate::config::Config;
use crate::service::Service;

pub(crate) struct HttpFrontEnd;

/// The timeouts of `config`'s HTTP and gRPC listeners.
pub(crate) fn limits(config: &Config) -> Limits {
    Limits {
        header_timeout: config.header_timeout,
        body_timeout: config.body_timeout,
        max_connections: config.max_connections,
        max_connections_per_client: config.max_connections_per_client,
    }
}

/// Whether a reload from `old` to `new` serves HTTP and gRPC again where they are: TLS
/// turned on or off, or their timeouts or connection limit changed.
pub(crate) fn served_again(old: &Config, new: &Config) -> bool {
    old.security.tls.is_some() != new.security.tls.is_some()
        || old.header_timeout != new.header_timeout
        || old.body_timeout != new.body_timeout
        || old.max_connections != new.max_connections
        || old.max_connections_per_client != new.max_connections_per_client
}

impl FrontEnd for HttpFrontEnd {
    fn name(&self) -> &'static str {
        "http"
    }

    fn listener(&self) -> Option<&'static str> {
        Some("http")
    }

    fn banner(&self, service: &Service) -> Vec<String> {
        let Some(base) = service.listening.address("http") else {
            return Vec::new();
        };
        vec![
            format!("Web page:  {base}/ui"),
            format!("REST API:  {base}/api/v1/devices"),
        ]
    }

    fn banner_end(&self, service: &Service) -> Vec<String> {
        let Some(base) = service.listening.address("http") else {
            return Vec::new();
        };
        vec![
            format!("Events:    {base}/api/v1/events"),
            format!("OpenAPI:   {base}/api/v1/openapi.json"),
            format!("Metrics:   {base}/metrics"),
            format!("Health:    {base}/livez  {base}/readyz"),
        ]
    }

    fn restarts(&self, old: &Config, new: &Config) -> bool {
        old.http != new.http || served_again(old, new)
    }

    fn prepare<'a>(
        &'a self,
        prepare: &'a Prepare<'a>,
    ) -> BoxFuture<'a, Result<Option<Box<dyn Starting>>, String>> {
        Box::pin(async move {
            let config = prepare.config;
            let was = prepare.old.map(|o| o.http);
            let listen =
                Listen::prepare(prepare, config.http, was, "listen.http", "--http").await?;
            Ok(Some(Box::new(HttpStarting {
                listen,
                limits: limits(config),
            }) as Box<dyn Starting>))
        })
    }
}

struct HttpStarting {
    listen: Listen,
    limits: Limits,
}

impl Starting for HttpStarting {
    fn start(
        self: Box<Self>,
        start: Start,
    ) -> BoxFuture<'static, Result<Box<dyn Running>, String>> {
        Box::pin(async move {
            let Start { service, tls, .. } = start;
            let scheme = if tls.is_some() { "https" } else { "http" };
            let (limits, serving) = (self.limits, service.clone());
            let address = move |addr| format!("{scheme}://{addr}");
            let serve = move |listener, stop: CancellationToken| async move {
                let shutdown = stop.cancelled_owned();
                let served = crate::api::serve_http(listener, serving, limits, tls, shutdown).await;
                if let Err(e) = served {
                    tracing::error!(error = %e, "HTTP server failed");
                }
            };
            let this = *self;
            this.listen
                .serve("listen.http", "http", &service, address, serve)
                .await
        })
    }
}

//! gRPC as one of the front-ends: `listen.grpc` bound when prepared, served again when it
//! moves, when TLS is turned on or off or when the timeouts change.

use futures_util::future::BoxFuture;

use tokio_util::sync::CancellationToken;

use crate::api::front_end::{FrontEnd, Listen, Prepare, Running, Start, Starting};
use crate::api::http::front_end::{limits, served_again};
use crate::config::Config;
use crate::service::Service;

pub(crate) struct GrpcFrontEnd;

impl FrontEnd for GrpcFrontEnd {
    fn name(&self) -> &'static str {
        "grpc"
    }

    fn listener(&self) -> Option<&'static str> {
        Some("grpc")
    }

    fn banner(&self, service: &Service) -> Vec<String> {
        service
            .listening
            .bound("grpc")
            .map(|addr| format!("gRPC:      {addr} (iogate.v1.Gateway, reflection, health)"))
            .into_iter()
            .collect()
    }

    fn restarts(&self, old: &Config, new: &Config) -> bool {
        old.grpc != new.grpc || served_again(old, new)
    }

    fn prepare<'a>(
        &'a self,
        prepare: &'a Prepare<'a>,
    ) -> BoxFuture<'a, Result<Option<Box<dyn Starting>>, String>> {
        Box::pin(async move {
            let config = prepare.config;
            let was = prepare.old.map(|o| o.grpc);
            let listen =
                Listen::prepare(prepare, config.grpc, was, "listen.grpc", "--grpc").await?;
            Ok(Some(Box::new(GrpcStarting {
                listen,
                limits: limits(config),
            }) as Box<dyn Starting>))
        })
    }
}

struct GrpcStarting {
    listen: Listen,
    limits: crate::api::http::Limits,
}

impl Starting for GrpcStarting {
    fn start(
        self: Box<Self>,
        start: Start,
    ) -> BoxFuture<'static, Result<Box<dyn Running>, String>> {
        Box::pin(async move {
            let Start { service, tls, .. } = start;
            let (limits, serving) = (self.limits, service.clone());
            let serve = move |listener, stop: CancellationToken| async move {
                let shutdown = stop.cancelled_owned();
                let served = crate::api::serve_grpc(listener, serving, limits, tls, shutdown).await;
                if let Err(e) = served {
                    tracing::error!(error = %e, "gRPC server failed");
                }
            };
            let this = *self;
            this.listen
                .serve(
                    "listen.grpc",
                    "grpc",
                    &service,
                    |addr| addr.to_string(),
                    serve,
                )
                .await
        })
    }
}

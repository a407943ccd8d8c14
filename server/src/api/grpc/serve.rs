//! The gRPC server on a listener: the gateway's service with health and reflection, every
//! call's token checked against its operation.

use std::future::Future;
use std::sync::Arc;

use tokio::net::TcpListener;

use crate::api::grpc;
use crate::api::grpc::burst;
use crate::api::http::accept;
use crate::service::Service;

/// Serves the gRPC API, with `grpc.health.v1` and server reflection, on `listener` until
/// `shutdown` resolves; connections as the HTTP listener's ([`accept`]).
pub(crate) async fn serve_grpc(
    listener: TcpListener,
    service: Arc<Service>,
    limits: crate::api::http::Limits,
    tls: Option<Arc<crate::tls::Tls>>,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> anyhow::Result<()> {
    use futures_util::StreamExt;
    use iogate_proto::pb::gateway_server::GatewayServer;
    let (health, health_service) = tonic_health::server::health_reporter();
    health.set_serving::<GatewayServer<grpc::GrpcApi>>().await;
    let reflection_v1 = tonic_reflection::server::Builder::configure()
        .register_encoded_file_descriptor_set(iogate_proto::FILE_DESCRIPTOR_SET)
        .register_encoded_file_descriptor_set(tonic_health::pb::FILE_DESCRIPTOR_SET)
        .build_v1()?;
    let reflection_v1alpha = tonic_reflection::server::Builder::configure()
        .register_encoded_file_descriptor_set(iogate_proto::FILE_DESCRIPTOR_SET)
        .register_encoded_file_descriptor_set(tonic_health::pb::FILE_DESCRIPTOR_SET)
        .build_v1alpha()?;
    let bounds = accept::Bounds::of(&service.metrics, true, limits.connections());
    let incoming = accept::ready(listener, bounds, tls, limits.header_timeout)
        .map(|conn| conn.map(burst::Burst::new));
    let tokens = service.tokens.clone();
    tonic::transport::Server::builder()
        // A peer that stops answering HTTP/2 pings is dropped; one connection cannot open
        // more than 256 calls at once.
        .http2_keepalive_interval(Some(std::time::Duration::from_secs(30)))
        .http2_keepalive_timeout(Some(std::time::Duration::from_secs(10)))
        .max_concurrent_streams(Some(256))
        .layer(tower::layer::layer_fn(move |inner| GrpcAuth {
            inner,
            tokens: tokens.clone(),
        }))
        .add_service(health_service)
        .add_service(reflection_v1)
        .add_service(reflection_v1alpha)
        .add_service(grpc::GrpcApi::server(service))
        .serve_with_incoming_shutdown(incoming, shutdown)
        .await?;
    Ok(())
}

/// Refuses a gRPC call without the role its method needs (UNAUTHENTICATED /
/// PERMISSION_DENIED), reading the `authorization` metadata.
#[derive(Clone)]
struct GrpcAuth<S> {
    inner: S,
    tokens: crate::auth::TokenTable,
}

impl<S, B> tower::Service<axum::http::Request<B>> for GrpcAuth<S>
where
    S: tower::Service<axum::http::Request<B>, Response = axum::http::Response<tonic::body::Body>>
        + Clone
        + Send
        + 'static,
    S::Future: Send + 'static,
    B: Send + 'static,
{
    type Response = S::Response;
    type Error = S::Error;
    type Future = std::pin::Pin<
        Box<dyn Future<Output = Result<Self::Response, Self::Error>> + Send + 'static>,
    >;

    fn poll_ready(
        &mut self,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<Result<(), Self::Error>> {
        self.inner.poll_ready(cx)
    }

    fn call(&mut self, request: axum::http::Request<B>) -> Self::Future {
        let denied = grpc::operation(request.uri().path()).and_then(|operation| {
            let header = request
                .headers()
                .get("authorization")
                .and_then(|v| v.to_str().ok());
            self.tokens.allows(header, operation).err()
        });
        match denied {
            None => Box::pin(self.inner.call(request)),
            Some(denied) => {
                let status = match denied {
                    crate::auth::Denied::Unauthenticated => tonic::Status::unauthenticated(
                        "send a known token: authorization: Bearer TOKEN",
                    ),
                    crate::auth::Denied::Forbidden { needed } => tonic::Status::permission_denied(
                        format!("this needs a token with the {} role", needed.name()),
                    ),
                };
                Box::pin(async move { Ok(status.into_http()) })
            }
        }
    }
}

//! The routes of the gRPC service: the generated server, and `Subscribe` answered with
//! messages encoded once.

use super::*;

/// The service `iogate.v1.Gateway`: the generated server's methods, except `Subscribe`,
/// answered here with messages encoded once for all subscribers (the generated server
/// would encode each subscriber's copy of a change).
#[derive(Clone)]
pub(crate) struct GatewayRoutes {
    pub(super) generated: GatewayServer<GrpcApi>,
    pub(super) api: Arc<GrpcApi>,
}

impl NamedService for GatewayRoutes {
    const NAME: &'static str = iogate_proto::SERVICE_NAME;
}

/// `Subscribe` with encoded messages.
struct SubscribeEncoded(Arc<GrpcApi>);

impl ServerStreamingService<pb::SubscribeRequest> for SubscribeEncoded {
    type Response = Bytes;
    type ResponseStream = EncodedStream;
    type Future = BoxFuture<Response<EncodedStream>, Status>;

    fn call(&mut self, request: Request<pb::SubscribeRequest>) -> Self::Future {
        let api = self.0.clone();
        Box::pin(async move {
            let client = request.remote_addr().map(|a| a.ip());
            api.subscribe_encoded(request.into_inner(), client)
                .map(Response::new)
        })
    }
}

impl<B> tower::Service<axum::http::Request<B>> for GatewayRoutes
where
    B: tonic::codegen::Body<Data = Bytes> + Send + 'static,
    B::Error: Into<StdError> + Send + 'static,
{
    type Response = axum::http::Response<tonic::body::Body>;
    type Error = Infallible;
    type Future = BoxFuture<Self::Response, Infallible>;

    fn poll_ready(
        &mut self,
        _cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<Result<(), Infallible>> {
        std::task::Poll::Ready(Ok(()))
    }

    fn call(&mut self, request: axum::http::Request<B>) -> Self::Future {
        if request.uri().path() != SUBSCRIBE_PATH {
            return self.generated.call(request);
        }
        let api = self.api.clone();
        Box::pin(async move {
            let mut grpc =
                tonic::server::Grpc::new(EncodedCodec::<pb::SubscribeRequest>::default())
                    .apply_max_message_size_config(Some(MAX_MESSAGE), Some(MAX_MESSAGE));
            Ok(grpc.server_streaming(SubscribeEncoded(api), request).await)
        })
    }
}

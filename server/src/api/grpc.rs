//! The gRPC service `iogate.v1.Gateway`: each call parses its message, calls the service,
//! and maps the result (or the error, in [`status`]) to protobuf.

use std::convert::Infallible;
use std::pin::Pin;
use std::sync::Arc;
use std::time::Duration;

use bytes::Bytes;
use futures_util::{Stream, StreamExt};
use iogate_proto::codec::EncodedCodec;
use iogate_proto::pb;
use iogate_proto::pb::gateway_server::{Gateway, GatewayServer};
use prost::Message;
use tokio_stream::wrappers::ReceiverStream;
use tonic::codegen::{BoxFuture, StdError};
use tonic::server::{NamedService, ServerStreamingService};
use tonic::{Request, Response, Status, Streaming};

use crate::auth::Operation;
use crate::codec::{Value, ValueError};
use crate::declare::{DeviceDeclaration, Endpoint, LinkDeclaration};
use crate::service::Refusal;
use crate::service::ReloadError;
use crate::service::{Accepted, Change, Prepared, ScanCycle, Service, ServiceError};
use crate::transaction::TransactionSpec;

pub(crate) mod burst;
pub(crate) mod front_end;
mod helpers;
mod routes;
pub(crate) mod serve;
pub(crate) mod to_pb;

use helpers::*;
pub(crate) use routes::GatewayRoutes;

/// Encoded `Update`s.
type EncodedStream = Pin<Box<dyn Stream<Item = Result<Bytes, Status>> + Send>>;
type ExchangeStream = Pin<Box<dyn Stream<Item = Result<pb::ExchangeResponse, Status>> + Send>>;

/// The name of a change's gRPC form (an encoded `Update`) among a field's wire forms.
const GRPC_FORM: &str = "grpc";

const SUBSCRIBE_PATH: &str = "/iogate.v1.Gateway/Subscribe";

/// An `Update` of `kind`, encoded.
fn encoded(kind: pb::update::Kind) -> Bytes {
    Bytes::from(pb::Update { kind: Some(kind) }.encode_to_vec())
}

/// The largest gRPC message either way (a snapshot of thousands of fields fits).
pub(crate) const MAX_MESSAGE: usize = 16 * 1024 * 1024;

pub(crate) struct GrpcApi {
    service: Arc<Service>,
}

/// The gRPC code of each kind of refusal: the gRPC API's one table.
fn grpc_code(refusal: Refusal) -> tonic::Code {
    match refusal {
        Refusal::Invalid => tonic::Code::InvalidArgument,
        Refusal::NotFound | Refusal::Gone => tonic::Code::NotFound,
        Refusal::Conflict => tonic::Code::FailedPrecondition,
        Refusal::Forbidden => tonic::Code::PermissionDenied,
        Refusal::Unavailable => tonic::Code::Unavailable,
        Refusal::TooMany | Refusal::Busy => tonic::Code::ResourceExhausted,
    }
}

/// The gRPC status of a service error.
pub(crate) fn status(e: ServiceError) -> Status {
    let (refusal, _) = e.refusal();
    let mut status = Status::new(grpc_code(refusal), e.to_string());
    // A standby's refusal names the active, for a client to ask there.
    if let ServiceError::Standby(Some(active)) = &e {
        let metadata = status.metadata_mut();
        if let Ok(node) = active.node.parse() {
            metadata.insert("iogate-active-node", node);
        }
        if let Some(Ok(grpc)) = active.addresses.get("grpc").map(|a| a.parse()) {
            metadata.insert("iogate-active-grpc", grpc);
        }
    }
    status
}

/// The operation a gRPC method is (`/iogate.v1.Gateway/Write`): every method of the
/// service named once; health checks need no token (reflection is a read).
pub(crate) fn operation(path: &str) -> Option<Operation> {
    if path.starts_with("/grpc.health.") {
        return None;
    }
    let method = path.rsplit('/').next().unwrap_or("");
    Some(match method {
        "ListProfiles" | "DescribeProfile" | "ListLinks" | "DescribeLink" | "ListDevices"
        | "DescribeDevice" | "Read" | "GetWrite" | "ListTransactions" | "GetHa" => Operation::Read,
        "Subscribe" => Operation::Subscribe,
        "Write" | "Exchange" => Operation::WriteOutputs,
        "Transact" => Operation::Transact,
        "SetTransaction" => Operation::SwitchTransaction,
        "EnsureLink" | "EnsureDevice" | "EnsureTransaction" => Operation::Declare,
        "RemoveDevice" | "RemoveLink" | "RemoveTransaction" => Operation::Remove,
        "ReloadConfig" => Operation::Reload,
        // Not a method of the service (UNIMPLEMENTED): as a read.
        _ => Operation::Read,
    })
}

#[tonic::async_trait]
impl Gateway for GrpcApi {
    async fn list_profiles(
        &self,
        _: Request<pb::ListProfilesRequest>,
    ) -> Result<Response<pb::ListProfilesResponse>, Status> {
        Ok(Response::new(pb::ListProfilesResponse {
            profiles: self
                .service
                .profiles()
                .iter()
                .map(|p| to_pb::profile(p, false))
                .collect(),
        }))
    }

    async fn describe_profile(
        &self,
        request: Request<pb::DescribeProfileRequest>,
    ) -> Result<Response<pb::Profile>, Status> {
        let profile = self
            .service
            .profile(&request.get_ref().name)
            .map_err(status)?;
        Ok(Response::new(to_pb::profile(&profile, true)))
    }

    async fn list_links(
        &self,
        _: Request<pb::ListLinksRequest>,
    ) -> Result<Response<pb::ListLinksResponse>, Status> {
        Ok(Response::new(pb::ListLinksResponse {
            links: self
                .service
                .links()
                .iter()
                .map(|l| to_pb::link(l))
                .collect(),
        }))
    }

    async fn describe_link(
        &self,
        request: Request<pb::DescribeLinkRequest>,
    ) -> Result<Response<pb::Link>, Status> {
        let link = self.service.link(&request.get_ref().name).map_err(status)?;
        Ok(Response::new(to_pb::link(&link)))
    }

    async fn list_devices(
        &self,
        _: Request<pb::ListDevicesRequest>,
    ) -> Result<Response<pb::ListDevicesResponse>, Status> {
        Ok(Response::new(pb::ListDevicesResponse {
            devices: self
                .service
                .devices()
                .iter()
                .map(|d| to_pb::device(d, None))
                .collect(),
        }))
    }

    async fn describe_device(
        &self,
        request: Request<pb::DescribeDeviceRequest>,
    ) -> Result<Response<pb::Device>, Status> {
        let device = self
            .service
            .device(&request.get_ref().name)
            .map_err(status)?;
        Ok(Response::new(to_pb::device(&device, Some(&self.service))))
    }

    async fn read(
        &self,
        request: Request<pb::ReadRequest>,
    ) -> Result<Response<pb::ReadResponse>, Status> {
        let r = request.get_ref();
        let snapshot = self.service.read(&self.select(&r.devices, &r.fields)?);
        Ok(Response::new(pb::ReadResponse {
            values: snapshot
                .values
                .iter()
                .map(|(f, sample)| {
                    to_pb::field_value(&self.service.field_view(&f.device, f.idx, sample))
                })
                .collect(),
            diagnostics: snapshot
                .diagnostics
                .iter()
                .map(|(d, diag)| to_pb::diagnostics(d, diag))
                .collect(),
        }))
    }

    async fn write(
        &self,
        request: Request<pb::WriteRequest>,
    ) -> Result<Response<pb::WriteResponse>, Status> {
        self.service.accepting().map_err(status)?;
        let writes = &request.get_ref().writes;
        if writes.is_empty() {
            return Err(Status::invalid_argument("no writes given"));
        }
        let prepared = writes
            .iter()
            .map(|w| GrpcApi::prepare(&self.service, w))
            .collect();
        let acks = self.service.write_all(prepared).map_err(status)?;
        Ok(Response::new(pb::WriteResponse {
            acks: acks.into_iter().map(ack).collect(),
        }))
    }

    async fn get_write(
        &self,
        request: Request<pb::GetWriteRequest>,
    ) -> Result<Response<pb::WriteStatus>, Status> {
        let record = self
            .service
            .write_outcome(request.get_ref().generation)
            .map_err(status)?;
        let ty = self.service.written_type(&record);
        Ok(Response::new(to_pb::write_status(&record, ty)))
    }

    type SubscribeStream = futures_util::stream::Empty<Result<pb::Update, Status>>;

    /// Never called: [`GatewayRoutes`] answers `Subscribe` before the generated server
    /// would, with updates encoded once for all subscribers ([`GrpcApi::subscribe_encoded`]).
    async fn subscribe(
        &self,
        _request: Request<pb::SubscribeRequest>,
    ) -> Result<Response<Self::SubscribeStream>, Status> {
        Err(Status::internal(
            "Subscribe is answered by the gateway's own route",
        ))
    }

    type ExchangeStream = ExchangeStream;

    async fn exchange(
        &self,
        request: Request<Streaming<pb::ExchangeRequest>>,
    ) -> Result<Response<Self::ExchangeStream>, Status> {
        self.service.accepting().map_err(status)?;
        let client = request.remote_addr().map(|a| a.ip());
        let slot = self.service.stream_slot_for(client).map_err(status)?;
        let mut inbound = request.into_inner();
        let service = self.service.clone();
        let token = service.tasks().token().clone();
        let (tx, rx) = tokio::sync::mpsc::channel(4);
        self.service.tasks().spawn(async move {
            let _slot = slot;
            let mut cycles = ScanCycle::new(service.clone());
            loop {
                let message = tokio::select! {
                    _ = token.cancelled() => break,
                    m = inbound.message() => m,
                };
                let message = match message {
                    Ok(Some(m)) => m,
                    Ok(None) => break,
                    Err(status) => {
                        tracing::debug!(error = %status, "exchange stream ended");
                        break;
                    }
                };
                let outputs = message
                    .outputs
                    .iter()
                    .map(|w| GrpcApi::prepare(&service, w))
                    .collect();
                let outcome = cycles.step(&message.devices, outputs);
                let response = pb::ExchangeResponse {
                    cycle: outcome.cycle,
                    inputs: outcome
                        .inputs()
                        .map(|(d, i)| to_pb::field_value(&service.field_view_now(d, i)))
                        .collect(),
                    diagnostics: outcome
                        .devices
                        .iter()
                        .map(|d| to_pb::diagnostics(d, &d.diagnostics()))
                        .collect(),
                    acks: outcome.acks.into_iter().map(ack).collect(),
                    errors: outcome.errors,
                };
                if tx.send(Ok(response)).await.is_err() {
                    break;
                }
            }
        });
        Ok(Response::new(Box::pin(ReceiverStream::new(rx))))
    }

    async fn ensure_link(
        &self,
        request: Request<pb::EnsureLinkRequest>,
    ) -> Result<Response<pb::EnsureLinkResponse>, Status> {
        self.service.accepting().map_err(status)?;
        let r = request.into_inner();
        let endpoint = match r.transport {
            Some(pb::ensure_link_request::Transport::Serial(s)) => Endpoint::Serial {
                port: s.port,
                baud: s.baud.into(),
                parity: s.parity,
                data_bits: s.data_bits.into(),
                stop_bits: s.stop_bits.into(),
                framing: s.framing,
            },
            Some(pb::ensure_link_request::Transport::Tcp(t)) => Endpoint::Tcp {
                host: t.host,
                port: t.port.into(),
                framing: t.framing,
            },
            None => {
                return Err(Status::invalid_argument(
                    "a link needs `serial` or `tcp` settings",
                ));
            }
        };
        let ensured = self
            .service
            .ensure_link(LinkDeclaration {
                name: (!r.name.is_empty()).then_some(r.name),
                endpoint,
                guard_time: Duration::from_millis(r.guard_time_ms.into()),
            })
            .map_err(status)?;
        Ok(Response::new(pb::EnsureLinkResponse {
            link: Some(to_pb::link(&ensured.value)),
            created: ensured.created,
        }))
    }

    async fn transact(
        &self,
        request: Request<pb::TransactRequest>,
    ) -> Result<Response<pb::TransactResponse>, Status> {
        let (link, spec) = transaction_spec(request.into_inner());
        let o = self.service.transact(&link, &spec).await.map_err(status)?;
        Ok(Response::new(transact_response(&o)))
    }

    async fn ensure_transaction(
        &self,
        request: Request<pb::EnsureTransactionRequest>,
    ) -> Result<Response<pb::TransactionStatus>, Status> {
        let r = request.into_inner();
        let (link, spec) = transaction_spec(r.parameters.unwrap_or_default());
        let (s, _) = self
            .service
            .ensure_transaction(crate::config::transactions::StandingConfig {
                name: r.name,
                link,
                spec,
                period: Duration::from_millis(r.period_ms.into()),
                enabled: r.enabled,
                line: 0,
            })
            .map_err(status)?;
        Ok(Response::new(transaction_status(&s, &s.status())))
    }

    async fn set_transaction(
        &self,
        request: Request<pb::SetTransactionRequest>,
    ) -> Result<Response<pb::TransactionStatus>, Status> {
        let r = request.into_inner();
        let mut s = self.service.transaction(&r.name).map_err(status)?;
        if r.set_values {
            let values = r.values.into_iter().map(json_number).collect();
            s = self
                .service
                .set_transaction_values(&r.name, values)
                .map_err(status)?;
        }
        if let Some(enabled) = r.enabled {
            s = self
                .service
                .enable_transaction(&r.name, enabled)
                .map_err(status)?;
        }
        if r.trigger {
            s = self.service.trigger_transaction(&r.name).map_err(status)?;
        }
        Ok(Response::new(transaction_status(&s, &s.status())))
    }

    async fn list_transactions(
        &self,
        _: Request<pb::ListTransactionsRequest>,
    ) -> Result<Response<pb::ListTransactionsResponse>, Status> {
        Ok(Response::new(pb::ListTransactionsResponse {
            transactions: self
                .service
                .standing()
                .all()
                .iter()
                .map(|s| transaction_status(s, &s.status()))
                .collect(),
        }))
    }

    async fn ensure_device(
        &self,
        request: Request<pb::EnsureDeviceRequest>,
    ) -> Result<Response<pb::EnsureDeviceResponse>, Status> {
        self.service.accepting().map_err(status)?;
        let r = request.into_inner();
        let ensured = self
            .service
            .ensure_device(DeviceDeclaration {
                name: r.name,
                profile: r.profile,
                link: r.link,
                slave_id: r.slave_id,
                refresh_rate: Duration::from_millis(r.refresh_rate_ms.into()),
                timeout: (r.timeout_ms > 0).then(|| Duration::from_millis(r.timeout_ms.into())),
            })
            .map_err(status)?;
        Ok(Response::new(pb::EnsureDeviceResponse {
            device: Some(to_pb::device(&ensured.value, None)),
            created: ensured.created,
        }))
    }

    async fn remove_device(
        &self,
        request: Request<pb::RemoveDeviceRequest>,
    ) -> Result<Response<pb::RemoveDeviceResponse>, Status> {
        self.service
            .remove_device(&request.into_inner().name)
            .map_err(status)?;
        Ok(Response::new(pb::RemoveDeviceResponse {}))
    }

    async fn remove_link(
        &self,
        request: Request<pb::RemoveLinkRequest>,
    ) -> Result<Response<pb::RemoveLinkResponse>, Status> {
        self.service
            .remove_link(&request.into_inner().name)
            .map_err(status)?;
        Ok(Response::new(pb::RemoveLinkResponse {}))
    }

    async fn remove_transaction(
        &self,
        request: Request<pb::RemoveTransactionRequest>,
    ) -> Result<Response<pb::RemoveTransactionResponse>, Status> {
        self.service
            .remove_transaction(&request.into_inner().name)
            .map_err(status)?;
        Ok(Response::new(pb::RemoveTransactionResponse {}))
    }

    async fn reload_config(
        &self,
        request: Request<pb::ReloadConfigRequest>,
    ) -> Result<Response<pb::ReloadConfigResponse>, Status> {
        let dry_run = request.into_inner().dry_run;
        let report = self
            .service
            .reload(crate::service::Trigger::Grpc, dry_run)
            .await
            .map_err(|e| match e {
                ReloadError::Invalid(problems) => Status::invalid_argument(format!(
                    "invalid configuration; nothing was changed:\n{problems}"
                )),
                other => Status::failed_precondition(other.to_string()),
            })?;
        Ok(Response::new(pb::ReloadConfigResponse {
            applied: !dry_run,
            report: Some(to_pb::config_report(&report)),
        }))
    }

    async fn get_ha(
        &self,
        _request: Request<pb::GetHaRequest>,
    ) -> Result<Response<pb::HaStatus>, Status> {
        Ok(Response::new(to_pb::ha_status(self.service.ha())))
    }
}

#[cfg(test)]
mod tests;

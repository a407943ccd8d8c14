//! The gRPC service `iogate.v1.Gateway`.

use std::collections::BTreeMap;
use std::pin::Pin;
use std::sync::Arc;
use std::time::Duration;

use futures_util::{Stream, StreamExt};
use iogate_proto::pb;
use iogate_proto::pb::gateway_server::Gateway;
use tokio_stream::StreamMap;
use tokio_stream::wrappers::{ReceiverStream, WatchStream};
use tonic::{Request, Response, Status, Streaming};

use super::pb as convert;
use crate::app::AppState;
use crate::cache::{AccessError, Device};
use crate::codec::{Value, ValueError};
use crate::config::{Framing, Transport};
use crate::declare::{self, DeclareError, DeviceDeclaration, LinkDeclaration};
use crate::profile::Direction;
use crate::writes::Lookup;

type UpdateStream = Pin<Box<dyn Stream<Item = Result<pb::Update, Status>> + Send>>;
type ExchangeStream = Pin<Box<dyn Stream<Item = Result<pb::ExchangeResponse, Status>> + Send>>;

pub struct GrpcApi {
    state: Arc<AppState>,
}

impl GrpcApi {
    pub fn new(state: Arc<AppState>) -> Self {
        GrpcApi { state }
    }

    /// The chosen fields (all of them when nothing is chosen), each once, in order.
    fn select(
        &self,
        devices: &[String],
        fields: &[pb::FieldRef],
    ) -> Result<Vec<(Arc<Device>, usize)>, Status> {
        let cache = &self.state.cache;
        let mut chosen: Vec<(Arc<Device>, usize)> = Vec::new();
        let mut push = |device: &Arc<Device>, idx: usize| {
            if !chosen
                .iter()
                .any(|(d, i)| Arc::ptr_eq(d, device) && *i == idx)
            {
                chosen.push((device.clone(), idx));
            }
        };
        let all = devices.is_empty() && fields.is_empty();
        let named: Vec<Arc<Device>> = if all {
            cache.devices()
        } else {
            devices
                .iter()
                .map(|n| cache.device(n))
                .collect::<Result<_, _>>()?
        };
        for device in &named {
            for idx in 0..device.profile.fields.len() {
                push(device, idx);
            }
        }
        for f in fields {
            let device = cache.device(&f.device)?;
            let idx = device.field_index(&f.field)?;
            push(&device, idx);
        }
        Ok(chosen)
    }

    /// Converts and checks one write; nothing is written.
    fn prepare(&self, w: &pb::FieldWrite) -> Result<(Arc<Device>, usize, Value), Status> {
        let device = self.state.cache.device(&w.device)?;
        let idx = device.field_index(&w.field)?;
        let field = device.field(idx);
        let value = w
            .value
            .as_ref()
            .ok_or(ValueError::Missing { ty: field.ty })
            .and_then(|v| Value::from_pb_as(field.ty, v))
            .map_err(|e| AccessError::InvalidValue {
                device: device.name().to_owned(),
                field: field.name.clone(),
                ty: field.ty,
                reason: e.to_string(),
            })?;
        device.check_write(idx, &value)?;
        Ok((device, idx, value))
    }

    fn shutting_down(&self) -> Result<(), Status> {
        if self.state.token.is_cancelled() {
            Err(Status::unavailable("the gateway is shutting down"))
        } else {
            Ok(())
        }
    }
}

impl From<AccessError> for Status {
    fn from(e: AccessError) -> Self {
        let message = e.to_string();
        match e {
            AccessError::UnknownDevice(_)
            | AccessError::UnknownField { .. }
            | AccessError::UnknownLink(_)
            | AccessError::UnknownProfile(_) => Status::not_found(message),
            AccessError::NotWritable { .. }
            | AccessError::NotAnInput { .. }
            | AccessError::NotSimulated(_) => Status::failed_precondition(message),
            AccessError::InvalidValue { .. } => Status::invalid_argument(message),
        }
    }
}

impl From<DeclareError> for Status {
    fn from(e: DeclareError) -> Self {
        match e {
            DeclareError::Invalid(m) => Status::invalid_argument(m),
            DeclareError::NotFound(m) => Status::not_found(m),
            DeclareError::Conflict(m) => Status::failed_precondition(m),
        }
    }
}

#[tonic::async_trait]
impl Gateway for GrpcApi {
    async fn list_profiles(
        &self,
        _: Request<pb::ListProfilesRequest>,
    ) -> Result<Response<pb::ListProfilesResponse>, Status> {
        Ok(Response::new(pb::ListProfilesResponse {
            profiles: self
                .state
                .cache
                .catalog
                .iter()
                .map(|p| convert::profile(p, false))
                .collect(),
        }))
    }

    async fn describe_profile(
        &self,
        request: Request<pb::DescribeProfileRequest>,
    ) -> Result<Response<pb::Profile>, Status> {
        let profile = self.state.cache.profile(&request.get_ref().name)?;
        Ok(Response::new(convert::profile(profile, true)))
    }

    async fn list_links(
        &self,
        _: Request<pb::ListLinksRequest>,
    ) -> Result<Response<pb::ListLinksResponse>, Status> {
        Ok(Response::new(pb::ListLinksResponse {
            links: self
                .state
                .cache
                .links()
                .iter()
                .map(|l| convert::link(l))
                .collect(),
        }))
    }

    async fn describe_link(
        &self,
        request: Request<pb::DescribeLinkRequest>,
    ) -> Result<Response<pb::Link>, Status> {
        let link = self.state.cache.link(&request.get_ref().name)?;
        Ok(Response::new(convert::link(&link)))
    }

    async fn list_devices(
        &self,
        _: Request<pb::ListDevicesRequest>,
    ) -> Result<Response<pb::ListDevicesResponse>, Status> {
        Ok(Response::new(pb::ListDevicesResponse {
            devices: self
                .state
                .cache
                .devices()
                .iter()
                .map(|d| convert::device(d, false))
                .collect(),
        }))
    }

    async fn describe_device(
        &self,
        request: Request<pb::DescribeDeviceRequest>,
    ) -> Result<Response<pb::Device>, Status> {
        let device = self.state.cache.device(&request.get_ref().name)?;
        Ok(Response::new(convert::device(&device, true)))
    }

    async fn read(
        &self,
        request: Request<pb::ReadRequest>,
    ) -> Result<Response<pb::ReadResponse>, Status> {
        let r = request.get_ref();
        let chosen = self.select(&r.devices, &r.fields)?;
        let mut devices: Vec<&Arc<Device>> = Vec::new();
        for (d, _) in &chosen {
            if !devices.iter().any(|x| Arc::ptr_eq(x, d)) {
                devices.push(d);
            }
        }
        Ok(Response::new(pb::ReadResponse {
            values: chosen
                .iter()
                .map(|(d, i)| convert::field_value(d, *i, &d.sample(*i)))
                .collect(),
            diagnostics: devices.iter().map(|d| convert::diagnostics(d)).collect(),
        }))
    }

    async fn write(
        &self,
        request: Request<pb::WriteRequest>,
    ) -> Result<Response<pb::WriteResponse>, Status> {
        self.shutting_down()?;
        let writes = &request.get_ref().writes;
        if writes.is_empty() {
            return Err(Status::invalid_argument("no writes given"));
        }
        let mut prepared = Vec::with_capacity(writes.len());
        let mut refused: Vec<Status> = Vec::new();
        for w in writes {
            match self.prepare(w) {
                Ok(p) => prepared.push(p),
                Err(e) => refused.push(e),
            }
        }
        if let Some(first) = refused.first() {
            let all: Vec<&str> = refused.iter().map(Status::message).collect();
            return Err(Status::new(
                first.code(),
                format!("nothing was written: {}", all.join("; ")),
            ));
        }
        let mut acks = Vec::with_capacity(prepared.len());
        for (device, idx, value) in prepared {
            let generation = device.request_write(idx, value)?;
            acks.push(pb::WriteAck {
                device: device.name().to_owned(),
                field: device.field(idx).name.clone(),
                generation,
            });
        }
        Ok(Response::new(pb::WriteResponse { acks }))
    }

    async fn get_write(
        &self,
        request: Request<pb::GetWriteRequest>,
    ) -> Result<Response<pb::WriteStatus>, Status> {
        let generation = request.get_ref().generation;
        match self.state.cache.writes.get(generation) {
            Lookup::Found(record) => {
                let ty = self
                    .state
                    .cache
                    .device(&record.device)
                    .ok()
                    .and_then(|d| d.profile.field_index(&record.field).map(|i| d.field(i).ty));
                Ok(Response::new(convert::write_status(&record, ty)))
            }
            Lookup::Expired => Err(Status::not_found(format!(
                "write {generation} is older than the last {} writes kept",
                crate::writes::WRITE_LOG_CAPACITY
            ))),
            Lookup::Unknown => Err(Status::not_found(format!(
                "no write has generation {generation}"
            ))),
        }
    }

    type SubscribeStream = UpdateStream;

    async fn subscribe(
        &self,
        request: Request<pb::SubscribeRequest>,
    ) -> Result<Response<Self::SubscribeStream>, Status> {
        self.shutting_down()?;
        let r = request.into_inner();
        let chosen = self.select(&r.devices, &r.fields)?;
        type Updates = Pin<Box<dyn Stream<Item = pb::Update> + Send>>;
        let mut streams: StreamMap<(usize, usize), Updates> = StreamMap::new();
        let mut seen: BTreeMap<String, usize> = BTreeMap::new();
        for (n, (device, idx)) in chosen.into_iter().enumerate() {
            if r.diagnostics && !seen.contains_key(device.name()) {
                seen.insert(device.name().to_owned(), n);
                let d = device.clone();
                let diag =
                    WatchStream::new(device.subscribe_diagnostics()).map(move |_| pb::Update {
                        kind: Some(pb::update::Kind::Diagnostics(convert::diagnostics(&d))),
                    });
                streams.insert((n, usize::MAX), Box::pin(diag));
            }
            let d = device.clone();
            let values = WatchStream::new(device.subscribe(idx)).map(move |sample| pb::Update {
                kind: Some(pb::update::Kind::Value(convert::field_value(
                    &d, idx, &sample,
                ))),
            });
            streams.insert((n, idx), Box::pin(values));
        }
        let stream = streams
            .map(|(_, update)| Ok(update))
            .take_until(self.state.token.clone().cancelled_owned());
        Ok(Response::new(Box::pin(stream)))
    }

    type ExchangeStream = ExchangeStream;

    async fn exchange(
        &self,
        request: Request<Streaming<pb::ExchangeRequest>>,
    ) -> Result<Response<Self::ExchangeStream>, Status> {
        self.shutting_down()?;
        let mut inbound = request.into_inner();
        let state = self.state.clone();
        let (tx, rx) = tokio::sync::mpsc::channel(4);
        tokio::spawn(async move {
            let api = GrpcApi::new(state.clone());
            let mut devices: Vec<Arc<Device>> = Vec::new();
            let mut cycle = 0u64;
            loop {
                let message = tokio::select! {
                    _ = state.token.cancelled() => break,
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
                let mut errors = Vec::new();
                if !message.devices.is_empty() {
                    devices.clear();
                    for name in &message.devices {
                        match state.cache.device(name) {
                            Ok(d) => devices.push(d),
                            Err(e) => errors.push(e.to_string()),
                        }
                    }
                }
                let mut acks = Vec::new();
                for out in &message.outputs {
                    match api.prepare(out) {
                        // Unchanged outputs are not written again.
                        Ok((device, idx, value))
                            if device.latest_value(idx).as_ref() == Some(&value) => {}
                        Ok((device, idx, value)) => match device.request_write(idx, value) {
                            Ok(generation) => acks.push(pb::WriteAck {
                                device: device.name().to_owned(),
                                field: device.field(idx).name.clone(),
                                generation,
                            }),
                            Err(e) => errors.push(e.to_string()),
                        },
                        Err(status) => errors.push(status.message().to_owned()),
                    }
                }
                cycle += 1;
                let response = pb::ExchangeResponse {
                    cycle,
                    inputs: devices
                        .iter()
                        .flat_map(|d| {
                            (0..d.profile.fields.len())
                                .filter(|&i| d.field(i).direction != Direction::Output)
                                .map(|i| convert::field_value(d, i, &d.sample(i)))
                        })
                        .collect(),
                    diagnostics: devices.iter().map(|d| convert::diagnostics(d)).collect(),
                    acks,
                    errors,
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
        self.shutting_down()?;
        let r = request.into_inner();
        let transport = match r.transport {
            Some(pb::ensure_link_request::Transport::Serial(s)) => {
                Transport::Serial(convert::serial_settings(&s).map_err(Status::invalid_argument)?)
            }
            Some(pb::ensure_link_request::Transport::Tcp(t)) => {
                let framing: Framing = declare::parse_framing(&t.framing).ok_or_else(|| {
                    Status::invalid_argument(format!(
                        "unknown framing `{}` (expected mbap or rtu)",
                        t.framing
                    ))
                })?;
                Transport::Tcp {
                    host: t.host,
                    port: if t.port == 0 {
                        502
                    } else {
                        u16::try_from(t.port).map_err(|_| {
                            Status::invalid_argument(format!("TCP port {} is past 65535", t.port))
                        })?
                    },
                    framing,
                }
            }
            None => {
                return Err(Status::invalid_argument(
                    "a link needs `serial` or `tcp` settings",
                ));
            }
        };
        let ensured = declare::ensure_link(
            &self.state.cache,
            &self.state.tasks,
            LinkDeclaration {
                name: (!r.name.is_empty()).then_some(r.name),
                transport,
                guard_time: Duration::from_millis(r.guard_time_ms.into()),
            },
        )?;
        Ok(Response::new(pb::EnsureLinkResponse {
            link: Some(convert::link(&ensured.value)),
            created: ensured.created,
        }))
    }

    async fn ensure_device(
        &self,
        request: Request<pb::EnsureDeviceRequest>,
    ) -> Result<Response<pb::EnsureDeviceResponse>, Status> {
        self.shutting_down()?;
        let r = request.into_inner();
        let ensured = declare::ensure_device(
            &self.state.cache,
            &self.state.tasks,
            DeviceDeclaration {
                name: r.name,
                profile: r.profile,
                link: r.link,
                slave_id: r.slave_id,
                refresh_rate: Duration::from_millis(r.refresh_rate_ms.into()),
                timeout: (r.timeout_ms > 0).then(|| Duration::from_millis(r.timeout_ms.into())),
            },
        )?;
        Ok(Response::new(pb::EnsureDeviceResponse {
            device: Some(convert::device(&ensured.value, false)),
            created: ensured.created,
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::app::{Setup, Tasks};
    use crate::cache::Cache;
    use crate::metrics::Metrics;

    #[tokio::test]
    async fn a_slow_subscriber_gets_the_newest_value_not_a_backlog() {
        // No device tasks run: only this test changes the value.
        let setup = Setup::demo().expect("demo");
        let cache = Arc::new(Cache::new(&setup.config, setup.catalog));
        let tasks = Tasks::new(
            tokio_util::task::TaskTracker::new(),
            tokio_util::sync::CancellationToken::new(),
            Arc::new(Metrics::new()),
        );
        let state = Arc::new(AppState::new(cache, tasks));
        let api = GrpcApi::new(state.clone());
        let request = pb::SubscribeRequest {
            devices: Vec::new(),
            fields: vec![pb::FieldRef {
                device: "plant".into(),
                field: "Recipe".into(),
            }],
            diagnostics: false,
        };
        let mut stream = api
            .subscribe(Request::new(request))
            .await
            .expect("subscribe")
            .into_inner();
        let first = stream.next().await.expect("current value").expect("ok");
        assert!(matches!(first.kind, Some(pb::update::Kind::Value(_))));

        // 50 changes while the subscriber reads nothing.
        let plant = state.cache.device("plant").expect("plant");
        let recipe = plant.field_index("Recipe").expect("field");
        for n in 1..=50u64 {
            plant.publish(recipe, Ok(Value::UInt(n)));
        }
        let next = stream.next().await.expect("an update").expect("ok");
        let Some(pb::update::Kind::Value(v)) = next.kind else {
            panic!("not a value")
        };
        assert_eq!(
            v.value.and_then(|v| v.kind),
            Some(pb::value::Kind::UintValue(50)),
            "the newest value, not the first change"
        );
        let pending = tokio::time::timeout(Duration::from_millis(50), stream.next()).await;
        assert!(pending.is_err(), "nothing else is queued: {pending:?}");
    }
}

//! A typed async client for iogate's gRPC API.
//!
//! ```no_run
//! # async fn demo() -> Result<(), iogate_client::Error> {
//! use iogate_client::{Client, Value};
//! let mut client = Client::connect("http://127.0.0.1:50051").await?;
//! let generation = client.write("sim", "DO_0", Value::Bool(true)).await?;
//! let status = client.wait_write(generation, std::time::Duration::from_secs(2)).await?;
//! println!("{status:?}");
//! # Ok(()) }
//! ```
#![forbid(unsafe_code)]
#![warn(missing_docs)]

use std::time::Duration;

use futures_util::{Stream, StreamExt};
use iogate_proto::pb;
use iogate_proto::pb::gateway_client::GatewayClient;
use serde::Serialize;
use tonic::transport::Channel;

mod declare;
pub mod fb;
mod pair;
mod types;

/// How a raw transaction ended, as the read and write function blocks report it.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct TransactOutcome {
    /// The last command got a correct response.
    pub actual: bool,
    /// 4 done; -1 interface unavailable; -2 response timeout; -3 unknown error.
    pub state: i32,
    /// A read's value, after divisor and precision.
    pub value: Option<f64>,
    /// The read block's message for what went wrong.
    pub error: Option<String>,
    /// The frames in hex.
    pub request: String,
    /// The answer's frame in hex, when one came.
    pub response: Option<String>,
    /// How long it took.
    pub elapsed_ms: f64,
}

/// IEC 61131-3 located addresses (`%IX0.0`, `%QW2`), for binding `AT` variables.
pub use iogate_types::located::{Area, Location, LocationError, Size};
pub use types::{
    DeviceInfo, Diagnostics, Direction, FieldInfo, FieldValue, IecType, LayoutMember, LinkInfo,
    ProfileInfo, Quality, Update, Value, ValueError, WriteOutcome, WriteStatus,
};

pub use declare::{DeviceDeclaration, SerialLink};
pub use iogate_proto::pb as proto;
pub use pair::{FOLLOW_PATIENCE, HaStatus};

/// What went wrong talking to the gateway.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The gateway could not be reached.
    #[error("cannot connect to {url}: {source}")]
    Connect {
        /// The address tried.
        url: String,
        /// Why it failed.
        source: tonic::transport::Error,
    },
    /// The gateway refused the request; `code` is the gRPC status code.
    #[error("{message} ({code:?})")]
    Status {
        /// The gRPC status code.
        code: tonic::Code,
        /// The gateway's message, naming the problem.
        message: String,
    },
    /// The answer lacked something it must have.
    #[error("unexpected answer: {0}")]
    Protocol(String),
    /// The request could not be made (a bad argument).
    #[error("{0}")]
    Invalid(String),
}

impl From<tonic::Status> for Error {
    fn from(s: tonic::Status) -> Self {
        Error::Status {
            code: s.code(),
            message: s.message().to_owned(),
        }
    }
}

/// Which fields to read or subscribe to: every field of `devices` plus each of `fields`;
/// nothing chosen means everything.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Selection {
    /// Devices whose every field is chosen.
    pub devices: Vec<String>,
    /// Single fields, `(device, field)`.
    pub fields: Vec<(String, String)>,
}

impl Selection {
    /// Everything.
    pub fn all() -> Selection {
        Selection::default()
    }

    /// Every field of one device.
    pub fn device(name: impl Into<String>) -> Selection {
        Selection {
            devices: vec![name.into()],
            fields: Vec::new(),
        }
    }

    /// One field.
    pub fn field(device: impl Into<String>, field: impl Into<String>) -> Selection {
        Selection {
            devices: Vec::new(),
            fields: vec![(device.into(), field.into())],
        }
    }

    fn refs(&self) -> Vec<pb::FieldRef> {
        self.fields
            .iter()
            .map(|(device, field)| pb::FieldRef {
                device: device.clone(),
                field: field.clone(),
            })
            .collect()
    }
}

/// One scan cycle's answer on an exchange stream.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ExchangeReply {
    /// The cycle's number on this stream.
    pub cycle: u64,
    /// The inputs (and inouts) of the chosen devices.
    pub inputs: Vec<FieldValue>,
    /// The chosen devices' diagnostics.
    pub diagnostics: Vec<Diagnostics>,
    /// Generations of the outputs written this cycle (changed values only).
    pub written: Vec<(String, String, u64)>,
    /// What the cycle refused or found, as messages.
    pub errors: Vec<String>,
}

/// A scan-cycle exchange: send outputs, get inputs and diagnostics.
pub struct Exchange {
    tx: tokio::sync::mpsc::Sender<pb::ExchangeRequest>,
    rx: tonic::Streaming<pb::ExchangeResponse>,
}

impl Exchange {
    /// One scan cycle: `outputs` as (device, field, value), and the devices whose inputs to
    /// answer with (empty keeps the previous choice).
    pub async fn cycle(
        &mut self,
        outputs: &[(&str, &str, Value)],
        devices: &[&str],
    ) -> Result<ExchangeReply, Error> {
        let request = pb::ExchangeRequest {
            outputs: outputs
                .iter()
                .map(|(d, f, v)| pb::FieldWrite {
                    device: (*d).to_owned(),
                    field: (*f).to_owned(),
                    value: Some(v.to_pb(None)),
                    relinquish: false,
                })
                .collect(),
            devices: devices.iter().map(|d| (*d).to_owned()).collect(),
        };
        self.tx
            .send(request)
            .await
            .map_err(|_| Error::Protocol("the exchange stream is closed".into()))?;
        let reply = self
            .rx
            .message()
            .await?
            .ok_or_else(|| Error::Protocol("the exchange stream ended".into()))?;
        Ok(ExchangeReply {
            cycle: reply.cycle,
            inputs: reply.inputs.into_iter().map(FieldValue::from_pb).collect(),
            diagnostics: reply
                .diagnostics
                .into_iter()
                .map(Diagnostics::from_pb)
                .collect(),
            written: reply
                .acks
                .into_iter()
                .map(|a| (a.device, a.field, a.generation))
                .collect(),
            errors: reply.errors,
        })
    }
}

/// A connection to an iogate gateway.
#[derive(Debug, Clone)]
pub struct Client {
    inner: GatewayClient<Channel>,
    /// Both nodes' addresses, for a client of an active/standby pair.
    urls: Vec<String>,
}

impl Client {
    /// Connects to `url`, e.g. `http://127.0.0.1:50051`.
    pub async fn connect(url: &str) -> Result<Client, Error> {
        let inner = GatewayClient::connect(url.to_owned())
            .await
            .map_err(|source| Error::Connect {
                url: url.to_owned(),
                source,
            })?;
        Ok(Client {
            inner,
            urls: Vec::new(),
        })
    }

    /// The generated stub, for anything this wrapper does not cover.
    pub fn raw(&mut self) -> &mut GatewayClient<Channel> {
        &mut self.inner
    }

    /// Every profile.
    pub async fn profiles(&mut self) -> Result<Vec<ProfileInfo>, Error> {
        let r = self.inner.list_profiles(pb::ListProfilesRequest {}).await?;
        Ok(r.into_inner()
            .profiles
            .into_iter()
            .map(ProfileInfo::from_pb)
            .collect())
    }

    /// One profile, with its fields and function-block layout.
    pub async fn profile(&mut self, name: &str) -> Result<ProfileInfo, Error> {
        let r = self
            .inner
            .describe_profile(pb::DescribeProfileRequest { name: name.into() })
            .await?;
        Ok(ProfileInfo::from_pb(r.into_inner()))
    }

    /// Every link with its diagnostics.
    pub async fn links(&mut self) -> Result<Vec<LinkInfo>, Error> {
        let r = self.inner.list_links(pb::ListLinksRequest {}).await?;
        Ok(r.into_inner()
            .links
            .into_iter()
            .map(LinkInfo::from_pb)
            .collect())
    }

    /// Every device with its diagnostics.
    pub async fn devices(&mut self) -> Result<Vec<DeviceInfo>, Error> {
        let r = self.inner.list_devices(pb::ListDevicesRequest {}).await?;
        Ok(r.into_inner()
            .devices
            .into_iter()
            .map(DeviceInfo::from_pb)
            .collect())
    }

    /// One device with every field's value.
    pub async fn device(&mut self, name: &str) -> Result<DeviceInfo, Error> {
        let r = self
            .inner
            .describe_device(pb::DescribeDeviceRequest { name: name.into() })
            .await?;
        Ok(DeviceInfo::from_pb(r.into_inner()))
    }

    /// A snapshot of the chosen fields.
    pub async fn read(&mut self, selection: &Selection) -> Result<Vec<FieldValue>, Error> {
        let r = self
            .inner
            .read(pb::ReadRequest {
                devices: selection.devices.clone(),
                fields: selection.refs(),
            })
            .await?;
        Ok(r.into_inner()
            .values
            .into_iter()
            .map(FieldValue::from_pb)
            .collect())
    }

    /// One field's value.
    pub async fn get(&mut self, device: &str, field: &str) -> Result<FieldValue, Error> {
        self.read(&Selection::field(device, field))
            .await?
            .into_iter()
            .next()
            .ok_or_else(|| Error::Protocol("no value in the answer".into()))
    }

    /// Writes one field; answers the write's generation.
    pub async fn write(&mut self, device: &str, field: &str, value: Value) -> Result<u64, Error> {
        Ok(self.write_many(&[(device, field, value)]).await?[0])
    }

    /// Writes several fields at once: all are accepted or none. A client of a pair whose
    /// node refused it (`UNAVAILABLE`: a standby, or a node lost) asks the active again.
    pub async fn write_many(&mut self, writes: &[(&str, &str, Value)]) -> Result<Vec<u64>, Error> {
        match self.write_once(writes).await {
            Err(e) if self.should_follow(&e) => {
                self.follow_active().await?;
                self.write_once(writes).await
            }
            other => other,
        }
    }

    async fn write_once(&mut self, writes: &[(&str, &str, Value)]) -> Result<Vec<u64>, Error> {
        let r = self
            .inner
            .write(pb::WriteRequest {
                writes: writes
                    .iter()
                    .map(|(d, f, v)| pb::FieldWrite {
                        device: (*d).to_owned(),
                        field: (*f).to_owned(),
                        value: Some(v.to_pb(None)),
                        relinquish: false,
                    })
                    .collect(),
            })
            .await?;
        let acks = r.into_inner().acks;
        if acks.len() != writes.len() {
            return Err(Error::Protocol(format!(
                "{} acks for {} writes",
                acks.len(),
                writes.len()
            )));
        }
        Ok(acks.into_iter().map(|a| a.generation).collect())
    }

    /// Relinquishes an output (BACnet: NULL at the field's priority, so a lower priority or
    /// the relinquish default takes over); refused where the field's protocol has none.
    /// Answers the write's generation.
    pub async fn relinquish(&mut self, device: &str, field: &str) -> Result<u64, Error> {
        let write = pb::FieldWrite {
            device: device.to_owned(),
            field: field.to_owned(),
            value: None,
            relinquish: true,
        };
        let r = self
            .inner
            .write(pb::WriteRequest {
                writes: vec![write],
            })
            .await?;
        match r.into_inner().acks.as_slice() {
            [ack] => Ok(ack.generation),
            acks => Err(Error::Protocol(format!("{} acks for 1 write", acks.len()))),
        }
    }

    /// Where the write with `generation` stands.
    /// A client of a pair follows the active when its node is lost: the outcome of a write
    /// the old active took is on the new one.
    pub async fn write_status(&mut self, generation: u64) -> Result<WriteStatus, Error> {
        let request = pb::GetWriteRequest { generation };
        let r = match self.inner.get_write(request).await {
            Err(e) if self.should_follow(&e.clone().into()) => {
                self.follow_active().await?;
                self.inner.get_write(request).await?
            }
            other => other?,
        };
        Ok(WriteStatus::from_pb(r.into_inner()))
    }

    /// Waits until a write is no longer pending, at most `patience`.
    pub async fn wait_write(
        &mut self,
        generation: u64,
        patience: Duration,
    ) -> Result<WriteStatus, Error> {
        let deadline = tokio::time::Instant::now() + patience;
        loop {
            let status = self.write_status(generation).await?;
            if status.outcome != WriteOutcome::Pending || tokio::time::Instant::now() >= deadline {
                return Ok(status);
            }
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    }

    /// Current values first, then every change; with `diagnostics`, the devices'
    /// diagnostics changes too.
    pub async fn subscribe(
        &mut self,
        selection: &Selection,
        diagnostics: bool,
    ) -> Result<impl Stream<Item = Result<Update, Error>> + use<>, Error> {
        let stream = self
            .inner
            .subscribe(pb::SubscribeRequest {
                devices: selection.devices.clone(),
                fields: selection.refs(),
                diagnostics,
                transactions: false,
            })
            .await?
            .into_inner();
        Ok(stream.map(|item| {
            let update = item?;
            match update.kind {
                Some(pb::update::Kind::Value(v)) => Ok(Update::Value(FieldValue::from_pb(v))),
                Some(pb::update::Kind::Diagnostics(d)) => {
                    Ok(Update::Diagnostics(Diagnostics::from_pb(d)))
                }
                Some(pb::update::Kind::Removed(r)) => Ok(Update::Removed {
                    device: r.device,
                    field: (!r.field.is_empty()).then_some(r.field),
                    reason: r.reason,
                }),
                Some(pb::update::Kind::Transaction(_)) | None => Err(Error::Protocol(
                    "an update this client did not ask for".into(),
                )),
            }
        }))
    }

    /// Opens a scan-cycle exchange.
    pub async fn exchange(&mut self) -> Result<Exchange, Error> {
        let (tx, rx) = tokio::sync::mpsc::channel(4);
        let responses = self
            .inner
            .exchange(tokio_stream::wrappers::ReceiverStream::new(rx))
            .await?
            .into_inner();
        Ok(Exchange { tx, rx: responses })
    }
}

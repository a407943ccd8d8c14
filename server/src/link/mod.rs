//! Links: the connection to a field bus (a serial port, a TCP socket) and the Modbus
//! transactions on it. Bytes belong here; values belong to `codec`.

pub(crate) mod ascii;
pub mod frame;
pub(crate) mod mbap;
pub mod precise;
pub mod rtu;
pub mod rtu_frame;
pub(crate) mod tcp;
pub mod timing;

use std::io;
use std::sync::Arc;
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncWrite};
use tokio::net::TcpStream;

use crate::config::{Framing, LinkConfig, Parity, SerialSettings, Transport};
use frame::{Exception, Request, Response};
use rtu::RtuTransport;
use tcp::MbapTransport;
use timing::LineTiming;

/// A link's error code, as source document 000's `SerialLink` reports it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum LinkCode {
    Ok = 0,
    NoPort = 1,
    OpenFailed = 2,
    Lost = 3,
}

impl LinkCode {
    /// The number the APIs and metrics show.
    pub(crate) fn code(self) -> i16 {
        self as i16
    }
}

/// Why a link is down.
#[derive(Debug, Clone, thiserror::Error)]
pub enum LinkFault {
    #[error("no port configured")]
    NoPort,
    #[error("cannot open {port}: {reason}")]
    OpenFailed { port: String, reason: String },
    #[error("cannot connect to {endpoint}: {reason}")]
    ConnectFailed { endpoint: String, reason: Cause },
    #[error("no connection within {0:?}")]
    ConnectTimeout(Duration),
    /// The open port or socket failed.
    #[error("link lost: {0}")]
    Lost(Cause),
}

/// Why a connection failed or was lost: the driver's own error (a socket's, or a
/// protocol's: `S7Error`, `EipError`), kept as it is rather than as its text.
pub type Cause = Arc<dyn std::error::Error + Send + Sync>;

impl LinkFault {
    /// The link lost, for a driver's reason.
    pub(crate) fn lost(why: impl std::error::Error + Send + Sync + 'static) -> LinkFault {
        LinkFault::Lost(Arc::new(why))
    }

    /// No connection to `endpoint`, for a driver's reason.
    pub(crate) fn connect_failed(
        endpoint: impl Into<String>,
        why: impl std::error::Error + Send + Sync + 'static,
    ) -> LinkFault {
        LinkFault::ConnectFailed {
            endpoint: endpoint.into(),
            reason: Arc::new(why),
        }
    }

    pub(crate) fn code(&self) -> LinkCode {
        match self {
            LinkFault::NoPort => LinkCode::NoPort,
            LinkFault::Lost(_) => LinkCode::Lost,
            _ => LinkCode::OpenFailed,
        }
    }
}

/// Anything a link can carry frames over.
pub trait ByteStream: AsyncRead + AsyncWrite + Unpin + Send {}
impl<T: AsyncRead + AsyncWrite + Unpin + Send> ByteStream for T {}

/// Byte counts of a connection.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Counters {
    pub(crate) bytes_sent: u64,
    pub(crate) bytes_received: u64,
    /// Received bytes that belonged to no transaction (late replies, noise).
    pub(crate) bytes_discarded: u64,
}

/// Why a transaction failed. An exception is the device's answer; everything else is a
/// failure to talk to it.
#[derive(Debug, Clone, thiserror::Error)]
pub enum TxError {
    #[error("{0}")]
    Exception(Exception),
    #[error("timeout")]
    Timeout,
    #[error("CRC mismatch")]
    Crc,
    #[error("invalid response: {0}")]
    Invalid(frame::Malformed),
    /// The connection failed: the port or socket must be reopened.
    #[error("I/O error: {0}")]
    Io(Arc<io::Error>),
}

impl From<io::Error> for TxError {
    fn from(e: io::Error) -> Self {
        TxError::Io(Arc::new(e))
    }
}

impl From<frame::ResponseError> for TxError {
    fn from(e: frame::ResponseError) -> Self {
        match e {
            frame::ResponseError::Exception(x) => TxError::Exception(x),
            frame::ResponseError::Invalid(msg) => TxError::Invalid(msg),
        }
    }
}

impl TxError {
    /// A label for metrics.
    pub(crate) fn outcome(&self) -> &'static str {
        match self {
            TxError::Exception(_) => "exception",
            TxError::Timeout => "timeout",
            TxError::Crc => "crc_error",
            TxError::Invalid(_) => "invalid_response",
            TxError::Io(_) => "io_error",
        }
    }
}

/// An open connection.
pub(crate) enum Connection {
    Rtu(RtuTransport),
    Mbap(MbapTransport),
}

impl Connection {
    pub(crate) async fn transact(
        &mut self,
        slave: u8,
        request: &Request,
        timeout: Duration,
    ) -> Result<Response, TxError> {
        match self {
            Connection::Rtu(t) => t.transact(slave, request, timeout).await,
            Connection::Mbap(t) => t.transact(slave, request, timeout).await,
        }
    }

    pub(crate) fn counters(&self) -> Counters {
        match self {
            Connection::Rtu(t) => t.counters,
            Connection::Mbap(t) => t.counters,
        }
    }
}

/// Opens the link's port or socket.
pub(crate) async fn open(config: &LinkConfig, guard: Duration) -> Result<Connection, LinkFault> {
    match &config.transport {
        Transport::Driver(d) => Err(LinkFault::OpenFailed {
            port: d.endpoint.clone(),
            reason: format!("a {} link carries no Modbus", d.protocol),
        }),
        Transport::Serial(s) => {
            let stream = open_serial(s)?;
            let transport = RtuTransport::new(Box::new(stream), Some(LineTiming::new(s)), guard);
            Ok(Connection::Rtu(if s.framing == Framing::Ascii {
                transport.ascii()
            } else {
                transport
            }))
        }
        Transport::Tcp {
            host,
            port,
            framing,
        } => {
            let stream = TcpStream::connect((host.as_str(), *port))
                .await
                .map_err(|e| LinkFault::ConnectFailed {
                    endpoint: format!("{host}:{port}"),
                    reason: Arc::new(e),
                })?;
            let _ = stream.set_nodelay(true);
            Ok(match framing {
                Framing::Mbap => Connection::Mbap(MbapTransport::new(Box::new(stream))),
                Framing::Rtu => Connection::Rtu(RtuTransport::new(Box::new(stream), None, guard)),
                Framing::Ascii => {
                    Connection::Rtu(RtuTransport::new(Box::new(stream), None, guard).ascii())
                }
            })
        }
    }
}

/// Opens a serial port with its line settings (no flow control): a link's, or one the
/// Modbus server answers on.
pub(crate) fn open_serial(s: &SerialSettings) -> Result<tokio_serial::SerialStream, LinkFault> {
    if s.port.trim().is_empty() {
        return Err(LinkFault::NoPort);
    }
    let parity = match s.parity {
        Parity::None => tokio_serial::Parity::None,
        Parity::Even => tokio_serial::Parity::Even,
        Parity::Odd => tokio_serial::Parity::Odd,
    };
    let data_bits = if s.data_bits == 7 {
        tokio_serial::DataBits::Seven
    } else {
        tokio_serial::DataBits::Eight
    };
    let stop_bits = if s.stop_bits == 2 {
        tokio_serial::StopBits::Two
    } else {
        tokio_serial::StopBits::One
    };
    let builder = tokio_serial::new(&s.port, s.baud)
        .parity(parity)
        .data_bits(data_bits)
        .stop_bits(stop_bits)
        .flow_control(tokio_serial::FlowControl::None);
    tokio_serial::SerialStream::open(&builder).map_err(|e| LinkFault::OpenFailed {
        port: s.port.clone(),
        reason: e.to_string(),
    })
}

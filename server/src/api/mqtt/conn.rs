//! One connection to the broker: TCP or TLS, CONNECT and its CONNACK, then packets both ways.
//! The front-end's task owns it; keep-alive pings, packet ids and acknowledgements are
//! counted here, what to publish is decided there.

use std::collections::BTreeMap;
use std::pin::Pin;
use std::sync::Arc;
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio::time::Instant;

use super::packet::{self, Connect, Incoming, PacketError};
use crate::api::mqtt::config::{MqttConfig, MqttVersion};

/// How long connecting (TCP, TLS and the CONNACK) may take.
pub(crate) const CONNECT_TIMEOUT: Duration = Duration::from_secs(10);
/// QoS 1 publishes sent and not yet acknowledged, at most (fewer when an MQTT 5 broker's
/// Receive Maximum says so).
pub(crate) const MAX_INFLIGHT: usize = 1024;
/// Publishes are written together once this many bytes wait (else when the session has
/// nothing more to send at once, [`Connection::flush`]).
const WRITE_BATCH: usize = 64 * 1024;

trait Io: AsyncRead + AsyncWrite + Send + Unpin {}
impl<T: AsyncRead + AsyncWrite + Send + Unpin> Io for T {}

/// Why the connection could not be made, or ended.
#[derive(Debug, thiserror::Error)]
pub(crate) enum ConnError {
    #[error("cannot connect to {0}: {1}")]
    Connect(String, std::io::Error),
    #[error("TLS with {0}: {1}")]
    Tls(String, std::io::Error),
    #[error("no answer from {0} within {1:?}")]
    Timeout(String, Duration),
    #[error("the broker refused the connection: {0} (code {1})")]
    Refused(&'static str, u8),
    #[error("the broker sent {0}")]
    Packet(#[from] PacketError),
    #[error("the broker did not answer a ping within the keep-alive")]
    KeepAlive,
    #[error("the broker closed the connection")]
    Closed,
    #[error("the broker disconnected (reason {0:#04x})")]
    Disconnected(u8),
    #[error(transparent)]
    Io(#[from] std::io::Error),
}

impl ConnError {
    /// Whether the CONNECT may have reached the broker: not when the TCP or TLS connection
    /// under it failed.
    pub(crate) fn connect_sent(&self) -> bool {
        !matches!(self, ConnError::Connect(..) | ConnError::Tls(..))
    }
}

/// The TLS settings a connection uses, loaded once when the front-end starts.
#[derive(Clone)]
pub(crate) struct TlsSetup {
    pub(crate) connector: tokio_rustls::TlsConnector,
}

impl TlsSetup {
    /// Loads the CA (else the compiled-in trust of the system is not available: a CA file
    /// is then required) and the optional client certificate.
    pub(crate) fn load(config: &MqttConfig) -> Result<TlsSetup, String> {
        let mut roots = rustls::RootCertStore::empty();
        let Some(ca) = &config.tls.ca else {
            return Err(
                "mqtts:// needs tls.ca (the CA that signed the broker's certificate)".into(),
            );
        };
        let text = |e: crate::tls::TlsError| e.to_string();
        for cert in crate::tls::read_certs(ca).map_err(text)? {
            roots
                .add(cert)
                .map_err(|e| format!("{}: {e}", ca.display()))?;
        }
        let builder = crate::tls::client_builder()
            .map_err(text)?
            .with_root_certificates(roots);
        let client = match (&config.tls.cert, &config.tls.key) {
            (Some(cert), Some(key)) => builder
                .with_client_auth_cert(
                    crate::tls::read_certs(cert).map_err(text)?,
                    crate::tls::read_key(key).map_err(text)?,
                )
                .map_err(|e| format!("{}: {e}", cert.display()))?,
            _ => builder.with_no_client_auth(),
        };
        Ok(TlsSetup {
            connector: tokio_rustls::TlsConnector::from(Arc::new(client)),
        })
    }
}

pub(crate) struct Connection {
    io: Pin<Box<dyn Io>>,
    version: MqttVersion,
    buf: Vec<u8>,
    /// Bytes of a packet too big to keep still to be read past.
    skip: usize,
    keep_alive: Duration,
    /// When a packet was last sent (a ping is due `keep_alive` after).
    last_sent: Instant,
    /// A ping waiting for its answer since.
    ping_sent: Option<Instant>,
    next_pkid: u16,
    /// QoS 1 publishes in flight: packet id -> the caller's tag.
    inflight: BTreeMap<u16, u64>,
    /// Tags of QoS 0 publishes not yet confirmed by a ping's answer.
    unconfirmed: Vec<u64>,
    /// The tags the ping in flight confirms when it is answered.
    ping_covers: Vec<u64>,
    /// Tags confirmed, for the caller to take.
    confirmed: Vec<u64>,
    /// Publishes encoded and not yet written.
    out: Vec<u8>,
    /// QoS 1 publishes in flight at most: [`MAX_INFLIGHT`] or the broker's maximum.
    max_inflight: usize,
    /// The largest packet the broker takes (its Maximum Packet Size; none said: no limit).
    max_packet: usize,
}

impl Connection {
    /// Connects, sends CONNECT and waits for an accepting CONNACK.
    pub(crate) async fn open(
        config: &MqttConfig,
        tls: Option<&TlsSetup>,
        connect: &Connect,
    ) -> Result<Connection, ConnError> {
        let url = config.url.to_string();
        tokio::time::timeout(CONNECT_TIMEOUT, Self::open_inner(config, tls, connect))
            .await
            .map_err(|_| ConnError::Timeout(url, CONNECT_TIMEOUT))?
    }

    async fn open_inner(
        config: &MqttConfig,
        tls: Option<&TlsSetup>,
        connect: &Connect,
    ) -> Result<Connection, ConnError> {
        let url = config.url.to_string();
        let tcp = TcpStream::connect((config.url.host.as_str(), config.url.port))
            .await
            .map_err(|e| ConnError::Connect(url.clone(), e))?;
        let _ = tcp.set_nodelay(true);
        let io: Pin<Box<dyn Io>> = match tls {
            Some(tls) => {
                let name = rustls::pki_types::ServerName::try_from(config.url.host.clone())
                    .map_err(|e| {
                        ConnError::Tls(url.clone(), std::io::Error::other(e.to_string()))
                    })?;
                let stream = tls
                    .connector
                    .connect(name, tcp)
                    .await
                    .map_err(|e| ConnError::Tls(url.clone(), e))?;
                Box::pin(stream)
            }
            None => Box::pin(tcp),
        };
        let mut conn = Connection {
            io,
            version: config.version,
            buf: Vec::with_capacity(4096),
            skip: 0,
            keep_alive: Duration::from_secs(u64::from(connect.keep_alive)),
            last_sent: Instant::now(),
            ping_sent: None,
            next_pkid: 1,
            inflight: BTreeMap::new(),
            unconfirmed: Vec::new(),
            ping_covers: Vec::new(),
            confirmed: Vec::new(),
            out: Vec::new(),
            max_inflight: MAX_INFLIGHT,
            max_packet: usize::MAX,
        };
        conn.send(&packet::connect(config.version, connect)).await?;
        match conn.read().await? {
            Incoming::ConnAck {
                code: 0,
                receive_maximum,
                maximum_packet,
                ..
            } => {
                if let Some(most) = receive_maximum {
                    conn.max_inflight = MAX_INFLIGHT.min(usize::from(most));
                }
                if let Some(most) = maximum_packet {
                    conn.max_packet = usize::try_from(most).unwrap_or(usize::MAX);
                }
                Ok(conn)
            }
            Incoming::ConnAck { code, .. } => Err(ConnError::Refused(
                packet::connack_reason(config.version, code),
                code,
            )),
            _ => Err(ConnError::Packet(PacketError::Malformed("CONNACK"))),
        }
    }

    /// Sends `bytes` now, after any publishes waiting.
    async fn send(&mut self, bytes: &[u8]) -> Result<(), ConnError> {
        self.out.extend_from_slice(bytes);
        self.flush().await
    }

    /// Writes the publishes waiting, if any.
    pub(crate) async fn flush(&mut self) -> Result<(), ConnError> {
        if self.out.is_empty() {
            return Ok(());
        }
        // Cancel-safe: what was written leaves `out` write by write, so a flush dropped
        // midway (a PUBACK sent from a `read` in a `select!`) never writes bytes twice.
        while !self.out.is_empty() {
            let n = self.io.write(&self.out).await?;
            if n == 0 {
                return Err(ConnError::Closed);
            }
            self.out.drain(..n);
        }
        self.io.flush().await?;
        if self.out.capacity() > 4 * WRITE_BATCH {
            self.out.shrink_to(WRITE_BATCH);
        }
        self.last_sent = Instant::now();
        Ok(())
    }

    /// The next packet from the broker. Cancel-safe: bytes read stay in the buffer. A packet
    /// read past ([`Incoming::Dropped`]) is acknowledged when it is a QoS 1 publish and
    /// handed on to be reported.
    pub(crate) async fn read(&mut self) -> Result<Incoming, ConnError> {
        loop {
            if let Some(packet) = self.read_buffered().await? {
                return Ok(packet);
            }
            let mut chunk = [0u8; 4096];
            let n = self.io.read(&mut chunk).await?;
            if n == 0 {
                return Err(ConnError::Closed);
            }
            let past = self.skip.min(n);
            self.skip -= past;
            self.buf.extend_from_slice(&chunk[past..n]);
        }
    }

    /// The next packet already read whole from the socket, if any (as [`Self::read`], but
    /// never waiting for the broker).
    pub(crate) async fn read_buffered(&mut self) -> Result<Option<Incoming>, ConnError> {
        let Some(packet) = packet::decode(self.version, &mut self.buf)? else {
            return Ok(None);
        };
        if let Incoming::Disconnect { code } = packet {
            return Err(ConnError::Disconnected(code));
        }
        if let Incoming::Dropped { pkid, rest, .. } = &packet {
            self.skip = *rest;
            if let Some(pkid) = *pkid {
                self.puback(pkid).await?;
            }
        }
        if packet == Incoming::PingResp {
            self.ping_sent = None;
            // The broker answers packets in order: every publish before the ping has been
            // received.
            self.confirmed.append(&mut self.ping_covers);
        }
        Ok(Some(packet))
    }

    /// When the keep-alive needs attention: a ping to send, or an answer overdue.
    pub(crate) fn keep_alive_due(&self) -> Option<Instant> {
        if self.keep_alive.is_zero() {
            return None;
        }
        Some(match self.ping_sent {
            Some(sent) => sent + self.keep_alive,
            None => self.last_sent + self.keep_alive,
        })
    }

    /// Sends a ping, or fails when the last one was not answered in time.
    pub(crate) async fn keep_alive(&mut self) -> Result<(), ConnError> {
        if self.ping_sent.is_some() {
            return Err(ConnError::KeepAlive);
        }
        self.ping().await
    }

    async fn ping(&mut self) -> Result<(), ConnError> {
        self.send(&packet::pingreq()).await?;
        self.ping_sent = Some(Instant::now());
        self.ping_covers = std::mem::take(&mut self.unconfirmed);
        Ok(())
    }

    /// Whether QoS 0 publishes wait for a ping to confirm them and none is in flight.
    pub(crate) fn barrier_due(&self) -> bool {
        self.ping_sent.is_none() && !self.unconfirmed.is_empty()
    }

    /// Sends a ping whose answer confirms the QoS 0 publishes sent before it (a broker
    /// handles a connection's packets in order). QoS 0 has no acknowledgement of its own.
    pub(crate) async fn barrier(&mut self) -> Result<(), ConnError> {
        if self.barrier_due() {
            self.ping().await?;
        }
        Ok(())
    }

    /// The tags of QoS 0 publishes confirmed since the last call.
    pub(crate) fn take_confirmed(&mut self) -> Vec<u64> {
        std::mem::take(&mut self.confirmed)
    }

    /// Whether another QoS 1 publish may be sent now.
    pub(crate) fn can_publish(&self) -> bool {
        self.inflight.len() < self.max_inflight
    }

    /// Publishes (the bytes go out with the next [`Self::flush`], or at once past
    /// [`WRITE_BATCH`] bytes); `false`, sending nothing, when the packet is larger than the
    /// broker's Maximum Packet Size (its tag is confirmed: there is nothing to wait for);
    /// a QoS 1 publish is remembered with `tag` until [`Self::acked`] gives it
    /// back, a QoS 0 one (with a `tag` other than 0) until a ping confirms it
    /// ([`Self::take_confirmed`]).
    pub(crate) async fn publish(
        &mut self,
        topic: &str,
        payload: &[u8],
        qos: u8,
        retain: bool,
        tag: u64,
    ) -> Result<bool, ConnError> {
        if packet::publish_size(self.version, topic, payload.len(), qos) > self.max_packet {
            // Never sent, so never to be confirmed: let its tracker go.
            if tag != 0 {
                self.confirmed.push(tag);
            }
            return Ok(false);
        }
        let pkid = if qos > 0 { self.take_pkid() } else { 0 };
        packet::write_publish(
            self.version,
            &mut self.out,
            topic,
            payload,
            (qos, retain),
            pkid,
        );
        if qos > 0 {
            self.inflight.insert(pkid, tag);
        } else if tag != 0 {
            self.unconfirmed.push(tag);
        }
        if self.out.len() >= WRITE_BATCH {
            self.flush().await?;
        }
        Ok(true)
    }

    /// The largest packet the broker takes.
    pub(crate) fn max_packet(&self) -> usize {
        self.max_packet
    }

    /// The tag of the publish a PUBACK acknowledges.
    pub(crate) fn acked(&mut self, pkid: u16) -> Option<u64> {
        self.inflight.remove(&pkid)
    }

    fn take_pkid(&mut self) -> u16 {
        loop {
            let id = self.next_pkid;
            self.next_pkid = self.next_pkid.checked_add(1).unwrap_or(1);
            if !self.inflight.contains_key(&id) {
                return id;
            }
        }
    }

    pub(crate) async fn subscribe(&mut self, filters: &[(String, u8)]) -> Result<(), ConnError> {
        let pkid = self.take_pkid();
        self.send(&packet::subscribe(self.version, pkid, filters))
            .await
    }

    pub(crate) async fn puback(&mut self, pkid: u16) -> Result<(), ConnError> {
        self.send(&packet::puback(pkid)).await
    }

    /// Ends the connection cleanly: the broker does not publish the Will. After the
    /// DISCONNECT the socket is read to its end (the broker closes it): a socket closed with
    /// unread bytes in it (the PUBACKs of the last publishes) is reset, and a reset can throw
    /// away the DISCONNECT before the broker reads it, which then publishes the Will.
    pub(crate) async fn disconnect(mut self) {
        let _ = tokio::time::timeout(Duration::from_secs(2), async {
            let _ = self.send(&packet::disconnect()).await;
            let _ = self.io.shutdown().await;
            let mut rest = [0u8; 4096];
            while let Ok(n) = self.io.read(&mut rest).await {
                if n == 0 {
                    break;
                }
            }
        })
        .await;
    }
}

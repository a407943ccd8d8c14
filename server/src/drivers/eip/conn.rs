//! A connection to a controller: TCP, a registered session, and explicit messages sent
//! unconnected (SendRRData), one at a time, each with its timeout and its own sender
//! context, matched in its answer.

use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

use super::cip::{self, Malformed};

/// Why a connection failed.
#[derive(Debug, thiserror::Error)]
pub(crate) enum EipError {
    #[error("{0}")]
    Io(#[from] std::io::Error),
    #[error("no answer in {0:?}")]
    Timeout(Duration),
    #[error("{0}")]
    Malformed(#[from] Malformed),
}

pub(crate) struct Connection {
    io: TcpStream,
    session: u32,
    context: u64,
    timeout: Duration,
    /// The route to the controller (port segments).
    route: Vec<u8>,
}

impl Connection {
    /// Connects and registers a session.
    pub(crate) async fn open(
        addr: (&str, u16),
        route: Vec<u8>,
        timeout: Duration,
    ) -> Result<Self, EipError> {
        let io = tokio::time::timeout(timeout, TcpStream::connect(addr))
            .await
            .map_err(|_| EipError::Timeout(timeout))??;
        let _ = io.set_nodelay(true);
        let mut conn = Connection {
            io,
            session: 0,
            context: 0,
            timeout,
            route,
        };
        let (head, _) = conn
            .exchange(cip::REGISTER_SESSION, &cip::register_session())
            .await?;
        conn.session = head.session;
        Ok(conn)
    }

    /// One encapsulation command and its answer's header and data.
    async fn exchange(
        &mut self,
        command: u16,
        data: &[u8],
    ) -> Result<(cip::Header, Vec<u8>), EipError> {
        self.context = self.context.wrapping_add(1);
        let packet = cip::encapsulate(command, self.session, self.context, data);
        let timeout = self.timeout;
        tokio::time::timeout(timeout, async {
            self.io.write_all(&packet).await?;
            loop {
                let mut head = [0u8; cip::HEADER];
                self.io.read_exact(&mut head).await?;
                let h = cip::header(&head)?;
                let mut body = vec![0u8; h.length];
                self.io.read_exact(&mut body).await?;
                // An answer to an earlier request given up on is passed over.
                if h.context != self.context {
                    continue;
                }
                if h.command != command {
                    return Err(Malformed::Command {
                        asked: command,
                        got: h.command,
                    }
                    .into());
                }
                if h.status != 0 {
                    return Err(Malformed::Encapsulation(h.status).into());
                }
                return Ok((h, body));
            }
        })
        .await
        .map_err(|_| EipError::Timeout(timeout))?
    }

    /// A CIP request to the controller (routed by its path) and its reply's bytes.
    pub(crate) async fn request(&mut self, message: &[u8]) -> Result<Vec<u8>, EipError> {
        let routed = cip::routed(message, &self.route);
        let seconds = self.timeout.as_secs().clamp(1, 60) as u16;
        let (_, body) = self
            .exchange(cip::SEND_RR_DATA, &cip::send_rr_data(&routed, seconds))
            .await?;
        Ok(cip::rr_data_reply(&body)?.to_vec())
    }

    /// The controller's identity as List Identity answers it: vendor, product code,
    /// revision, serial number, product name.
    pub(crate) async fn identity(
        &mut self,
    ) -> Result<Option<(u16, u16, String, u32, String)>, EipError> {
        let (_, body) = self.exchange(cip::LIST_IDENTITY, &[]).await?;
        Ok(cip::identity(&body))
    }
}

//! A connection to a controller: TCP, a registered session, and explicit messages sent
//! unconnected (SendRRData), one at a time, each with its timeout and its own sender
//! context, matched in its answer.

use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

use super::cip::{self, Malformed};
use super::manager;

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
    /// The class 3 connection Forward Open made, if the controller took one.
    connected: Option<Connected>,
}

/// A connection for connected messages: the controller's id for it, the sequence count of
/// the last message, and its size.
struct Connected {
    o_t: u32,
    seq: u16,
    size: usize,
    /// The serial Forward Open gave it (Forward Close names it).
    serial: u16,
}

/// The largest message an unconnected request may carry, in every Logix controller.
const UNCONNECTED: usize = 480;
use super::plan::{CONNECTED_OVERHEAD, LARGE};
/// The size Forward Open asks for, where Large Forward Open is refused.
const SMALL: usize = 504;

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
            connected: None,
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
        // RegisterSession goes with a sender context of zero: any is allowed (Vol. 2,
        // 2-4.4), and libplctag's ab_server refuses any other.
        self.context = match command {
            cip::REGISTER_SESSION => 0,
            _ => self.context.wrapping_add(1),
        };
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
                // An answer to an earlier request given up on is passed over. A controller
                // that answers with the sender context zeroed (libplctag's ab_server) is
                // matched by its command: one request is outstanding at a time.
                let zeroed = h.context == 0 && h.command == command;
                if h.context != self.context && !zeroed {
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

    /// Opens a class 3 connection: Large Forward Open (4,002 bytes), else Forward Open (504);
    /// without one (a controller that refuses both), messages go unconnected.
    pub(crate) async fn forward_open(&mut self, serial: u16) -> Result<(), EipError> {
        let t_o = 0x4947_0000 | u32::from(serial);
        for (size, large) in [(LARGE, true), (SMALL, false)] {
            let message = manager::forward_open(&self.route, size as u16, large, t_o, serial);
            // A controller that does not know the service may refuse it with an
            // encapsulation status or an answer of its own: the next size is tried, then
            // messages go unconnected. A lost connection ends the open.
            let body = match self
                .exchange(cip::SEND_RR_DATA, &cip::send_rr_data(&message, 5))
                .await
            {
                Ok((_, body)) => body,
                Err(EipError::Malformed(_)) => continue,
                Err(e) => return Err(e),
            };
            let Ok(reply) = cip::rr_data_reply(&body).and_then(cip::reply) else {
                continue;
            };
            if reply.status == 0
                && reply.answers(message[0]).is_ok()
                && let Some(id) = reply.data.get(..4)
            {
                self.connected = Some(Connected {
                    o_t: u32::from_le_bytes([id[0], id[1], id[2], id[3]]),
                    seq: 0,
                    size,
                    serial,
                });
                return Ok(());
            }
        }
        Ok(())
    }

    /// The size of a connection's messages, or 0 unconnected.
    pub(crate) fn connection_size(&self) -> usize {
        self.connected.as_ref().map_or(0, |c| c.size)
    }

    /// The most bytes a request's message (and its reply's) may take.
    pub(crate) fn message_limit(&self) -> usize {
        match &self.connected {
            // The sequence count and the reply's header within the connection's size.
            Some(c) => c.size - CONNECTED_OVERHEAD,
            None => UNCONNECTED,
        }
    }

    /// A CIP request to the controller (on the connection, else routed by its path) and
    /// its reply's bytes.
    pub(crate) async fn request(&mut self, message: &[u8]) -> Result<Vec<u8>, EipError> {
        if let Some(c) = &mut self.connected {
            c.seq = c.seq.wrapping_add(1);
            let (o_t, seq) = (c.o_t, c.seq);
            let (_, body) = self
                .exchange(cip::SEND_UNIT_DATA, &cip::send_unit_data(o_t, seq, message))
                .await?;
            let (got, reply) = cip::unit_data_reply(&body)?;
            if got != seq {
                return Err(Malformed::Refused(format!(
                    "the answer to message {got} where {seq} was asked"
                ))
                .into());
            }
            return Ok(reply.to_vec());
        }
        let routed = cip::routed(message, &self.route);
        let seconds = self.timeout.as_secs().clamp(1, 60) as u16;
        let (_, body) = self
            .exchange(cip::SEND_RR_DATA, &cip::send_rr_data(&routed, seconds))
            .await?;
        let answer = cip::rr_data_reply(&body)?;
        if !self.route.is_empty() {
            cip::route_failed(message, answer)?;
        }
        Ok(answer.to_vec())
    }

    /// Leaves: Forward Close of the connection (the controller frees it now, not after
    /// its timeout), then UnRegister Session; the answers are not waited for past the
    /// request's timeout, and a failure changes nothing (the connection is dropped anyway).
    pub(crate) async fn close(mut self) {
        if let Some(c) = self.connected.take() {
            let message = manager::forward_close(&self.route, c.serial);
            let _ = self
                .exchange(cip::SEND_RR_DATA, &cip::send_rr_data(&message, 5))
                .await;
        }
        self.context = self.context.wrapping_add(1);
        let packet = cip::encapsulate(cip::UNREGISTER_SESSION, self.session, self.context, &[]);
        let _ = self.io.write_all(&packet).await;
        let _ = self.io.shutdown().await;
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

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::net::TcpListener;

    /// A controller as strict as libplctag's ab_server: RegisterSession with any sender
    /// context but zero is refused (encapsulation status 1).
    #[tokio::test]
    async fn a_session_is_registered_with_a_sender_context_of_zero() {
        let listener = TcpListener::bind("127.0.0.1:0").await.expect("bind");
        let port = listener.local_addr().expect("addr").port();
        let peer = tokio::spawn(async move {
            let (mut io, _) = listener.accept().await.expect("accept");
            let mut request = [0u8; cip::HEADER + 4];
            io.read_exact(&mut request).await.expect("request");
            let context = u64::from_le_bytes(request[12..20].try_into().expect("8 bytes"));
            let status = u32::from(context != 0);
            let mut answer = request;
            answer[4..8].copy_from_slice(&7u32.to_le_bytes());
            answer[8..12].copy_from_slice(&status.to_le_bytes());
            io.write_all(&answer).await.expect("answer");
            context
        });
        let conn = Connection::open(("127.0.0.1", port), Vec::new(), Duration::from_secs(5))
            .await
            .expect("registered");
        assert_eq!(conn.session, 7);
        assert_eq!(peer.await.expect("peer"), 0);
    }

    /// Answers RegisterSession, then each SendRRData with the next of `replies` (CIP
    /// reply bytes in an unconnected data item).
    async fn controller(replies: Vec<Vec<u8>>) -> u16 {
        let listener = TcpListener::bind("127.0.0.1:0").await.expect("bind");
        let port = listener.local_addr().expect("addr").port();
        tokio::spawn(async move {
            let (mut io, _) = listener.accept().await.expect("accept");
            let mut first = true;
            let mut replies = replies.into_iter();
            loop {
                let mut head = [0u8; cip::HEADER];
                if io.read_exact(&mut head).await.is_err() {
                    return;
                }
                let h = cip::header(&head).expect("header");
                let mut body = vec![0u8; h.length];
                io.read_exact(&mut body).await.expect("body");
                let data = match std::mem::take(&mut first) {
                    true => body,
                    false => {
                        let Some(r) = replies.next() else { return };
                        let mut d = vec![0, 0, 0, 0, 0, 0, 2, 0, 0, 0, 0, 0, 0xB2, 0];
                        d.extend_from_slice(&(r.len() as u16).to_le_bytes());
                        d.extend_from_slice(&r);
                        d
                    }
                };
                let answer = cip::encapsulate(h.command, 9, h.context, &data);
                io.write_all(&answer).await.expect("answer");
            }
        });
        port
    }

    /// A module on the route that does not answer: the Unconnected Send's own error reply
    /// (status 0x01, extended 0x0204: timed out) refuses that request, and the connection
    /// goes on; without a route the reply is the message's, and so is a Read Tag
    /// Fragmented's of another status.
    #[tokio::test]
    async fn an_unconnected_sends_own_error_refuses_the_request_and_the_link_goes_on() {
        let timed_out = b"\xd2\x00\x01\x01\x04\x02\x00\x00".to_vec();
        let good = b"\xcc\x00\x00\x00\xc4\x00\x07\x00\x00\x00".to_vec();
        // A Read Tag Fragmented's own "no such tag" shares the service number.
        let no_tag = b"\xd2\x00\x05\x00".to_vec();
        let replies = vec![
            timed_out.clone(),
            good.clone(),
            timed_out.clone(),
            no_tag.clone(),
        ];
        let port = controller(replies).await;
        let timeout = Duration::from_secs(5);
        let mut conn = Connection::open(("127.0.0.1", port), vec![1, 0], timeout)
            .await
            .expect("registered");
        let read = cip::read_tag(b"\x91\x01A\x00", 1);
        let refused = conn.request(&read).await.expect_err("refused");
        let text = refused.to_string();
        assert!(
            matches!(
                refused,
                EipError::Malformed(Malformed::Route {
                    status: 1,
                    ext: Some(0x0204)
                })
            ),
            "{text}"
        );
        assert!(
            text.contains("the route to the controller failed"),
            "{text}"
        );
        assert_eq!(conn.request(&read).await.expect("read"), good);
        let fragmented = cip::read_fragmented(b"\x91\x01A\x00", 1, 0);
        assert!(matches!(
            conn.request(&fragmented).await,
            Err(EipError::Malformed(Malformed::Route { status: 1, .. }))
        ));
        assert_eq!(conn.request(&fragmented).await.expect("own"), no_tag);

        let port = controller(vec![timed_out.clone()]).await;
        let mut conn = Connection::open(("127.0.0.1", port), Vec::new(), timeout)
            .await
            .expect("registered");
        assert_eq!(conn.request(&read).await.expect("unrouted"), timed_out);
    }
}

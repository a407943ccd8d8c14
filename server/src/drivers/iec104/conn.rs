//! A connection to a controlled station as the controlling station keeps it: TCP within t0,
//! STARTDT confirmed within t1, then one task owns the socket. It numbers the I-frames it
//! sends and holds at most `k` of them unacknowledged (each acknowledged within t1, or the
//! connection is closed), acknowledges what it receives after `w` frames or t2, tests a
//! quiet connection after t3 (TESTFR con within t1), and checks every frame: a sequence
//! number out of order, an acknowledgement of a frame never sent, a malformed frame, each
//! close the connection naming it. Received ASDUs go to the connection's `Router`.
//!
//! A standby connection (the other of a redundancy group) is opened without STARTDT: its
//! station answers a test frame within t1, and it is tested after t3 of quiet like any
//! connection, until the gateway starts it (`Connection::start`).

use std::sync::Arc;
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio::sync::{mpsc, watch};
use tokio::time::Instant;

use super::apci::{self, Frame, Unnumbered};
use super::asdu::Asdu;
use super::config::Settings;
use super::route::Router;
use super::window::{Broken, Limits, Window};

/// Why a connection failed or ended.
#[derive(Debug, Clone, thiserror::Error)]
pub(crate) enum Iec104Error {
    #[error("{0}")]
    Io(String),
    #[error("no connection within t0 ({0:?})")]
    Connect(Duration),
    #[error("no {0} within t1 ({1:?})")]
    Start(&'static str, Duration),
    #[error("the station sent a malformed frame: {0}")]
    Frame(#[from] apci::Malformed),
    #[error("{0}")]
    Window(#[from] Broken),
    #[error("the station closed the connection")]
    Closed,
    #[error("the station sent {0} to the controlling station")]
    Unexpected(&'static str),
}

impl From<std::io::Error> for Iec104Error {
    fn from(e: std::io::Error) -> Self {
        Iec104Error::Io(e.to_string())
    }
}

/// The link task's side of an open connection.
pub(crate) struct Connection {
    pub(crate) send: mpsc::Sender<Asdu>,
    pub(crate) router: Arc<Router>,
    pub(crate) lost: watch::Receiver<Option<Iec104Error>>,
    /// When it was lost.
    pub(crate) lost_at: Arc<std::sync::OnceLock<Instant>>,
    pub(crate) state: watch::Receiver<State>,
    /// Asks the task to send STARTDT act (a standby taking over).
    start: Arc<tokio::sync::Notify>,
    task: tokio::task::JoinHandle<()>,
}

impl Connection {
    /// Starts data transfer on a standby connection: STARTDT act now; `state.started`
    /// says when the station confirmed it.
    pub(crate) fn start(&self) {
        self.start.notify_one();
    }
}

/// Whether a connection is opened with data transfer started or as a standby.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Opening {
    Started,
    Standby,
}

/// What `/links` shows of the connection.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(crate) struct State {
    /// I-frames sent and not acknowledged yet (at most k).
    pub(crate) unacknowledged: u16,
    /// I-frames received and not acknowledged yet (at most w).
    pub(crate) unconfirmed: u16,
    pub(crate) sent: u64,
    pub(crate) received: u64,
    /// STARTDT confirmed: data transfer on.
    pub(crate) started: bool,
}

impl Drop for Connection {
    fn drop(&mut self) {
        self.task.abort();
    }
}

/// Opens a connection to `(host, port)`: TCP within t0, then STARTDT (a standby: TESTFR)
/// confirmed within t1.
pub(crate) async fn open(
    host: &str,
    port: u16,
    s: &Settings,
    router: Arc<Router>,
    opening: Opening,
) -> Result<Connection, Iec104Error> {
    let io = connect(host, port, s).await?;
    handshake(io, s, router, opening).await
}

/// TCP to `(host, port)` within t0.
pub(crate) async fn connect(host: &str, port: u16, s: &Settings) -> Result<TcpStream, Iec104Error> {
    let io = tokio::time::timeout(s.t0, TcpStream::connect((host, port)))
        .await
        .map_err(|_| Iec104Error::Connect(s.t0))??;
    let _ = io.set_nodelay(true);
    Ok(io)
}

/// STARTDT (a standby: TESTFR) on a connected socket, confirmed within t1; then the
/// connection's task.
pub(crate) async fn handshake(
    mut io: TcpStream,
    s: &Settings,
    router: Arc<Router>,
    opening: Opening,
) -> Result<Connection, Iec104Error> {
    let (ask, answer) = match opening {
        Opening::Started => (Unnumbered::StartAct, Unnumbered::StartCon),
        Opening::Standby => (Unnumbered::TestAct, Unnumbered::TestCon),
    };
    io.write_all(&Frame::U(ask).encode()).await?;
    let mut buf = Vec::with_capacity(512);
    let deadline = Instant::now() + s.t1;
    loop {
        match next_frame(&mut io, &mut buf, deadline).await? {
            Some(Frame::U(u)) if u == answer => break,
            Some(Frame::U(Unnumbered::TestAct)) => {
                io.write_all(&Frame::U(Unnumbered::TestCon).encode())
                    .await?;
            }
            Some(Frame::U(u)) => return Err(Iec104Error::Unexpected(u.name())),
            Some(_) => {
                return Err(Iec104Error::Unexpected(
                    "an I- or S-frame before STARTDT con",
                ));
            }
            None => return Err(Iec104Error::Start(answer.name(), s.t1)),
        }
    }
    let (send, outgoing) = mpsc::channel(64);
    let (lost_tx, lost) = watch::channel(None);
    let (state_tx, state) = watch::channel(State {
        started: opening == Opening::Started,
        ..State::default()
    });
    let start = Arc::new(tokio::sync::Notify::new());
    let limits = Limits {
        k: s.k,
        w: s.w,
        t1: s.t1,
        t2: s.t2,
        t3: s.t3,
    };
    let link = Link {
        io,
        buf,
        window: Window::new(limits),
        router: router.clone(),
        state: state_tx,
        start: start.clone(),
        starting: false,
    };
    let lost_at = Arc::new(std::sync::OnceLock::new());
    let at = lost_at.clone();
    let task = tokio::spawn(async move {
        let router = link.router.clone();
        let why = link.run(outgoing).await;
        let _ = at.set(Instant::now());
        let _ = lost_tx.send(Some(why));
        router.close();
    });
    Ok(Connection {
        send,
        router,
        lost,
        lost_at,
        state,
        start,
        task,
    })
}

/// The next whole frame from `io` (`None` past `deadline`).
async fn next_frame(
    io: &mut TcpStream,
    buf: &mut Vec<u8>,
    deadline: Instant,
) -> Result<Option<Frame>, Iec104Error> {
    loop {
        if let Some((frame, used)) = Frame::decode(buf)? {
            buf.drain(..used);
            return Ok(Some(frame));
        }
        let mut chunk = [0u8; 512];
        let n = match tokio::time::timeout_at(deadline, io.read(&mut chunk)).await {
            Err(_) => return Ok(None),
            Ok(n) => n?,
        };
        if n == 0 {
            return Err(Iec104Error::Closed);
        }
        buf.extend_from_slice(&chunk[..n]);
    }
}

/// The connection's task.
struct Link {
    io: TcpStream,
    buf: Vec<u8>,
    window: Window,
    router: Arc<Router>,
    state: watch::Sender<State>,
    start: Arc<tokio::sync::Notify>,
    /// STARTDT act sent, its confirmation awaited.
    starting: bool,
}

impl Link {
    async fn run(mut self, mut outgoing: mpsc::Receiver<Asdu>) -> Iec104Error {
        loop {
            if let Err(why) = self.turn(&mut outgoing).await {
                return why;
            }
        }
    }

    /// Waits for the next thing to do and does it.
    async fn turn(&mut self, outgoing: &mut mpsc::Receiver<Asdu>) -> Result<(), Iec104Error> {
        let deadline = self.window.deadline();
        let room = self.window.room();
        let mut chunk = [0u8; 1024];
        tokio::select! {
            read = self.io.read(&mut chunk) => {
                let n = read?;
                if n == 0 {
                    return Err(Iec104Error::Closed);
                }
                self.buf.extend_from_slice(&chunk[..n]);
                self.window.heard();
                while let Some((frame, used)) = Frame::decode(&self.buf)? {
                    self.buf.drain(..used);
                    self.take(frame).await?;
                }
            }
            asdu = outgoing.recv(), if room => match asdu {
                Some(asdu) => self.send(asdu).await?,
                None => return Err(Iec104Error::Closed),
            },
            () = tokio::time::sleep_until(deadline) => self.timers().await?,
            () = self.start.notified(), if !self.starting && !self.state.borrow().started => {
                self.starting = true;
                self.io.write_all(&Frame::U(Unnumbered::StartAct).encode()).await?;
            }
        }
        let counts = *self.state.borrow();
        self.state.send_replace(State {
            unacknowledged: self.window.unacknowledged(),
            unconfirmed: self.window.unconfirmed(),
            ..counts
        });
        Ok(())
    }

    async fn timers(&mut self) -> Result<(), Iec104Error> {
        let due = self.window.due()?;
        if due.confirm {
            self.confirm().await?;
        }
        if due.test {
            self.io
                .write_all(&Frame::U(Unnumbered::TestAct).encode())
                .await?;
        }
        Ok(())
    }

    /// Acknowledges every I-frame received (an S-frame).
    async fn confirm(&mut self) -> Result<(), Iec104Error> {
        let recv = self.window.confirm();
        self.io.write_all(&Frame::S { recv }.encode()).await?;
        Ok(())
    }

    async fn send(&mut self, asdu: Asdu) -> Result<(), Iec104Error> {
        let Ok(octets) = asdu.encode() else {
            return Ok(());
        };
        let (send, recv) = self.window.send();
        let frame = Frame::I {
            send,
            recv,
            asdu: octets,
        };
        self.io.write_all(&frame.encode()).await?;
        let mut state = *self.state.borrow();
        state.sent += 1;
        self.state.send_replace(state);
        Ok(())
    }

    async fn take(&mut self, frame: Frame) -> Result<(), Iec104Error> {
        match frame {
            Frame::I { .. } if !self.state.borrow().started => {
                return Err(Iec104Error::Unexpected(
                    "an I-frame on a connection with data transfer stopped",
                ));
            }
            Frame::I { send, recv, asdu } => {
                let confirm = self.window.received(send, recv)?;
                let mut state = *self.state.borrow();
                state.received += 1;
                self.state.send_replace(state);
                self.router.take(&asdu);
                if confirm {
                    self.confirm().await?;
                }
            }
            Frame::S { recv } => self.window.acknowledged(recv)?,
            Frame::U(Unnumbered::TestAct) => {
                self.io
                    .write_all(&Frame::U(Unnumbered::TestCon).encode())
                    .await?;
            }
            Frame::U(Unnumbered::TestCon) => self.window.tested(),
            Frame::U(Unnumbered::StartCon) if self.starting => {
                self.starting = false;
                self.state.send_modify(|s| s.started = true);
            }
            Frame::U(u) => return Err(Iec104Error::Unexpected(u.name())),
        }
        Ok(())
    }
}

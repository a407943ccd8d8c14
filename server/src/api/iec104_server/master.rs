//! One master's connection, the outstation's side of it: nothing but U-frames until the
//! master starts data transfer (STARTDT act, confirmed), then its ASDUs answered and
//! spontaneous data sent as the `k` window allows; STOPDT stops it again (confirmed once
//! what was sent is acknowledged). The windows and timers are the standard's (`k`, `w`, t1
//! to t3); a frame out of sequence, an acknowledgement of nothing sent, a malformed frame,
//! t1 expired, or a master that asks faster than it takes answers each end the connection,
//! logged with why. The served fields' changes are followed from STARTDT to STOPDT only;
//! an I-frame before STARTDT is acknowledged and not executed.

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use futures_util::{FutureExt, StreamExt};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio::sync::watch;
use tokio_util::sync::CancellationToken;

use super::config::Iec104ServerConfig;
use super::served::Served;
use super::station::Station;
use super::status::Iec104Metrics;
use crate::drivers::iec104::apci::{Frame, Unnumbered};
use crate::drivers::iec104::window::{Broken, Limits, Window};
use crate::service::{Change, Changes, Service};

/// Changes taken at once, at most, before the connection is looked at again.
const DRAIN: usize = 1024;
/// How often commands waiting for their outcome are looked at.
const OUTCOMES_EVERY: Duration = Duration::from_millis(20);

/// Why a master's connection ended.
#[derive(Debug, thiserror::Error)]
pub(crate) enum Ended {
    #[error("{0}")]
    Io(#[from] std::io::Error),
    #[error("the master sent a malformed frame: {0}")]
    Frame(#[from] crate::drivers::iec104::apci::Malformed),
    #[error("{0}")]
    Window(#[from] Broken),
    #[error("the master closed the connection")]
    Closed,
    #[error("its changes cannot be followed: {0}")]
    Refused(String),
    #[error("the master sent {0}, which only an outstation sends")]
    Unexpected(&'static str),
    #[error("the master did not take an answer within t1 ({0:?})")]
    Stuck(Duration),
    #[error(
        "the master asks faster than it takes answers ({} wait)",
        super::station::MAX_REPLIES
    )]
    Flooded,
    #[error("the outstation stopped")]
    Stopped,
}

impl Ended {
    /// Its name in the metrics' `reason` label.
    pub(crate) fn reason(&self) -> &'static str {
        match self {
            Ended::Io(_) => "io",
            Ended::Frame(_) => "malformed",
            Ended::Window(Broken::Unacknowledged(_) | Broken::Untested(_)) => "t1",
            Ended::Window(_) => "window",
            Ended::Closed => "closed",
            Ended::Refused(_) => "refused",
            Ended::Unexpected(_) => "unexpected",
            Ended::Stuck(_) => "t1",
            Ended::Flooded => "flooded",
            Ended::Stopped => "stopped",
        }
    }
}

pub(crate) struct Master {
    pub(crate) io: TcpStream,
    pub(crate) peer: SocketAddr,
    pub(crate) config: Arc<Iec104ServerConfig>,
    pub(crate) service: Arc<Service>,
    pub(crate) served: watch::Receiver<Arc<Served>>,
    pub(crate) metrics: Arc<Iec104Metrics>,
    pub(crate) selections: super::selection::Selections,
}

struct Run {
    io: TcpStream,
    buf: Vec<u8>,
    window: Window,
    t1: Duration,
    /// Data transfer on (STARTDT confirmed); STOPDT asked and not confirmed yet.
    started: bool,
    stopping: bool,
    station: Station,
    served: Arc<Served>,
    /// The served fields' changes, taken while data transfer is on (current values first,
    /// what later changes are compared with).
    changes: Option<Changes>,
    service: Arc<Service>,
    peer: SocketAddr,
    /// I-frames received before STARTDT (acknowledged, not executed).
    ignored: u64,
    metrics: Arc<Iec104Metrics>,
}

impl Master {
    pub(crate) async fn serve(mut self, stop: CancellationToken) {
        let c = &self.config;
        let limits = Limits {
            k: c.k,
            w: c.w,
            t1: c.t1,
            t2: c.t2,
            t3: c.t3,
        };
        let served = self.served.borrow_and_update().clone();
        let mut station = Station::new(self.service.clone(), c, self.selections.clone());
        station.spontaneous.reset(served.table.points.len());
        let mut run = Run {
            io: self.io,
            buf: Vec::with_capacity(512),
            window: Window::new(limits),
            t1: c.t1,
            started: false,
            stopping: false,
            station,
            served,
            changes: None,
            service: self.service.clone(),
            peer: self.peer,
            ignored: 0,
            metrics: self.metrics.clone(),
        };
        run.metrics.connected();
        let why = loop {
            let step = tokio::select! {
                _ = stop.cancelled() => Err(Ended::Stopped),
                r = run.turn(&mut self.served) => r,
            };
            if let Err(why) = step {
                break why;
            }
        };
        run.metrics.ended(run.started, why.reason());
        match why {
            Ended::Closed | Ended::Stopped => {
                tracing::info!(peer = %self.peer, "IEC 104 master disconnected: {why}")
            }
            why => tracing::warn!(peer = %self.peer, "IEC 104 master's connection closed: {why}"),
        }
        let _ = run.io.shutdown().await;
    }
}

async fn next_change(changes: &mut Option<Changes>) -> Option<Change> {
    match changes {
        Some(c) => c.next().await,
        None => std::future::pending().await,
    }
}

impl Run {
    async fn turn(&mut self, table: &mut watch::Receiver<Arc<Served>>) -> Result<(), Ended> {
        let deadline = self.window.deadline();
        let waiting = self.station.waiting();
        let mut chunk = [0u8; 2048];
        tokio::select! {
            read = self.io.read(&mut chunk) => {
                let n = read?;
                if n == 0 {
                    return Err(Ended::Closed);
                }
                self.buf.extend_from_slice(&chunk[..n]);
                // Heard when a frame is whole: bytes trickled in one at a time are not a
                // master's life sign (t3, then TESTFR, then t1 end such a connection).
                while let Some((frame, used)) = Frame::decode(&self.buf)? {
                    self.window.heard();
                    self.buf.drain(..used);
                    self.take(frame).await?;
                }
            }
            change = next_change(&mut self.changes) => match change {
                Some(change) => {
                    self.changed(change);
                    self.drain();
                }
                None => self.changes = None,
            },
            Ok(()) = table.changed() => {
                self.served = table.borrow_and_update().clone();
                self.station.spontaneous.reset(self.served.table.points.len());
                if self.changes.is_some() {
                    self.subscribe()?;
                }
            }
            () = tokio::time::sleep(OUTCOMES_EVERY), if waiting => self.station.outcomes(),
            () = tokio::time::sleep_until(deadline) => {
                let due = self.window.due()?;
                if due.confirm {
                    self.confirm().await?;
                }
                if due.test {
                    self.write(&Frame::U(Unnumbered::TestAct).encode()).await?;
                }
            }
        }
        if self.station.overflowing() {
            return Err(Ended::Flooded);
        }
        self.flush().await
    }

    fn changed(&mut self, change: Change) {
        let Change::Value {
            device,
            idx,
            sample,
            ..
        } = change
        else {
            return;
        };
        let quality = device.quality(&sample, tokio::time::Instant::now());
        let at = sample.updated.map(|(_, at)| at);
        let started = self.started && !self.stopping;
        for &i in self.served.table.monitors(device.name(), idx) {
            let reading = (sample.value.clone(), quality, at);
            self.station
                .spontaneous
                .changed(&self.served, i, reading, started);
        }
    }

    /// Takes the changes that came meanwhile (at most [`DRAIN`]) before anything is sent,
    /// so a device's read goes out in full ASDUs rather than one object a frame.
    fn drain(&mut self) {
        for _ in 0..DRAIN {
            let Some(changes) = self.changes.as_mut() else {
                return;
            };
            match changes.next().now_or_never() {
                Some(Some(change)) => self.changed(change),
                Some(None) => {
                    self.changes = None;
                    return;
                }
                None => return,
            }
        }
    }

    /// Follows the served fields' changes from now on: their current values first, what
    /// the next change of each is compared with.
    fn subscribe(&mut self) -> Result<(), Ended> {
        self.changes = None;
        self.station
            .spontaneous
            .reset(self.served.table.points.len());
        let everything = self.service.select::<&str, &str>(&[], &[]);
        let changes = everything
            .and_then(|s| self.service.subscribe_for(s, false, Some(self.peer.ip())))
            .map_err(|e| Ended::Refused(e.to_string()))?;
        self.changes = Some(changes);
        Ok(())
    }

    /// Sends what waits while the window has room and data transfer is on.
    async fn flush(&mut self) -> Result<(), Ended> {
        while self.started && !self.stopping && self.window.room() && self.station.has_next() {
            let Some(asdu) = self.station.next(&self.served) else {
                break;
            };
            if asdu.is_empty() {
                continue;
            }
            let (send, recv) = self.window.send();
            self.metrics.sent(&asdu);
            self.write(&Frame::I { send, recv, asdu }.encode()).await?;
        }
        if self.stopping && self.window.unacknowledged() == 0 {
            self.stopping = false;
            self.started = false;
            self.metrics.transfer(false);
            // Nothing is followed while nobody asks.
            self.changes = None;
            self.write(&Frame::U(Unnumbered::StopCon).encode()).await?;
        }
        Ok(())
    }

    async fn write(&mut self, octets: &[u8]) -> Result<(), Ended> {
        match tokio::time::timeout(self.t1, self.io.write_all(octets)).await {
            Ok(r) => Ok(r?),
            Err(_) => Err(Ended::Stuck(self.t1)),
        }
    }

    async fn confirm(&mut self) -> Result<(), Ended> {
        let recv = self.window.confirm();
        self.write(&Frame::S { recv }.encode()).await
    }

    async fn take(&mut self, frame: Frame) -> Result<(), Ended> {
        match frame {
            Frame::I { send, recv, asdu } => {
                let confirm = self.window.received(send, recv)?;
                self.metrics.received();
                if self.started {
                    self.station.take(&self.served, &asdu);
                } else {
                    // As lib60870's stations do: counted and acknowledged, not executed.
                    self.ignored += 1;
                    if self.ignored == 1 {
                        tracing::warn!(peer = %self.peer, "IEC 104 master sent an I-frame before STARTDT: not executed");
                    }
                }
                if confirm {
                    self.confirm().await?;
                }
            }
            Frame::S { recv } => self.window.acknowledged(recv)?,
            Frame::U(Unnumbered::StartAct) => {
                if !self.started {
                    self.subscribe()?;
                    self.metrics.transfer(true);
                }
                self.started = true;
                self.stopping = false;
                self.write(&Frame::U(Unnumbered::StartCon).encode()).await?;
            }
            Frame::U(Unnumbered::StopAct) => {
                // Confirmed once every I-frame sent is acknowledged (`flush`); what was
                // received is acknowledged now.
                if self.window.unconfirmed() > 0 {
                    self.confirm().await?;
                }
                self.stopping = self.started;
                if !self.started {
                    self.write(&Frame::U(Unnumbered::StopCon).encode()).await?;
                }
            }
            Frame::U(Unnumbered::TestAct) => {
                self.write(&Frame::U(Unnumbered::TestCon).encode()).await?
            }
            Frame::U(Unnumbered::TestCon) => self.window.tested(),
            Frame::U(u) => return Err(Ended::Unexpected(u.name())),
        }
        Ok(())
    }
}

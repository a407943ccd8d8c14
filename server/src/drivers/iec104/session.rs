//! An open link to a station: its devices' fields registered with the connection's router,
//! general and counter interrogations (at connect, on their periods, and again when the
//! station says it initialised), each confirmed and terminated before its values are
//! judged complete, and commands: an output's value as its command, selected first where
//! the field says so, the station's confirmation its outcome.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use tokio::time::Instant;

use super::asdu::{Asdu, Object, cause};
use super::config::Settings;
use super::conn::{self, Connection, Iec104Error, Opening};
use super::element::Element;
use super::redundancy::Standby;
use super::route::{Answers, Router};
use super::types::{TypeId, id};
use super::{Plan, is_input, lost, point};
use crate::cache::{Device, FieldError, Link};
use crate::link::LinkFault;

/// An output on a new connection: a command point is not read back, so what it shows is
/// the value last written (not vouched for now), or nothing yet; not a lost link's error.
fn command_point(device: &Device, idx: usize) {
    let sample = device.sample(idx);
    use iogate_types::Quality;
    if matches!(sample.quality, Quality::Good | Quality::NeverRead) {
        return;
    }
    let why = |what: &str| FieldError::Device(format!("a command point, not read back: {what}"));
    match sample.value {
        Some(v) => device.publish_from(
            idx,
            Ok(v),
            Some(why(
                "the value last written before the connection was opened again",
            )),
            None,
            crate::cache::Stamp::now(),
        ),
        None => device.publish(idx, Err(why("nothing written yet"))),
    }
}

/// Each connection's number, so that a device's plan knows the connection it was
/// registered with.
static GENERATION: AtomicU64 = AtomicU64::new(1);

/// QOI: the station's general interrogation; QCC: every counter, read (no freeze).
const STATION: u8 = 20;
const ALL_COUNTERS: u8 = 5;

pub(crate) struct Station {
    conn: Connection,
    pub(super) link: Arc<Link>,
    pub(super) settings: Settings,
    pub(super) generation: u64,
    /// The other connection of the redundancy group, where the station has a `backup`.
    standby: Option<Standby>,
    /// A standby started (STARTDT act sent): its confirmation is due by then, and what
    /// `/links` says of the station once it came.
    starting: Option<(Instant, String)>,
    /// The counts `/links` was last told.
    told: Option<(conn::State, u64, u64)>,
}

impl Station {
    /// Connects to the station's address, else to its backup; with a backup, the other
    /// address is held as the standby.
    pub(super) async fn open(s: Settings, link: &Arc<Link>) -> Result<Station, LinkFault> {
        let router = Arc::new(Router::default());
        let endpoint = format!("{}:{}", s.host, s.port);
        let first = conn::open(&s.host, s.port, &s, router.clone(), Opening::Started).await;
        let (conn, active) = match (first, &s.backup) {
            (Ok(c), _) => {
                link.set_peer("station", endpoint);
                (c, 0)
            }
            (Err(e), None) => return Err(LinkFault::connect_failed(endpoint, e)),
            (Err(e), Some((host, port))) => {
                tracing::warn!(error = %e, endpoint, "IEC 104: the station does not connect; trying its backup address");
                let backup = format!("{host}:{port}");
                let c = conn::open(host, *port, &s, router, Opening::Started)
                    .await
                    .map_err(|e| LinkFault::connect_failed(backup.clone(), e))?;
                link.set_peer("station", format!("{backup} (the backup)"));
                (c, 1)
            }
        };
        let standby = s.backup.clone().map(|backup| {
            let addresses = [(s.host.clone(), s.port), backup];
            Standby::hold(addresses, active, s.clone(), link.clone())
        });
        link.set_peer("windows", format!("k {}, w {}", s.k, s.w));
        link.set_peer(
            "timers",
            format!("t0 {:?}, t1 {:?}, t2 {:?}, t3 {:?}", s.t0, s.t1, s.t2, s.t3),
        );
        Ok(Station {
            conn,
            link: link.clone(),
            settings: s,
            generation: GENERATION.fetch_add(1, Ordering::Relaxed),
            standby,
            starting: None,
            told: None,
        })
    }

    /// Registers the device's input fields with this connection.
    pub(super) fn register(&self, device: &Arc<Device>, plan: &mut Plan) {
        plan.common_address = match device.config.at(point::COMMON_ADDRESS) {
            Some(text) => point::common_address(text),
            None => Ok(self.settings.common_address),
        };
        let ioas: Vec<(usize, u32, Option<TypeId>)> = plan
            .places
            .iter()
            .enumerate()
            .filter(|(i, _)| is_input(device, *i))
            .filter_map(|(i, p)| p.as_ref().ok().map(|p| (i, p.ioa, p.fixed)))
            .collect();
        for (i, p) in plan.places.iter().enumerate() {
            if let Err(why) = p {
                device.publish(i, Err(FieldError::Device(why.clone())));
            } else if !is_input(device, i) {
                command_point(device, i);
            }
        }
        if let Ok(ca) = plan.common_address {
            self.conn.router.register(device, ca, &ioas);
        }
        plan.generation = self.generation;
        plan.interrogated = None;
        plan.answered = false;
        plan.counted = None;
    }

    /// Interrogates the device's common address when it never was on this connection,
    /// its period has passed, or the station initialised since.
    pub(super) async fn interrogate_when_due(
        &mut self,
        device: &Arc<Device>,
        plan: &mut Plan,
        ca: u16,
    ) -> Result<(), LinkFault> {
        let due = |last: Option<Instant>, period: Option<Duration>| match last {
            None => true,
            Some(t) => period.is_some_and(|p| t.elapsed() >= p),
        };
        self.tell_state();
        let restarted = self.conn.router.restarted.swap(false, Ordering::Relaxed);
        // Until one is answered on this connection, a general interrogation is asked again
        // every four t1, not every refresh.
        let period = if plan.answered {
            self.settings.interrogation
        } else {
            Some(self.settings.t1 * 4)
        };
        let mut first = false;
        if restarted || due(plan.interrogated, period) {
            plan.interrogated = Some(Instant::now());
            if self.settings.clock_sync {
                self.set_clock(ca).await?;
            }
            if let Err(why) = self.interrogation(id::C_IC_NA_1, ca, STATION).await? {
                self.link.progress.ended();
                device.doubt_reads(&FieldError::Device(why));
                return Ok(());
            }
            first = !std::mem::replace(&mut plan.answered, true);
        }
        // Counters: asked at the first answer when it left fields unreported (the devices'
        // fields are scanned only then), and on their period.
        let counters = if first {
            plan.counted = Some(Instant::now());
            !self.conn.router.unseen(device, ca).is_empty()
        } else {
            plan.counted.is_some() && due(plan.counted, self.settings.counter_interrogation)
        };
        if counters {
            plan.counted = Some(Instant::now());
            if let Err(why) = self.interrogation(id::C_CI_NA_1, ca, ALL_COUNTERS).await? {
                tracing::warn!(device = %device.name(), "{why}");
            }
        }
        // The connection is alive (the station answers test frames within t1): it
        // vouches for every value it has not changed.
        self.link.progress.ended();
        device.vouch();
        if first {
            for (idx, ioa) in self.conn.router.unseen(device, ca) {
                let why = format!(
                    "the station at common address {ca} sent nothing for IOA {ioa} in its answers to general and counter interrogation"
                );
                device.publish(idx, Err(FieldError::Device(why)));
            }
        }
        Ok(())
    }

    /// Sets the station's clock at `ca` to the gateway's (C_CS_NA_1, UTC), its
    /// confirmation or refusal shown in `/links`; a refusal does not stop the reading.
    async fn set_clock(&self, ca: u16) -> Result<(), LinkFault> {
        let now = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| i64::try_from(d.as_millis()).unwrap_or(i64::MAX));
        let element = Element::ClockSync(super::time::Cp56::at(now));
        let mut answers = self
            .request(self.asdu(id::C_CS_NA_1, ca, 0, element))
            .await?;
        let outcome = match answers.next(self.settings.t1).await {
            Some(a) if a.cause == cause::ACT_CON && !a.negative => "confirmed".to_owned(),
            Some(a) => format!(
                "refused: {}{}",
                if a.negative { "negative " } else { "" },
                cause::name(a.cause)
            ),
            None => format!("not confirmed within t1 ({:?})", self.settings.t1),
        };
        if !outcome.starts_with('c') {
            self.lost_while_asked()?;
            tracing::warn!(
                common_address = ca,
                "IEC 104: clock synchronisation {outcome}"
            );
        }
        let at = crate::civil::Civil::from_millis(now).map_or(now.to_string(), |c| c.to_string());
        self.link.set_peer(
            "clock",
            format!("set at common address {ca} to {at} UTC: {outcome}"),
        );
        Ok(())
    }

    /// The connection's windows and counts, as `/links` shows them.
    fn tell_state(&mut self) {
        let st = *self.conn.state.borrow();
        let r = &self.conn.router;
        let counts = (
            st,
            r.malformed.load(Ordering::Relaxed),
            r.unrouted.load(Ordering::Relaxed),
        );
        // Told only when it changed (a device read every millisecond tells it once).
        if self.told == Some(counts) {
            return;
        }
        self.told = Some(counts);
        let transfer = if st.started {
            "started (STARTDT confirmed)"
        } else {
            "stopped"
        };
        self.link.set_peer("data_transfer", transfer.to_owned());
        self.link.set_peer(
            "i_frames",
            format!(
                "sent {} ({} unacknowledged of k {}), received {} ({} unconfirmed of w {}); {} malformed ASDUs, {} for nothing configured",
                st.sent,
                st.unacknowledged,
                self.settings.k,
                st.received,
                st.unconfirmed,
                self.settings.w,
                r.malformed.load(Ordering::Relaxed),
                r.unrouted.load(Ordering::Relaxed),
            ),
        );
    }

    /// Sends the station an ASDU and waits for its answers.
    pub(super) async fn request(&self, asdu: Asdu) -> Result<Answers, LinkFault> {
        let first = asdu.objects.first().map_or(0, |o| o.ioa);
        let answers = self
            .conn
            .router
            .expect(asdu.type_id, asdu.common_address, first);
        if self.conn.send.send(asdu).await.is_err() {
            return Err(lost(Iec104Error::Closed));
        }
        Ok(answers)
    }

    pub(super) fn asdu(&self, type_id: u8, ca: u16, ioa: u32, element: Element) -> Asdu {
        let mut asdu = Asdu::new(
            TypeId(type_id),
            cause::ACTIVATION,
            ca,
            vec![Object {
                ioa,
                element,
                time: None,
            }],
        );
        asdu.originator = self.settings.originator;
        asdu
    }

    /// A general or counter interrogation: confirmed within t1, terminated within four.
    async fn interrogation(
        &self,
        type_id: u8,
        ca: u16,
        qualifier: u8,
    ) -> Result<Result<(), String>, LinkFault> {
        let element = if type_id == id::C_IC_NA_1 {
            Element::Interrogation(qualifier)
        } else {
            Element::CounterInterrogation(qualifier)
        };
        let what = TypeId(type_id).name();
        let mut answers = self.request(self.asdu(type_id, ca, 0, element)).await?;
        let t1 = self.settings.t1;
        self.link.progress.started(Instant::now() + t1 * 5);
        match answers.next(t1).await {
            Some(a) if a.cause == cause::ACT_CON && !a.negative => {}
            Some(a) => {
                return Ok(Err(format!(
                    "the station refused {what} at common address {ca}: {}{}",
                    if a.negative { "negative " } else { "" },
                    cause::name(a.cause)
                )));
            }
            None => {
                self.lost_while_asked()?;
                return Ok(Err(format!("no confirmation of {what} within t1 ({t1:?})")));
            }
        }
        let deadline = Instant::now() + t1 * 4;
        while let Some(a) = answers
            .next(deadline.saturating_duration_since(Instant::now()))
            .await
        {
            if a.cause == cause::ACT_TERM {
                return Ok(Ok(()));
            }
        }
        self.lost_while_asked()?;
        Ok(Err(format!(
            "{what} at common address {ca} was not terminated within {:?}",
            t1 * 4
        )))
    }

    /// The connection's loss, if the wait for an answer ended because it was lost.
    fn lost_while_asked(&self) -> Result<(), LinkFault> {
        match self.conn.lost.borrow().clone() {
            Some(why) => Err(lost(why)),
            None => Ok(()),
        }
    }

    pub(super) async fn stop(self) {
        drop(self.conn);
    }

    /// Resolves when the link is lost: the started connection, and no standby took over.
    pub(super) async fn lost_now(&mut self) -> Iec104Error {
        loop {
            if let Err(why) = self.ready().await {
                return why;
            }
            let _ = self.conn.lost.wait_for(Option::is_some).await;
        }
    }

    /// Whether the connection is there to be used: the started one alive, or a standby
    /// started in its place (STARTDT confirmed within t1). Cancelled, it goes on where it
    /// stopped when called again.
    pub(super) async fn ready(&mut self) -> Result<(), Iec104Error> {
        loop {
            if let Some((deadline, told)) = &self.starting {
                let t1 = self.settings.t1;
                let mut state = self.conn.state.clone();
                let started = tokio::time::timeout_at(*deadline, state.wait_for(|s| s.started));
                if !matches!(started.await, Ok(Ok(_))) {
                    // Lost meanwhile (both connections gone): that is why, not t1.
                    let lost = self.conn.lost.borrow().clone();
                    return Err(lost.unwrap_or(Iec104Error::Start("STARTDT con", t1)));
                }
                self.link.set_peer("station", told.clone());
                self.starting = None;
            }
            let Some(why) = self.conn.lost.borrow().clone() else {
                return Ok(());
            };
            let lost_at = self.conn.lost_at.get().copied();
            let closed = matches!(why, Iec104Error::Closed | Iec104Error::Io(_));
            let taken = match &self.standby {
                Some(s) => s.take(lost_at, closed).await,
                None => None,
            };
            let Some((standby, at)) = taken else {
                return Err(why);
            };
            tracing::warn!(error = %why, standby = at, "IEC 104: the started connection was lost; starting the standby");
            standby.start();
            self.conn = standby;
            self.generation = GENERATION.fetch_add(1, Ordering::Relaxed);
            let told = format!("{at} (took over when the other connection was lost: {why})");
            self.starting = Some((Instant::now() + self.settings.t1, told));
            self.link
                .set_peer("station", format!("{at} (starting: STARTDT sent)"));
        }
    }
}

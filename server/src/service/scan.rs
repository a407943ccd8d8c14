//! Scans of configured links (`POST /api/v1/links/{link}/scan`): each probe waits in the
//! link's inbox like a raw transaction and goes on the line between polls, so polling is
//! never held up for more than one probe; the state of each scan (progress, devices found)
//! is a `watch` its readers follow. One scan a link at a time; the last [`KEPT_SCANS`] kept.

use std::collections::VecDeque;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use serde::Serialize;
use tokio::sync::{oneshot, watch};
use tokio_util::sync::CancellationToken;

use super::{Service, ServiceError};
use crate::cache::{Link, PassthroughError, Probe};
use crate::config::{Framing, Transport};
use crate::scan::report::Summary;
use crate::scan::{Plan, Prober, Progress, ScanError, Setting};

/// How many scans are kept (the oldest finished one is forgotten first).
pub const KEPT_SCANS: usize = 16;
/// How long a probe may wait in a busy link's inbox before the scan gives up.
const PROBE_WAIT: Duration = Duration::from_secs(10);

/// A scan as its readers see it: where it stands, and its result so far (what is tried, the
/// longest it takes on an idle line, said before it starts, the devices found and their
/// `devices:` entries), as `iogate scan --json` prints it.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct ScanState {
    pub id: u64,
    pub link: String,
    /// `running`, `done`, `failed` or `cancelled`.
    pub state: &'static str,
    pub probed: usize,
    pub total: usize,
    pub elapsed_ms: u64,
    #[serde(flatten)]
    pub result: Summary,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

#[derive(Debug)]
struct Record {
    id: u64,
    link: String,
    state: watch::Sender<ScanState>,
    cancel: CancellationToken,
}

/// The scans of the gateway's links.
#[derive(Debug, Default)]
pub struct Scans {
    next: AtomicU64,
    records: std::sync::Mutex<VecDeque<Record>>,
}

fn lock<T>(m: &std::sync::Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// A scan's probes through a link's inbox.
struct LinkProber {
    link: Arc<Link>,
    slot: Duration,
}

#[async_trait::async_trait]
impl Prober for LinkProber {
    async fn set(&mut self, _setting: &Setting) -> Result<(), ScanError> {
        Ok(())
    }

    async fn probe(&mut self, slave: u8, pdu: &[u8], early: bool) -> Result<Vec<u8>, ScanError> {
        // A full inbox is other clients' traffic: wait for room, within PROBE_WAIT.
        let started = tokio::time::Instant::now();
        loop {
            let (reply, answer) = oneshot::channel();
            self.link.submit_probe(Probe {
                slave,
                pdu: pdu.to_vec(),
                slot: self.slot,
                early,
                deadline: started + PROBE_WAIT,
                reply,
            });
            match answer.await {
                Ok(Ok(heard)) => return Ok(heard),
                Ok(Err(PassthroughError::Busy)) if started.elapsed() < PROBE_WAIT => {
                    tokio::time::sleep(Duration::from_millis(20)).await;
                }
                Ok(Err(e)) => {
                    return Err(ScanError::Port(format!("link {}: {e}", self.link.name())));
                }
                Err(_) => {
                    return Err(ScanError::Port(format!(
                        "link {}: its task gave no answer",
                        self.link.name()
                    )));
                }
            }
        }
    }
}

impl Service {
    /// Starts a scan of `link` at its own line setting: ids (default 1-247), a slot of
    /// `timeout` each (default 50 ms). The state says how long it will take before it starts.
    pub(crate) fn start_scan(
        &self,
        link: &str,
        ids: Option<&str>,
        timeout: Option<Duration>,
    ) -> Result<ScanState, ServiceError> {
        let link = self.link(link)?;
        let setting = rtu_setting(&link)?;
        let plan = Plan {
            settings: vec![setting],
            ids: crate::scan::parse_ids(ids.unwrap_or("1-247")).map_err(ServiceError::Scan)?,
            timeout: timeout.unwrap_or(crate::scan::DEFAULT_TIMEOUT),
        };
        if setting.baud > 0 {
            plan.check().map_err(ServiceError::Scan)?;
        }
        let mut records = lock(&self.scans.records);
        if let Some(running) = records
            .iter()
            .find(|r| r.link == link.name() && r.state.borrow().state == "running")
        {
            self.metrics
                .bound("scans", self.cache.links().len())
                .refused();
            return Err(ServiceError::ScanRunning {
                link: link.name().to_owned(),
                id: running.id,
            });
        }
        let id = self.scans.next.fetch_add(1, Ordering::Relaxed) + 1;
        let first = ScanState {
            id,
            link: link.name().to_owned(),
            state: "running",
            probed: 0,
            total: plan.ids.len(),
            elapsed_ms: 0,
            result: Summary::new(&plan, Default::default(), None, link.name()),
            error: None,
        };
        let (state, _) = watch::channel(first.clone());
        let cancel = self.tasks().token().child_token();
        while records.len() >= KEPT_SCANS {
            match records
                .iter()
                .position(|r| r.state.borrow().state != "running")
            {
                Some(i) => {
                    records.remove(i);
                }
                None => break,
            }
        }
        records.push_back(Record {
            id,
            link: link.name().to_owned(),
            state: state.clone(),
            cancel: cancel.clone(),
        });
        drop(records);
        let profiles: Vec<_> = self.cache.catalog().iter().cloned().collect();
        let prober = LinkProber {
            link: link.clone(),
            slot: plan.timeout,
        };
        self.tasks().spawn(run_scan(
            prober,
            plan,
            profiles,
            state,
            cancel,
            link.name().to_owned(),
        ));
        Ok(first)
    }

    /// A scan's state, to read or follow.
    /// Scans running now.
    pub(crate) fn running_scans(&self) -> usize {
        lock(&self.scans.records)
            .iter()
            .filter(|r| r.state.borrow().state == "running")
            .count()
    }

    pub(crate) fn scan(&self, id: u64) -> Result<watch::Receiver<ScanState>, ServiceError> {
        lock(&self.scans.records)
            .iter()
            .find(|r| r.id == id)
            .map(|r| r.state.subscribe())
            .ok_or(ServiceError::UnknownScan(id))
    }

    /// Stops a running scan between two probes.
    pub(crate) fn cancel_scan(&self, id: u64) -> Result<(), ServiceError> {
        lock(&self.scans.records)
            .iter()
            .find(|r| r.id == id)
            .map(|r| r.cancel.cancel())
            .ok_or(ServiceError::UnknownScan(id))
    }
}

/// The line setting a scan of `link` probes at: its own, for a link that carries RTU
/// frames (serial, or RTU over TCP).
fn rtu_setting(link: &Link) -> Result<Setting, ServiceError> {
    match &link.config().transport {
        Transport::Serial(s) if s.framing == Framing::Rtu => Ok(Setting {
            baud: s.baud,
            parity: s.parity,
        }),
        Transport::Tcp {
            framing: Framing::Rtu,
            ..
        } => Ok(Setting {
            baud: 0,
            parity: crate::config::Parity::None,
        }),
        _ => Err(ServiceError::Scan(format!(
            "link {} does not carry RTU frames: a scan probes serial RTU lines (and RTU over TCP)",
            link.name()
        ))),
    }
}

/// A scan's run, its progress and its end in its state.
async fn run_scan(
    mut prober: LinkProber,
    plan: Plan,
    profiles: Vec<Arc<crate::profile::Profile>>,
    state: watch::Sender<ScanState>,
    cancel: tokio_util::sync::CancellationToken,
    name: String,
) {
    let started = std::time::Instant::now();
    let mut on_progress = |p: Progress| {
        state.send_modify(|s| {
            s.elapsed_ms = started.elapsed().as_millis() as u64;
            match p {
                Progress::Tried { done, .. } => s.probed = done,
                Progress::Found(d) => s.result.devices.push(*d),
                Progress::Setting { .. } => {}
            }
        });
    };
    let result = crate::scan::run(&mut prober, &plan, &profiles, &mut on_progress, &cancel).await;
    state.send_modify(|s| {
        s.elapsed_ms = started.elapsed().as_millis() as u64;
        match result {
            Ok(scanned) => {
                s.result = Summary::new(&plan, scanned, None, &name);
                s.state = "done";
            }
            Err(ScanError::Cancelled) => s.state = "cancelled",
            Err(e) => {
                s.state = "failed";
                s.error = Some(e.to_string());
            }
        }
    });
}

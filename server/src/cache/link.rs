//! One link as the cache sees it: its settings and devices, its diagnostics, and the inbox
//! of its task. Devices can be added at run time, and a link declared without a port can be
//! given one: each change publishes a new [`LinkState`], which the link's task takes in at its
//! next turn ([`Link::subscribe`]); the task owns what it builds from it.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};

use tokio::sync::{Notify, oneshot, watch};

use super::Device;
use super::sample::LinkDiagnostics;
use std::time::Duration;

use crate::config::{LinkConfig, Transport};
use crate::link::frame::{Request, Response};
use crate::link::{LinkCode, LinkFault, TxError};

/// A request put on the link as it is, for another master (a Modbus TCP client forwarding
/// to a slave, a raw transaction): queued in the link's bounded inbox, and sent by the link's
/// task between polls so it never collides with them on a half-duplex line.
#[derive(Debug)]
pub struct Passthrough {
    pub slave: u8,
    pub request: Request,
    pub timeout: Duration,
    /// When its caller stops waiting: a request that cannot be answered by then is never
    /// sent.
    pub deadline: tokio::time::Instant,
    pub reply: oneshot::Sender<Result<Response, PassthroughError>>,
    /// Told where the request is, for a caller that shows it (source document 002's
    /// states 1-3); `None` for one that does not.
    pub stage: Option<tokio::sync::watch::Sender<Stage>>,
}

/// Where a queued request is: in the inbox, taken by the link's task (waiting for the
/// line's silence), or on the line waiting for its answer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    Queued,
    Taken,
    Sent,
}

/// How many requests a link's inbox holds; one more is answered busy at once.
pub const INBOX_CAPACITY: usize = 8;

/// Why a queued request got no answer. `Busy` and `Expired` were never sent.
#[derive(Debug, Clone, thiserror::Error)]
pub enum PassthroughError {
    #[error(transparent)]
    Tx(#[from] TxError),
    #[error("the link is down: {0}")]
    LinkDown(LinkFault),
    #[error("the link's inbox is full ({INBOX_CAPACITY} requests); nothing was sent")]
    Busy,
    #[error("the request waited past its caller's deadline; nothing was sent")]
    Expired,
    /// The link speaks another field protocol than Modbus: nothing was sent.
    #[error("the link does not speak Modbus; nothing was sent")]
    NotModbus,
    /// The link's task gave no answer in time (it stopped, or is stalled).
    #[error("the link's task gave no answer")]
    NoAnswer,
}

/// A scan's probe of one slave id, queued like a [`Passthrough`]: the request PDU goes on
/// the line as it is and every byte heard within the slot comes back, for the scan to judge
/// (`crate::scan`). Only RTU links carry probes; others answer at once.
#[derive(Debug)]
pub struct Probe {
    pub slave: u8,
    pub pdu: Vec<u8>,
    /// The probe's whole slot: silence, request and answer.
    pub slot: Duration,
    /// End the slot once a whole answer is followed by the line's silence.
    pub early: bool,
    pub deadline: tokio::time::Instant,
    pub reply: oneshot::Sender<Result<Vec<u8>, PassthroughError>>,
}

/// What waits in a link's inbox.
#[derive(Debug)]
pub enum Inbox {
    Request(Passthrough),
    Probe(Probe),
}

impl Inbox {
    /// Whether its caller has stopped waiting for the answer.
    pub(crate) fn abandoned(&self) -> bool {
        match self {
            Inbox::Request(r) => r.reply.is_closed(),
            Inbox::Probe(p) => p.reply.is_closed(),
        }
    }

    /// Whether, sent at `now`, its answer could come only after its caller's deadline.
    pub(crate) fn too_late(&self, now: tokio::time::Instant) -> bool {
        let (wait, deadline) = match self {
            Inbox::Request(r) => (r.timeout, r.deadline),
            Inbox::Probe(p) => (p.slot, p.deadline),
        };
        now + wait > deadline
    }

    /// Answers it unsent with `error`.
    pub(crate) fn refuse(self, error: PassthroughError) {
        match self {
            Inbox::Request(r) => {
                let _ = r.reply.send(Err(error));
            }
            Inbox::Probe(p) => {
                let _ = p.reply.send(Err(error));
            }
        }
    }
}

/// A queued request with when it came.
#[derive(Debug)]
struct Queued {
    request: Inbox,
    since: tokio::time::Instant,
}

/// Where the link's task is: in a transaction that must end by a deadline, or not. A task
/// past its deadline by more than [`Progress::GRACE`] makes no progress: the link is stalled.
#[derive(Debug, Default)]
pub struct Progress {
    deadline: Mutex<Option<tokio::time::Instant>>,
    /// When the last transaction ended.
    last_end: Mutex<Option<tokio::time::Instant>>,
}

impl Progress {
    /// Beyond a transaction's own bound (its timeout and wire time) before the link counts
    /// as stalled.
    pub(crate) const GRACE: Duration = Duration::from_secs(5);

    /// A transaction began that must end by `deadline`.
    pub fn started(&self, deadline: tokio::time::Instant) {
        *super::lock(&self.deadline) = Some(deadline);
    }

    /// The transaction ended.
    pub fn ended(&self) {
        *super::lock(&self.deadline) = None;
        *super::lock(&self.last_end) = Some(tokio::time::Instant::now());
    }

    /// Whether the task is working the line: in a transaction within its bound, or one
    /// ended within `window` of `now`. A device whose value is old while its line works is
    /// waiting for its turn (late), not cut off (stale).
    pub(crate) fn working(&self, now: tokio::time::Instant, window: Duration) -> bool {
        let in_transaction = (*super::lock(&self.deadline)).is_some_and(|d| now <= d + Self::GRACE);
        in_transaction
            || (*super::lock(&self.last_end))
                .is_some_and(|at| now.saturating_duration_since(at) <= window)
    }

    /// Whether the task is inside a transaction now.
    pub(crate) fn in_transaction(&self) -> bool {
        super::lock(&self.deadline).is_some()
    }

    /// How long the task is past its transaction's deadline and grace, if it is.
    pub(crate) fn stalled_for(&self, now: tokio::time::Instant) -> Option<Duration> {
        let deadline = (*super::lock(&self.deadline))?;
        now.checked_duration_since(deadline + Self::GRACE)
    }
}

/// How busy the line is: the share of time the refresh rates demand (`planned`, serial
/// links), and the share the link's task measured over its last window of transactions.
#[derive(Debug, Default)]
pub struct Utilisation(Mutex<(Option<f64>, Option<f64>)>);

impl Utilisation {
    pub(crate) fn set_planned(&self, planned: Option<f64>) {
        super::lock(&self.0).0 = planned;
    }

    pub(crate) fn set_measured(&self, measured: f64) {
        super::lock(&self.0).1 = Some(measured);
    }

    /// `(planned, measured)`.
    pub(crate) fn get(&self) -> (Option<f64>, Option<f64>) {
        *super::lock(&self.0)
    }
}

/// What a link is told to be: its settings and the devices it polls, in the order they
/// were added. Published whole on each change; the link's task takes in the newest.
#[derive(Debug, Clone)]
pub struct LinkState {
    pub(crate) config: LinkConfig,
    pub(crate) members: Vec<Arc<Device>>,
}

/// A link, its diagnostics and the devices on it.
#[derive(Debug)]
pub struct Link {
    name: String,
    /// Settings and membership, sent to the link's task as a message that holds only the
    /// newest (a change made while the task is busy replaces the one before it).
    state: watch::Sender<LinkState>,
    diagnostics: watch::Sender<LinkDiagnostics>,
    /// Wakes the link's task when a write to one of its devices is requested or a request
    /// is queued.
    pub(crate) wake: Arc<Notify>,
    queue: Mutex<VecDeque<Queued>>,
    /// Stops the link's task when the link is removed.
    task: Mutex<Option<tokio_util::sync::CancellationToken>>,
    /// Whether the link's task keeps within its transactions' bounds.
    pub progress: Arc<Progress>,
    pub(crate) utilisation: Arc<Utilisation>,
    /// What the driver learned of the device at the other end (a PLC's order number, the
    /// PDU size it granted, its operating state), in the order told.
    peer: Mutex<Vec<(&'static str, String)>>,
    /// Why the link is down (the last failure to open it, or how it was lost).
    down: Mutex<Option<String>>,
}

impl Link {
    pub(crate) fn new(config: LinkConfig) -> Self {
        Link {
            wake: Arc::new(Notify::new()),
            name: config.name.clone(),
            state: watch::Sender::new(LinkState {
                config,
                members: Vec::new(),
            }),
            diagnostics: watch::Sender::new(LinkDiagnostics {
                connected: false,
                error_code: LinkCode::Ok,
            }),
            queue: Mutex::new(VecDeque::new()),
            task: Mutex::new(None),
            down: Mutex::new(None),
            progress: Arc::new(Progress::default()),
            utilisation: Arc::new(Utilisation::default()),
            peer: Mutex::new(Vec::new()),
        }
    }

    /// What is known of the device at the other end.
    pub(crate) fn peer(&self) -> Vec<(&'static str, String)> {
        super::lock(&self.peer).clone()
    }

    /// Why the link is down, if it is.
    pub(crate) fn down(&self) -> Option<String> {
        super::lock(&self.down).clone()
    }

    /// Tells why the link is down (`None`: it is up).
    pub(crate) fn set_down(&self, why: Option<String>) {
        *super::lock(&self.down) = why;
    }

    /// Forgets what was known of the device at the other end (a new connection, perhaps to
    /// another device, is being opened).
    pub(crate) fn clear_peer(&self) {
        super::lock(&self.peer).clear();
    }

    /// Tells one fact of the device at the other end (replacing the one before).
    pub(crate) fn set_peer(&self, key: &'static str, value: String) {
        let mut peer = super::lock(&self.peer);
        match peer.iter_mut().find(|(k, _)| *k == key) {
            Some(slot) => slot.1 = value,
            None => peer.push((key, value)),
        }
    }

    /// Whether the link's task is stuck in a transaction past its bound (and since when).
    pub(crate) fn stalled(&self) -> Option<Duration> {
        self.progress.stalled_for(tokio::time::Instant::now())
    }

    /// Remembers the token that stops the link's task.
    pub(crate) fn attach_task(&self, token: tokio_util::sync::CancellationToken) {
        *super::lock(&self.task) = Some(token);
    }

    /// Stops the link's task (the link was removed); it closes its port or socket.
    pub(crate) fn stop(&self) {
        if let Some(token) = super::lock(&self.task).take() {
            token.cancel();
        }
    }

    pub(crate) fn name(&self) -> &str {
        &self.name
    }

    /// The link's settings as they are now.
    pub(crate) fn config(&self) -> LinkConfig {
        self.state.borrow().config.clone()
    }

    /// Whether the link has a transport to open: a serial link declared with an empty port
    /// has none until it is declared again with one (`SerialLink` error 1 meanwhile).
    pub(crate) fn is_configured(&self) -> bool {
        self.state.borrow().config.transport.is_configured()
    }

    /// The link's settings and members, as its task takes them in: the receiver sees the
    /// current state as new, and each change after it.
    pub(crate) fn subscribe(&self) -> watch::Receiver<LinkState> {
        let mut receiver = self.state.subscribe();
        receiver.mark_changed();
        receiver
    }

    /// Gives the link other settings (a reload changed them): its task closes the port or
    /// socket and opens it again with them, its devices staying members.
    pub(crate) fn reconfigure(&self, config: LinkConfig) {
        self.state.send_modify(|s| s.config = config);
    }

    /// Gives an unconfigured link its transport; its task opens it at once.
    pub(crate) fn configure(&self, transport: Transport, guard_time: Duration) {
        self.state.send_modify(|s| {
            s.config.transport = transport;
            s.config.guard_time = guard_time;
        });
    }

    pub(crate) fn diagnostics(&self) -> LinkDiagnostics {
        self.diagnostics.borrow().clone()
    }

    pub(crate) fn set_diagnostics(&self, diagnostics: LinkDiagnostics) {
        self.diagnostics.send_if_modified(|d| {
            let changed = *d != diagnostics;
            *d = diagnostics;
            changed
        });
    }

    /// The devices on the link, in the order they were added.
    pub(crate) fn members(&self) -> Vec<Arc<Device>> {
        self.state.borrow().members.clone()
    }

    /// Queues a request for the link's task; the answer comes on its `reply`: at once
    /// [`PassthroughError::Busy`] when the inbox is full.
    pub fn submit(&self, request: Passthrough) {
        self.enqueue(Inbox::Request(request));
    }

    /// Queues a scan's probe, as [`Link::submit`] a request.
    pub fn submit_probe(&self, probe: Probe) {
        self.enqueue(Inbox::Probe(probe));
    }

    fn enqueue(&self, request: Inbox) {
        let mut queue = super::lock(&self.queue);
        if queue.len() >= INBOX_CAPACITY {
            drop(queue);
            request.refuse(PassthroughError::Busy);
            return;
        }
        queue.push_back(Queued {
            request,
            since: tokio::time::Instant::now(),
        });
        drop(queue);
        self.wake.notify_one();
    }

    /// The oldest queued request, for the link's task.
    pub(crate) fn take_queued(&self) -> Option<Inbox> {
        super::lock(&self.queue).pop_front().map(|q| q.request)
    }

    /// How many requests wait, and how long the oldest has.
    pub(crate) fn inbox(&self) -> (usize, Duration) {
        let queue = super::lock(&self.queue);
        let oldest = queue.front().map_or(Duration::ZERO, |q| q.since.elapsed());
        (queue.len(), oldest)
    }

    /// Takes a removed device off the link; its task stops polling it.
    pub(crate) fn remove_member(&self, device: &Arc<Device>) {
        self.state
            .send_modify(|s| s.members.retain(|m| !Arc::ptr_eq(m, device)));
    }

    /// Puts `next` in `old`'s place among the members (one change for the link's task).
    pub(crate) fn replace_member(&self, old: &Arc<Device>, next: Arc<Device>) {
        next.set_line(self.progress.clone());
        self.state.send_modify(
            |s| match s.members.iter_mut().find(|m| Arc::ptr_eq(m, old)) {
                Some(slot) => *slot = next,
                None => s.members.push(next),
            },
        );
    }

    /// Puts a device on the link, once.
    pub(crate) fn add_member(&self, device: Arc<Device>) {
        device.set_line(self.progress.clone());
        self.state.send_if_modified(|s| {
            let new = !s.members.iter().any(|m| Arc::ptr_eq(m, &device));
            if new {
                s.members.push(device);
            }
            new
        });
    }
}

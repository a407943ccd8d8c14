//! The task that owns a link: it opens (and reopens) the port, then polls the link's devices,
//! each at its `refresh_rate`, the most overdue first; pending writes go before reads. A
//! device that stops answering is backed off: until it answers again it costs the link one
//! probe transaction (one timeout) per backoff period, and the other devices keep their rates.

use std::collections::VecDeque;
use std::sync::Arc;
use std::time::Duration;

use tokio::time::{Instant, sleep_until};
use tokio_util::sync::CancellationToken;

use crate::cache::{Device, Link, LinkDiagnostics};
use crate::config::Transport;
use crate::link::frame::{Exception, Request, Response};
use crate::link::timing::LineTiming;
use crate::link::{self, Connection, Counters, LINK_LOST, LINK_OK, TxError};
use crate::metrics::Metrics;
use crate::plan::{self, ReadBatch, WriteItem, WriteOp};

/// Waits between attempts to open a link: doubling from the first to the last.
pub const REOPEN_MIN: Duration = Duration::from_millis(250);
pub const REOPEN_MAX: Duration = Duration::from_secs(8);
/// How long a device that stopped answering is left alone: doubling up to the maximum.
pub const BACKOFF_MIN: Duration = Duration::from_secs(1);
pub const BACKOFF_MAX: Duration = Duration::from_secs(16);
/// Connecting to a TCP endpoint gives up after this long.
pub const CONNECT_TIMEOUT: Duration = Duration::from_secs(3);
const UTILISATION_WINDOW: Duration = Duration::from_secs(1);

struct Polled {
    device: Arc<Device>,
    slave: u8,
    reads: Vec<ReadBatch>,
    next_due: Instant,
    /// Set while the device does not answer: when to probe it next, and the period.
    backoff: Option<(Instant, Duration)>,
    /// Write the latest requested outputs again (after a reconnect).
    rewrite: bool,
    /// The device refused FC15/FC16 (exception 01): write items one at a time.
    single_writes: bool,
}

impl Polled {
    fn due(&self) -> Instant {
        self.backoff.map_or(self.next_due, |(until, _)| until)
    }
}

/// The connection and what is measured on it.
struct Bus {
    conn: Connection,
    metrics: Arc<Metrics>,
    link: String,
    busy: Duration,
    window_start: Instant,
    counted: Counters,
    planned: Option<f64>,
}

impl Bus {
    /// One transaction, tried `1 + retries` times when the device does not answer properly.
    async fn transact(
        &mut self,
        device: &Device,
        request: &Request,
        retries: u32,
    ) -> (Result<Response, TxError>, Duration) {
        let slave = device.config.slave_id.unwrap_or(0);
        let mut attempt = 0;
        loop {
            let started = Instant::now();
            let result = self
                .conn
                .transact(slave, request, device.config.timeout)
                .await;
            let elapsed = started.elapsed();
            self.busy += elapsed;
            self.metrics
                .transaction(device.name(), request.function(), &result, elapsed);
            self.account();
            match &result {
                Err(TxError::Timeout | TxError::Crc | TxError::Invalid(_)) if attempt < retries => {
                    tracing::debug!(device = %device.name(), function = %request.function(), attempt, error = %result.as_ref().err().map(ToString::to_string).unwrap_or_default(), "retrying");
                    attempt += 1;
                }
                _ => return (result, elapsed),
            }
        }
    }

    /// Moves byte counts and the measured utilisation into the metrics.
    fn account(&mut self) {
        let now = self.conn.counters();
        self.metrics.link_bytes(
            &self.link,
            now.bytes_sent - self.counted.bytes_sent,
            now.bytes_received - self.counted.bytes_received,
            now.bytes_discarded - self.counted.bytes_discarded,
        );
        self.counted = now;
        let window = self.window_start.elapsed();
        if window >= UTILISATION_WINDOW {
            let measured = self.busy.as_secs_f64() / window.as_secs_f64();
            self.metrics
                .link_utilisation(&self.link, self.planned, measured.min(1.0));
            self.busy = Duration::ZERO;
            self.window_start = Instant::now();
        }
    }
}

enum Ended {
    Shutdown,
    Lost(String),
}

pub struct LinkTask {
    link: Arc<Link>,
    devices: Vec<Polled>,
    /// The link's member version `devices` reflects.
    version: u64,
    metrics: Arc<Metrics>,
    /// The bus utilisation the refresh rates demand (serial links).
    planned: Option<f64>,
    /// Round-robin position for writes.
    cursor: usize,
}

impl LinkTask {
    pub fn new(link: Arc<Link>, metrics: Arc<Metrics>) -> Self {
        let mut task = LinkTask {
            link,
            devices: Vec::new(),
            version: u64::MAX,
            metrics,
            planned: None,
            cursor: 0,
        };
        task.sync_members();
        task
    }

    /// Takes in devices added to the link since the last look.
    fn sync_members(&mut self) {
        let version = self.link.version();
        if version == self.version {
            return;
        }
        self.version = version;
        let now = Instant::now();
        for device in self.link.members().into_iter().skip(self.devices.len()) {
            tracing::debug!(link = %self.link.name(), device = %device.name(), "polling device");
            self.devices.push(Polled {
                slave: device.config.slave_id.unwrap_or(0),
                reads: plan::read_batches(
                    &device.profile,
                    device.config.max_batch,
                    device.config.max_gap,
                ),
                device,
                next_due: now,
                backoff: None,
                rewrite: true,
                single_writes: false,
            });
        }
        self.planned = match &self.link.config.transport {
            Transport::Serial(s) => Some(plan::utilisation(
                self.devices
                    .iter()
                    .map(|p| (&p.device.config, p.reads.as_slice())),
                &LineTiming::new(s),
                self.link.config.guard_time,
            )),
            Transport::Tcp { .. } => None,
        };
        if let Some(u) = self.planned {
            self.metrics
                .link_utilisation(self.link.name(), self.planned, 0.0);
            if u > 1.0 {
                tracing::warn!(link = %self.link.name(), utilisation = format!("{:.0}%", u * 100.0), "the refresh rates need more than the line can carry");
            }
        }
    }

    pub async fn run(mut self, token: CancellationToken) {
        let name = self.link.config.name.clone();
        let mut reopen = REOPEN_MIN;
        let mut lost = false;
        let mut last_error = String::new();
        'reopen: loop {
            self.sync_members();
            let opened = tokio::select! {
                _ = token.cancelled() => break,
                r = tokio::time::timeout(CONNECT_TIMEOUT, link::open(&self.link.config, self.link.config.guard_time)) => r,
            };
            let opened = opened.unwrap_or_else(|_| {
                Err(link::OpenError {
                    code: link::LINK_OPEN_FAILED,
                    message: format!("no connection within {CONNECT_TIMEOUT:?}"),
                })
            });
            match opened {
                Err(e) => {
                    let code = if lost { LINK_LOST } else { e.code };
                    self.link.set_diagnostics(LinkDiagnostics {
                        connected: false,
                        error_code: code,
                    });
                    if e.message != last_error {
                        tracing::warn!(link = %name, error = %e.message, retry_in = ?reopen, "cannot open the link");
                        last_error = e.message.clone();
                    }
                    self.all_unreachable(&e.message);
                }
                Ok(conn) => {
                    if lost {
                        self.metrics.link_reconnected(&name);
                    }
                    tracing::info!(link = %name, "link open");
                    last_error.clear();
                    self.link.set_diagnostics(LinkDiagnostics {
                        connected: true,
                        error_code: LINK_OK,
                    });
                    reopen = REOPEN_MIN;
                    let now = Instant::now();
                    for p in &mut self.devices {
                        p.rewrite = true;
                        p.next_due = now;
                        p.backoff = None;
                    }
                    let bus = Bus {
                        counted: conn.counters(),
                        conn,
                        metrics: self.metrics.clone(),
                        link: name.clone(),
                        busy: Duration::ZERO,
                        window_start: Instant::now(),
                        planned: self.planned,
                    };
                    match self.serve(bus, &token).await {
                        Ended::Shutdown => break,
                        Ended::Lost(error) => {
                            tracing::warn!(link = %name, error = %error, "link lost, reopening");
                            lost = true;
                            self.link.set_diagnostics(LinkDiagnostics {
                                connected: false,
                                error_code: LINK_LOST,
                            });
                            last_error = format!("link lost: {error}");
                            self.all_unreachable(&last_error);
                        }
                    }
                }
            }
            // While the link is down, writes (and devices declared meanwhile) are answered at
            // once rather than at the next attempt to open it.
            let retry_at = Instant::now() + reopen;
            loop {
                tokio::select! {
                    _ = token.cancelled() => break 'reopen,
                    _ = sleep_until(retry_at) => break,
                    _ = self.link.wake.notified() => {
                        self.sync_members();
                        self.all_unreachable(&last_error);
                    }
                }
            }
            reopen = (reopen * 2).min(REOPEN_MAX);
        }
        self.link.set_diagnostics(LinkDiagnostics {
            connected: false,
            error_code: self.link.diagnostics().error_code,
        });
        tracing::debug!(link = %name, "link task stopped");
    }

    fn all_unreachable(&self, reason: &str) {
        for p in &self.devices {
            p.device.set_unreachable();
            p.device.fail_reads(reason);
            for w in p.device.take_writes() {
                p.device.finish_write(
                    w.generation,
                    Err(format!(
                        "{reason}; the latest value is written when the link is back"
                    )),
                );
            }
        }
    }

    async fn serve(&mut self, mut bus: Bus, token: &CancellationToken) -> Ended {
        loop {
            if token.is_cancelled() {
                return Ended::Shutdown;
            }
            self.sync_members();
            bus.planned = self.planned;
            let step = if let Some(i) = self.next_writer() {
                self.write_device(i, &mut bus).await
            } else if let Some(i) = self.next_due(Instant::now()) {
                self.poll_device(i, &mut bus).await
            } else {
                let until = self
                    .devices
                    .iter()
                    .map(Polled::due)
                    .min()
                    .unwrap_or_else(|| Instant::now() + Duration::from_secs(3600));
                tokio::select! {
                    _ = token.cancelled() => return Ended::Shutdown,
                    _ = sleep_until(until) => {}
                    _ = self.link.wake.notified() => {}
                }
                Ok(())
            };
            if let Err(error) = step {
                return Ended::Lost(error);
            }
        }
    }

    /// The next device, in round-robin order, with writes to put on the bus.
    fn next_writer(&mut self) -> Option<usize> {
        let n = self.devices.len();
        let found = (0..n).map(|k| (self.cursor + k) % n).find(|&i| {
            let p = &self.devices[i];
            p.device.has_pending_writes()
                || (p.rewrite && p.backoff.is_none() && p.device.has_requested_values())
        })?;
        self.cursor = (found + 1) % n;
        Some(found)
    }

    /// The most overdue device, if any is due.
    fn next_due(&self, now: Instant) -> Option<usize> {
        self.devices
            .iter()
            .enumerate()
            .filter(|(_, p)| p.due() <= now)
            .min_by_key(|(_, p)| p.due())
            .map(|(i, _)| i)
    }

    async fn poll_device(&mut self, i: usize, bus: &mut Bus) -> Result<(), String> {
        let p = &mut self.devices[i];
        let device = p.device.clone();
        let started = Instant::now();
        if p.backoff.is_some() {
            // A probe: one transaction, no retries.
            let Some(first) = p.reads.first() else {
                p.backoff = None;
                return Ok(());
            };
            let (result, _) = bus.transact(&device, &first.request(), 0).await;
            match result {
                Ok(_) | Err(TxError::Exception(_)) => {
                    tracing::info!(device = %device.name(), slave = p.slave, "device answers again");
                    p.backoff = None;
                    p.rewrite = true;
                }
                Err(TxError::Io(e)) => return Err(e.to_string()),
                Err(e) => {
                    let period = p
                        .backoff
                        .map_or(BACKOFF_MIN, |(_, d)| (d * 2).min(BACKOFF_MAX));
                    p.backoff = Some((Instant::now() + period, period));
                    device.fail_reads(&format!("no response: {e}"));
                    return Ok(());
                }
            }
        }
        let mut k = 0;
        let mut last_response = Duration::ZERO;
        while k < p.reads.len() {
            let batch = p.reads[k].clone();
            let (result, elapsed) = bus
                .transact(&device, &batch.request(), device.config.retries)
                .await;
            match result {
                Ok(response) => {
                    last_response = elapsed;
                    for (field, value) in batch.decode(&device.profile, &response) {
                        device.publish(field, value);
                    }
                    k += 1;
                }
                Err(TxError::Exception(x))
                    if (x == Exception::ILLEGAL_DATA_ADDRESS
                        || x == Exception::ILLEGAL_DATA_VALUE)
                        && batch.fields.len() > 1 =>
                {
                    if let Some((a, b)) = batch.split(&device.profile) {
                        tracing::info!(device = %device.name(), address = batch.address, count = batch.count, exception = %x, "device refused a batch; splitting it");
                        p.reads.splice(k..=k, [a, b]);
                    }
                }
                Err(TxError::Exception(x)) => {
                    last_response = elapsed;
                    for &field in &batch.fields {
                        device.publish(field, Err(x.to_string()));
                    }
                    k += 1;
                }
                Err(TxError::Io(e)) => return Err(e.to_string()),
                Err(e) => {
                    if device.diagnostics().connected || p.backoff.is_none() {
                        tracing::warn!(device = %device.name(), slave = p.slave, error = %e, backoff = ?BACKOFF_MIN, "device does not answer");
                    }
                    device.record_cycle(false, started.elapsed());
                    device.fail_reads(&format!("no response: {e}"));
                    p.backoff = Some((Instant::now() + BACKOFF_MIN, BACKOFF_MIN));
                    p.rewrite = true;
                    return Ok(());
                }
            }
        }
        device.record_cycle(true, last_response);
        p.next_due = (started + device.config.refresh_rate).max(Instant::now());
        Ok(())
    }

    async fn write_device(&mut self, i: usize, bus: &mut Bus) -> Result<(), String> {
        let p = &mut self.devices[i];
        let device = p.device.clone();
        let taken = device.take_writes();
        if p.backoff.is_some() {
            for w in taken {
                device.finish_write(
                    w.generation,
                    Err("the device does not answer; the latest value is written when it answers again".into()),
                );
            }
            return Ok(());
        }
        let mut items: Vec<WriteItem> = taken
            .into_iter()
            .map(|w| WriteItem {
                field: w.field,
                value: w.value,
                generation: Some(w.generation),
            })
            .collect();
        if p.rewrite {
            for (field, value) in device.latest_requested() {
                if !items.iter().any(|it| it.field == field) {
                    items.push(WriteItem {
                        field,
                        value,
                        generation: None,
                    });
                }
            }
            p.rewrite = false;
        }
        let finish = |item: &WriteItem, result: Result<(), String>| {
            if let Some(g) = item.generation {
                device.finish_write(g, result);
            }
        };
        let (ops, refused) = plan::write_ops(&device.profile, &items, p.single_writes);
        for (n, reason) in refused {
            finish(&items[n], Err(reason));
        }
        let mut ops: VecDeque<WriteOp> = ops.into();
        while let Some(op) = ops.pop_front() {
            let result = match &op {
                WriteOp::Direct { request, .. } => bus
                    .transact(&device, request, device.config.retries)
                    .await
                    .0
                    .map(drop),
                WriteOp::Bits { address, bits, .. } => {
                    write_bits(bus, &device, *address, bits).await
                }
            };
            match result {
                Ok(()) => {
                    for &n in op.items() {
                        finish(&items[n], Ok(()));
                        device.publish(items[n].field, Ok(items[n].value.clone()));
                    }
                }
                Err(TxError::Exception(Exception::ILLEGAL_FUNCTION))
                    if op.is_multiple() && op.items().len() > 1 =>
                {
                    // The device has no FC15/FC16: write these (and later ones) one by one.
                    tracing::info!(device = %device.name(), slave = p.slave, "device refused FC15/FC16; writing items one at a time");
                    p.single_writes = true;
                    let subset = op.items().to_vec();
                    let sub: Vec<WriteItem> = subset.iter().map(|&n| items[n].clone()).collect();
                    let (singles, _) = plan::write_ops(&device.profile, &sub, true);
                    for single in singles.into_iter().rev() {
                        ops.push_front(single.remap(&subset));
                    }
                }
                Err(e) => {
                    let reason = e.to_string();
                    for &n in op.items() {
                        finish(&items[n], Err(reason.clone()));
                    }
                    if matches!(e, TxError::Exception(_)) {
                        continue;
                    }
                    // The device or the link is gone: the rest cannot be written now.
                    for rest in ops.drain(..) {
                        for &n in rest.items() {
                            finish(&items[n], Err(format!("not sent: {reason}")));
                        }
                    }
                    p.rewrite = true;
                    if let TxError::Io(io) = e {
                        return Err(io.to_string());
                    }
                    tracing::warn!(device = %device.name(), slave = p.slave, error = %reason, "write got no answer; backing off");
                    device.record_cycle(false, Duration::ZERO);
                    device.fail_reads(&format!("no response: {reason}"));
                    p.backoff = Some((Instant::now() + BACKOFF_MIN, BACKOFF_MIN));
                }
            }
        }
        Ok(())
    }
}

/// Sets bits of a holding register, keeping the others: FC03 read, then FC06 write.
async fn write_bits(
    bus: &mut Bus,
    device: &Device,
    address: u16,
    bits: &[(u8, bool)],
) -> Result<(), TxError> {
    let read = Request::ReadHoldingRegisters { address, count: 1 };
    let current = match bus.transact(device, &read, device.config.retries).await.0? {
        Response::Registers(regs) if regs.len() == 1 => regs[0],
        other => {
            return Err(TxError::Invalid(format!(
                "unexpected answer to a register read: {other:?}"
            )));
        }
    };
    let value = bits.iter().fold(current, |acc, &(bit, on)| {
        if on {
            acc | 1 << bit
        } else {
            acc & !(1 << bit)
        }
    });
    let write = Request::WriteSingleRegister { address, value };
    bus.transact(device, &write, device.config.retries)
        .await
        .0
        .map(drop)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cache::Cache;
    use crate::codec::Value;
    use crate::config::{Parity, SerialSettings};
    use crate::link::frame::crc16;
    use crate::link::rtu::RtuTransport;
    use crate::profile::Catalog;
    use crate::writes::{Lookup, WriteStatus};
    use std::sync::atomic::{AtomicU32, Ordering};
    use tokio::io::{AsyncReadExt, AsyncWriteExt, DuplexStream};

    /// Slave 1 answers register reads with its request count; slave 2 never answers.
    async fn devices(mut io: DuplexStream, asked: Arc<[AtomicU32; 3]>) {
        let mut request = [0u8; 8];
        while io.read_exact(&mut request).await.is_ok() {
            let slave = usize::from(request[0]).min(2);
            let n = asked[slave].fetch_add(1, Ordering::Relaxed) + 1;
            if slave == 1 {
                let mut answer = vec![1, request[1], 2];
                answer.extend_from_slice(&(n as u16).to_be_bytes());
                answer.extend_from_slice(&crc16(&answer).to_le_bytes());
                if io.write_all(&answer).await.is_err() {
                    return;
                }
            }
        }
    }

    #[tokio::test(start_paused = true)]
    async fn a_write_while_the_link_is_down_fails_at_once() {
        let config = crate::config::parse(
            "c.yaml",
            "links:\n  - { name: bus, serial: { port: /nonexistent/ttyIOGATE9, baud: 9600 } }\ndevices:\n  - { name: out, profile: Out, link: bus, slave_id: 1 }\n",
        )
        .expect("config");
        let profile = crate::profile::load_str(
            "out.yaml",
            "name: Out\nfields:\n  - { name: Q, type: BOOL, direction: output, register: { address: 0, kind: coil } }\n",
        )
        .expect("profile");
        let cache = Cache::new(&config, Catalog::new([profile]));
        let task = LinkTask::new(cache.links()[0].clone(), Arc::new(Metrics::new()));
        let token = CancellationToken::new();
        let running = tokio::spawn(task.run(token.clone()));
        // Long enough for the reopen wait to have grown to its 8 s maximum.
        tokio::time::sleep(Duration::from_secs(30)).await;
        let device = cache.device("out").expect("device");
        let generation = device
            .request_write(0, Value::Bool(true))
            .expect("accepted");
        tokio::time::sleep(Duration::from_millis(10)).await;
        let Lookup::Found(record) = cache.writes.get(generation) else {
            panic!("write not logged")
        };
        assert_eq!(record.status, WriteStatus::Failed);
        assert!(
            record
                .error
                .as_deref()
                .is_some_and(|e| e.contains("cannot open")),
            "{record:?}"
        );
        token.cancel();
        running.await.expect("task ends");
    }

    #[tokio::test(start_paused = true)]
    async fn a_dead_device_costs_one_probe_per_backoff_period_and_the_other_keeps_its_rate() {
        let config = crate::config::parse(
            "c.yaml",
            "links:\n  - { name: bus, serial: { port: /dev/null, baud: 19200 } }\ndevices:\n  - { name: alive, profile: One, link: bus, slave_id: 1, refresh_rate: 100ms, timeout: 100ms, retries: 1 }\n  - { name: dead, profile: One, link: bus, slave_id: 2, refresh_rate: 100ms, timeout: 100ms, retries: 1 }\n",
        )
        .expect("config");
        let profile = crate::profile::load_str(
            "one.yaml",
            "name: One\nfields:\n  - { name: N, type: UINT, direction: input, register: { address: 0, kind: input_register } }\n",
        )
        .expect("profile");
        let cache = Cache::new(&config, Catalog::new([profile]));
        let metrics = Arc::new(Metrics::new());
        let link = cache.links()[0].clone();
        let mut task = LinkTask::new(link, metrics.clone());

        let (gateway, device_end) = tokio::io::duplex(4096);
        let asked: Arc<[AtomicU32; 3]> = Arc::new(Default::default());
        tokio::spawn(devices(device_end, asked.clone()));
        let timing = LineTiming::new(&SerialSettings {
            port: String::new(),
            baud: 19_200,
            parity: Parity::None,
            data_bits: 8,
            stop_bits: 1,
        });
        let conn = Connection::Rtu(RtuTransport::new(
            Box::new(gateway),
            Some(timing),
            Duration::ZERO,
        ));
        let bus = Bus {
            counted: conn.counters(),
            conn,
            metrics,
            link: "bus".into(),
            busy: Duration::ZERO,
            window_start: Instant::now(),
            planned: None,
        };
        let token = CancellationToken::new();
        let stop = token.clone();
        let serving = tokio::spawn(async move { task.serve(bus, &stop).await });
        tokio::time::sleep(Duration::from_secs(10)).await;
        token.cancel();
        assert!(matches!(serving.await, Ok(Ended::Shutdown)));

        // The dead device: one cycle of two attempts, then probes 1, 2 and 4 s apart.
        let dead = asked[2].load(Ordering::Relaxed);
        println!("dead device: {dead} requests in 10 s");
        assert!(
            (5..=7).contains(&dead),
            "{dead} requests to the dead device"
        );
        let dead_device = cache.device("dead").expect("dead");
        assert_eq!(dead_device.diagnostics().error_code, 10);
        assert!(!dead_device.diagnostics().connected);
        // Each costs about 150 ms (timeout and late-reply window): under a second in all,
        // so the live device keeps close to its 100 ms rate: at least 88 of 100 cycles.
        let alive = cache.device("alive").expect("alive").diagnostics();
        assert!(alive.connected);
        println!("live device: {} cycles in 10 s", alive.io_cycles);
        assert!(alive.io_cycles >= 88, "{} cycles in 10 s", alive.io_cycles);
    }
}

//! The Modbus TCP server front-end: MBAP framing on TCP connections from masters (SCADA,
//! HMIs, PLCs), each request answered by the service. Requests on one connection are
//! answered in order (pipelined requests too); a malformed MBAP header (protocol id not 0,
//! length out of bounds) or a function code no request has (0, 128-255) closes that
//! connection and nothing else. At most
//! `max_connections` are open: a new master then closes the connection that has waited
//! longest on its master (for a request, or for it to take an answer), those that never
//! sent a request first; only when every connection is being answered is the new one
//! closed. A connection is closed after `idle_timeout` without a request, and when its
//! master does not take an answer within the write timeout.

pub(crate) mod front_end;
mod slots;

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Duration;

use prometheus_client::metrics::counter::Counter;
use tokio::io::{AsyncReadExt, AsyncWriteExt, BufReader};
use tokio::net::{TcpListener, TcpStream};
use tokio_util::sync::CancellationToken;

use crate::link::frame::{Exception, Request};
use crate::link::mbap;
use crate::service::Service;
use slots::{Slot, Slots, Taken};

/// The longest an answer may wait for its master to take it (the idle timeout when that
/// is shorter): a master that stops reading loses its connection, not the gateway's memory.
pub(crate) const MAX_WRITE_WAIT: Duration = Duration::from_secs(10);

/// Accepts masters until `shutdown`; each connection runs as a task of the gateway.
pub(crate) async fn serve_modbus(
    listener: TcpListener,
    service: Arc<Service>,
    shutdown: CancellationToken,
) {
    let Some(image) = service.modbus() else {
        return;
    };
    let (max, per_client) = (
        image.config.max_connections,
        image.config.max_connections_per_client,
    );
    let per_client = per_client.min(max);
    let slots = Arc::new(Slots::new(max, per_client));
    let bound = (service.metrics).bound("modbus_connections", max);
    let client_bound = (service.metrics).bound("modbus_connections_per_client", per_client);
    let idle = image.config.idle_timeout;
    loop {
        let accepted = tokio::select! {
            _ = shutdown.cancelled() => break,
            a = listener.accept() => a,
        };
        let (stream, peer) = match accepted {
            Ok(a) => a,
            Err(e) => {
                // Out of file descriptors and the like: wait a little, keep serving.
                tracing::warn!(error = %e, "cannot accept a Modbus connection");
                tokio::time::sleep(Duration::from_millis(50)).await;
                continue;
            }
        };
        let slot = match slots.take(peer) {
            Taken::Free(slot) => slot,
            Taken::Evicted { slot, evicted, own } => {
                let (why, counted) = match own {
                    true => ("max_connections_per_client", &client_bound),
                    false => ("max_connections", &bound),
                };
                tracing::info!(%peer, closed = %evicted, "Modbus connection closed to make room for a new master ({why} reached)");
                service.metrics.server_evicted();
                counted.refused();
                slot
            }
            Taken::ClientFull => {
                tracing::info!(%peer, "Modbus connection refused: max_connections_per_client reached from this address, every one being answered");
                service.metrics.server_refused();
                client_bound.refused();
                drop(stream);
                continue;
            }
            Taken::Full => {
                tracing::info!(%peer, "Modbus connection refused: max_connections reached, every connection being answered");
                service.metrics.server_refused();
                bound.refused();
                drop(stream);
                continue;
            }
        };
        let _ = stream.set_nodelay(true);
        client_bound.set_used(slots.most_of_one_client());
        let (service, token, slots) = (service.clone(), shutdown.clone(), slots.clone());
        let client_bound = client_bound.clone();
        let held = bound.hold();
        service.clone().tasks().spawn(async move {
            let _held = held;
            service.metrics.server_connection(true);
            if let Err(reason) = connection(stream, &service, idle, &token, &slot).await {
                tracing::debug!(%peer, %reason, "Modbus connection closed");
            }
            service.metrics.server_connection(false);
            slots.release(&slot);
            client_bound.set_used(slots.most_of_one_client());
        });
    }
}

/// Why the gateway closed a master's connection.
#[derive(Debug, thiserror::Error)]
enum Closed {
    #[error("idle timeout")]
    Idle,
    #[error("idle timeout in the middle of a frame")]
    IdleMidFrame,
    #[error("the master did not take its answer within {0:?}")]
    WriteTimeout(Duration),
    #[error("closed for a new master")]
    Evicted,
    #[error("function code {0:#04x} is no request's (1-127; 128-255 are exception answers)")]
    NotARequest(u8),
    #[error(transparent)]
    Io(std::io::Error),
    #[error("malformed {0}")]
    Malformed(#[from] mbap::Malformed),
}

/// Serves one master until it leaves, stays idle too long, does not take its answers,
/// sends a malformed header, is closed for a new master, or the gateway shuts down.
async fn connection(
    stream: TcpStream,
    service: &Service,
    idle: Duration,
    token: &CancellationToken,
    slot: &Slot,
) -> Result<(), Closed> {
    // Buffered: one read usually brings a whole request (or several pipelined ones).
    let mut stream = BufReader::new(stream);
    let mut counters = Counters::default();
    let mut header = [0u8; mbap::HEADER_LEN];
    let mut pdu = Vec::with_capacity(256);
    let mut frame = Vec::with_capacity(mbap::HEADER_LEN + 256);
    let write_wait = idle.min(MAX_WRITE_WAIT);
    // Made once for the connection, not once a request: waiting on a token registers with
    // its tree, shared by every connection, and a timer with the runtime's wheel. The idle
    // timer is moved on only when it fires early (`last` is when the master last sent).
    let stopped = token.cancelled();
    let evicted = slot.evict.cancelled();
    let idle_timer = tokio::time::sleep(idle);
    tokio::pin!(stopped, evicted, idle_timer);
    let mut last = tokio::time::Instant::now();
    // Fills `$buf` from the master; returns from the connection when it is stopped,
    // evicted, or idle (`$idle`: the error then) since `last`.
    macro_rules! read_whole {
        ($buf:expr, $idle:expr) => {
            loop {
                let read = tokio::select! {
                    biased;
                    r = stream.read_exact($buf) => Some(r),
                    _ = &mut stopped => return Ok(()),
                    _ = &mut evicted => return Err(Closed::Evicted),
                    _ = &mut idle_timer => None,
                };
                match read {
                    Some(r) => break r,
                    None if last.elapsed() >= idle => return Err($idle),
                    None => idle_timer.as_mut().reset(last + idle),
                }
            }
        };
    }
    loop {
        match read_whole!(&mut header, Closed::Idle) {
            Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => return Ok(()),
            Err(e) => return Err(Closed::Io(e)),
            Ok(_) => {}
        }
        last = tokio::time::Instant::now();
        let header = mbap::Header::parse(&header)?;
        let unit = header.unit;
        pdu.clear();
        pdu.resize(header.pdu_len, 0);
        if let Err(e) = read_whole!(&mut pdu, Closed::IdleMidFrame) {
            return Err(Closed::Io(e));
        }
        // 0 and 128-255 are no function code a master may send: answering 0x80 | code
        // would read as an exception to another function, so the stream is out of step.
        match pdu.first() {
            Some(&code) if code == 0 || code >= 0x80 => return Err(Closed::NotARequest(code)),
            _ => {}
        }
        slot.on_master.store(false, Ordering::Release);
        slot.served.store(true, Ordering::Relaxed);
        mbap::start_frame(&mut frame);
        answer_into(service, Some(unit), &pdu, &mut counters, &mut frame).await;
        mbap::finish_frame(&mut frame, header.transaction, unit);
        send(&mut stream, &frame, slot, write_wait, evicted.as_mut()).await?;
        // Waiting for the next request from now (so an active master is not taken for an
        // idle one, and its idle time runs from its answer).
        slot.wait_on_master();
        last = tokio::time::Instant::now();
    }
}

/// Writes an answer: usually the socket takes it whole at once; otherwise the connection
/// waits on its master to take the rest, at most `write_wait`, unless it is evicted.
async fn send(
    stream: &mut BufReader<TcpStream>,
    frame: &[u8],
    slot: &Slot,
    write_wait: Duration,
    evicted: std::pin::Pin<&mut tokio_util::sync::WaitForCancellationFuture<'_>>,
) -> Result<(), Closed> {
    let sent = match stream.get_ref().try_write(frame) {
        Ok(n) => n,
        Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => 0,
        Err(e) => return Err(Closed::Io(e)),
    };
    if sent == frame.len() {
        return Ok(());
    }
    slot.wait_on_master();
    let written = tokio::select! {
        biased;
        w = tokio::time::timeout(write_wait, stream.write_all(&frame[sent..])) => w,
        _ = evicted => return Err(Closed::Evicted),
    };
    match written {
        Ok(Ok(())) => Ok(()),
        Ok(Err(e)) => Err(Closed::Io(e)),
        Err(_) => Err(Closed::WriteTimeout(write_wait)),
    }
}

/// A connection's (or serial port's) handles on the request counters, so that counting a
/// request costs no label lookup: a few entries, looked up in order (cheaper than hashing
/// for the handful of functions a master uses).
#[derive(Default)]
pub(crate) struct Counters(Vec<CounterEntry>);

type CounterEntry = ((u8, Option<u8>), (Counter, Option<Counter>));

impl Counters {
    fn count(&mut self, service: &Service, code: u8, exception: Option<u8>) {
        let key = (code, exception);
        let at = match self.0.iter().position(|(k, _)| *k == key) {
            Some(at) => at,
            None => {
                self.0.push((key, Self::handles(service, code, exception)));
                self.0.len() - 1
            }
        };
        let (requests, exceptions) = &self.0[at].1;
        requests.inc();
        if let Some(e) = exceptions {
            e.inc();
        }
    }

    /// The counters of requests with `code` and `exception`.
    fn handles(service: &Service, code: u8, exception: Option<u8>) -> (Counter, Option<Counter>) {
        let outcome = if exception.is_some() {
            "exception"
        } else {
            "ok"
        };
        (
            service
                .metrics
                .server_requests(&format!("fc{code:02}"), outcome),
            exception.map(|x| service.metrics.server_exceptions(x)),
        )
    }
}

/// The response PDU to a request PDU for `unit`, routed as the TCP server routes unit ids;
/// for `None` (a serial port's own unit id) from the server's own map. The one place a
/// request is answered, whatever its framing.
pub(crate) async fn answer(
    service: &Service,
    unit: Option<u8>,
    pdu: &[u8],
    counters: &mut Counters,
) -> Vec<u8> {
    let mut out = Vec::new();
    answer_into(service, unit, pdu, counters, &mut out).await;
    out
}

/// [`answer`], appending the response PDU to `out` (a frame being built).
pub(crate) async fn answer_into(
    service: &Service,
    unit: Option<u8>,
    pdu: &[u8],
    counters: &mut Counters,
    out: &mut Vec<u8>,
) {
    let code = pdu.first().copied().unwrap_or(0);
    let result = match (Request::parse(pdu), unit) {
        // The standby of a pair serves nothing of the field: 0B, as a gateway whose target
        // does not answer (a master with two gateways asks the other).
        (Ok(_), _) if !service.tasks().role().owns_field() => Err(Exception::GATEWAY_TARGET_FAILED),
        (Ok(request), Some(unit)) => service
            .modbus_request(unit, &request)
            .await
            .map(|r| r.write_pdu(&request, out)),
        (Ok(request), None) => service
            .modbus_request_local(&request)
            .map(|r| r.write_pdu(&request, out)),
        (Err(x), _) => Err(x),
    };
    match result {
        Ok(()) => counters.count(service, code, None),
        Err(x @ Exception(code_x)) => {
            counters.count(service, code, Some(code_x));
            out.extend_from_slice(&x.to_pdu(code));
        }
    }
}

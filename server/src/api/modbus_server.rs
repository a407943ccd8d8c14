//! The Modbus TCP server front-end: MBAP framing on TCP connections from masters (SCADA,
//! HMIs, PLCs), each request answered by the service. Requests on one connection are
//! answered in order (pipelined requests too); a malformed MBAP header (protocol id not 0,
//! length out of bounds) closes that connection and nothing else; extra connections beyond
//! `max_connections` are closed at once; an idle connection is closed after `idle_timeout`.

use std::sync::Arc;
use std::time::Duration;

use std::collections::HashMap;

use prometheus_client::metrics::counter::Counter;
use tokio::io::{AsyncReadExt, AsyncWriteExt, BufReader};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::Semaphore;
use tokio_util::sync::CancellationToken;

use crate::link::frame::{Exception, Request};
use crate::link::mbap;
use crate::service::Service;

/// Accepts masters until `shutdown`; each connection runs as a task of the gateway.
pub(crate) async fn serve_modbus(
    listener: TcpListener,
    service: Arc<Service>,
    shutdown: CancellationToken,
) {
    let Some(image) = service.modbus() else {
        return;
    };
    let slots = Arc::new(Semaphore::new(image.config.max_connections));
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
        let Ok(permit) = slots.clone().try_acquire_owned() else {
            tracing::debug!(%peer, "Modbus connection refused: max_connections reached");
            service.metrics.server_refused();
            drop(stream);
            continue;
        };
        let _ = stream.set_nodelay(true);
        let (service, token) = (service.clone(), shutdown.clone());
        service.clone().tasks().spawn(async move {
            service.metrics.server_connection(true);
            if let Err(reason) = connection(stream, &service, idle, &token).await {
                tracing::debug!(%peer, %reason, "Modbus connection closed");
            }
            service.metrics.server_connection(false);
            drop(permit);
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
    #[error(transparent)]
    Io(std::io::Error),
    #[error("malformed {0}")]
    Malformed(#[from] mbap::Malformed),
}

/// Serves one master until it leaves, stays idle too long, sends a malformed header, or the
/// gateway shuts down.
async fn connection(
    stream: TcpStream,
    service: &Service,
    idle: Duration,
    token: &CancellationToken,
) -> Result<(), Closed> {
    // Buffered: one read usually brings a whole request (or several pipelined ones).
    let mut stream = BufReader::new(stream);
    let mut counters = Counters::default();
    let mut header = [0u8; mbap::HEADER_LEN];
    loop {
        let read = tokio::select! {
            _ = token.cancelled() => return Ok(()),
            r = tokio::time::timeout(idle, stream.read_exact(&mut header)) => r,
        };
        match read {
            Err(_) => return Err(Closed::Idle),
            Ok(Err(e)) if e.kind() == std::io::ErrorKind::UnexpectedEof => return Ok(()),
            Ok(Err(e)) => return Err(Closed::Io(e)),
            Ok(Ok(_)) => {}
        }
        let header = mbap::Header::parse(&header)?;
        let unit = header.unit;
        let mut pdu = vec![0u8; header.pdu_len];
        match tokio::time::timeout(idle, stream.read_exact(&mut pdu)).await {
            Ok(Ok(_)) => {}
            Ok(Err(e)) => return Err(Closed::Io(e)),
            Err(_) => return Err(Closed::IdleMidFrame),
        }
        let answer = answer(service, unit, &pdu, &mut counters).await;
        let frame = mbap::frame(header.transaction, unit, &answer);
        stream.write_all(&frame).await.map_err(Closed::Io)?;
    }
}

/// A connection's handles on the request counters, so that counting a request costs no
/// label lookup.
#[derive(Default)]
struct Counters(HashMap<(u8, Option<u8>), (Counter, Option<Counter>)>);

impl Counters {
    fn count(&mut self, service: &Service, code: u8, exception: Option<u8>) {
        let (requests, exceptions) = self.0.entry((code, exception)).or_insert_with(|| {
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
        });
        requests.inc();
        if let Some(e) = exceptions {
            e.inc();
        }
    }
}

/// The response PDU to a request PDU for `unit`.
async fn answer(service: &Service, unit: u8, pdu: &[u8], counters: &mut Counters) -> Vec<u8> {
    let code = pdu.first().copied().unwrap_or(0);
    let result = match Request::parse(pdu) {
        Ok(request) => service
            .modbus_request(unit, &request)
            .await
            .map(|r| r.to_pdu(&request)),
        Err(x) => Err(x),
    };
    match result {
        Ok(response) => {
            counters.count(service, code, None);
            response
        }
        Err(x @ Exception(code_x)) => {
            counters.count(service, code, Some(code_x));
            x.to_pdu(code)
        }
    }
}

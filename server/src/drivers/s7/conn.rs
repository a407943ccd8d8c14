//! A connection to a PLC: TCP, the COTP connection (TSAPs from rack and slot, or given),
//! the S7 communication set up with its PDU size; jobs sent one at a time, each answer
//! matched to its job by reference.

use std::io;
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

use super::pdu::{self, Item, Malformed};
use super::szl;

/// The most late answers (to jobs given up on) passed over while waiting for one.
const STALE: usize = 8;

/// The most jobs asked to be sent before their answers.
const PARALLEL: u16 = 8;

/// Each job's items (bytes or return codes), or the PLC's refusal of the job.
pub(crate) type Answers = Vec<Result<Vec<Result<Vec<u8>, u8>>, Malformed>>;

/// Why a job failed.
#[derive(Debug, thiserror::Error)]
pub(crate) enum S7Error {
    #[error("{0}")]
    Io(#[from] io::Error),
    #[error("{0}")]
    Malformed(#[from] Malformed),
    #[error("no answer within {0:?}")]
    Timeout(Duration),
    #[error(
        "the PLC refused the connection to TSAP {remote:#06x} ({why}): check rack and slot (S7-300/400: the CPU's slot, often 2; S7-1200/1500: rack 0, slot 1) or, for S7-200 and LOGO!, local_tsap and remote_tsap"
    )]
    Refused { remote: u16, why: String },
}

/// An open connection.
pub(crate) struct Connection {
    stream: TcpStream,
    /// The PDU size the PLC granted.
    pub(crate) pdu: u16,
    /// How many jobs the PLC takes before answering the first (its AmQ).
    pub(crate) parallel: u16,
    reference: u16,
    timeout: Duration,
}

/// The most bytes an answer split over COTP data frames may put together: more than any PDU
/// a PLC grants (960) with its headers.
const REASSEMBLED: usize = 8 * 1024;

/// The S7 answer in a frame, which must be the one to job `reference`.
fn answered(frame: &[u8], reference: u16) -> Result<pdu::Answer<'_>, Malformed> {
    let a = pdu::answer(frame)?;
    if a.reference != reference {
        return Err(Malformed::Reference {
            expected: reference,
            got: a.reference,
        });
    }
    Ok(a)
}

impl Connection {
    /// Connects, opens the COTP connection and sets up communication asking for `pdu`.
    pub(crate) async fn open(
        addr: (&str, u16),
        local: u16,
        remote: u16,
        pdu: u16,
        timeout: Duration,
    ) -> Result<Connection, S7Error> {
        let stream = tokio::time::timeout(timeout, TcpStream::connect(addr))
            .await
            .map_err(|_| S7Error::Timeout(timeout))?
            .map_err(|e| match e.kind() {
                io::ErrorKind::ConnectionRefused => io::Error::new(
                    e.kind(),
                    format!(
                        "connection refused: nothing listens on port {} there (is it the PLC's address, and its port 102 open?)",
                        addr.1
                    ),
                ),
                _ => e,
            })?;
        let _ = stream.set_nodelay(true);
        let mut conn = Connection {
            stream,
            pdu: 0,
            parallel: 1,
            reference: 0,
            timeout,
        };
        conn.stream
            .write_all(&pdu::connect_request(local, remote))
            .await?;
        let confirmed = match conn.frame().await {
            Ok(confirm) => pdu::connect_confirm(&confirm).map_err(|e| e.to_string()),
            Err(S7Error::Timeout(t)) => return Err(S7Error::Timeout(t)),
            Err(e) => Err(e.to_string()),
        };
        confirmed.map_err(|why| S7Error::Refused { remote, why })?;
        let reference = conn.next_reference();
        let answer = conn
            .job(reference, &pdu::setup(reference, pdu, PARALLEL))
            .await?;
        let (granted, parallel) = pdu::granted(&answered(&answer, reference)?)?;
        conn.pdu = granted;
        conn.parallel = parallel.clamp(1, PARALLEL);
        Ok(conn)
    }

    fn next_reference(&mut self) -> u16 {
        self.reference = self.reference.wrapping_add(1);
        self.reference
    }

    /// One TPKT frame's payload.
    async fn tpkt(&mut self) -> Result<Vec<u8>, S7Error> {
        let mut head = [0u8; 4];
        self.stream.read_exact(&mut head).await?;
        if head[0] != 3 {
            return Err(S7Error::Malformed(Malformed::Tpkt(head[0])));
        }
        let len = usize::from(u16::from_be_bytes([head[2], head[3]]));
        if len < 7 {
            return Err(S7Error::Malformed(Malformed::Short(len)));
        }
        let mut payload = vec![0u8; len - 4];
        self.stream.read_exact(&mut payload).await?;
        Ok(payload)
    }

    /// One answer's payload, by the deadline: a TPKT frame, or the data of several COTP
    /// data frames put together up to the one marked last (some communication processors
    /// and gateways split an answer so), within [`REASSEMBLED`] bytes.
    async fn frame(&mut self) -> Result<Vec<u8>, S7Error> {
        let timeout = self.timeout;
        let read = async {
            let mut payload = self.tpkt().await?;
            while pdu::more_to_come(&payload) {
                let next = self.tpkt().await?;
                let data = pdu::data_unit(&next)?;
                if payload.len() + data.len() > REASSEMBLED {
                    return Err(S7Error::Malformed(Malformed::Reassembled(REASSEMBLED)));
                }
                payload.extend_from_slice(data);
                if !pdu::more_to_come(&next) {
                    pdu::mark_last(&mut payload);
                }
            }
            Ok(payload)
        };
        tokio::time::timeout(timeout, read)
            .await
            .map_err(|_| S7Error::Timeout(timeout))?
    }

    /// Sends job `reference` and reads its answer, passing over late answers to jobs given
    /// up on (a timeout) before it.
    async fn job(&mut self, reference: u16, request: &[u8]) -> Result<Vec<u8>, S7Error> {
        self.stream.write_all(request).await?;
        let mut got = 0;
        for _ in 0..=STALE {
            let frame = self.frame().await?;
            got = pdu::answer(&frame)?.reference;
            if got == reference {
                return Ok(frame);
            }
        }
        Err(Malformed::Reference {
            expected: reference,
            got,
        }
        .into())
    }

    /// Reads `items` in one job: each item's bytes or its return code.
    #[cfg(test)]
    pub(crate) async fn read(
        &mut self,
        items: &[Item],
    ) -> Result<Vec<Result<Vec<u8>, u8>>, S7Error> {
        let reference = self.next_reference();
        let answer = self.job(reference, &pdu::read(reference, items)).await?;
        Ok(pdu::read_items(&answered(&answer, reference)?, items)?)
    }

    /// Reads several jobs of items, as many at a time as the PLC takes: each job's answer,
    /// or the PLC's refusal of it. `started` is told before each answer is awaited.
    pub(crate) async fn read_jobs(
        &mut self,
        jobs: &[&[Item]],
        started: impl Fn(),
    ) -> Result<Answers, S7Error> {
        let mut out: Answers = vec![Err(Malformed::Truncated); jobs.len()];
        let mut waiting: std::collections::VecDeque<(u16, usize)> = Default::default();
        let (mut next, mut stale) = (0, 0);
        while next < jobs.len() || !waiting.is_empty() {
            while next < jobs.len() && waiting.len() < usize::from(self.parallel) {
                let reference = self.next_reference();
                self.stream
                    .write_all(&pdu::read(reference, jobs[next]))
                    .await?;
                waiting.push_back((reference, next));
                next += 1;
            }
            started();
            let frame = self.frame().await?;
            let answer = pdu::answer(&frame)?;
            let Some(at) = waiting.iter().position(|(r, _)| *r == answer.reference) else {
                // A late answer to a job given up on: passed over, a few times at most.
                stale += 1;
                if stale > STALE {
                    return Err(Malformed::Reference {
                        expected: waiting.front().map_or(0, |w| w.0),
                        got: answer.reference,
                    }
                    .into());
                }
                continue;
            };
            let Some((_, job)) = waiting.remove(at) else {
                continue;
            };
            // The frame was whole (TPKT counts it): an answer that does not fit its
            // request fails that job's fields, naming why, and the connection goes on.
            out[job] = pdu::read_items(&answer, jobs[job]);
        }
        Ok(out)
    }

    /// Reads SZL `id` at `index`: its records.
    pub(crate) async fn szl(&mut self, id: u16, index: u16) -> Result<Vec<Vec<u8>>, S7Error> {
        let reference = self.next_reference();
        let answer = self
            .job(reference, &szl::request(reference, id, index))
            .await?;
        Ok(szl::records(&answered(&answer, reference)?)?)
    }

    /// Writes `items` in one job: each item's outcome.
    pub(crate) async fn write(
        &mut self,
        items: &[(Item, Vec<u8>)],
    ) -> Result<Vec<Result<(), u8>>, S7Error> {
        let reference = self.next_reference();
        let answer = self.job(reference, &pdu::write(reference, items)).await?;
        Ok(pdu::write_items(
            &answered(&answer, reference)?,
            items.len(),
        )?)
    }
}

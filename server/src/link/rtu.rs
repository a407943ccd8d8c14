//! Modbus RTU and ASCII transactions over a byte stream (a serial port, or a TCP socket to a
//! serial device server). ASCII frames (`ascii`) differ only in their form: a request is
//! sent as `:`, hexadecimal characters with an LRC, CR LF, and an answer is taken from its
//! `:` to its CR LF; every guarantee below holds for both.
//!
//! This layer exists because a client that only wraps calls in a timeout cannot be made safe
//! on a shared RS-485 line: it keeps no inter-frame silence, and after a timeout it reads a
//! late reply as the answer to the next request. Here every transaction:
//! - waits for the line to have been silent for 3.5 characters (1.75 ms above 19200 baud)
//!   plus the link's guard time, discarding anything that arrived in between;
//! - reads exactly the response its request calls for, with a deadline;
//! - checks slave, function, byte count, CRC and write echo, and rejects anything else;
//! - after a timeout or a rejected frame, discards input until the line has been quiet for
//!   the late-reply window (half the timeout, at most 50 ms, at least the silence plus guard),
//!   so a late reply is dropped rather than taken as the answer to the next request. The
//!   window restarts with every byte, so it only has to cover the gap before a late frame's
//!   first byte; a dead device costs its timeout plus that window.
//! - after a timeout, remembers that the slave may still answer until twice the timeout
//!   (at most a second past it). RTU frames carry no transaction id: a late answer to one
//!   read looks exactly like the answer to another read of the same slave, function and
//!   length (two masters forwarding reads of registers 0 and 500 to a slow slave). Such a
//!   request is not sent until the late answer has arrived and been discarded, or that
//!   horizon has passed. Any other request goes at once: a late frame arriving in its
//!   place fails its slave, function or length check, an error, never a wrong value.

use std::io;
use std::time::Duration;

use futures_util::FutureExt;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::time::{Instant, timeout_at};

use super::precise;

use super::ascii;
use super::frame::{Malformed, Request, Response};
use super::rtu_frame::{self, Unframed, rtu_frame};
use super::timing::LineTiming;
use super::{ByteStream, Counters, TxError};

/// Room for the longest frame a byte count can announce: 5 + 255 bytes.
const MAX_FRAME: usize = 260;
/// The longest late-reply window.
pub(crate) const MAX_LATE_WINDOW: Duration = Duration::from_millis(50);
/// How long past its timeout a silent slave's answer is still waited out, at most.
pub(crate) const MAX_LATE_HORIZON: Duration = Duration::from_secs(1);

/// A request that timed out: its answer may still come, until `until`.
#[derive(Debug, Clone, Copy)]
struct Late {
    slave: u8,
    function: u8,
    /// The answer's frame length: an answer of another length is no confusion.
    answer_len: usize,
    until: Instant,
    /// Bytes discarded since the timeout; a whole answer's worth means it came.
    discarded: usize,
}

pub struct RtuTransport {
    io: Box<dyn ByteStream>,
    /// Frames in ASCII, not RTU.
    ascii: bool,
    /// Wire timing of a serial line; `None` over TCP, where there is no line to keep quiet.
    timing: Option<LineTiming>,
    guard: Duration,
    /// When the line was last busy (the end of the last frame sent or received).
    last_activity: Instant,
    timer: precise::Timer,
    /// A request that timed out and whose answer may still come.
    late: Option<Late>,
    pub(crate) counters: Counters,
}

impl RtuTransport {
    pub fn new(io: Box<dyn ByteStream>, timing: Option<LineTiming>, guard: Duration) -> Self {
        RtuTransport {
            io,
            ascii: false,
            timing,
            guard,
            last_activity: Instant::now(),
            timer: precise::Timer::new(),
            late: None,
            counters: Counters::default(),
        }
    }

    /// The same transport with ASCII frames.
    pub fn ascii(self) -> Self {
        RtuTransport {
            ascii: true,
            ..self
        }
    }

    /// The characters of the frame whose RTU form has `bytes` bytes.
    fn frame_chars(&self, bytes: usize) -> usize {
        super::timing::frame_chars(self.ascii, bytes)
    }

    fn silence(&self) -> Duration {
        self.timing.map_or(Duration::ZERO, |t| t.silence()) + self.guard
    }

    /// The wire time of the frame whose RTU form has `bytes` bytes.
    fn frame_time(&self, bytes: usize) -> Duration {
        self.timing.map_or(Duration::ZERO, |t| {
            t.char_time() * self.frame_chars(bytes) as u32
        })
    }

    /// One request and its response. `timeout` runs from the end of the request on the wire.
    pub async fn transact(
        &mut self,
        slave: u8,
        request: &Request,
        timeout: Duration,
    ) -> Result<Response, TxError> {
        let answer_len = self.frame_chars(request.response_len() + 3);
        self.wait_out_late(slave, request.function().code(), answer_len)
            .await?;
        self.quiet_line(self.silence()).await?;
        let rtu = rtu_frame(slave, request);
        let rtu_len = rtu.len();
        let frame = if self.ascii {
            ascii::encode(&rtu[..rtu_len - 2])
        } else {
            rtu
        };
        self.io.write_all(&frame).await?;
        self.io.flush().await?;
        self.counters.bytes_sent += frame.len() as u64;
        let sent = Instant::now() + self.frame_time(rtu_len);
        self.last_activity = sent;
        let result = self.read_response(slave, request, sent + timeout).await;
        match &result {
            Ok(_) | Err(TxError::Exception(_)) | Err(TxError::Io(_)) => {}
            Err(e) => {
                if matches!(e, TxError::Timeout) {
                    self.late = Some(Late {
                        slave,
                        function: request.function().code(),
                        answer_len,
                        until: sent + timeout + timeout.min(MAX_LATE_HORIZON),
                        discarded: 0,
                    });
                }
                // The quiet window starts now: a reply still on its way is discarded.
                self.last_activity = Instant::now();
                let window = (timeout / 2).min(MAX_LATE_WINDOW).max(self.silence());
                self.quiet_line(window).await?;
            }
        }
        result
    }

    /// A scan's probe (RTU frames only): sends `pdu` to `slave` after the line's silence and
    /// keeps every byte that comes back until `until`: one answer, two, or a garbled mix,
    /// which only the scan can judge. With `early`, it stops once what came is whole RTU
    /// frames (by their CRCs) followed by the line's silence. No late-reply window follows:
    /// a scan's next probe goes to another slave, whose answer a late one cannot pass for.
    pub(crate) async fn probe(
        &mut self,
        slave: u8,
        pdu: &[u8],
        until: Instant,
        early: bool,
    ) -> Result<Vec<u8>, TxError> {
        if self.ascii {
            return Err(TxError::Invalid(Malformed::NotRtu));
        }
        self.quiet_line(self.silence()).await?;
        let frame = rtu_frame::seal(slave, pdu);
        self.io.write_all(&frame).await?;
        self.io.flush().await?;
        self.counters.bytes_sent += frame.len() as u64;
        self.last_activity = Instant::now() + self.frame_time(frame.len());
        // Silence ends a frame; over a link with no line timing, two milliseconds.
        let gap = self.silence().max(Duration::from_millis(2));
        let mut heard = Vec::new();
        let mut chunk = [0u8; MAX_FRAME];
        loop {
            let stop = if early && rtu_frame::whole_frames(&heard) {
                (self.last_activity + gap).min(until)
            } else {
                until
            };
            let read = tokio::select! {
                biased;
                read = self.io.read(&mut chunk) => read,
                _ = self.timer.sleep_until(stop) => break,
            };
            match read {
                Ok(0) => return Err(io::Error::from(io::ErrorKind::UnexpectedEof).into()),
                Ok(n) => {
                    self.counters.bytes_received += n as u64;
                    self.last_activity = Instant::now();
                    heard.extend_from_slice(&chunk[..n]);
                    if heard.len() > 4 * MAX_FRAME {
                        break;
                    }
                }
                Err(e) => return Err(e.into()),
            }
        }
        Ok(heard)
    }

    /// Before a request that a late answer could be taken for (same slave, function and
    /// answer length as one that timed out), discards input until that answer has come or
    /// its horizon has passed.
    async fn wait_out_late(
        &mut self,
        slave: u8,
        function: u8,
        answer_len: usize,
    ) -> Result<(), TxError> {
        let Some(late) = self.late else {
            return Ok(());
        };
        let now = Instant::now();
        let came = late.discarded >= late.answer_len;
        if came || now >= late.until {
            self.late = None;
            return Ok(());
        }
        if (late.slave, late.function, late.answer_len) != (slave, function, answer_len) {
            return Ok(());
        }
        let mut scratch = [0u8; MAX_FRAME];
        while let Some(late) = self.late {
            if late.discarded >= late.answer_len {
                break;
            }
            let read = tokio::select! {
                read = self.io.read(&mut scratch) => read,
                _ = self.timer.sleep_until(late.until) => break,
            };
            match read {
                Ok(0) => return Err(io::Error::from(io::ErrorKind::UnexpectedEof).into()),
                Ok(n) => self.discard(n),
                Err(e) => return Err(e.into()),
            }
        }
        self.late = None;
        Ok(())
    }

    async fn read_response(
        &mut self,
        slave: u8,
        request: &Request,
        deadline: Instant,
    ) -> Result<Response, TxError> {
        if self.ascii {
            return self.read_ascii_response(slave, request, deadline).await;
        }
        let mut buf = [0u8; MAX_FRAME];
        self.read_into(&mut buf[..3], deadline).await?;
        let fc = request.function().code();
        let total = if buf[1] == fc | 0x80 {
            5
        } else if buf[1] != fc {
            return Err(TxError::Invalid(Malformed::Function {
                found: buf[1],
                asked: request.function(),
            }));
        } else if request.is_read() {
            let expected = request.response_len() - 2;
            if usize::from(buf[2]) != expected {
                return Err(TxError::Invalid(Malformed::ByteCount {
                    found: usize::from(buf[2]),
                    expected,
                }));
            }
            // slave, function, byte count, data, CRC
            5 + expected
        } else {
            8
        };
        self.read_into(&mut buf[3..total], deadline).await?;
        self.last_activity = Instant::now();
        let (found, pdu) = match rtu_frame::open(&buf[..total]) {
            Ok(opened) => opened,
            Err(Unframed::Crc | Unframed::Short) => return Err(TxError::Crc),
        };
        if found != slave {
            return Err(TxError::Invalid(Malformed::Slave {
                found,
                expected: slave,
            }));
        }
        request.parse_response(pdu).map_err(TxError::from)
    }

    /// An ASCII answer: characters before its `:` are discarded, a frame is taken at its
    /// CR LF, and then checked as an RTU one is (LRC for CRC).
    async fn read_ascii_response(
        &mut self,
        slave: u8,
        request: &Request,
        deadline: Instant,
    ) -> Result<Response, TxError> {
        let mut assembler = ascii::Assembler::default();
        let mut chunk = [0u8; MAX_FRAME];
        let body = loop {
            let n = match timeout_at(deadline, self.io.read(&mut chunk)).await {
                Err(_) => return Err(TxError::Timeout),
                Ok(Err(e)) => return Err(e.into()),
                Ok(Ok(0)) => {
                    return Err(io::Error::from(io::ErrorKind::UnexpectedEof).into());
                }
                Ok(Ok(n)) => n,
            };
            self.counters.bytes_received += n as u64;
            let ended = chunk[..n]
                .iter()
                .enumerate()
                .find_map(|(i, &c)| assembler.push(c).map(|frame| (i, frame)));
            if let Some((i, frame)) = ended {
                // Whatever came after the frame belongs to no transaction.
                let after = n - i - 1;
                self.counters.bytes_discarded += (assembler.dropped + after) as u64;
                self.last_activity = Instant::now();
                break frame.map_err(|e| match e {
                    ascii::AsciiError::Lrc { .. } => TxError::Crc,
                    other => TxError::Invalid(Malformed::Ascii(other)),
                })?;
            }
        };
        if body[0] != slave {
            return Err(TxError::Invalid(Malformed::Slave {
                found: body[0],
                expected: slave,
            }));
        }
        request.parse_response(&body[1..]).map_err(TxError::from)
    }

    async fn read_into(&mut self, buf: &mut [u8], deadline: Instant) -> Result<(), TxError> {
        match timeout_at(deadline, self.io.read_exact(buf)).await {
            Err(_) => Err(TxError::Timeout),
            Ok(Err(e)) => Err(e.into()),
            Ok(Ok(_)) => {
                self.counters.bytes_received += buf.len() as u64;
                Ok(())
            }
        }
    }

    /// Waits until the line has been silent for `quiet`, discarding whatever arrives.
    async fn quiet_line(&mut self, quiet: Duration) -> Result<(), TxError> {
        let mut scratch = [0u8; MAX_FRAME];
        loop {
            // Drop what is already buffered, without a timer: tokio's timers tick in whole
            // milliseconds, which would cost every transaction up to a millisecond.
            while let Some(read) = self.io.read(&mut scratch).now_or_never() {
                match read {
                    Ok(0) => return Err(io::Error::from(io::ErrorKind::UnexpectedEof).into()),
                    Ok(n) => self.discard(n),
                    Err(e) => return Err(e.into()),
                }
            }
            let until = self.last_activity + quiet;
            if Instant::now() >= until {
                return Ok(());
            }
            // A precise timer (`precise`): the silence ends within a tenth of a millisecond,
            // not at the runtime timer's next tick. A byte arriving meanwhile starts the
            // silence again.
            let read = tokio::select! {
                biased;
                read = self.io.read(&mut scratch) => read,
                _ = self.timer.sleep_until(until) => return Ok(()),
            };
            match read {
                Ok(0) => return Err(io::Error::from(io::ErrorKind::UnexpectedEof).into()),
                Ok(n) => self.discard(n),
                Err(e) => return Err(e.into()),
            }
        }
    }

    fn discard(&mut self, n: usize) {
        self.counters.bytes_received += n as u64;
        self.counters.bytes_discarded += n as u64;
        self.last_activity = Instant::now();
        if let Some(late) = &mut self.late {
            late.discarded += n;
        }
    }
}

#[cfg(test)]
#[path = "rtu_tests.rs"]
mod tests;

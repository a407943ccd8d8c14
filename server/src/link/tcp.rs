//! Modbus TCP transactions (MBAP header). Each request carries a transaction id; an answer
//! with another id (a late reply to a request that timed out) is discarded, so it is never
//! taken as the answer to a later request.

use std::io;
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::time::{Instant, timeout_at};

use super::frame::{Malformed, Request, Response};
use super::mbap;
use super::{ByteStream, Counters, TxError};

pub(crate) struct MbapTransport {
    io: Box<dyn ByteStream>,
    next_id: u16,
    pub(crate) counters: Counters,
}

impl MbapTransport {
    pub(crate) fn new(io: Box<dyn ByteStream>) -> Self {
        MbapTransport {
            io,
            next_id: 1,
            counters: Counters::default(),
        }
    }

    pub(crate) async fn transact(
        &mut self,
        unit: u8,
        request: &Request,
        timeout: Duration,
    ) -> Result<Response, TxError> {
        let id = self.next_id;
        self.next_id = self.next_id.wrapping_add(1);
        let mut pdu = Vec::with_capacity(6 + 2 * usize::from(request.count()));
        request.encode(&mut pdu);
        let frame = mbap::frame(id, unit, &pdu);
        self.io.write_all(&frame).await?;
        self.io.flush().await?;
        self.counters.bytes_sent += frame.len() as u64;

        let deadline = Instant::now() + timeout;
        loop {
            let mut bytes = [0u8; mbap::HEADER_LEN];
            self.read_into(&mut bytes, deadline).await?;
            // A malformed header leaves the stream out of step; only a new connection can
            // recover it.
            let header = mbap::Header::parse(&bytes)
                .map_err(|e| io::Error::new(io::ErrorKind::InvalidData, e.to_string()))?;
            let mut body = vec![0u8; header.pdu_len];
            self.read_into(&mut body, deadline).await?;
            if header.transaction != id {
                self.counters.bytes_discarded += (mbap::HEADER_LEN + body.len()) as u64;
                continue;
            }
            if header.unit != unit {
                return Err(TxError::Invalid(Malformed::Unit {
                    found: header.unit,
                    expected: unit,
                }));
            }
            return request.parse_response(&body).map_err(TxError::from);
        }
    }

    /// Fills `buf` by `deadline`. A timeout in the middle of a frame leaves the stream out of
    /// step, which only a new connection recovers, so it is reported as an I/O error.
    async fn read_into(&mut self, buf: &mut [u8], deadline: Instant) -> Result<(), TxError> {
        let mut filled = 0;
        while filled < buf.len() {
            match timeout_at(deadline, self.io.read(&mut buf[filled..])).await {
                Err(_) if filled == 0 => return Err(TxError::Timeout),
                Err(_) => {
                    return Err(io::Error::new(
                        io::ErrorKind::TimedOut,
                        "timed out in the middle of a frame",
                    )
                    .into());
                }
                Ok(Ok(0)) => return Err(io::Error::from(io::ErrorKind::UnexpectedEof).into()),
                Ok(Ok(n)) => {
                    filled += n;
                    self.counters.bytes_received += n as u64;
                }
                Ok(Err(e)) => return Err(e.into()),
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::io::DuplexStream;

    const TIMEOUT: Duration = Duration::from_millis(100);

    fn read1() -> Request {
        Request::ReadInputRegisters {
            address: 4,
            count: 1,
        }
    }

    fn answer(id: u16, unit: u8, value: u16) -> Vec<u8> {
        let mut f = id.to_be_bytes().to_vec();
        f.extend_from_slice(&[0, 0, 0, 5, unit, 0x04, 2]);
        f.extend_from_slice(&value.to_be_bytes());
        f
    }

    async fn request(device: &mut DuplexStream) -> u16 {
        let mut buf = [0u8; 12];
        device.read_exact(&mut buf).await.expect("request");
        assert_eq!(&buf[2..], &[0, 0, 0, 6, 7, 0x04, 0, 4, 0, 1]);
        u16::from_be_bytes([buf[0], buf[1]])
    }

    #[tokio::test(start_paused = true)]
    async fn late_replies_with_an_old_transaction_id_are_skipped() {
        let (gateway, mut device) = tokio::io::duplex(1024);
        let mut t = MbapTransport::new(Box::new(gateway));
        tokio::spawn(async move {
            let first = request(&mut device).await;
            // Arrives while the gateway waits for its second answer.
            tokio::time::sleep(TIMEOUT * 3 / 2).await;
            device
                .write_all(&answer(first, 7, 0xBAD0))
                .await
                .expect("late");
            let second = request(&mut device).await;
            device
                .write_all(&answer(second, 7, 42))
                .await
                .expect("good");
        });
        assert!(matches!(
            t.transact(7, &read1(), TIMEOUT).await,
            Err(TxError::Timeout)
        ));
        assert_eq!(
            t.transact(7, &read1(), TIMEOUT).await.expect("second"),
            Response::Registers(vec![42])
        );
        assert_eq!(t.counters.bytes_discarded, 11);
    }

    #[tokio::test(start_paused = true)]
    async fn a_bad_header_or_wrong_unit_is_rejected() {
        let (gateway, mut device) = tokio::io::duplex(1024);
        let mut t = MbapTransport::new(Box::new(gateway));
        tokio::spawn(async move {
            let id = request(&mut device).await;
            device.write_all(&answer(id, 9, 1)).await.expect("write");
            let id = request(&mut device).await;
            let mut bad = answer(id, 7, 1);
            bad[2] = 1; // protocol id must be 0
            device.write_all(&bad).await.expect("write");
        });
        assert!(
            matches!(t.transact(7, &read1(), TIMEOUT).await, Err(TxError::Invalid(m)) if m.to_string().contains("unit 9"))
        );
        assert!(matches!(
            t.transact(7, &read1(), TIMEOUT).await,
            Err(TxError::Io(_))
        ));
    }

    /// Sends `read1` and lets the device answer `answer` (its transaction id patched in when
    /// `keep_id` and the answer is long enough).
    fn transact_against(answer: Vec<u8>, keep_id: bool) -> Result<Response, TxError> {
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .start_paused(true)
            .build()
            .expect("runtime");
        runtime.block_on(async {
            let (gateway, mut device) = tokio::io::duplex(4096);
            let mut t = MbapTransport::new(Box::new(gateway));
            tokio::spawn(async move {
                let mut buf = [0u8; 12];
                if device.read_exact(&mut buf).await.is_ok() {
                    let mut answer = answer;
                    if keep_id && answer.len() >= 2 {
                        answer[..2].copy_from_slice(&buf[..2]);
                    }
                    let _ = device.write_all(&answer).await;
                }
                tokio::time::sleep(Duration::from_secs(60)).await;
            });
            t.transact(7, &read1(), TIMEOUT).await
        })
    }

    proptest::proptest! {
        // A long run: `PROPTEST_CASES=1000000 cargo test --release -p iogate --lib mbap`.
        #[test]
        fn any_mbap_answer_is_a_value_or_an_error_never_a_panic(
            answer in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..300),
            keep_id in proptest::prelude::any::<bool>(),
        ) {
            let _ = transact_against(answer, keep_id);
        }

        #[test]
        fn a_good_mbap_answer_with_a_header_byte_changed_is_never_accepted(
            // Protocol id, length, unit, function, byte count (MBAP has no checksum: the
            // data bytes themselves cannot be checked).
            at in 2usize..9,
            flip in 1u8..=255,
        ) {
            let mut bad = answer(0, 7, 42);
            bad[at] ^= flip;
            let answer = transact_against(bad, true);
            proptest::prop_assert!(answer.is_err(), "byte {}: {:?}", at, answer);
        }
    }
}

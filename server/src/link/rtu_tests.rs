use super::*;
use crate::config::{Parity, SerialSettings};
use crate::link::frame::Exception;
use tokio::io::DuplexStream;

const TIMEOUT: Duration = Duration::from_millis(100);

fn line_9600() -> LineTiming {
    LineTiming::new(&SerialSettings {
        port: "test".into(),
        baud: 9600,
        parity: Parity::None,
        data_bits: 8,
        stop_bits: 1,
        framing: Default::default(),
    })
}

fn read2() -> Request {
    Request::ReadHoldingRegisters {
        address: 0,
        count: 2,
    }
}

/// A response frame with a correct CRC.
fn frame(bytes: &[u8]) -> Vec<u8> {
    let mut f = bytes.to_vec();
    f.extend_from_slice(&rtu_frame::crc16(bytes).to_le_bytes());
    f
}

fn registers(slave: u8, a: u16, b: u16) -> Vec<u8> {
    let [a0, a1] = a.to_be_bytes();
    let [b0, b1] = b.to_be_bytes();
    frame(&[slave, 0x03, 4, a0, a1, b0, b1])
}

async fn request(device: &mut DuplexStream) -> (Vec<u8>, Instant) {
    let mut buf = [0u8; 8];
    device.read_exact(&mut buf).await.expect("request");
    (buf.to_vec(), Instant::now())
}

fn transport(gateway: DuplexStream, guard: Duration) -> RtuTransport {
    RtuTransport::new(Box::new(gateway), Some(line_9600()), guard)
}

#[tokio::test(start_paused = true)]
async fn frames_are_separated_by_the_silence_and_guard_time() {
    let (gateway, mut device) = tokio::io::duplex(1024);
    let guard = Duration::from_millis(5);
    let mut t = transport(gateway, guard);
    let dev = tokio::spawn(async move {
        let (req, _) = request(&mut device).await;
        assert_eq!(req, rtu_frame(1, &read2()));
        device.write_all(&registers(1, 1, 2)).await.expect("write");
        let answered = Instant::now();
        let (_, second) = request(&mut device).await;
        device.write_all(&registers(1, 3, 4)).await.expect("write");
        second - answered
    });
    assert_eq!(
        t.transact(1, &read2(), TIMEOUT).await.expect("first"),
        Response::Registers(vec![1, 2])
    );
    assert_eq!(
        t.transact(1, &read2(), TIMEOUT).await.expect("second"),
        Response::Registers(vec![3, 4])
    );
    let gap = dev.await.expect("device");
    assert!(gap >= line_9600().silence() + guard, "{gap:?}");
}

#[tokio::test(start_paused = true)]
async fn a_late_reply_is_never_taken_as_the_next_answer() {
    let (gateway, mut device) = tokio::io::duplex(1024);
    let mut t = transport(gateway, Duration::ZERO);
    tokio::spawn(async move {
        request(&mut device).await;
        // Answers 20% after the timeout, with data that must never be seen.
        tokio::time::sleep(TIMEOUT * 6 / 5).await;
        device
            .write_all(&registers(1, 0xBAD0, 0xBAD0))
            .await
            .expect("write");
        request(&mut device).await;
        device.write_all(&registers(1, 7, 8)).await.expect("write");
    });
    let started = Instant::now();
    assert!(matches!(
        t.transact(1, &read2(), TIMEOUT).await,
        Err(TxError::Timeout)
    ));
    assert_eq!(
        t.transact(1, &read2(), TIMEOUT).await.expect("second"),
        Response::Registers(vec![7, 8])
    );
    assert_eq!(
        t.counters.bytes_discarded, 9,
        "the late frame was discarded"
    );
    assert!(started.elapsed() < TIMEOUT * 3);
}

#[tokio::test(start_paused = true)]
async fn a_late_answer_to_one_read_is_never_taken_for_another_read_of_the_slave() {
    // A slave that answers every read 1.5 timeouts late, with the register address it
    // was asked for as the data: reads of 0 and 500 alternate, as two masters forwarding
    // through the gateway would send them.
    let (gateway, mut device) = tokio::io::duplex(1024);
    let mut t = transport(gateway, Duration::ZERO);
    tokio::spawn(async move {
        loop {
            let (req, _) = request(&mut device).await;
            let address = u16::from_be_bytes([req[2], req[3]]);
            tokio::time::sleep(TIMEOUT * 3 / 2).await;
            if device
                .write_all(&registers(1, address, address))
                .await
                .is_err()
            {
                return;
            }
        }
    });
    let read = |address| Request::ReadHoldingRegisters { address, count: 2 };
    let mut answers = 0;
    for k in 0..20u16 {
        let address = if k % 2 == 0 { 0 } else { 500 };
        match t.transact(1, &read(address), TIMEOUT).await {
            Ok(Response::Registers(values)) => {
                assert_eq!(values, vec![address, address], "another read's answer");
                answers += 1;
            }
            Ok(other) => panic!("{other:?}"),
            Err(TxError::Timeout) => {}
            Err(e) => panic!("{e}"),
        }
    }
    // Every read timed out (the slave is too slow) and none got another's value.
    assert_eq!(answers, 0);
    assert!(
        t.counters.bytes_discarded >= 9 * 19,
        "late answers were discarded"
    );
    // A long enough timeout gets the right answer again.
    assert_eq!(
        t.transact(1, &read(7), TIMEOUT * 2).await.expect("in time"),
        Response::Registers(vec![7, 7])
    );
}

#[tokio::test(start_paused = true)]
async fn a_silent_device_costs_its_timeout_and_the_late_reply_window() {
    let (gateway, _device) = tokio::io::duplex(1024);
    let mut t = transport(gateway, Duration::ZERO);
    let request_on_wire = line_9600().frame_time(8);
    let started = Instant::now();
    assert!(matches!(
        t.transact(1, &read2(), TIMEOUT).await,
        Err(TxError::Timeout)
    ));
    let cost = started.elapsed();
    // The silence before the first frame, the frame, the timeout, the window. Time is
    // paused, but timers fire on whole milliseconds.
    let expected = line_9600().silence() + request_on_wire + TIMEOUT + TIMEOUT / 2;
    assert!(
        cost >= expected && cost <= expected + Duration::from_millis(2),
        "{cost:?}"
    );
    // A long timeout keeps a window of at most 50 ms (another slave, so the first one's
    // late answer is not waited out).
    let long = Duration::from_secs(1);
    let started = Instant::now();
    assert!(matches!(
        t.transact(2, &read2(), long).await,
        Err(TxError::Timeout)
    ));
    let cost = started.elapsed();
    let expected = request_on_wire + long + MAX_LATE_WINDOW;
    assert!(
        cost >= expected && cost <= expected + line_9600().silence() + Duration::from_millis(2),
        "{cost:?}"
    );
}

#[tokio::test(start_paused = true)]
async fn wrong_length_bad_crc_and_wrong_slave_are_rejected_and_the_line_recovers() {
    let (gateway, mut device) = tokio::io::duplex(1024);
    let mut t = transport(gateway, Duration::ZERO);
    tokio::spawn(async move {
        // One register short, with a valid CRC.
        request(&mut device).await;
        device
            .write_all(&frame(&[1, 0x03, 2, 0, 1]))
            .await
            .expect("write");
        // A corrupted CRC.
        request(&mut device).await;
        let mut bad = registers(1, 1, 2);
        let last = bad.len() - 1;
        bad[last] ^= 0xFF;
        device.write_all(&bad).await.expect("write");
        // Another slave's answer.
        request(&mut device).await;
        device.write_all(&registers(9, 1, 2)).await.expect("write");
        // An exception.
        request(&mut device).await;
        device
            .write_all(&frame(&[1, 0x83, 0x02]))
            .await
            .expect("write");
        // And a good answer.
        request(&mut device).await;
        device.write_all(&registers(1, 5, 6)).await.expect("write");
    });
    assert!(
        matches!(t.transact(1, &read2(), TIMEOUT).await, Err(TxError::Invalid(m)) if m.to_string().contains("byte count 2"))
    );
    assert!(matches!(
        t.transact(1, &read2(), TIMEOUT).await,
        Err(TxError::Crc)
    ));
    assert!(
        matches!(t.transact(1, &read2(), TIMEOUT).await, Err(TxError::Invalid(m)) if m.to_string().contains("slave 9"))
    );
    assert!(matches!(
        t.transact(1, &read2(), TIMEOUT).await,
        Err(TxError::Exception(Exception::ILLEGAL_DATA_ADDRESS))
    ));
    assert_eq!(
        t.transact(1, &read2(), TIMEOUT).await.expect("good"),
        Response::Registers(vec![5, 6])
    );
}

#[tokio::test(start_paused = true)]
async fn a_closed_port_is_an_io_error() {
    let (gateway, device) = tokio::io::duplex(1024);
    let mut t = transport(gateway, Duration::ZERO);
    drop(device);
    assert!(matches!(
        t.transact(1, &read2(), TIMEOUT).await,
        Err(TxError::Io(_))
    ));
}

/// Runs one transaction against a device that answers `answer` to whatever it is asked.
fn transact_against(request: &Request, answer: Vec<u8>) -> Result<Response, TxError> {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .start_paused(true)
        .build()
        .expect("runtime");
    runtime.block_on(async {
        let (gateway, mut device) = tokio::io::duplex(4096);
        let mut t = transport(gateway, Duration::ZERO);
        tokio::spawn(async move {
            let mut buf = [0u8; 8];
            if device.read_exact(&mut buf).await.is_ok() {
                let _ = device.write_all(&answer).await;
            }
            // Stay connected: a closed line is a different error.
            tokio::time::sleep(Duration::from_secs(60)).await;
        });
        t.transact(1, request, TIMEOUT).await
    })
}

fn requests() -> impl proptest::strategy::Strategy<Value = Request> {
    use proptest::prelude::*;
    prop_oneof![
        (0u16..100, 1u16..126)
            .prop_map(|(address, count)| Request::ReadHoldingRegisters { address, count }),
        (0u16..100, 1u16..126)
            .prop_map(|(address, count)| Request::ReadInputRegisters { address, count }),
        (0u16..100, 1u16..2001).prop_map(|(address, count)| Request::ReadCoils { address, count }),
        (0u16..100, any::<u16>())
            .prop_map(|(address, value)| Request::WriteSingleRegister { address, value }),
        (0u16..100, any::<bool>())
            .prop_map(|(address, value)| Request::WriteSingleCoil { address, value }),
    ]
}

proptest::proptest! {
    #[test]
    fn any_answer_is_a_value_or_an_error_never_a_panic(
        request in requests(),
        answer in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..300),
    ) {
        let _ = transact_against(&request, answer);
    }

    #[test]
    fn a_good_answer_with_one_byte_changed_is_never_accepted(
        request in requests(),
        at in proptest::prelude::any::<proptest::sample::Index>(),
        flip in 1u8..=255,
    ) {
        // The good answer: registers or bits of zeros, or the write's echo.
        let mut pdu = Vec::new();
        request.encode(&mut pdu);
        let good: Vec<u8> = match &request {
            r if r.is_read() => {
                let n = r.response_len() - 2;
                let mut f = vec![1, pdu[0], n as u8];
                f.extend(std::iter::repeat_n(0u8, n));
                f
            }
            _ => [&[1u8][..], &pdu[..5]].concat(),
        };
        let framed = frame(&good);
        proptest::prop_assert!(transact_against(&request, framed.clone()).is_ok());
        let mut corrupted = framed;
        let i = at.index(corrupted.len());
        corrupted[i] ^= flip;
        proptest::prop_assert!(transact_against(&request, corrupted).is_err());
    }
}

/// An ASCII frame of `body` (address and PDU).
fn ascii_answer(body: &[u8]) -> Vec<u8> {
    crate::link::ascii::encode(body)
}

/// Reads one ASCII request (through its LF).
async fn ascii_request(device: &mut DuplexStream) -> Vec<u8> {
    let mut frame = Vec::new();
    let mut byte = [0u8; 1];
    while frame.last() != Some(&b'\n') {
        device.read_exact(&mut byte).await.expect("request");
        frame.push(byte[0]);
    }
    frame
}

#[tokio::test(start_paused = true)]
async fn ascii_frames_go_out_and_come_back_checked_like_rtu_ones() {
    let (gateway, mut device) = tokio::io::duplex(1024);
    let mut t = transport(gateway, Duration::ZERO).ascii();
    tokio::spawn(async move {
        // The request as the specification writes it.
        let req = ascii_request(&mut device).await;
        assert_eq!(req, b":010300000002FA\r\n".to_vec());
        // Noise before the answer's `:` is dropped; the answer taken.
        let mut answer = b"\x00zz".to_vec();
        answer.extend(ascii_answer(&[1, 0x03, 4, 0, 1, 0, 2]));
        device.write_all(&answer).await.expect("write");
        // A bad LRC.
        ascii_request(&mut device).await;
        let mut bad = ascii_answer(&[1, 0x03, 4, 0, 1, 0, 2]);
        let at = bad.len() - 3;
        bad[at] = if bad[at] == b'0' { b'1' } else { b'0' };
        device.write_all(&bad).await.expect("write");
        // Another slave's answer.
        ascii_request(&mut device).await;
        device
            .write_all(&ascii_answer(&[9, 0x03, 4, 0, 1, 0, 2]))
            .await
            .expect("write");
        // Not hexadecimal.
        ascii_request(&mut device).await;
        device.write_all(b":01030G\r\n").await.expect("write");
        // An exception, then a good answer in lower case.
        ascii_request(&mut device).await;
        device
            .write_all(&ascii_answer(&[1, 0x83, 0x02]))
            .await
            .expect("write");
        ascii_request(&mut device).await;
        let good = String::from_utf8(ascii_answer(&[1, 0x03, 4, 0, 5, 0, 6]))
            .expect("text")
            .to_lowercase();
        device.write_all(good.as_bytes()).await.expect("write");
    });
    assert_eq!(
        t.transact(1, &read2(), TIMEOUT).await.expect("first"),
        Response::Registers(vec![1, 2])
    );
    assert_eq!(t.counters.bytes_discarded, 3, "the noise");
    assert!(matches!(
        t.transact(1, &read2(), TIMEOUT).await,
        Err(TxError::Crc)
    ));
    assert!(
        matches!(t.transact(1, &read2(), TIMEOUT).await, Err(TxError::Invalid(m)) if m.to_string().contains("slave 9"))
    );
    assert!(
        matches!(t.transact(1, &read2(), TIMEOUT).await, Err(TxError::Invalid(m)) if m.to_string().contains("hexadecimal"))
    );
    assert!(matches!(
        t.transact(1, &read2(), TIMEOUT).await,
        Err(TxError::Exception(Exception::ILLEGAL_DATA_ADDRESS))
    ));
    assert_eq!(
        t.transact(1, &read2(), TIMEOUT).await.expect("good"),
        Response::Registers(vec![5, 6])
    );
}

#[tokio::test(start_paused = true)]
async fn a_late_ascii_answer_to_one_read_is_never_taken_for_another() {
    // As for RTU: a slave answering 1.5 timeouts late, with the address it was asked
    // for as the data.
    let (gateway, mut device) = tokio::io::duplex(4096);
    let mut t = transport(gateway, Duration::ZERO).ascii();
    tokio::spawn(async move {
        loop {
            let req = ascii_request(&mut device).await;
            let hex = std::str::from_utf8(&req[5..9]).expect("text");
            let address = u16::from_str_radix(hex, 16).expect("address");
            let [hi, lo] = address.to_be_bytes();
            tokio::time::sleep(TIMEOUT * 3 / 2).await;
            let answer = ascii_answer(&[1, 0x03, 4, hi, lo, hi, lo]);
            if device.write_all(&answer).await.is_err() {
                return;
            }
        }
    });
    let read = |address| Request::ReadHoldingRegisters { address, count: 2 };
    for k in 0..10u16 {
        let address = if k % 2 == 0 { 0 } else { 500 };
        match t.transact(1, &read(address), TIMEOUT).await {
            Ok(Response::Registers(values)) => {
                assert_eq!(values, vec![address, address], "another read's answer")
            }
            Ok(other) => panic!("{other:?}"),
            Err(TxError::Timeout) => {}
            Err(e) => panic!("{e}"),
        }
    }
    assert!(
        t.counters.bytes_discarded > 0,
        "late answers were discarded"
    );
    assert_eq!(
        t.transact(1, &read(7), TIMEOUT * 2).await.expect("in time"),
        Response::Registers(vec![7, 7])
    );
}

#[test]
fn an_ascii_frame_takes_twice_the_characters_and_three_more() {
    let t = LineTiming::new(&SerialSettings {
        framing: crate::config::Framing::Ascii,
        data_bits: 7,
        parity: Parity::Even,
        ..SerialSettings {
            port: "test".into(),
            baud: 9600,
            parity: Parity::None,
            data_bits: 8,
            stop_bits: 1,
            framing: Default::default(),
        }
    });
    // 8-byte RTU request: `:` + 2 x 7 + CR LF = 17 characters of 10 bits (7E1).
    assert_eq!(t.bits_per_char, 10);
    assert_eq!(t.frame_chars(8), 17);
    assert_eq!(t.frame_time(8), t.char_time() * 17);
}

#[tokio::test(start_paused = true)]
async fn noise_on_the_line_before_a_request_is_discarded() {
    let (gateway, mut device) = tokio::io::duplex(1024);
    let mut t = transport(gateway, Duration::ZERO);
    device.write_all(&[0x55, 0xAA, 0x01]).await.expect("noise");
    tokio::spawn(async move {
        request(&mut device).await;
        device.write_all(&registers(1, 1, 1)).await.expect("write");
    });
    assert_eq!(
        t.transact(1, &read2(), TIMEOUT).await.expect("good"),
        Response::Registers(vec![1, 1])
    );
    assert_eq!(t.counters.bytes_discarded, 3);
}

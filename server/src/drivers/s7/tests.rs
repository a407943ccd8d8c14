use std::time::Duration;

use super::address::Area;
use super::config::remote_tsap;
use super::conn::Connection;
use super::pdu::Item;
use super::szl;

/// Snap7's server (python-snap7) with DB1 of 64 bytes (0x12 0x34 0xAB at 0) and 16 merker
/// bytes, on a free port; killed when dropped.
struct Snap7(std::process::Child, u16);

impl Drop for Snap7 {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn snap7() -> Option<Snap7> {
    use std::io::BufRead;
    // The tests install what they need, as a newcomer's `cargo test` runs them.
    // python-snap7 runs in the tests' own Python, made from tests/python/requirements.txt.
    let venv = concat!(env!("CARGO_MANIFEST_DIR"), "/../tests/python/venv.sh");
    let made = std::process::Command::new("bash")
        .arg(venv)
        .stderr(std::process::Stdio::inherit())
        .output()
        .expect("running tests/python/venv.sh");
    assert!(made.status.success(), "tests/python/venv.sh failed");
    let python = String::from_utf8_lossy(&made.stdout).trim().to_string();
    let script = r#"
import ctypes, sys, time, socket
from snap7.server import Server
from snap7.type import SrvArea
s = socket.socket(); s.bind(("127.0.0.1", 0)); port = s.getsockname()[1]; s.close()
srv = Server(log=False)
db1 = (ctypes.c_uint8 * 64)(); db1[0] = 0x12; db1[1] = 0x34; db1[2] = 0xAB
mk = (ctypes.c_uint8 * 16)()
tm = (ctypes.c_uint8 * 16)(); tm[4] = 0x21; tm[5] = 0x25
ct = (ctypes.c_uint8 * 16)(); ct[3] = 0x01; ct[4] = 0x23
srv.register_area(SrvArea.DB, 1, db1); srv.register_area(SrvArea.MK, 0, mk)
srv.register_area(SrvArea.TM, 0, tm); srv.register_area(SrvArea.CT, 0, ct)
srv.start(tcp_port=port)
print(port, flush=True)
while sys.stdin.read(1): pass
"#;
    let mut child = std::process::Command::new(python)
        .args(["-c", script])
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .ok()?;
    let out = child.stdout.take()?;
    let mut line = String::new();
    std::io::BufReader::new(out).read_line(&mut line).ok()?;
    let port = line.trim().parse().ok()?;
    Some(Snap7(child, port))
}

/// Snap7's server and a connection to it of a kind (1 PG, 3 S7 basic) asking for `pdu`.
async fn connect(kind: i128, pdu: u16) -> (Snap7, Connection) {
    let server = snap7().expect("Snap7 starts (python-snap7, in tests/.venv)");
    let c = Connection::open(
        ("127.0.0.1", server.1),
        0x0100,
        remote_tsap(kind, 0, 1) as u16,
        pdu,
        Duration::from_secs(3),
    )
    .await
    .expect("connected");
    (server, c)
}

#[tokio::test]
async fn reads_and_writes_bytes_and_bits_of_snap7s_server() {
    let (_server, mut c) = connect(3, 960).await;
    assert!(c.pdu >= 240, "PDU {}", c.pdu);
    let db = |byte, length| Item {
        area: Area::DataBlock,
        db: 1,
        byte,
        bit: None,
        length,
    };
    let read = c.read(&[db(0, 3), db(1, 1)]).await.expect("read");
    assert_eq!(read, vec![Ok(vec![0x12, 0x34, 0xAB]), Ok(vec![0x34])]);
    // A data block that does not exist is that item's error, the others are read.
    let missing = Item { db: 9, ..db(0, 2) };
    let read = c.read(&[missing, db(0, 1)]).await.expect("read");
    assert_eq!(read[1], Ok(vec![0x12]));
    assert!(read[0].is_err(), "{read:?}");
    // A bit written alone leaves its neighbours.
    let bit = Item {
        bit: Some(3),
        ..db(2, 1)
    };
    let written = c.write(&[(bit, vec![0])]).await.expect("write");
    assert_eq!(written, vec![Ok(())]);
    let read = c.read(&[db(2, 1)]).await.expect("read");
    assert_eq!(read, vec![Ok(vec![0xAB & !0x08])]);
    let m = Item {
        area: Area::Merkers,
        db: 0,
        byte: 4,
        bit: None,
        length: 2,
    };
    assert_eq!(
        c.write(&[(m, vec![0xBE, 0xEF])]).await.expect("write"),
        vec![Ok(())]
    );
    assert_eq!(
        c.read(&[m]).await.expect("read"),
        vec![Ok(vec![0xBE, 0xEF])]
    );
}

#[tokio::test]
async fn the_plcs_identity_state_timers_and_counters_are_read() {
    let (_server, mut c) = connect(1, 240).await;
    assert_eq!(c.pdu, 240, "the PDU size asked is granted");
    let name = c
        .szl(szl::COMPONENT_ID, szl::MODULE_NAME)
        .await
        .expect("SZL");
    assert_eq!(
        szl::text(&name[0], szl::NAME_LEN).as_deref(),
        Some("CPU 315-2 PN/DP")
    );
    let order = c.szl(szl::MODULE_ID, 1).await.expect("SZL");
    assert_eq!(
        szl::text(&order[0], szl::ORDER_LEN).as_deref(),
        Some("6ES7 315-2EH14-0AB0")
    );
    let state = c.szl(szl::CPU_STATE, 0).await.expect("SZL");
    assert_eq!(szl::mode(&state[0]), Some(szl::Mode::Run));
    let cell = |area, byte, length| Item {
        area,
        db: 0,
        byte,
        bit: None,
        length,
    };
    // Timers and counters go by number (Snap7's server keeps timer or counter n at byte
    // n / 2 of its buffer, where a PLC has word n; its own client reads them the same).
    let read = c
        .read(&[cell(Area::Timers, 4, 2), cell(Area::Counters, 6, 1)])
        .await
        .expect("read");
    assert_eq!(read, vec![Ok(vec![0, 0, 0x21, 0x25]), Ok(vec![0x01, 0x23])]);
}

/// DBW0 of DB1.
const DB1_WORD0: Item = Item {
    area: Area::DataBlock,
    db: 1,
    byte: 0,
    bit: None,
    length: 2,
};

/// How a PLC of our own behaves.
#[derive(Clone, Copy)]
enum Fake {
    /// Refuses the COTP connection (a disconnect request).
    CotpRefused,
    /// Answers every job with this error class and code in its header.
    Refuses(u8, u8),
    /// Answers a user-data job (an SZL read) only after this long; a read with 0x1234.
    LateSzl(Duration),
    /// Answers a read of a word with this many bytes (and their length in bits), then,
    /// asked again, with the word.
    Longer(u8),
}

/// A PLC of our own that confirms the connection and the setup (a PDU of 480, one job at a
/// time), then answers as `fake` says.
async fn fake_plc(fake: Fake) -> u16 {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
        .await
        .expect("bind");
    let port = listener.local_addr().expect("addr").port();
    tokio::spawn(async move {
        let Ok((mut s, _)) = listener.accept().await else {
            return;
        };
        let mut head = [0u8; 4];
        let mut reads = 0;
        while s.read_exact(&mut head).await.is_ok() {
            let len = usize::from(u16::from_be_bytes([head[2], head[3]]));
            let mut body = vec![0u8; len.saturating_sub(4)];
            if s.read_exact(&mut body).await.is_err() {
                return;
            }
            let r = (
                body.get(7).copied().unwrap_or(0),
                body.get(8).copied().unwrap_or(0),
            );
            let answer: Vec<u8> = match (body.get(1), fake) {
                (Some(0xE0), Fake::CotpRefused) => vec![3, 0, 0, 11, 6, 0x80, 0, 1, 0, 1, 0],
                (Some(0xE0), _) => vec![3, 0, 0, 11, 6, 0xD0, 0, 1, 0, 1, 0],
                _ if body.get(13) == Some(&0xF0) => vec![
                    3, 0, 0, 27, 2, 0xF0, 0x80, 0x32, 3, 0, 0, r.0, r.1, 0, 8, 0, 0, 0, 0, 0xF0, 0,
                    0, 1, 0, 1, 1, 0xE0,
                ],
                (_, Fake::Refuses(class, code)) => vec![
                    3, 0, 0, 19, 2, 0xF0, 0x80, 0x32, 3, 0, 0, r.0, r.1, 0, 0, 0, 0, class, code,
                ],
                (_, Fake::LateSzl(after)) if body.get(4) == Some(&7) => {
                    tokio::time::sleep(after).await;
                    vec![
                        3, 0, 0, 19, 2, 0xF0, 0x80, 0x32, 3, 0, 0, r.0, r.1, 0, 0, 0, 0, 0x81, 4,
                    ]
                }
                (_, Fake::Longer(n)) if reads == 0 => {
                    reads += 1;
                    let mut a = vec![
                        3,
                        0,
                        0,
                        0,
                        2,
                        0xF0,
                        0x80,
                        0x32,
                        3,
                        0,
                        0,
                        r.0,
                        r.1,
                        0,
                        2,
                        0,
                        4 + n,
                        0,
                        0,
                        4,
                        1,
                        0xFF,
                        4,
                        0,
                        n * 8,
                    ];
                    a.extend((0..n).map(|k| 0x12 + k));
                    a[3] = a.len() as u8;
                    a
                }
                _ => vec![
                    3, 0, 0, 27, 2, 0xF0, 0x80, 0x32, 3, 0, 0, r.0, r.1, 0, 2, 0, 6, 0, 0, 4, 1,
                    0xFF, 4, 0, 16, 0x12, 0x34,
                ],
            };
            if s.write_all(&answer).await.is_err() {
                return;
            }
        }
    });
    port
}

#[tokio::test]
async fn refusals_name_what_to_change_on_the_plc() {
    let open = |port| {
        Connection::open(
            ("127.0.0.1", port),
            0x0100,
            0x0102,
            960,
            Duration::from_secs(2),
        )
    };
    // PUT/GET not allowed (an S7-1200/1500's 8104): the job's error, the connection kept.
    let mut c = open(fake_plc(Fake::Refuses(0x81, 0x04)).await)
        .await
        .expect("connected");
    assert_eq!((c.pdu, c.parallel), (480, 1));
    let item = DB1_WORD0;
    let answers = c.read_jobs(&[&[item]], || {}).await.expect("answered");
    let why = answers[0].as_ref().expect_err("refused").to_string();
    assert!(why.contains("8104") && why.contains("PUT/GET"), "{why}");
    let szl = c
        .szl(szl::CPU_STATE, 0)
        .await
        .expect_err("refused")
        .to_string();
    assert!(szl.contains("8104"), "{szl}");
    // A protection level: D602.
    let mut c = open(fake_plc(Fake::Refuses(0xD6, 0x02)).await)
        .await
        .expect("connected");
    let answers = c.read_jobs(&[&[item]], || {}).await.expect("answered");
    let why = answers[0].as_ref().expect_err("refused").to_string();
    assert!(why.contains("protection level"), "{why}");
    // The COTP connection refused: rack and slot to check.
    let e = open(fake_plc(Fake::CotpRefused).await)
        .await
        .err()
        .map(|e| e.to_string());
    assert!(
        e.as_deref()
            .is_some_and(|e| e.contains("0x0102") && e.contains("rack and slot")),
        "{e:?}"
    );
    // Nothing listening.
    let closed = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
    let port = closed.local_addr().expect("addr").port();
    drop(closed);
    let e = open(port).await.err().map(|e| e.to_string());
    assert!(
        e.as_deref().is_some_and(|e| e.contains("nothing listens")),
        "{e:?}"
    );
}

#[tokio::test]
async fn an_item_answered_longer_than_asked_fails_its_job_and_the_connection_goes_on() {
    let port = fake_plc(Fake::Longer(9)).await;
    let mut c = Connection::open(
        ("127.0.0.1", port),
        0x0100,
        0x0102,
        960,
        Duration::from_secs(2),
    )
    .await
    .expect("connected");
    let answers = c.read_jobs(&[&[DB1_WORD0]], || {}).await.expect("read");
    let why = answers[0].as_ref().expect_err("not a value").to_string();
    assert_eq!(why, "item 1 of the answer has 9 bytes for 2 asked");
    // The same connection reads the next answer, which fits.
    let answers = c.read_jobs(&[&[DB1_WORD0]], || {}).await.expect("read");
    assert_eq!(answers[0], Ok(vec![Ok(vec![0x12, 0x34])]));
}

#[test]
fn an_answer_item_of_another_size_or_length_than_asked_is_refused() {
    use super::pdu::{answer, read_items};
    let word = DB1_WORD0;
    let bit = Item {
        bit: Some(3),
        length: 1,
        ..DB1_WORD0
    };
    // The S7 header and a Read Var answer of `data` for `items` items.
    let frame = |items: u8, data: &[u8]| {
        let mut f = vec![2, 0xF0, 0x80, 0x32, 3, 0, 0, 0, 1, 0, 2];
        f.extend_from_slice(&(data.len() as u16).to_be_bytes());
        f.extend_from_slice(&[0, 0, 4, items]);
        f.extend_from_slice(data);
        f
    };
    let read = |items: &[Item], data: &[u8]| {
        let f = frame(items.len() as u8, data);
        let a = answer(&f).expect("an answer");
        read_items(&a, items).map_err(|e| e.to_string())
    };
    assert_eq!(
        read(&[word], &[0xFF, 4, 0, 16, 1, 2]),
        Ok(vec![Ok(vec![1, 2])])
    );
    assert_eq!(
        read(&[word], &[0xFF, 4, 0, 8, 1]),
        Err("item 1 of the answer has 1 bytes for 2 asked".into())
    );
    assert_eq!(
        read(&[word], &[0xFF, 3, 0, 1, 1]),
        Err("item 1 of the answer has transport size 0x03, not the one asked".into())
    );
    assert_eq!(
        read(&[bit], &[0xFF, 4, 0, 8, 1]),
        Err("item 1 of the answer has transport size 0x04, not the one asked".into())
    );
    assert_eq!(
        read(&[word], &[0xFF, 4, 0, 12, 1, 2]),
        Err("item 1 of the answer has transport size 0x04, not the one asked".into()),
        "12 bits are no whole bytes"
    );
    assert_eq!(
        read(&[word], &[0xFF, 4, 0, 16, 1, 2, 3, 4]),
        Err("the answer has 2 bytes past its last item".into())
    );
    assert_eq!(read(&[bit], &[0xFF, 3, 0, 1, 1, 0]), Ok(vec![Ok(vec![1])]));
    // Two items: the second's bytes are where the first's length says, never shifted.
    assert_eq!(
        read(&[bit, word], &[0xFF, 3, 0, 1, 1, 0, 0xFF, 4, 0, 16, 7, 8]),
        Ok(vec![Ok(vec![1]), Ok(vec![7, 8])])
    );
}

#[tokio::test]
async fn a_late_answer_to_a_job_given_up_on_is_passed_over() {
    let port = fake_plc(Fake::LateSzl(Duration::from_millis(300))).await;
    let mut c = Connection::open(
        ("127.0.0.1", port),
        0x0100,
        0x0102,
        960,
        Duration::from_millis(150),
    )
    .await
    .expect("connected");
    let silent = c.szl(szl::CPU_STATE, 0).await;
    assert!(
        matches!(silent, Err(super::conn::S7Error::Timeout(_))),
        "{silent:?}"
    );
    let item = DB1_WORD0;
    // The SZL's answer comes while this read waits: passed over, the read's own is taken.
    tokio::time::sleep(Duration::from_millis(100)).await;
    let answers = c.read_jobs(&[&[item]], || {}).await.expect("read");
    assert_eq!(answers[0], Ok(vec![Ok(vec![0x12, 0x34])]));
}

proptest::proptest! {
    /// Whatever a PLC (or something posing as one) answers, it is an answer or an error
    /// naming what is wrong, never a panic.
    #[test]
    fn any_answer_is_parsed_or_refused(
        bytes in proptest::collection::vec(proptest::num::u8::ANY, 0..300),
        user_data: bool,
        asked in 0usize..30,
    ) {
        // Mostly a plausible head (a data frame, the S7 id, an answer's kind), then anything.
        let kind = if user_data { 7 } else { 3 };
        let mut frame = vec![2, 0xF0, 0x80, 0x32, kind, 0, 0];
        frame.extend_from_slice(&bytes);
        for payload in [&bytes[..], &frame[..]] {
            if let Ok(a) = super::pdu::answer(payload) {
                let _ = super::pdu::read_items(&a, &super::pdu::fuzz_items(asked));
                let _ = super::pdu::write_items(&a, asked);
                let _ = super::pdu::granted(&a);
                if let Ok(records) = szl::records(&a) {
                    for r in &records {
                        let _ = szl::text(r, szl::NAME_LEN);
                        let _ = szl::mode(r);
                    }
                }
            }
            let _ = super::pdu::connect_confirm(payload);
        }
    }
}

proptest::proptest! {
    /// Whatever bytes an item holds, every form decodes them to a value or an error.
    #[test]
    fn any_bytes_decode_or_fail_by_every_form(
        bytes in proptest::collection::vec(proptest::num::u8::ANY, 0..40),
        n in 0u16..20,
    ) {
        crate::drivers::register();
        use crate::codec::IecType;
        use crate::drivers::s7::form::Form;
        let forms = [
            Form::Bit(7), Form::Number, Form::Char, Form::WChar, Form::String(n),
            Form::WString(n), Form::Dt, Form::Dtl, Form::Timer, Form::Counter,
        ];
        for form in forms {
            for ty in IecType::ALL {
                let _ = super::value::decode(form, ty, &bytes);
            }
        }
    }
}

#[test]
fn a_user_data_answer_of_its_bare_header_is_short_not_a_panic() {
    // Found by `any_answer_is_parsed_or_refused`: ten bytes of a user-data header and no
    // more once made the parser look at an acknowledgement's error bytes.
    let frame = [2, 0xF0, 0x80, 0x32, 7, 0, 0, 0, 1, 0, 0, 0, 0];
    let a = super::pdu::answer(&frame).expect("a header");
    assert!(a.refused.is_none());
    assert!(szl::records(&a).is_err());
}

#[test]
fn an_s7_link_is_checked_with_each_problem_at_its_line() {
    crate::drivers::register();
    let yaml = "links:\n  - name: plc\n    s7:\n      host: 10.0.0.30\n      rack: 9\n      slot: 1\n      pdu_size: 100\n      connection_type: hmi\n      remote_tsap: 0x1G\n      speed: fast\n";
    let config = crate::config::parse("c.yaml", yaml).expect("parses");
    let text = crate::drivers::check_links(&config).to_string();
    for expected in [
        "c.yaml:5: link plc: s7.rack",
        "c.yaml:7: link plc: s7.pdu_size",
        "c.yaml:8: link plc: s7.connection_type: unknown `hmi` (expected pg, op or s7)",
        "c.yaml:9: link plc: s7.remote_tsap: `0x1G` is not a number",
        "c.yaml:10: link plc: s7: unknown key `speed`",
    ] {
        assert!(text.contains(expected), "missing {expected:?} in:\n{text}");
    }
    let good = "links:\n  - name: plc\n    s7: { host: 10.0.0.30, rack: 0, slot: 2, connection_type: op }\n";
    let config = crate::config::parse("c.yaml", good).expect("parses");
    assert_eq!(crate::drivers::check_links(&config).to_string(), "");
}

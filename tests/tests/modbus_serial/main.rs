//! Modbus over serial lines against independent implementations on pseudo-terminals: the
//! gateway's Modbus server as an RTU and an ASCII slave read and written by pymodbus and
//! libmodbus's mbpoll, and an ASCII link polling a pymodbus ASCII slave. Every byte between
//! master and slave passes a sniffer that checks the frames on the line.
//!
//! A pseudo-terminal carries bytes whatever the character: the gateway's ends are set up
//! as configured (8E1, 7E1), the peers' as 8N1, since Linux refuses parity on a pty to
//! pyserial and libmodbus.

mod slave;

use std::sync::{Arc, Mutex};
use std::time::Duration;

use serde_json::{Value, json};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::time::Instant;
use tokio_serial::{SerialPort, SerialStream};

use iogate_tests::devices::{pty_at, temp_dir};
use iogate_tests::{TestGateway, eventually, repo_file, run_installer};

/// Which way bytes went.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Way {
    /// From the master(s) to the slave.
    Request,
    /// From the slave to the master(s).
    Answer,
}

/// Bytes as they crossed the line, with when.
type Seen = Arc<Mutex<Vec<(Way, Vec<u8>, Instant)>>>;

/// Joins two pty pairs' master ends, recording every chunk: the masters' side and the
/// slave's side of one line.
fn sniffer(masters: SerialStream, slave: SerialStream) -> Seen {
    let seen: Seen = Arc::default();
    let (m_read, m_write) = tokio::io::split(masters);
    let (s_read, s_write) = tokio::io::split(slave);
    pipe(m_read, s_write, seen.clone(), Way::Request);
    pipe(s_read, m_write, seen.clone(), Way::Answer);
    seen
}

/// Copies `from` to `to` until either ends, recording each chunk as going `way`.
fn pipe(
    mut from: impl AsyncRead + Unpin + Send + 'static,
    mut to: impl AsyncWrite + Unpin + Send + 'static,
    log: Seen,
    way: Way,
) {
    tokio::spawn(async move {
        let mut buf = [0u8; 1024];
        while let Ok(n) = from.read(&mut buf).await {
            if n == 0 {
                break;
            }
            record(&log, way, &buf[..n]);
            if to.write_all(&buf[..n]).await.is_err() {
                break;
            }
        }
    });
}

fn record(seen: &Seen, way: Way, bytes: &[u8]) {
    seen.lock()
        .expect("sniffer")
        .push((way, bytes.to_vec(), Instant::now()));
}

fn crc16(data: &[u8]) -> u16 {
    iogate_tests::devices::crc16(data)
}

/// The RTU answers in `bytes`, split by their own lengths, each checked: unit, CRC.
fn rtu_answers(bytes: &[u8], unit: u8) -> Vec<Vec<u8>> {
    let mut frames = Vec::new();
    let mut rest = bytes;
    while !rest.is_empty() {
        assert!(rest.len() >= 5, "a cut answer: {rest:02x?}");
        let len = match rest[1] {
            1..=4 => 5 + usize::from(rest[2]),
            5 | 6 | 15 | 16 => 8,
            f if f & 0x80 != 0 => 5,
            f => panic!("an answer of function {f:#04x}: {rest:02x?}"),
        };
        let frame = &rest[..len];
        assert_eq!(frame[0], unit, "an answer from another unit: {frame:02x?}");
        assert_eq!(
            crc16(&frame[..len - 2]).to_le_bytes(),
            [frame[len - 2], frame[len - 1]],
            "bad CRC in {frame:02x?}"
        );
        frames.push(frame.to_vec());
        rest = &rest[len..];
    }
    frames
}

/// The ASCII frames in `bytes`, each checked: `:`, hex, LRC, CR LF; their address and PDU.
fn ascii_frames(bytes: &[u8]) -> Vec<Vec<u8>> {
    let text = std::str::from_utf8(bytes).expect("ASCII frames are text");
    text.split_terminator("\r\n")
        .map(|f| {
            let hex = f.strip_prefix(':').expect("a frame starts with `:`");
            let raw: Vec<u8> = (0..hex.len())
                .step_by(2)
                .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).expect("hex"))
                .collect();
            let (lrc, body) = raw.split_last().expect("LRC");
            let sum = body.iter().fold(0u8, |s, b| s.wrapping_add(*b));
            assert_eq!(sum.wrapping_add(*lrc), 0, "bad LRC in {f}");
            body.to_vec()
        })
        .collect()
}

fn way_bytes(seen: &Seen, way: Way) -> Vec<u8> {
    seen.lock()
        .expect("sniffer")
        .iter()
        .filter(|(w, _, _)| *w == way)
        .flat_map(|(_, b, _)| b.clone())
        .collect()
}

/// A line: the masters' end (its path, and the pty held open), and the gateway's end at
/// `dir/name`, joined by a sniffer.
struct Line {
    masters_path: String,
    /// Held so that the masters' end stays while masters come and go.
    _masters_end: SerialStream,
    seen: Seen,
}

fn line(dir: &std::path::Path, name: &str) -> (Line, SerialStream) {
    let (masters_master, masters_end) = SerialStream::pair().expect("pty");
    let masters_path = masters_end.name().expect("pty name");
    let (slave_master, gateway_holder) = pty_at(&dir.join(name)).expect("pty");
    let seen = sniffer(masters_master, slave_master);
    (
        Line {
            masters_path,
            _masters_end: masters_end,
            seen,
        },
        gateway_holder,
    )
}

/// A gateway whose Modbus server answers as unit 7 (beside the simulated device `sim`) on
/// the gateway's end of a sniffed line, `ttyGW` in a directory of its own, with `settings`
/// after the port; once the port is open: the line, the held pty, the gateway and the
/// port's path.
async fn slave_gateway(
    name: &str,
    settings: &str,
) -> (Line, SerialStream, TestGateway, std::path::PathBuf) {
    let dir = temp_dir(name);
    let port = dir.join("ttyGW");
    let (line, holder) = line(&dir, "ttyGW");
    let gw = TestGateway::start(&gateway_config(&port, settings))
        .await
        .expect("gateway");
    eventually("the port open", || async {
        serial_state(&gw).await["state"] == "open"
    })
    .await
    .expect("open");
    (line, holder, gw, port)
}

/// For each answer on the line, the time since the end of the request before it (its last
/// chunk for which `ends` holds).
fn answer_gaps(seen: &Seen, ends: impl Fn(&[u8]) -> bool) -> Vec<Duration> {
    let seen = seen.lock().expect("sniffer").clone();
    let mut request_end = None;
    let mut gaps = Vec::new();
    for (way, bytes, at) in &seen {
        match way {
            Way::Request if ends(bytes) => request_end = Some(*at),
            Way::Request => {}
            Way::Answer => {
                if let Some(end) = request_end.take() {
                    gaps.push(at.duration_since(end));
                }
            }
        }
    }
    gaps
}

async fn serial_state(gw: &TestGateway) -> Value {
    let (_, map) = gw.get("/api/v1/map").await.expect("map");
    map["serial"][0].clone()
}

async fn python(script: &str, args: &[&str]) -> Value {
    let out = tokio::process::Command::new(iogate_tests::python())
        .arg(repo_file(script))
        .args(args)
        .output()
        .await
        .expect("python3");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{script}: {}\n{stdout}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_str(stdout.trim()).unwrap_or_else(|e| panic!("{e}: {stdout}"))
}

fn gateway_config(port: &std::path::Path, serial_extra: &str) -> String {
    format!(
        "devices:\n  - {{ name: sim, profile: SimIo, refresh_rate: 100ms }}\n\
         modbus_server:\n  auto: true\n  map:\n    - {{ at: \"%IX100.0\", field: sim.connected }}\n  \
         serial:\n    - {{ port: {}, unit_id: 7{serial_extra} }}\n",
        port.display()
    )
}

/// What a master got for each request, as `master.py` reports it; the same over RTU and
/// ASCII.
fn assert_master_results(got: &Value) {
    assert_eq!(got["fc16"], json!("ok"), "{got}");
    assert_eq!(got["fc03"], json!([11, 22, 33]), "{got}");
    assert_eq!(got["fc06"], json!("ok"), "{got}");
    assert_eq!(got["fc03_single"], json!([44]), "{got}");
    assert_eq!(got["fc15"], json!("ok"), "{got}");
    assert_eq!(got["fc01"], json!([true, false, true]), "{got}");
    assert_eq!(got["fc05"], json!("ok"), "{got}");
    // %IX100.0 is sim.connected.
    assert_eq!(got["fc02"], json!([true]), "{got}");
    assert!(got["fc04"].is_array(), "{got}");
    assert_eq!(got["illegal_address"], json!({"exception": 2}), "{got}");
    assert_eq!(got["illegal_function"], json!({"exception": 1}), "{got}");
    assert_eq!(got["broadcast"], json!("sent"), "{got}");
    assert!(got["other_unit"]["no_answer"].is_string(), "{got}");
    // The broadcast was applied.
    assert_eq!(got["after_broadcast"], json!([555]), "{got}");
}

/// An RTU frame: `body` and its CRC.
fn rtu(body: &[u8]) -> Vec<u8> {
    let mut frame = body.to_vec();
    frame.extend_from_slice(&crc16(body).to_le_bytes());
    frame
}

/// A deterministic stream of pseudo-random bytes (xorshift).
fn noise(seed: u64, len: usize) -> Vec<u8> {
    let mut x = seed.max(1);
    (0..len)
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 24) as u8
        })
        .collect()
}

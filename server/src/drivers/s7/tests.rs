use std::time::Duration;

use super::config::remote_tsap;
use super::conn::Connection;
use super::pdu::Item;
use super::szl;
use crate::profile::s7_address::Area;

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
    let mut child = std::process::Command::new("python3")
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
    let server = snap7().expect("python-snap7 is needed: bash tests/s7/install.sh");
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

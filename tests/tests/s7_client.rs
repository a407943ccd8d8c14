//! The S7 driver against Snap7's server (python-snap7): a gateway reading a DB's fields of
//! every size and writing them back, a bit without touching its neighbours.

use iogate_tests::TestGateway;
use iogate_tests::devices::temp_dir;
use serde_json::json;

/// Snap7's server with DB1 (64 bytes) on a free port; killed when dropped.
struct Snap7(std::process::Child, u16);

impl Drop for Snap7 {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn snap7() -> anyhow::Result<Snap7> {
    use std::io::BufRead;
    iogate_tests::run_installer("s7/install.sh")?;
    let script = r#"
import ctypes, struct, sys, socket
from snap7.server import Server
from snap7.type import SrvArea
s = socket.socket(); s.bind(("127.0.0.1", 0)); port = s.getsockname()[1]; s.close()
srv = Server(log=False)
db1 = (ctypes.c_uint8 * 64)()
data = struct.pack(">BhiqfdB", 0b10101010, -300, 100000, -(2**40), 1.5, 2.25, 200)
for i, b in enumerate(data): db1[i] = b
name = b"press"
db1[40] = 20; db1[41] = len(name)
for i, b in enumerate(name): db1[42 + i] = b
srv.register_area(SrvArea.DB, 1, db1)
srv.start(tcp_port=port)
print(port, flush=True)
while sys.stdin.read(1): pass
"#;
    let mut child = std::process::Command::new("python3")
        .args(["-c", script])
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .spawn()?;
    let out = child
        .stdout
        .take()
        .ok_or_else(|| anyhow::anyhow!("stdout"))?;
    let mut line = String::new();
    std::io::BufReader::new(out).read_line(&mut line)?;
    let port = line.trim().parse()?;
    Ok(Snap7(child, port))
}

const PROFILE: &str = r#"name: Press
protocol: s7
fields:
  - { name: Flags, type: BYTE, direction: input, address: DB1.DBB0 }
  - { name: Bit1, type: BOOL, direction: inout, address: DB1.DBX0.1 }
  - { name: Bit2, type: BOOL, direction: inout, address: DB1.DBX0.2 }
  - { name: I, type: INT, direction: inout, address: DB1.DBW1 }
  - { name: D, type: DINT, direction: inout, address: DB1.DBD3 }
  - { name: L, type: LINT, direction: inout, address: DB1.7 }
  - { name: R, type: REAL, direction: inout, address: DB1.DBD15 }
  - { name: LR, type: LREAL, direction: inout, address: DB1.19 }
  - { name: U, type: USINT, direction: inout, address: DB1.DBB27 }
  - { name: S, type: STRING, direction: inout, address: DB1.40, length: 20 }
  - { name: Missing, type: INT, direction: input, address: DB9.DBW0 }
"#;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_plcs_data_block_is_read_and_written_through_the_gateway() -> anyhow::Result<()> {
    let plc = snap7()?;
    let dir = temp_dir("s7-client");
    std::fs::create_dir_all(dir.join("profiles"))?;
    std::fs::write(dir.join("profiles/press.yaml"), PROFILE)?;
    let config = format!(
        "profiles: {}\nlinks:\n  - name: plc\n    s7: {{ host: 127.0.0.1, port: {}, rack: 0, slot: 1 }}\ndevices:\n  - {{ name: press, profile: Press, link: plc, refresh_rate: 100ms }}\n",
        dir.join("profiles").display(),
        plc.1
    );
    let gw = TestGateway::start(&config).await?;
    let device = gw
        .until("/api/v1/devices/press", "read", |d| {
            d["fields"]["S"]["quality"] == "good"
        })
        .await?;
    let f = |n: &str| device["fields"][n]["value"].clone();
    assert_eq!(f("Flags"), json!(0b10101010));
    assert_eq!((f("Bit1"), f("Bit2")), (json!(true), json!(false)));
    assert_eq!(f("I"), json!(-300));
    assert_eq!(f("D"), json!(100000));
    assert_eq!(f("L"), json!(-(1i64 << 40)));
    assert_eq!(f("R"), json!(1.5));
    assert_eq!(f("LR"), json!(2.25));
    assert_eq!(f("U"), json!(200));
    assert_eq!(f("S"), json!("press"));
    let missing = &device["fields"]["Missing"];
    assert_eq!(missing["quality"], "bad", "{missing}");
    // A bit written alone: its neighbours in the byte keep their values.
    let (_, w) = gw
        .send(
            reqwest::Method::PUT,
            "/api/v1/devices/press/fields/Bit2",
            json!({"value": true}).to_string(),
        )
        .await?;
    let generation = w["generation"].as_u64().unwrap_or_default();
    let outcome = gw
        .until(&format!("/api/v1/writes/{generation}"), "written", |w| {
            w["status"] != "pending"
        })
        .await?;
    assert_eq!(outcome["status"], "written", "{outcome}");
    gw.until("/api/v1/devices/press", "Flags with bit 2", |d| {
        d["fields"]["Flags"]["value"] == json!(0b10101110)
    })
    .await?;
    for (field, value) in [
        ("I", json!(1234)),
        ("R", json!(-2.5)),
        ("S", json!("line 2")),
    ] {
        let (_, w) = gw
            .send(
                reqwest::Method::PUT,
                &format!("/api/v1/devices/press/fields/{field}"),
                json!({"value": value}).to_string(),
            )
            .await?;
        let generation = w["generation"].as_u64().unwrap_or_default();
        let outcome = gw
            .until(&format!("/api/v1/writes/{generation}"), "written", |w| {
                w["status"] != "pending"
            })
            .await?;
        assert_eq!(outcome["status"], "written", "{field}: {outcome}");
    }
    gw.until("/api/v1/devices/press", "written values read back", |d| {
        d["fields"]["I"]["value"] == json!(1234)
            && d["fields"]["R"]["value"] == json!(-2.5)
            && d["fields"]["S"]["value"] == json!("line 2")
    })
    .await?;
    gw.shutdown().await;
    Ok(())
}

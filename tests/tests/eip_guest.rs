//! A guest on someone else's Logix (cpppo's simulator, pylogix as the other client): an
//! output another client set is not written back after a connection drop, and a session
//! given up on is closed on the controller (Forward Close, UnRegister Session), not left to
//! its timeouts.

use iogate_tests::TestGateway;
use iogate_tests::cable::Cable;
use iogate_tests::devices::temp_dir;
use iogate_tests::eip::LogixPlc;
use serde_json::{Value, json};

const PROFILE: &str = r#"name: Guest
protocol: ab-eip
fields:
  - { name: Count, type: DINT, direction: inout, tag: Count }
  - { name: Speed, type: REAL, direction: input, tag: Speed }
"#;

async fn guest(name: &str, port: u16) -> anyhow::Result<TestGateway> {
    let dir = temp_dir(name);
    std::fs::create_dir_all(dir.join("profiles"))?;
    std::fs::write(dir.join("profiles/guest.yaml"), PROFILE)?;
    TestGateway::start(&format!(
        "profiles: {}\nlinks:\n  - {{ name: plc, eip: {{ host: 127.0.0.1, port: {port}, path: \"1,0\", timeout: 1s }} }}\ndevices:\n  - {{ name: guest, profile: Guest, link: plc, refresh_rate: 50ms }}\n",
        dir.join("profiles").display()
    ))
    .await
}

fn field<'a>(device: &'a Value, name: &str) -> &'a Value {
    &device["fields"][name]
}

/// The device after `n` more read cycles than now.
async fn cycles_on(gw: &TestGateway, n: u64) -> anyhow::Result<Value> {
    let (_, now) = gw.get("/api/v1/devices/guest").await?;
    let from = now["io_cycles"].as_u64().unwrap_or_default();
    gw.until("/api/v1/devices/guest", "read cycles", |d| {
        d["io_cycles"].as_u64().unwrap_or_default() >= from + n && d["connected"] == true
    })
    .await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_tag_another_client_set_is_not_written_back_after_a_connection_drop() -> anyhow::Result<()>
{
    let plc = LogixPlc::start(None, &["Count=DINT", "Speed=REAL"]).await?;
    let cable = Cable::to(plc.port).await?;
    let gw = guest("eip-guest-rewrite", cable.port).await?;
    let d = gw
        .until("/api/v1/devices/guest", "read", |d| {
            field(d, "Count")["quality"] == "good"
        })
        .await?;
    assert_eq!(d["rewrite_outputs"], "never", "EtherNet/IP's default");
    let outcome = gw
        .write_outcome("guest", "Count", json!(5))
        .await?
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    assert_eq!(outcome["status"], "written", "{outcome}");
    // pylogix sets 99; the gateway reads it; the connection drops for a moment.
    let wrote = plc.write(&["Count=99"]).await?;
    assert_eq!(wrote["Count"], "Success", "{wrote}");
    gw.until("/api/v1/devices/guest", "99 read", |d| {
        field(d, "Count")["value"] == json!(99)
    })
    .await?;
    cable.cut();
    iogate_tests::eventually("the gateway connects again", || async {
        cable.accepted() >= 2
    })
    .await?;
    let d = cycles_on(&gw, 3).await?;
    assert_eq!(field(&d, "Count")["value"], json!(99), "{d}");
    let read = plc.read(&["Count"]).await?;
    assert_eq!(read["Count"], json!(99), "99 stays: {read}");
    assert_eq!(
        field(&d, "Count")["last_write"]["generation"],
        outcome["generation"],
        "no write of the gateway's own: {d}"
    );
    gw.shutdown().await;
    plc.kill().await
}

/// The encapsulation commands in `bytes` (messages one after another), each with its data.
fn messages(bytes: &[u8]) -> Vec<(u16, &[u8])> {
    let mut out = Vec::new();
    let mut at = 0;
    while let Some(head) = bytes.get(at..at + 24) {
        let command = u16::from_le_bytes([head[0], head[1]]);
        let len = usize::from(u16::from_le_bytes([head[2], head[3]]));
        let Some(data) = bytes.get(at + 24..at + 24 + len) else {
            break;
        };
        out.push((command, data));
        at += 24 + len;
    }
    out
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_session_given_up_on_is_closed_on_the_controller() -> anyhow::Result<()> {
    let plc = LogixPlc::start(None, &["Count=DINT", "Speed=REAL"]).await?;
    let cable = Cable::to(plc.port).await?;
    let gw = guest("eip-guest-close", cable.port).await?;
    gw.until("/api/v1/devices/guest", "read", |d| {
        field(d, "Speed")["quality"] == "good"
    })
    .await?;
    // The controller goes silent on the open connection: the gateway gives up on it and
    // opens another.
    let before = cable.sent()[0].len();
    cable.hush();
    iogate_tests::eventually("a new connection", || async { cable.accepted() >= 2 }).await?;
    cycles_on(&gw, 2).await?;
    iogate_tests::eventually("the old connection closed by the gateway", || async {
        cable.open() == 1
    })
    .await?;
    let sent = cable.sent();
    let after = messages(&sent[0][before..]);
    let commands: Vec<u16> = after.iter().map(|(c, _)| *c).collect();
    // SendRRData (0x6F) with Forward Close (0x4E to the Connection Manager, class 6
    // instance 1), then UnRegister Session (0x66).
    let forward_close = after.iter().any(|(c, data)| {
        *c == 0x6F
            && data
                .windows(6)
                .any(|w| w == [0x4E, 0x02, 0x20, 0x06, 0x24, 0x01])
    });
    assert!(forward_close, "no Forward Close: {commands:x?}");
    assert_eq!(commands.last(), Some(&0x66), "{commands:x?}");
    gw.shutdown().await;
    plc.kill().await
}

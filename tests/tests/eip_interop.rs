//! Logix controllers of other makes than the one the driver was built with, made from cpppo's
//! simulator by rewriting its answers as theirs are: one that zeroes the sender context of
//! every answer (libplctag's `ab_server` does), one that refuses List Identity, one without
//! Multiple Service Packets (ab_server, some CompactLogix and Micro800 firmware).

use iogate_tests::TestGateway;
use iogate_tests::cable::Cable;
use iogate_tests::devices::temp_dir;
use iogate_tests::eip::LogixPlc;
use serde_json::json;

const PROFILE: &str = "name: Peer\nprotocol: ab-eip\nfields:\n  - { name: N, type: DINT, direction: inout, tag: Count }\n";

async fn gateway(name: &str, port: u16) -> anyhow::Result<TestGateway> {
    let dir = temp_dir(name);
    std::fs::create_dir_all(dir.join("profiles"))?;
    std::fs::write(dir.join("profiles/peer.yaml"), PROFILE)?;
    TestGateway::start(&format!(
        "profiles: {}\nlinks:\n  - {{ name: plc, eip: {{ host: 127.0.0.1, port: {port}, path: \"1,0\", timeout: 1s }} }}\ndevices:\n  - {{ name: d, profile: Peer, link: plc, refresh_rate: 100ms }}\n",
        dir.join("profiles").display()
    ))
    .await
}

/// Every encapsulation answer with its sender context (bytes 12-19) zeroed.
fn zero_context(answer: &[u8]) -> Vec<u8> {
    let mut answer = answer.to_vec();
    if let Some(context) = answer.get_mut(12..20) {
        context.fill(0);
    }
    answer
}

/// A List Identity answer (command 0x63) turned into a refusal: status 1, "invalid or
/// unsupported command".
fn refuse_identity(answer: &[u8]) -> Vec<u8> {
    let mut answer = answer.to_vec();
    if answer.len() >= 24 && answer[..2] == [0x63, 0x00] {
        answer[8..12].copy_from_slice(&1u32.to_le_bytes());
    }
    answer
}

/// Every Multiple Service Packet answer (CIP service 0x8A, in a connected or unconnected
/// data item) turned into CIP status 0x08, "service not supported".
fn refuse_multiple(answer: &[u8]) -> Vec<u8> {
    let word = |at: usize| {
        answer
            .get(at..at + 2)
            .map(|b| u16::from_le_bytes([b[0], b[1]]))
    };
    let (Some(command), Some(count)) = (word(0), word(30)) else {
        return answer.to_vec();
    };
    if command != 0x6F && command != 0x70 {
        return answer.to_vec();
    }
    let mut out = answer[..32].to_vec();
    let mut at = 32;
    for _ in 0..count {
        let (Some(kind), Some(len)) = (word(at), word(at + 2)) else {
            return answer.to_vec();
        };
        let Some(data) = answer.get(at + 4..at + 4 + usize::from(len)) else {
            return answer.to_vec();
        };
        // A connected data item starts with its sequence count.
        let skip = if kind == 0xB1 { 2 } else { 0 };
        let mut data = data.to_vec();
        if (kind == 0xB1 || kind == 0xB2) && data.get(skip) == Some(&0x8A) {
            data.truncate(skip);
            data.extend_from_slice(&[0x8A, 0x00, 0x08, 0x00]);
        }
        out.extend_from_slice(&kind.to_le_bytes());
        out.extend_from_slice(&(data.len() as u16).to_le_bytes());
        out.extend_from_slice(&data);
        at += 4 + usize::from(len);
    }
    let length = (out.len() - 24) as u16;
    out[2..4].copy_from_slice(&length.to_le_bytes());
    out
}

/// The controller behind `cable` read and written, and the link's state.
async fn read_and_written(
    name: &str,
    cable: &Cable,
    plc: &LogixPlc,
) -> anyhow::Result<serde_json::Value> {
    let gw = gateway(name, cable.port).await?;
    gw.until("/api/v1/devices/d", "read", |d| {
        d["fields"]["N"]["quality"] == "good" && d["fields"]["N"]["value"] == json!(77)
    })
    .await?;
    let outcome = gw
        .write_outcome("d", "N", json!(5))
        .await?
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    assert_eq!(outcome["status"], "written", "{outcome}");
    let read = plc.read(&["Count"]).await?;
    assert_eq!(read["Count"], json!(5), "{read}");
    let (_, mut link) = gw.get("/api/v1/links/plc").await?;
    let plan = reqwest::get(gw.url("/api/v1/links/plc/plan"))
        .await?
        .text()
        .await?;
    link["plan"] = json!(plan);
    gw.shutdown().await;
    Ok(link)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_controller_that_zeroes_the_sender_context_is_read_and_written() -> anyhow::Result<()> {
    let plc = LogixPlc::start(None, &["Count=DINT"]).await?;
    plc.write(&["Count=77"]).await?;
    let cable = Cable::rewriting(plc.port, zero_context).await?;
    let link = read_and_written("eip-zero-context", &cable, &plc).await?;
    assert_eq!(link["connected"], true, "{link}");
    assert_eq!(cable.accepted(), 1, "one connection, never given up on");
    plc.kill().await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_controller_that_refuses_list_identity_is_read_on_without_it() -> anyhow::Result<()> {
    let plc = LogixPlc::start(None, &["Count=DINT"]).await?;
    plc.write(&["Count=77"]).await?;
    let cable = Cable::rewriting(plc.port, refuse_identity).await?;
    let link = read_and_written("eip-no-identity", &cable, &plc).await?;
    let said = link["peer"]["identity"].as_str().unwrap_or_default();
    assert!(said.starts_with("unknown"), "{link}");
    assert!(link["peer"]["product_name"].is_null(), "{link}");
    assert_eq!(cable.accepted(), 1, "{link}");
    plc.kill().await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_controller_without_multiple_service_packets_is_read_one_tag_a_request()
-> anyhow::Result<()> {
    let plc = LogixPlc::start(None, &["Count=DINT"]).await?;
    plc.write(&["Count=77"]).await?;
    let cable = Cable::rewriting(plc.port, refuse_multiple).await?;
    let link = read_and_written("eip-no-multiple", &cable, &plc).await?;
    let said = link["peer"]["multiple_service_packets"]
        .as_str()
        .unwrap_or_default();
    assert!(said.starts_with("unsupported"), "{link}");
    let plan = link["plan"].as_str().unwrap_or_default();
    assert!(
        plan.contains("multiple service packets: unsupported"),
        "{plan}"
    );
    assert_eq!(
        cable.accepted(),
        1,
        "one connection, never given up on: {link}"
    );
    plc.kill().await
}

//! What a gateway costs a PLC that opens and then fails: for a minute, each driver's peer
//! behind a cable that passes the opening handshake of every connection and closes it at
//! the first read (Modbus TCP: at the first request; S7: after COTP and Setup
//! Communication; EtherNet/IP: after Register Session and Forward Open): connections made
//! per minute, and the most open on the peer at once. Then how long an OPC UA device's values
//! take to be fresh again after the server deleted its subscription.
//!
//! `cargo bench -p iogate-tests --bench guest`

use std::time::{Duration, Instant};

use iogate_tests::TestGateway;
use iogate_tests::cable::Cable;
use iogate_tests::devices::{ModbusDevice, modbus_tcp_server, temp_dir};
use serde_json::json;

const STORM: Duration = Duration::from_secs(60);

/// A gateway with one device `d` of `profile` on a link of `link` settings.
async fn gateway(
    name: &str,
    link: &str,
    profile: &str,
    device: &str,
) -> anyhow::Result<TestGateway> {
    let dir = temp_dir(name);
    std::fs::create_dir_all(dir.join("profiles"))?;
    std::fs::write(dir.join("profiles/p.yaml"), profile)?;
    TestGateway::start(&format!(
        "profiles: {}\nlinks:\n  - {{ name: l, {link} }}\ndevices:\n  - {{ name: d, profile: P, link: l, refresh_rate: 100ms{device} }}\n",
        dir.join("profiles").display(),
    ))
    .await
}

/// Connections made in [`STORM`] and the most open at once.
async fn storm(cable: &Cable) -> (usize, usize) {
    let started = Instant::now();
    let mut most = 0;
    while started.elapsed() < STORM {
        most = most.max(cable.open());
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    (cable.accepted(), most)
}

async fn modbus() -> anyhow::Result<(usize, usize)> {
    let (port, server) = modbus_tcp_server(ModbusDevice::default()).await;
    let cable = Cable::failing_after(port, Some(0)).await?;
    let gw = gateway(
        "bench-guest-modbus",
        &format!("tcp: {{ host: 127.0.0.1, port: {} }}", cable.port),
        "name: P\nfields:\n  - { name: N, type: UINT, direction: input, register: { address: 0, kind: input_register } }\n",
        ", slave_id: 1",
    )
    .await?;
    let out = storm(&cable).await;
    gw.shutdown().await;
    server.abort();
    Ok(out)
}

async fn s7() -> anyhow::Result<(usize, usize)> {
    let plc = iogate_tests::s7::S7Plc::start(None).await?;
    let cable = Cable::failing_after(plc.port, Some(2)).await?;
    let gw = gateway(
        "bench-guest-s7",
        &format!("s7: {{ host: 127.0.0.1, port: {}, timeout: 1s }}", cable.port),
        "name: P\nprotocol: s7\nfields:\n  - { name: N, type: INT, direction: input, address: MW10 }\n",
        "",
    )
    .await?;
    let out = storm(&cable).await;
    gw.shutdown().await;
    plc.kill().await?;
    Ok(out)
}

async fn eip() -> anyhow::Result<(usize, usize)> {
    let plc = iogate_tests::eip::LogixPlc::start(None, &["Count=DINT"]).await?;
    let cable = Cable::failing_after(plc.port, Some(2)).await?;
    let gw = gateway(
        "bench-guest-eip",
        &format!(
            "eip: {{ host: 127.0.0.1, port: {}, path: \"1,0\", timeout: 1s }}",
            cable.port
        ),
        "name: P\nprotocol: ab-eip\nfields:\n  - { name: N, type: DINT, direction: input, tag: Count }\n",
        "",
    )
    .await?;
    let out = storm(&cable).await;
    gw.shutdown().await;
    plc.kill().await?;
    Ok(out)
}

/// Seconds from each of five subscription deletions to the device's next fresh value.
async fn deleted_subscriptions() -> anyhow::Result<Vec<f64>> {
    let mut plc = iogate_tests::plc::UaPlc::start(&[]).await?;
    let dir = temp_dir("bench-guest-opcua");
    let gw = gateway(
        "bench-guest-opcua",
        &format!(
            "opcua: {{ url: \"{}\", pki_dir: {} }}",
            plc.url,
            dir.join("pki").display()
        ),
        &format!(
            "name: P\nprotocol: opcua\nfields:\n  - {{ name: N, type: UDINT, direction: input, node: \"ns={};s=Line1.UDInt\" }}\n",
            plc.ns
        ),
        "",
    )
    .await?;
    gw.until("/api/v1/devices/d", "read", |d| {
        d["fields"]["N"]["quality"] == "good"
    })
    .await?;
    let mut took = Vec::new();
    for k in 0..5u64 {
        let started = Instant::now();
        plc.cmd(json!({"cmd": "drop_subscriptions"})).await?;
        plc.set("UDInt", json!(k + 1)).await?;
        gw.until("/api/v1/devices/d", "fresh", |d| {
            d["fields"]["N"]["value"] == json!(k + 1) && d["fields"]["N"]["quality"] == "good"
        })
        .await?;
        took.push(started.elapsed().as_secs_f64());
    }
    gw.shutdown().await;
    plc.kill().await?;
    Ok(took)
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() -> anyhow::Result<()> {
    let (m, s, e) = tokio::join!(modbus(), s7(), eip());
    println!(
        "A peer that opens and then fails, for {} s:",
        STORM.as_secs()
    );
    println!("| driver | connections a minute | most open at once |");
    println!("| --- | --- | --- |");
    for (name, r) in [("Modbus TCP", m), ("S7", s), ("EtherNet/IP", e)] {
        let (made, most) = r?;
        let per_minute = made as f64 * 60.0 / STORM.as_secs_f64();
        println!("| {name} | {per_minute:.0} | {most} |");
    }
    let took = deleted_subscriptions().await?;
    let text: Vec<String> = took.iter().map(|t| format!("{t:.2} s")).collect();
    println!(
        "OPC UA, a deleted subscription's values fresh again after: {}",
        text.join(", ")
    );
    Ok(())
}

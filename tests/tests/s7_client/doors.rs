//! An S7 PLC's device through the gateway's other doors, unchanged: gRPC (a value, the
//! link's PLC identity), the change stream (SSE), the Modbus TCP server's map (read, and a
//! Modbus write that reaches the PLC) and the metrics.

use super::*;
use iogate_tests::SseReader;
use iogate_tests::s7::S7Plc;
use tokio_modbus::prelude::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn grpc_sse_the_modbus_server_and_metrics_serve_an_s7_device() -> anyhow::Result<()> {
    let mut plc = S7Plc::start(None).await?;
    let more = "modbus_server:\n  listen: 127.0.0.1:0\n  auto: true\n";
    let gw = gateway_with("s7-doors", plc.port, more).await?;
    until_device(&gw, "press960", "read", |d| {
        field(d, "In")["quality"] == "good"
    })
    .await?;

    let mut grpc = gw.client().await?;
    let read = grpc.get("press960", "In").await?;
    assert_eq!(
        read.value,
        Some(iogate_client::Value::Int(-300)),
        "{read:?}"
    );
    let links = grpc.links().await?;
    let link = links
        .iter()
        .find(|l| l.name == "plc960")
        .ok_or_else(|| anyhow::anyhow!("no plc960 in {links:?}"))?;
    assert_eq!(
        link.peer.get("module").map(String::as_str),
        Some("CPU 315-2 PN/DP"),
        "{link:?}"
    );

    // The map's automatic binding of In, read and written by a Modbus master.
    let (_, map) = gw.get("/api/v1/map").await?;
    let binding = map["bindings"]
        .as_array()
        .and_then(|b| {
            b.iter()
                .find(|b| b["device"] == "press960" && b["field"] == "In")
        })
        .ok_or_else(|| anyhow::anyhow!("no binding of In in {map}"))?;
    let register = binding["address"]
        .as_u64()
        .ok_or_else(|| anyhow::anyhow!("no address in {binding}"))? as u16;
    let addr = gw
        .modbus
        .ok_or_else(|| anyhow::anyhow!("no Modbus server"))?;
    let mut master = tcp::connect_slave(addr, Slave(1)).await?;
    let words = master.read_holding_registers(register, 1).await??;
    assert_eq!(words, vec![(-300i16) as u16]);
    // The change stream tells the write's value as the PLC holds it.
    let mut events = SseReader::open(&gw, "/api/v1/events?device=press960").await?;
    master.write_single_register(register, 4321).await??;
    let told = events
        .until(|_, e| e["field"] == "In" && e["value"] == json!(4321))
        .await?;
    assert_eq!(told["device"], "press960", "{told}");
    until_device(&gw, "press960", "the Modbus write read back", |d| {
        field(d, "In")["value"] == json!(4321)
    })
    .await?;
    assert_eq!(plc.dump("DB 1", 2, 2).await?, "10e1");
    let metrics = reqwest::get(gw.url("/metrics")).await?.text().await?;
    assert!(
        metrics.lines().any(|l| l.contains("link=\"plc960\"")),
        "no metric of the link: {metrics}"
    );
    gw.shutdown().await;
    plc.kill().await
}

//! An OPC UA server's device through the gateway's other doors, unchanged: gRPC, and the
//! Modbus TCP server's map (read, and a Modbus write that reaches the OPC UA server).

use iogate_tests::devices::temp_dir;
use iogate_tests::plc::UaPlc;
use serde_json::json;
use tokio_modbus::prelude::*;

use super::{gateway_with, until_field};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn grpc_and_the_modbus_server_serve_an_opcua_device_as_any_other() -> anyhow::Result<()> {
    let dir = temp_dir("uaclient-doors");
    let mut plc = UaPlc::start(&[]).await?;
    let more = "modbus_server:\n  listen: 127.0.0.1:0\n  auto: true\n";
    let gw = gateway_with(&dir, &plc, "", more).await?;
    until_field(&gw, "I", "read", |f| f["quality"] == "good").await?;

    let mut grpc = gw.client().await?;
    let read = grpc.get("line1", "I").await?;
    assert_eq!(
        read.value,
        Some(iogate_client::Value::Int(-300)),
        "{read:?}"
    );
    let profile = grpc.profile("TestPlc").await?;
    let speed = profile
        .fields
        .iter()
        .find(|f| f.name == "Speed")
        .ok_or_else(|| anyhow::anyhow!("no Speed in {profile:?}"))?;
    assert_eq!(
        (
            speed.point.as_str(),
            speed.point_key.as_str(),
            speed.kind.as_str()
        ),
        ("2:Line1/2:Speed", "browse_path", "point")
    );
    let links = grpc.links().await?;
    assert_eq!(links[0].endpoint, format!("opcua {}", plc.url), "{links:?}");

    // The map's automatic binding puts the INT field I at %QW1 (holding register 1).
    let (_, binding) = gw.get("/api/v1/map/%25QW1").await?;
    assert_eq!(binding["field"], "I", "{binding}");
    let addr = gw
        .modbus
        .ok_or_else(|| anyhow::anyhow!("no Modbus server"))?;
    let mut master = tcp::connect_slave(addr, Slave(1)).await?;
    let words = master.read_holding_registers(1, 1).await??;
    assert_eq!(words, vec![(-300i16) as u16]);
    master.write_single_register(1, 1234).await??;
    until_field(&gw, "I", "the Modbus write read back", |f| {
        f["value"] == json!(1234)
    })
    .await?;
    assert_eq!(plc.get("Int").await?, json!(1234));
    gw.shutdown().await;
    plc.kill().await
}

//! The Modbus TCP server as SCADA uses it: tokio-modbus's TCP client as the master, the
//! gateway on loopback port 0, fields at IEC located addresses (OpenPLC's address map).

mod connections;
mod serving;

use std::net::SocketAddr;
use std::time::Duration;

use reqwest::Method;
use serde_json::json;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio_modbus::ExceptionCode;
use tokio_modbus::client::Context;
use tokio_modbus::prelude::*;

use iogate_tests::devices::{RtuBus, pty_at, temp_dir};
use iogate_tests::{TestGateway, eventually};

const SIM_MAP: &str = "\
devices:
  - { name: sim, profile: SimIo, refresh_rate: 20ms }
  - { name: plant, profile: SimPlant, refresh_rate: 20ms }
modbus_server:
  listen: 127.0.0.1:0
  map:
    - { at: \"%IX0.0\", field: sim.DI_0 }
    - { at: \"%QX2.6\", field: sim.DO_0 }
    - { at: \"%IW0\", field: plant.Pressure }
    - { at: \"%IW1\", field: plant.error_code }
    - { at: \"%QW2\", field: plant.Recipe }
    - { at: \"%MW0\", field: plant.TrimOffset }
    - { at: \"%MD0\", field: plant.BatchCount }
    - { at: \"%MD1\", field: plant.TemperatureSetpoint }
    - { at: \"%ML0\", field: plant.FlowTotal }
    - { at: \"%ML1\", field: plant.MixTime }
    - { at: \"%IX100.0\", field: sim.connected }
";

/// Waits (at most [`iogate_tests::PATIENCE`]) until `check` holds.
async fn until(what: &str, mut check: impl AsyncFnMut() -> bool) {
    let deadline = tokio::time::Instant::now() + iogate_tests::PATIENCE;
    while !check().await {
        assert!(tokio::time::Instant::now() < deadline, "timed out: {what}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

async fn master(addr: SocketAddr, unit: u8) -> Context {
    tcp::connect_slave(addr, Slave(unit))
        .await
        .expect("connect")
}

async fn simulate(gw: &TestGateway, device: &str, field: &str, value: serde_json::Value) {
    let (status, body) = gw
        .send(
            Method::PUT,
            &format!("/api/v1/devices/{device}/fields/{field}/simulate"),
            json!({ "value": value }).to_string(),
        )
        .await
        .expect("simulate");
    assert_eq!(status, 202, "{body}");
}

async fn field(gw: &TestGateway, device: &str, field: &str) -> serde_json::Value {
    gw.get(&format!("/api/v1/devices/{device}/fields/{field}"))
        .await
        .expect("field")
        .1["value"]
        .clone()
}

/// Sends raw bytes and reads what comes back before the connection closes or goes quiet.
async fn raw(stream: &mut TcpStream, bytes: &[u8]) -> Vec<u8> {
    stream.write_all(bytes).await.expect("write");
    let mut out = vec![0u8; 300];
    match tokio::time::timeout(Duration::from_secs(2), stream.read(&mut out)).await {
        Ok(Ok(n)) => out.truncate(n),
        _ => out.clear(),
    }
    out
}

/// Whether the server has closed the connection (end of stream or reset), waiting for it
/// at most [`iogate_tests::PATIENCE`].
async fn closed(stream: &mut TcpStream) -> bool {
    let mut buf = [0u8; 64];
    matches!(
        tokio::time::timeout(iogate_tests::PATIENCE, stream.read(&mut buf)).await,
        Ok(Ok(0) | Err(_))
    )
}

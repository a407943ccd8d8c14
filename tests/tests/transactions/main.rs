//! Raw transactions through the gateway (the write block of source document 002 and the
//! read block of source document 004), on a bus of slaves behind a pseudo-terminal, queued
//! in the link's task between polls.

mod deadlines_and_periods;
mod over_tcp_and_grpc;
mod raw;
mod standing;

use reqwest::Method;
use serde_json::{Value, json};

use iogate_tests::TestGateway;
use iogate_tests::devices::{Behaviour, RtuBus, pty_at, temp_dir};

struct OnBus {
    gw: TestGateway,
    _pty: tokio_serial::SerialStream,
    task: tokio::task::JoinHandle<()>,
}

async fn on_bus(name: &str, bus: &RtuBus, devices: &str) -> OnBus {
    let dir = temp_dir(name);
    let port = dir.join("ttyTX");
    let (device_end, holder) = pty_at(&port).expect("pty");
    let task = bus.serve(device_end);
    let gw = TestGateway::start(&format!(
        "links:\n  - {{ name: rs485, serial: {{ port: {}, baud: 115200 }} }}\n{devices}",
        port.display()
    ))
    .await
    .expect("gateway");
    OnBus {
        gw,
        _pty: holder,
        task,
    }
}

async fn transact(gw: &TestGateway, body: Value) -> (u16, Value) {
    gw.send(
        Method::POST,
        "/api/v1/links/rs485/transactions",
        body.to_string(),
    )
    .await
    .expect("transaction")
}

fn read_request() -> iogate_client::proto::TransactRequest {
    iogate_client::proto::TransactRequest {
        link: "rs485".into(),
        function: 3,
        slave: 1,
        address: 0,
        value_type: "SIGNED_NUMBER16".into(),
        divisor: 10,
        precision: Some(1),
        byte_order: "BigEndian".into(),
        timeout_ms: 50,
        ..Default::default()
    }
}

/// Calls `step` every 10 ms (a scan cycle) until it says done, at most 5 s.
async fn cycles(mut step: impl FnMut() -> bool) {
    let deadline = tokio::time::Instant::now() + std::time::Duration::from_secs(5);
    while !step() {
        assert!(tokio::time::Instant::now() < deadline, "timed out");
        tokio::time::sleep(std::time::Duration::from_millis(10)).await;
    }
}

/// A gateway with a Modbus TCP link to a tokio-modbus device, and an independent master
/// (tokio-modbus's client) connected to the same device to set and read its tables.
async fn with_tcp_device() -> (
    TestGateway,
    tokio_modbus::client::Context,
    tokio::task::JoinHandle<()>,
) {
    use iogate_tests::devices::{ModbusDevice, modbus_tcp_server};
    let (port, server) = modbus_tcp_server(ModbusDevice::default()).await;
    let gw = TestGateway::start(&format!(
        "links:\n  - {{ name: rs485, tcp: {{ host: 127.0.0.1, port: {port} }} }}\n"
    ))
    .await
    .expect("gateway");
    let master = tokio_modbus::client::tcp::connect_slave(
        ([127, 0, 0, 1], port).into(),
        tokio_modbus::Slave(1),
    )
    .await
    .expect("master");
    (gw, master, server)
}

/// The documented rule for FC01/02 (docs/transactions.md), written out as bytes of
/// bit strings: byte k holds coils 8k.., the last only the bits left over; the bytes are
/// ordered as register bytes, then their bits are concatenated, most significant first.
fn expected_bits(coils: &[bool], order: &str) -> u64 {
    let bytes: Vec<String> = coils
        .chunks(8)
        .map(|c| c.iter().rev().map(|&b| if b { '1' } else { '0' }).collect())
        .collect();
    let words: Vec<Vec<String>> = bytes.chunks(2).map(<[String]>::to_vec).collect();
    let ordered: Vec<String> = match order {
        "BigEndian" => bytes.clone(),
        "LittleEndian" => bytes.iter().rev().cloned().collect(),
        "SwapBytes" => words.iter().flat_map(|w| w.iter().rev().cloned()).collect(),
        _ => words.iter().rev().flatten().cloned().collect(),
    };
    u64::from_str_radix(&ordered.concat(), 2).expect("bits")
}

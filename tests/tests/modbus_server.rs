//! The Modbus TCP server as SCADA uses it: tokio-modbus's TCP client as the master, the
//! gateway on loopback port 0, fields at IEC located addresses (OpenPLC's address map).

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

#[tokio::test]
async fn every_function_and_location_kind_serves_the_cache() {
    let gw = TestGateway::start(SIM_MAP).await.expect("gateway");
    let addr = gw.modbus.expect("modbus server");
    let mut ctx = master(addr, 1).await;

    // FC02 %IX0.0 follows a simulated input; %IX100.0 (discrete input 800) shows `connected`.
    simulate(&gw, "sim", "DI_0", json!(true)).await;
    until(
        "DI_0 read over Modbus",
        async || matches!(ctx.read_discrete_inputs(0, 1).await, Ok(Ok(v)) if v == [true]),
    )
    .await;
    assert_eq!(
        ctx.read_discrete_inputs(800, 1).await.expect("io"),
        Ok(vec![true])
    );

    // FC05 on coil 22 is %QX2.6: sim.DO_0 is written through the write path.
    assert_eq!(ctx.write_single_coil(22, true).await.expect("io"), Ok(()));
    gw.until("/api/v1/devices/sim/fields/DO_0", "DO_0 written", |b| {
        b["value"] == true && b["last_write"]["status"] == "written"
    })
    .await
    .expect("written");
    assert_eq!(ctx.read_coils(22, 1).await.expect("io"), Ok(vec![true]));
    // FC15 across it and gateway memory on both sides.
    assert_eq!(
        ctx.write_multiple_coils(21, &[true, false, true])
            .await
            .expect("io"),
        Ok(())
    );
    // Reads serve the cache: the coil shows false once the device (here a simulated one)
    // has taken the write; the memory coils at once.
    until("coils 20-23", async || {
        matches!(ctx.read_coils(20, 4).await, Ok(Ok(v)) if v == [false, true, false, true])
    })
    .await;
    gw.until("/api/v1/devices/sim/fields/DO_0", "DO_0 false", |b| {
        b["value"] == false
    })
    .await
    .expect("false");

    // FC04: %IW0 is an INT, served as its 16-bit two's complement; %IW1 a diagnostic; an
    // unbound input register reads 0.
    simulate(&gw, "plant", "Pressure", json!(-5)).await;
    until(
        "Pressure over Modbus",
        async || matches!(ctx.read_input_registers(0, 3).await, Ok(Ok(v)) if v == [0xFFFB, 0, 0]),
    )
    .await;

    // FC06 and FC16 into %QW2, %MD1 (REAL), %ML1 (TIME); read back with FC03.
    assert_eq!(ctx.write_single_register(2, 7).await.expect("io"), Ok(()));
    let real = 21.5f32.to_bits();
    assert_eq!(
        ctx.write_multiple_registers(2050, &[(real >> 16) as u16, real as u16])
            .await
            .expect("io"),
        Ok(())
    );
    let ms = 90_000u64.to_be_bytes();
    let time: Vec<u16> = ms
        .chunks(2)
        .map(|p| u16::from_be_bytes([p[0], p[1]]))
        .collect();
    assert_eq!(
        ctx.write_multiple_registers(4100, &time).await.expect("io"),
        Ok(())
    );
    gw.until("/api/v1/devices/plant", "outputs written", |b| {
        b["fields"]["Recipe"]["value"] == 7
            && b["fields"]["TemperatureSetpoint"]["value"] == 21.5
            && b["fields"]["MixTime"]["value"] == 90_000
    })
    .await
    .expect("written");
    assert_eq!(
        ctx.read_holding_registers(2050, 2).await.expect("io"),
        Ok(vec![(real >> 16) as u16, real as u16])
    );
    assert_eq!(
        ctx.read_holding_registers(4100, 4).await.expect("io"),
        Ok(time.clone())
    );

    // %MD0 (DINT input): read as two registers, high word first; writing it is refused.
    simulate(&gw, "plant", "BatchCount", json!(-70_000)).await;
    let want = (-70_000i32) as u32;
    until("BatchCount", async || {
        matches!(ctx.read_holding_registers(2048, 2).await, Ok(Ok(v)) if v == [(want >> 16) as u16, want as u16])
    })
    .await;
    assert_eq!(
        ctx.write_multiple_registers(2048, &[0, 1])
            .await
            .expect("io"),
        Err(ExceptionCode::IllegalDataAddress),
        "an input is not written"
    );
    // Half of a 32-bit field: refused, nothing written.
    assert_eq!(
        ctx.write_single_register(2050, 0).await.expect("io"),
        Err(ExceptionCode::IllegalDataAddress)
    );
    assert_eq!(
        field(&gw, "plant", "TemperatureSetpoint").await,
        json!(21.5)
    );

    // Out of range for the field: exception 03, nothing written.
    assert_eq!(
        ctx.write_single_register(2, 300).await.expect("io"),
        Err(ExceptionCode::IllegalDataValue)
    );
    // All or nothing across a field (%MW0, SINT) and memory (%MW1, %MW2).
    assert_eq!(
        ctx.write_multiple_registers(1024, &[5, 7, 8])
            .await
            .expect("io"),
        Ok(())
    );
    assert_eq!(
        ctx.write_multiple_registers(1024, &[500, 9, 9])
            .await
            .expect("io"),
        Err(ExceptionCode::IllegalDataValue)
    );
    gw.until(
        "/api/v1/devices/plant/fields/TrimOffset",
        "TrimOffset",
        |b| b["value"] == 5,
    )
    .await
    .expect("trim");
    assert_eq!(
        ctx.read_holding_registers(1024, 3).await.expect("io"),
        Ok(vec![5, 7, 8]),
        "the refused write changed nothing, memory included"
    );
    // Recipe still holds 7.
    assert_eq!(field(&gw, "plant", "Recipe").await, json!(7));

    // Addresses outside the space: exception 02. Units 0 and 255 are this server too;
    // another unit that is not forwarded gets 0x0A.
    assert_eq!(
        ctx.read_holding_registers(8190, 4).await.expect("io"),
        Err(ExceptionCode::IllegalDataAddress)
    );
    assert_eq!(
        ctx.read_coils(1599, 2).await.expect("io"),
        Err(ExceptionCode::IllegalDataAddress)
    );
    for unit in [0, 255] {
        let mut c = master(addr, unit).await;
        assert_eq!(c.read_coils(22, 1).await.expect("io"), Ok(vec![false]));
    }
    let mut other = master(addr, 9).await;
    assert_eq!(
        other.read_coils(0, 1).await.expect("io"),
        Err(ExceptionCode::GatewayPathUnavailable)
    );

    // The map over REST.
    let (status, map) = gw.get("/api/v1/map").await.expect("map");
    assert_eq!(status, 200);
    let coil = map["bindings"]
        .as_array()
        .expect("bindings")
        .iter()
        .find(|b| b["at"] == "%QX2.6")
        .expect("%QX2.6 listed")
        .clone();
    assert_eq!(
        coil,
        json!({"at": "%QX2.6", "table": "coil", "address": 22, "device": "sim", "field": "DO_0", "type": "BOOL", "access": "rw", "auto": false})
    );
    // Located addresses are accepted wherever device.field is.
    let (status, value) = gw.get("/api/v1/map/%25MD1").await.expect("located");
    assert_eq!(status, 200, "{value}");
    assert_eq!(value["value"], 21.5);
    let metrics = gw.metrics().await.expect("metrics");
    assert!(
        metrics.contains("iogate_modbus_server_requests_total{function=\"fc05\",outcome=\"ok\"}"),
        "{metrics}"
    );
    assert!(metrics.contains("iogate_modbus_server_exceptions_total{code=\"03\"}"));
    gw.shutdown().await;
}

#[tokio::test]
async fn read_only_refuses_every_write_and_quality_can_answer_0x0b() {
    let config = "\
devices:
  - { name: sim, profile: SimIo, refresh_rate: 20ms }
links:
  - { name: plc, tcp: { host: 127.0.0.1, port: 9 } }
modbus_server:
  listen: 127.0.0.1:0
  read_only: true
  on_bad_quality: exception
  map:
    - { at: \"%QX0.0\", field: sim.DO_0 }
";
    let gw = TestGateway::start(config).await.expect("gateway");
    let mut ctx = master(gw.modbus.expect("server"), 1).await;
    assert_eq!(
        ctx.write_single_coil(0, true).await.expect("io"),
        Err(ExceptionCode::IllegalFunction)
    );
    assert_eq!(
        ctx.write_single_register(1500, 1).await.expect("io"),
        Err(ExceptionCode::IllegalFunction)
    );
    until("DO_0 served", async || {
        matches!(ctx.read_coils(0, 1).await, Ok(Ok(_)))
    })
    .await;
    gw.shutdown().await;

    // A field that was never read answers 0x0B under `on_bad_quality: exception`.
    let dir = temp_dir("mbs-quality");
    let port = dir.join("ttyQ");
    let bus = RtuBus::default(); // no slaves: nobody answers
    let (device_end, _holder) = pty_at(&port).expect("pty");
    let task = bus.serve(device_end);
    let gw = TestGateway::start(&format!(
        "links:\n  - {{ name: bus, serial: {{ port: {}, baud: 115200 }} }}\ndevices:\n  - {{ name: rack, profile: MyIoModule, link: bus, slave_id: 1, timeout: 20ms }}\nmodbus_server:\n  listen: 127.0.0.1:0\n  on_bad_quality: exception\n  auto: true\n",
        port.display()
    ))
    .await
    .expect("gateway");
    let mut ctx = master(gw.modbus.expect("server"), 1).await;
    assert_eq!(
        ctx.read_discrete_inputs(0, 1).await.expect("io"),
        Err(ExceptionCode::GatewayTargetDevice)
    );
    gw.shutdown().await;
    task.abort();
}

#[tokio::test]
async fn gateway_memory_is_kept_across_a_restart() {
    let dir = temp_dir("mbs-memory");
    let file = dir.join("memory.json");
    let config = format!(
        "modbus_server:\n  listen: 127.0.0.1:0\n  memory_file: {}\n",
        file.display()
    );
    let gw = TestGateway::start(&config).await.expect("gateway");
    let mut ctx = master(gw.modbus.expect("server"), 1).await;
    assert_eq!(
        ctx.write_multiple_registers(2048, &[0x1234, 0x5678])
            .await
            .expect("io"),
        Ok(())
    );
    assert_eq!(ctx.write_single_coil(801, true).await.expect("io"), Ok(()));
    let (_, memory) = gw.get("/api/v1/memory").await.expect("memory");
    assert_eq!(memory["registers"]["%MD0"], 0x1234_5678);
    assert_eq!(memory["coils"]["%QX100.1"], true);
    gw.shutdown().await;

    let gw = TestGateway::start(&config).await.expect("again");
    let mut ctx = master(gw.modbus.expect("server"), 1).await;
    assert_eq!(
        ctx.read_holding_registers(2048, 2).await.expect("io"),
        Ok(vec![0x1234, 0x5678])
    );
    assert_eq!(ctx.read_coils(801, 1).await.expect("io"), Ok(vec![true]));
    gw.shutdown().await;
}

#[tokio::test]
async fn writes_reach_a_device_and_foreign_units_pass_through_to_the_line() {
    let bus = RtuBus::default();
    bus.slave(1, |_| {});
    bus.slave(2, |s| s.tables.holding[5] = 4242);
    let dir = temp_dir("mbs-forward");
    let port = dir.join("ttyF");
    let (device_end, _holder) = pty_at(&port).expect("pty");
    let task = bus.serve(device_end);
    let gw = TestGateway::start(&format!(
        "links:\n  - {{ name: rs485, serial: {{ port: {}, baud: 115200 }} }}\ndevices:\n  - {{ name: rack, profile: MyIoModule, link: rs485, slave_id: 1, refresh_rate: 50ms, timeout: 50ms }}\nmodbus_server:\n  listen: 127.0.0.1:0\n  auto: true\n  forward:\n    - {{ unit_ids: \"2-9\", link: rs485 }}\n",
        port.display()
    ))
    .await
    .expect("gateway");
    let addr = gw.modbus.expect("server");

    // MyIoModule's first coil output is the first %QX auto binds: coil 0.
    let (_, map) = gw.get("/api/v1/map").await.expect("map");
    let first_coil = map["bindings"]
        .as_array()
        .expect("bindings")
        .iter()
        .find(|b| b["table"] == "coil")
        .expect("a coil")
        .clone();
    assert_eq!(first_coil["at"], "%QX0.0", "{map}");
    let mut ctx = master(addr, 1).await;
    assert_eq!(ctx.write_single_coil(0, true).await.expect("io"), Ok(()));
    eventually("the coil reached the device", || async {
        bus.read_slave(1, |s| s.tables.coils[0]) == Some(true)
    })
    .await
    .expect("on the bus");

    // Unit 2 is forwarded as it is, between polls.
    let mut forwarded = master(addr, 2).await;
    assert_eq!(
        forwarded.read_holding_registers(5, 1).await.expect("io"),
        Ok(vec![4242])
    );
    assert_eq!(
        forwarded.write_single_register(6, 77).await.expect("io"),
        Ok(())
    );
    assert_eq!(bus.read_slave(2, |s| s.tables.holding[6]), Some(77));
    // Unit 3 is silent: 0x0B. Unit 12 is not forwarded: 0x0A.
    let mut silent = master(addr, 3).await;
    assert_eq!(
        silent.read_holding_registers(0, 1).await.expect("io"),
        Err(ExceptionCode::GatewayTargetDevice)
    );
    let mut unknown = master(addr, 12).await;
    assert_eq!(
        unknown.read_holding_registers(0, 1).await.expect("io"),
        Err(ExceptionCode::GatewayPathUnavailable)
    );
    // Polling went on meanwhile.
    let (_, rack) = gw.get("/api/v1/devices/rack").await.expect("rack");
    assert_eq!(rack["connected"], true, "{rack}");
    gw.shutdown().await;
    task.abort();
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

#[tokio::test]
async fn malformed_frames_close_only_their_connection() {
    let gw = TestGateway::start(
        "devices:\n  - { name: sim, profile: SimIo }\nmodbus_server:\n  listen: 127.0.0.1:0\n  max_connections: 2\n  auto: true\n",
    )
    .await
    .expect("gateway");
    let addr = gw.modbus.expect("server");
    let mut good = TcpStream::connect(addr).await.expect("connect");
    // Two pipelined requests, answered in order with their transaction ids.
    let mut both = Vec::new();
    both.extend_from_slice(&[0, 1, 0, 0, 0, 6, 1, 3, 0, 0, 0, 1]);
    both.extend_from_slice(&[0, 2, 0, 0, 0, 6, 1, 1, 0, 0, 0, 1]);
    good.write_all(&both).await.expect("write");
    let mut answers = [0u8; 11 + 10];
    good.read_exact(&mut answers).await.expect("both answers");
    assert_eq!(&answers[..2], &[0, 1]);
    assert_eq!(answers[7], 3);
    assert_eq!(&answers[11..13], &[0, 2]);
    assert_eq!(answers[18], 1);
    // An unknown function: exception 01; a quantity out of bounds: 03.
    assert_eq!(
        raw(&mut good, &[0, 3, 0, 0, 0, 2, 1, 0x2B]).await,
        [0, 3, 0, 0, 0, 3, 1, 0xAB, 1]
    );
    assert_eq!(
        raw(&mut good, &[0, 4, 0, 0, 0, 6, 1, 3, 0, 0, 0, 126]).await,
        [0, 4, 0, 0, 0, 3, 1, 0x83, 3]
    );

    // Protocol id 1: that connection is closed; a length of 300 likewise.
    let mut bad = TcpStream::connect(addr).await.expect("connect");
    assert!(
        raw(&mut bad, &[0, 5, 0, 1, 0, 6, 1, 3, 0, 0, 0, 1])
            .await
            .is_empty()
    );
    let mut bad = TcpStream::connect(addr).await.expect("connect");
    assert!(raw(&mut bad, &[0, 6, 0, 0, 1, 44, 1, 3]).await.is_empty());
    // Function codes no request has: 0x83 (an exception answer's) and 0.
    for code in [0x83, 0x80, 0xFF, 0] {
        let mut bad = TcpStream::connect(addr).await.expect("connect");
        assert!(
            raw(&mut bad, &[0, 6, 0, 0, 0, 6, 1, code, 0, 0, 0, 1])
                .await
                .is_empty(),
            "{code:#04x}"
        );
    }
    // The good one goes on.
    assert_eq!(
        raw(&mut good, &[0, 7, 0, 0, 0, 6, 1, 1, 0, 0, 0, 1])
            .await
            .len(),
        10
    );

    gw.shutdown().await;
}

#[tokio::test]
async fn a_new_master_closes_the_connection_idle_longest_and_is_served_at_once() {
    let gw = TestGateway::start(
        "devices:\n  - { name: sim, profile: SimIo }\nmodbus_server:\n  listen: 127.0.0.1:0\n  max_connections: 3\n  auto: true\n",
    )
    .await
    .expect("gateway");
    let addr = gw.modbus.expect("server");
    let request = |id: u8| [0, id, 0, 0, 0, 6, 1, 1, 0, 0, 0, 1];
    // Three slots: a master that polls, one that was served once and went quiet, and a
    // socket that never sent a byte (a slow loris), all within the idle timeout (60 s).
    let mut active = TcpStream::connect(addr).await.expect("connect");
    assert_eq!(raw(&mut active, &request(1)).await.len(), 10);
    let mut quiet = TcpStream::connect(addr).await.expect("connect");
    assert_eq!(raw(&mut quiet, &request(2)).await.len(), 10);
    let mut loris = TcpStream::connect(addr).await.expect("connect");
    loris.write_all(&[0, 3, 0]).await.expect("half a header");
    assert_eq!(raw(&mut active, &request(4)).await.len(), 10);
    // A fresh master is served at once: the socket that never sent a request goes first.
    let mut fresh = TcpStream::connect(addr).await.expect("connect");
    assert_eq!(raw(&mut fresh, &request(5)).await.len(), 10);
    assert!(closed(&mut loris).await, "the slow loris is closed");
    // The next one closes the quiet master, never the one that polls.
    assert_eq!(raw(&mut active, &request(6)).await.len(), 10);
    assert_eq!(raw(&mut fresh, &request(7)).await.len(), 10);
    let mut next = TcpStream::connect(addr).await.expect("connect");
    assert_eq!(raw(&mut next, &request(8)).await.len(), 10);
    assert!(closed(&mut quiet).await, "the quiet master is closed");
    assert_eq!(raw(&mut active, &request(9)).await.len(), 10);
    let metrics = gw.metrics().await.expect("metrics");
    assert!(
        metrics.contains("iogate_modbus_server_evicted_connections_total 2"),
        "{metrics}"
    );
    assert!(
        metrics.contains("iogate_modbus_server_refused_connections_total 0"),
        "{metrics}"
    );
    gw.shutdown().await;
}

#[tokio::test]
async fn a_master_that_never_reads_its_answers_loses_its_connection() {
    let gw = TestGateway::start(
        "devices:\n  - { name: sim, profile: SimIo }\nmodbus_server:\n  listen: 127.0.0.1:0\n  idle_timeout: 1s\n  auto: true\n",
    )
    .await
    .expect("gateway");
    let addr = gw.modbus.expect("server");
    let mut greedy = TcpStream::connect(addr).await.expect("connect");
    // FC03 x125 pipelined without reading an answer (each answer 259 bytes), until the
    // socket buffers are full both ways and the gateway's write waits for this master.
    let mut requests = Vec::new();
    for id in 0..1000u16 {
        let [hi, lo] = id.to_be_bytes();
        requests.extend_from_slice(&[hi, lo, 0, 0, 0, 6, 1, 3, 0, 0, 0, 125]);
    }
    let sent = async {
        loop {
            if greedy.write_all(&requests).await.is_err() {
                return;
            }
        }
    };
    // Its writes fail once the gateway has closed the connection (the answer it could not
    // hand over within the write timeout); before, the connection stayed for ever.
    tokio::time::timeout(Duration::from_secs(30), sent)
        .await
        .expect("the gateway closed the connection of a master that does not read");
    eventually("the connection gone", || async {
        gw.metrics()
            .await
            .is_ok_and(|m| m.contains("iogate_modbus_server_connections 0\n"))
    })
    .await
    .expect("no connection left");
    gw.shutdown().await;
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

#[test]
fn invalid_located_addresses_are_config_errors_with_their_reasons() {
    let config = "\
devices:
  - { name: sim, profile: SimIo }
  - { name: plant, profile: SimPlant }
modbus_server:
  listen: 127.0.0.1:0
  map:
    - { at: \"%IX0.8\", field: sim.DI_0 }
    - { at: \"%QX0.0.1\", field: sim.DO_0 }
    - { at: \"%IB1.1\", field: sim.DI_0 }
    - { at: \"%IB1\", field: sim.DI_0 }
    - { at: \"%MD0\", field: sim.DI_0 }
    - { at: \"%IW0\", field: plant.BatchName }
    - { at: \"%QX1.0\", field: sim.DI_0 }
    - { at: \"%MW1024\", field: plant.Pressure }
    - { at: \"%IW5\", field: plant.Pressure }
    - { at: \"%IW5\", field: plant.SpeedRpm }
";
    let mut parsed = iogate::config::parse("c.yaml", config);
    let problems = match &mut parsed {
        Err(p) => p.to_string(),
        Ok(c) => {
            c.profiles = Some(iogate_tests::profiles_dir());
            match iogate::app::Setup::from_config(c.clone(), std::path::Path::new(".")) {
                Err(p) => p.to_string(),
                Ok(_) => String::from("no problems"),
            }
        }
    };
    for needle in [
        "c.yaml:7: modbus_server.map[0].at: `%IX0.8`: the least significant index is greater than 7",
        "c.yaml:8: modbus_server.map[1].at: `%QX0.0.1`: three part hierarchy is not permitted",
        "c.yaml:9: modbus_server.map[2].at: `%IB1.1`: two part hierarchy is only permitted for X data size",
    ] {
        assert!(
            problems.contains(needle),
            "missing {needle:?} in\n{problems}"
        );
    }
    // The map is checked once the addresses parse.
    let config = config
        .lines()
        .filter(|l| !l.contains("%IX0.8") && !l.contains("%QX0.0.1") && !l.contains("%IB1.1"))
        .collect::<Vec<_>>()
        .join("\n");
    let mut c = iogate::config::parse("c.yaml", &config).expect("parses");
    c.profiles = Some(iogate_tests::profiles_dir());
    let problems = iogate::app::Setup::from_config(c, std::path::Path::new("."))
        .expect_err("bad map")
        .to_string();
    for needle in [
        "%IB1 has no Modbus address in the linux address space",
        "a BOOL does not fit %MD0",
        "a STRING does not fit %IW0",
        "%QX1.0 is an output location that masters write",
        "%MW1024 is past the end of the linux address space",
        "%IW5: overlaps %IW5",
    ] {
        assert!(
            problems.contains(needle),
            "missing {needle:?} in\n{problems}"
        );
    }
}

#[tokio::test]
async fn grpc_and_the_client_accept_located_addresses() {
    let gw = TestGateway::start(SIM_MAP).await.expect("gateway");
    let mut client = gw.client().await.expect("client");
    let generation = client
        .write("", "%QW2", iogate_client::Value::UInt(9))
        .await
        .expect("write by location");
    let status = client
        .wait_write(generation, Duration::from_secs(5))
        .await
        .expect("outcome");
    assert_eq!(status.field, "Recipe");
    assert_eq!(status.outcome, iogate_client::WriteOutcome::Written);
    let value = client.get("", "%QW2").await.expect("read by location");
    assert_eq!(
        (value.device.as_str(), value.field.as_str()),
        ("plant", "Recipe")
    );
    let unbound = client.get("", "%QW900").await;
    assert!(
        matches!(&unbound, Err(iogate_client::Error::Status { code, message }) if *code == tonic::Code::NotFound && message.contains("no field is bound to %QW900")),
        "{unbound:?}"
    );
    let invalid = client.get("", "%QX0.8").await;
    assert!(
        matches!(&invalid, Err(iogate_client::Error::Status { code, message }) if *code == tonic::Code::InvalidArgument && message.contains("the least significant index is greater than 7")),
        "{invalid:?}"
    );
    let at: iogate_client::Location = "%QX2.6".parse().expect("the client parses locations");
    assert_eq!(at.bit_number(), Some(22));
    gw.shutdown().await;
}

#[tokio::test]
async fn an_idle_master_is_closed_after_idle_timeout() {
    let gw = TestGateway::start("modbus_server:\n  listen: 127.0.0.1:0\n  idle_timeout: 200ms\n")
        .await
        .expect("gateway");
    let mut idle = TcpStream::connect(gw.modbus.expect("server"))
        .await
        .expect("connect");
    let started = std::time::Instant::now();
    let mut buf = [0u8; 8];
    let read = tokio::time::timeout(Duration::from_secs(5), idle.read(&mut buf))
        .await
        .expect("closed by the server, not by this test's patience");
    assert!(matches!(read, Ok(0)), "{read:?}");
    assert!(started.elapsed() >= Duration::from_millis(150));
    gw.shutdown().await;
}

#[tokio::test]
async fn a_time_that_does_not_fit_its_double_word_is_an_exception_not_a_clamped_number() {
    let gw = TestGateway::start(
        "devices:\n  - { name: plant, profile: SimPlant, refresh_rate: 20ms }\n\
         modbus_server:\n  listen: 127.0.0.1:0\n  map:\n    - { at: \"%MD3\", field: plant.MixTime }\n",
    )
    .await
    .expect("gateway");
    let mut ctx = master(gw.modbus.expect("modbus server"), 1).await;
    // T#24d20h31m23s647ms fits: 0x7FFFFFFF.
    let (status, body) = gw
        .send(
            Method::PUT,
            "/api/v1/devices/plant/fields/MixTime",
            json!({"value": 2_147_483_647i64}).to_string(),
        )
        .await
        .expect("write");
    assert_eq!(status, 202, "{body}");
    until("the largest TIME a double word holds", async || {
        matches!(ctx.read_holding_registers(2054, 2).await, Ok(Ok(v)) if v == [0x7FFF, 0xFFFF])
    })
    .await;
    // T#30d does not: exception 0B, never 2147483647.
    gw.send(
        Method::PUT,
        "/api/v1/devices/plant/fields/MixTime",
        json!({"value": "T#30d"}).to_string(),
    )
    .await
    .expect("write");
    until("T#30d refused", async || {
        matches!(
            ctx.read_holding_registers(2054, 2).await,
            Ok(Err(ExceptionCode::GatewayTargetDevice))
        )
    })
    .await;
    gw.shutdown().await;
}

#[tokio::test]
async fn masters_forwarding_to_a_slow_slave_never_get_each_others_registers() {
    // A slave answering 300 ms late (the forward's timeout is 200 ms): its late answer to one
    // master's read must never be taken as the answer to the other master's read.
    let bus = RtuBus::default();
    bus.slave(2, |s| {
        s.behaviour = iogate_tests::devices::Behaviour::Slow(Duration::from_millis(300));
        s.tables.holding[0] = 1000;
        s.tables.holding[500] = 5000;
    });
    let dir = temp_dir("mbs-slow-forward");
    let port = dir.join("ttySLOW");
    let (device_end, _holder) = pty_at(&port).expect("pty");
    let task = bus.serve(device_end);
    let gw = TestGateway::start(&format!(
        "links:\n  - {{ name: rs485, serial: {{ port: {}, baud: 115200 }} }}\nmodbus_server:\n  listen: 127.0.0.1:0\n  forward:\n    - {{ unit_ids: \"2\", link: rs485 }}\n",
        port.display()
    ))
    .await
    .expect("gateway");
    let addr = gw.modbus.expect("modbus server");
    let reader = |address: u16, value: u16| async move {
        let mut ctx = master(addr, 2).await;
        let mut wrong = 0;
        let mut answered = 0;
        for _ in 0..4 {
            match ctx.read_holding_registers(address, 1).await {
                Ok(Ok(v)) if v == [value] => answered += 1,
                Ok(Ok(_)) => wrong += 1,
                Ok(Err(_)) | Err(_) => {}
            }
        }
        (wrong, answered)
    };
    let (a, b) = tokio::join!(reader(0, 1000), reader(500, 5000));
    assert_eq!(
        (a.0, b.0),
        (0, 0),
        "answers taken for another read: {a:?} {b:?}"
    );
    gw.shutdown().await;
    task.abort();
}

#[tokio::test]
async fn a_flood_of_forwarded_writes_gets_busy_answers_and_never_starves_polling() {
    // A slave answering writes after 120 ms, forwarded to by 12 masters at once, on a line
    // that also polls a device every 10 ms.
    let bus = RtuBus::default();
    bus.slave(1, |_| {});
    bus.slave(2, |s| {
        s.behaviour = iogate_tests::devices::Behaviour::Slow(Duration::from_millis(120));
    });
    let dir = temp_dir("mbs-flood");
    let port = dir.join("ttyFLOOD");
    let (device_end, _holder) = pty_at(&port).expect("pty");
    let task = bus.serve(device_end);
    let gw = TestGateway::start(&format!(
        "links:\n  - {{ name: rs485, serial: {{ port: {}, baud: 115200 }} }}\ndevices:\n  - {{ name: io, profile: MyIoModule, link: rs485, slave_id: 1, refresh_rate: 10ms }}\nmodbus_server:\n  listen: 127.0.0.1:0\n  forward:\n    - {{ unit_ids: \"2\", link: rs485 }}\n",
        port.display()
    ))
    .await
    .expect("gateway");
    gw.until("/api/v1/devices/io", "polled", |b| b["connected"] == true)
        .await
        .expect("polled");
    let cycles = |b: &serde_json::Value| b["io_cycles"].as_u64().unwrap_or(0);
    let before = cycles(&gw.get("/api/v1/devices/io").await.expect("io").1);
    let addr = gw.modbus.expect("modbus server");
    let masters = (0..12u16).map(|m| async move {
        let mut ctx = master(addr, 2).await;
        let mut answers = Vec::new();
        for k in 0..4u16 {
            let value = 1000 * (m + 1) + k;
            let answer =
                tokio::time::timeout(Duration::from_secs(10), ctx.write_single_register(m, value))
                    .await
                    .expect("the gateway answers");
            answers.push((value, answer.expect("io")));
        }
        answers
    });
    let answers: Vec<(u16, Result<(), ExceptionCode>)> = futures_util::future::join_all(masters)
        .await
        .into_iter()
        .flatten()
        .collect();
    let after = cycles(&gw.get("/api/v1/devices/io").await.expect("io").1);
    let executed: Vec<u16> = bus
        .seen()
        .into_iter()
        .filter(|s| s.slave == 2 && s.function == 6)
        .filter_map(|s| s.value)
        .collect();
    let busy = answers
        .iter()
        .filter(|(_, a)| *a == Err(ExceptionCode::ServerDeviceBusy))
        .count();
    assert!(busy > 0, "the inbox filled up: {answers:?}");
    for (value, answer) in &answers {
        match answer {
            Ok(()) => assert!(
                executed.contains(value),
                "{value} answered OK but not written"
            ),
            Err(_) => assert!(
                !executed.contains(value),
                "{value} answered {answer:?} but written"
            ),
        }
    }
    // At most one forwarded request between two poll cycles while polls are due.
    let polled = after - before;
    eprintln!(
        "{} writes: {} OK, {busy} busy, {} executed; {polled} poll cycles meanwhile",
        answers.len(),
        answers.iter().filter(|(_, a)| a.is_ok()).count(),
        executed.len()
    );
    assert!(
        polled as usize >= executed.len() / 2,
        "{polled} poll cycles for {} forwarded writes",
        executed.len()
    );
    let metrics = gw.metrics().await.expect("metrics");
    assert!(
        metrics.contains("iogate_link_inbox_dropped_total{link=\"rs485\",reason=\"busy\"}"),
        "{metrics}"
    );
    assert!(
        metrics.contains("iogate_link_inbox_requests{link=\"rs485\"} 0"),
        "{metrics}"
    );
    gw.shutdown().await;
    task.abort();
}

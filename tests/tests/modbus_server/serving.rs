use super::*;

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
    // The address bound (the config asked for port 0).
    assert_eq!(map["listen"], addr.to_string());
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

use super::*;

#[tokio::test]
async fn every_type_and_byte_order_reads_as_the_device_holds_it() {
    // (type, extra register options, value bytes, expected JSON)
    let cases: Vec<(&str, &str, Vec<u8>, Value)> = vec![
        ("SINT", "", (-5i16).to_be_bytes().to_vec(), json!(-5)),
        ("USINT", "", 200u16.to_be_bytes().to_vec(), json!(200)),
        ("BYTE", "", 0xA5u16.to_be_bytes().to_vec(), json!(0xA5)),
        ("INT", "", (-12345i16).to_be_bytes().to_vec(), json!(-12345)),
        ("UINT", "", 54321u16.to_be_bytes().to_vec(), json!(54321)),
        ("WORD", "", 0xBEEFu16.to_be_bytes().to_vec(), json!(0xBEEF)),
        (
            "DINT",
            ", word_count: 2",
            (-123_456_789i32).to_be_bytes().to_vec(),
            json!(-123_456_789),
        ),
        (
            "UDINT",
            ", word_count: 2",
            3_000_000_000u32.to_be_bytes().to_vec(),
            json!(3_000_000_000u32),
        ),
        (
            "DWORD",
            ", word_count: 2",
            0xDEAD_BEEFu32.to_be_bytes().to_vec(),
            json!(0xDEAD_BEEFu32),
        ),
        (
            "LINT",
            ", word_count: 4",
            (-1_234_567_890_123_456_789i64).to_be_bytes().to_vec(),
            json!(-1_234_567_890_123_456_789i64),
        ),
        (
            "ULINT",
            ", word_count: 4",
            12_345_678_901_234_567_890u64.to_be_bytes().to_vec(),
            json!(12_345_678_901_234_567_890u64),
        ),
        (
            "LWORD",
            ", word_count: 4",
            0x0123_4567_89AB_CDEFu64.to_be_bytes().to_vec(),
            json!(0x0123_4567_89AB_CDEFu64),
        ),
        (
            "REAL",
            ", word_count: 2",
            230.5f32.to_be_bytes().to_vec(),
            json!(230.5),
        ),
        (
            "LREAL",
            ", word_count: 4",
            1.0e100f64.to_be_bytes().to_vec(),
            json!(1.0e100),
        ),
        (
            "REAL",
            ", scale: 0.1, offset: -40",
            450i16.to_be_bytes().to_vec(),
            json!(5.0),
        ),
        (
            "LREAL",
            ", raw_type: UDINT, scale: 0.01",
            123_456_789u32.to_be_bytes().to_vec(),
            json!(1_234_567.89),
        ),
        (
            "TIME",
            ", word_count: 4",
            90_500i64.to_be_bytes().to_vec(),
            json!(90_500),
        ),
        // With no word_count every type takes one register (the default is 1): wider
        // types read it widened, sign-extended when signed.
        ("DINT", "", (-1234i16).to_be_bytes().to_vec(), json!(-1234)),
        ("UDINT", "", 0xFFFEu16.to_be_bytes().to_vec(), json!(0xFFFE)),
        ("DWORD", "", 0x8001u16.to_be_bytes().to_vec(), json!(0x8001)),
        ("LINT", "", (-2i16).to_be_bytes().to_vec(), json!(-2)),
        ("ULINT", "", 40_000u16.to_be_bytes().to_vec(), json!(40_000)),
        ("LWORD", "", 0xABCDu16.to_be_bytes().to_vec(), json!(0xABCD)),
        ("TIME", "", (-500i16).to_be_bytes().to_vec(), json!(-500)),
        (
            "TIME",
            ", word_count: 1",
            30_000i16.to_be_bytes().to_vec(),
            json!(30_000),
        ),
        (
            "TIME",
            ", word_count: 2",
            86_400_000i32.to_be_bytes().to_vec(),
            json!(86_400_000),
        ),
        (
            "STRING",
            ", word_count: 4",
            b"HELLO W\0".to_vec(),
            json!("HELLO W"),
        ),
    ];
    let device = ModbusDevice::default();
    let mut profile = String::from("name: AllTypes\nfields:\n");
    let mut expected = Vec::new();
    let mut address = 0u16;
    // Outputs of the same types and orders in holding registers from 100, written later.
    let mut out_address = 100u16;
    let mut outputs = serde_json::Map::new();
    let mut written: Vec<(String, u16, Vec<u16>)> = Vec::new();
    {
        let mut tables = device.tables.lock().expect("tables");
        for (i, (ty, extra, bytes, value)) in cases.iter().enumerate() {
            for order in ORDERS {
                let name = format!("F{i}_{}", order.replace('-', "_"));
                profile.push_str(&format!(
                    "  - {{ name: {name}, type: {ty}, direction: input, register: {{ address: {address}, kind: input_register, byte_order: {order}{extra} }} }}\n"
                ));
                for (k, r) in registers(order, bytes).into_iter().enumerate() {
                    tables.input[usize::from(address) + k] = r;
                }
                address += (bytes.len() / 2) as u16;
                expected.push((name, value.clone()));
                let out = format!("O{i}_{}", order.replace('-', "_"));
                profile.push_str(&format!(
                    "  - {{ name: {out}, type: {ty}, direction: output, register: {{ address: {out_address}, kind: holding_register, byte_order: {order}{extra} }} }}\n"
                ));
                outputs.insert(out.clone(), value.clone());
                written.push((out, out_address, registers(order, bytes)));
                out_address += (bytes.len() / 2) as u16;
            }
        }
        tables.coils[3] = true;
        tables.discrete[5] = true;
        tables.input[900] = 0b1000;
        tables.holding[7] = 2;
    }
    profile.push_str("  - { name: Coil3, type: BOOL, direction: output, register: { address: 3, kind: coil } }\n");
    profile.push_str("  - { name: Di5, type: BOOL, direction: input, register: { address: 5, kind: discrete_input } }\n");
    profile.push_str("  - { name: Bit3, type: BOOL, direction: input, register: { address: 900, kind: input_register, bit: 3 } }\n");
    profile.push_str("  - { name: Bit2, type: BOOL, direction: input, register: { address: 900, kind: input_register, bit: 2 } }\n");
    profile.push_str("  - { name: Flag, type: BOOL, direction: input, register: { address: 7, kind: holding_register } }\n");
    for (name, value) in [
        ("Coil3", true),
        ("Di5", true),
        ("Bit3", true),
        ("Bit2", false),
        ("Flag", true),
    ] {
        expected.push((name.to_owned(), json!(value)));
    }

    let dir = temp_dir("all-types");
    std::fs::create_dir_all(dir.join("profiles")).expect("dir");
    std::fs::write(dir.join("profiles/all_types.yaml"), &profile).expect("profile");
    let port = dir.join("ttyBUS");
    let (device_end, _holder) = pty_at(&port).expect("pty");
    let server = tokio::spawn(
        tokio_modbus::server::rtu::Server::new(device_end).serve_forever(device.clone()),
    );
    let gw = TestGateway::start(&format!(
        "profiles: {}\n{}devices:\n  - {{ name: dev, profile: AllTypes, link: bus, slave_id: 1, refresh_rate: 50ms }}\n",
        dir.join("profiles").display(),
        link_yaml(&port)
    ))
    .await
    .expect("gateway");
    let body = gw.all_read("dev").await.expect("values");
    for (name, value) in &expected {
        let got = &body["fields"][name]["value"];
        let same = match (got.as_f64(), value.as_f64()) {
            (Some(a), Some(b)) if got.is_f64() || value.is_f64() => (a - b).abs() <= b.abs() * 1e-9,
            _ => got == value,
        };
        assert!(same, "{name}: got {got}, expected {value}");
    }
    assert_eq!(body["connected"], true);
    assert_eq!(body["error_code"], 0);

    // Every type and order written in one PATCH lands as the same registers.
    let (status, body) = gw
        .send(
            Method::PATCH,
            "/api/v1/devices/dev/fields",
            Value::Object(outputs).to_string(),
        )
        .await
        .expect("patch");
    assert_eq!(status, 202, "{body}");
    let generations: Vec<u64> = body["writes"]
        .as_array()
        .expect("writes")
        .iter()
        .filter_map(|w| w["generation"].as_u64())
        .collect();
    assert_eq!(generations.len(), written.len());
    for g in generations {
        gw.until(&format!("/api/v1/writes/{g}"), "written", |b| {
            b["status"] == "written"
        })
        .await
        .expect("written");
    }
    let tables = device.tables.lock().expect("tables").clone();
    for (name, address, regs) in &written {
        let start = usize::from(*address);
        assert_eq!(
            &tables.holding[start..start + regs.len()],
            regs.as_slice(),
            "{name}"
        );
    }
    gw.shutdown().await;
    server.abort();
}

/// A gateway on a fresh bus; `devices` is the YAML list of devices.
/// What `bus_gateway` starts: the gateway, the holder of the pty's gateway end, the bus task
/// and the port path.
#[tokio::test]
async fn a_cycle_is_the_minimal_number_of_batched_transactions() {
    let bus = RtuBus::default();
    bus.slave(1, |_| {});
    let (gw, _pty, task, _) = bus_gateway(
        "minimal",
        &bus,
        &[],
        "  - { name: io, profile: MyIoModule, link: bus, slave_id: 1, refresh_rate: 20ms }\n",
    )
    .await;
    gw.until("/api/v1/devices/io", "three cycles", |b| {
        b["io_cycles"].as_u64() >= Some(3)
    })
    .await
    .expect("cycles");
    bus.clear_seen();
    gw.until("/api/v1/devices/io", "more cycles", |b| {
        b["io_cycles"].as_u64() >= Some(8)
    })
    .await
    .expect("cycles");
    let seen = bus.seen();
    let mut distinct: Vec<(u8, u16, u16)> = seen
        .iter()
        .map(|s| (s.function, s.address, s.count))
        .collect();
    distinct.sort();
    distinct.dedup();
    // 8 discrete inputs, 8 coils, 4 input registers, 2 holding registers: one read each.
    assert_eq!(distinct, vec![(1, 0, 8), (2, 0, 8), (3, 0, 2), (4, 0, 4)]);
    gw.shutdown().await;
    task.abort();
}

#[tokio::test]
async fn a_burst_of_writes_becomes_a_few_bus_writes_and_the_last_value_lands() {
    // The bus answers at 9600-baud speed, as a real line would.
    let bus = RtuBus::at_baud(9600);
    bus.slave(1, |_| {});
    let (gw, _pty, task, _) = bus_gateway(
        "burst",
        &bus,
        &[],
        "  - { name: io, profile: MyIoModule, link: bus, slave_id: 1, refresh_rate: 200ms }\n",
    )
    .await;
    gw.until("/api/v1/devices/io", "connected", |b| {
        b["connected"] == true
    })
    .await
    .expect("connected");
    // 100 writes at once, as a burst from several clients; the newest is the one with the
    // highest generation.
    let puts = (0..100u32).map(|i| {
        let gw = &gw;
        async move {
            let value = f64::from(i) * 0.01;
            let (status, body) = gw
                .send(
                    Method::PUT,
                    "/api/v1/devices/io/fields/AO_0",
                    json!({ "value": value }).to_string(),
                )
                .await
                .expect("put");
            assert_eq!(status, 202, "{body}");
            (body["generation"].as_u64().expect("generation"), i)
        }
    });
    let mut accepted = futures_util::future::join_all(puts).await;
    accepted.sort();
    let (last, newest) = *accepted.last().expect("100 writes");
    gw.until(&format!("/api/v1/writes/{last}"), "last write", |b| {
        b["status"] == "written"
    })
    .await
    .expect("written");
    let value = bus.read_slave(1, |s| s.tables.holding[0]).expect("slave");
    assert_eq!(
        u32::from(value),
        newest * 10,
        "the newest value, at 0.001 V per count"
    );
    for (generation, _) in &accepted {
        let (_, body) = gw
            .get(&format!("/api/v1/writes/{generation}"))
            .await
            .expect("get");
        assert!(
            body["status"] == "written" || body["status"] == "superseded",
            "write {generation}: {body}"
        );
    }
    let writes = bus
        .seen()
        .iter()
        .filter(|s| s.function == 6 || s.function == 16)
        .count();
    println!("100 writes to one field became {writes} bus writes");
    assert!(writes <= 5, "{writes} bus writes for 100 requests");
    gw.shutdown().await;
    task.abort();
}

#[tokio::test]
async fn a_device_without_fc15_and_fc16_gets_single_writes() {
    let bus = RtuBus::default();
    bus.slave(1, |s| s.single_writes_only = true);
    let (gw, _pty, task, _) = bus_gateway(
        "single-writes",
        &bus,
        &[],
        "  - { name: io, profile: MyIoModule, link: bus, slave_id: 1, refresh_rate: 50ms }\n",
    )
    .await;
    gw.until("/api/v1/devices/io", "connected", |b| {
        b["connected"] == true
    })
    .await
    .expect("connected");
    let patch = |body: &'static str| {
        let gw = &gw;
        async move {
            let (status, answer) = gw
                .send(Method::PATCH, "/api/v1/devices/io/fields", body)
                .await
                .expect("patch");
            assert_eq!(status, 202, "{answer}");
            let last = answer["writes"]
                .as_array()
                .and_then(|w| w.iter().filter_map(|x| x["generation"].as_u64()).max())
                .expect("generations");
            for w in answer["writes"].as_array().expect("writes") {
                let g = w["generation"].as_u64().expect("generation");
                gw.until(&format!("/api/v1/writes/{g}"), "written", |b| {
                    b["status"] == "written"
                })
                .await
                .expect("every write lands");
            }
            last
        }
    };
    patch(r#"{"DO_0": true, "DO_1": true, "DO_2": true, "AO_0": 1.5, "AO_1": 2.5}"#).await;
    let tables = bus.read_slave(1, |s| s.tables.clone()).expect("slave");
    assert_eq!(&tables.coils[..3], &[true, true, true]);
    assert_eq!(&tables.holding[..2], &[1500, 2500]);
    let seen = bus.seen();
    let count = |f: u8| seen.iter().filter(|s| s.function == f).count();
    assert_eq!((count(15), count(16)), (1, 1), "each refused once");
    assert_eq!((count(5), count(6)), (3, 2), "then written one by one");

    // The device's limits are remembered: no more FC15/FC16.
    bus.clear_seen();
    patch(r#"{"DO_3": true, "DO_4": true}"#).await;
    let seen = bus.seen();
    assert!(
        seen.iter().all(|s| s.function != 15 && s.function != 16),
        "{seen:?}"
    );
    assert_eq!(seen.iter().filter(|s| s.function == 5).count(), 2);
    gw.shutdown().await;
    task.abort();
}

use super::*;

#[tokio::test]
async fn the_write_blocks_example_is_the_documented_frame_and_its_echo() {
    let bus = RtuBus::default();
    bus.slave(17, |_| {});
    let on = on_bus("tx-write", &bus, "").await;
    let (status, answer) = transact(
        &on.gw,
        json!({"function": 6, "slave": 17, "address": 1, "type": "uint8",
               "byte_order": "Big-endian", "values": [3], "timeout_ms": 100}),
    )
    .await;
    assert_eq!(status, 200, "{answer}");
    assert_eq!(answer["request"], "11 06 00 01 00 03 9A 9B");
    assert_eq!(answer["response"], "11 06 00 01 00 03 9A 9B");
    assert_eq!(
        (&answer["actual"], &answer["state"]),
        (&json!(true), &json!(4))
    );
    assert_eq!(answer["error"], Value::Null);
    assert!(answer["elapsed_ms"].as_f64().is_some_and(|ms| ms > 0.0));
    assert_eq!(bus.read_slave(17, |s| s.tables.holding[1]), Some(3));

    // int32 values with FC16, in the three documented byte orders of 0x01020304.
    for (order, registers) in [
        ("Big-endian", [0x0102, 0x0304]),
        ("Little-endian", [0x0403, 0x0201]),
        ("Big-endian (2 bytes)", [0x0201, 0x0403]),
    ] {
        let (status, answer) = transact(
            &on.gw,
            json!({"function": 16, "slave": 17, "address": 10, "type": "int32",
                   "byte_order": order, "values": [0x0102_0304], "timeout_ms": 100}),
        )
        .await;
        assert_eq!((status, &answer["actual"]), (200, &json!(true)), "{answer}");
        assert_eq!(
            bus.read_slave(17, |s| [s.tables.holding[10], s.tables.holding[11]]),
            Some(registers),
            "{order}"
        );
    }
    // A real number as int32/float is IEEE-754; coils with FC15.
    transact(
        &on.gw,
        json!({"function": 16, "slave": 17, "address": 20, "type": "float",
               "byte_order": "BigEndian", "values": [12.6, -1], "timeout_ms": 100}),
    )
    .await;
    let f = 12.6f32.to_bits();
    let m = (-1.0f32).to_bits();
    assert_eq!(
        bus.read_slave(17, |s| s.tables.holding[20..24].to_vec()),
        Some(vec![(f >> 16) as u16, f as u16, (m >> 16) as u16, m as u16])
    );
    let (_, answer) = transact(
        &on.gw,
        json!({"function": 15, "slave": 17, "address": 3, "values": [true, false, 1], "timeout_ms": 100}),
    )
    .await;
    assert_eq!(answer["state"], 4, "{answer}");
    assert_eq!(
        bus.read_slave(17, |s| s.tables.coils[3..6].to_vec()),
        Some(vec![true, false, true])
    );
    on.gw.shutdown().await;
    on.task.abort();
}

#[tokio::test]
async fn the_read_blocks_examples_hold_and_failures_are_named() {
    let bus = RtuBus::default();
    bus.slave(1, |s| {
        for (i, on) in [true, false, true, true].into_iter().enumerate() {
            s.tables.coils[i] = on;
        }
        s.tables.holding[0] = 215;
        let bits = 23.987f32.to_bits();
        s.tables.input[4] = (bits >> 16) as u16;
        s.tables.input[5] = bits as u16;
        s.tables.input[8] = 0x0100; // 1 in little-endian bytes
    });
    bus.slave(2, |s| s.behaviour = Behaviour::Exception(2));
    let on = on_bus("tx-read", &bus, "").await;
    let cases = [
        (
            json!({"function": 1, "slave": 1, "address": 0, "bit_count": 4, "timeout_ms": 100}),
            json!(13.0),
        ),
        (
            json!({"function": 3, "slave": 1, "address": 0, "value_type": "SIGNED_NUMBER16",
                "divisor": 10, "precision": 1, "byte_order": "BigEndian", "timeout_ms": 100}),
            json!(21.5),
        ),
        (
            json!({"function": 4, "slave": 1, "address": 4, "value_type": "FLOAT",
                "divisor": 1, "precision": 2, "byte_order": "BigEndian", "timeout_ms": 100}),
            json!(23.98),
        ),
        (
            json!({"function": 4, "slave": 1, "address": 8, "value_type": "UNSIGNED_NUMBER16",
                "byte_order": "LittleEndian", "timeout_ms": 100}),
            json!(1.0),
        ),
    ];
    for (body, value) in cases {
        let (status, answer) = transact(&on.gw, body.clone()).await;
        assert_eq!(status, 200, "{answer}");
        assert_eq!(answer["value"], value, "{body}: {answer}");
        assert_eq!(
            (&answer["actual"], &answer["state"]),
            (&json!(true), &json!(4))
        );
    }

    // A silent slave: -2, "Slave timeout", no response frame.
    let (status, answer) = transact(
        &on.gw,
        json!({"function": 3, "slave": 9, "address": 0, "value_type": "UNSIGNED_NUMBER16",
               "byte_order": "BigEndian", "timeout_ms": 50}),
    )
    .await;
    assert_eq!(
        status, 200,
        "a transaction that ran and failed is still 200"
    );
    assert_eq!(
        (
            &answer["actual"],
            &answer["state"],
            &answer["error"],
            &answer["response"]
        ),
        (
            &json!(false),
            &json!(-2),
            &json!("Slave timeout"),
            &Value::Null
        )
    );
    // An exception: its message and the exception frame.
    let (_, answer) = transact(
        &on.gw,
        json!({"function": 3, "slave": 2, "address": 0, "value_type": "UNSIGNED_NUMBER16",
               "byte_order": "BigEndian", "timeout_ms": 100}),
    )
    .await;
    assert_eq!(answer["error"], "Invalid address", "{answer}");
    assert_eq!(answer["state"], -3);
    assert!(
        answer["response"]
            .as_str()
            .is_some_and(|r| r.starts_with("02 83 02")),
        "{answer}"
    );
    on.gw.shutdown().await;
    on.task.abort();
}

#[tokio::test]
async fn parameters_are_refused_with_every_message_before_anything_is_sent() {
    let bus = RtuBus::default();
    bus.slave(1, |_| {});
    let on = on_bus("tx-params", &bus, "").await;
    let (status, answer) = transact(
        &on.gw,
        json!({"function": 3, "slave": 0, "address": 70000, "value_type": "DOUBLE",
               "divisor": 0, "precision": 4, "timeout_ms": 5}),
    )
    .await;
    assert_eq!(status, 400, "{answer}");
    let message = answer["error"]["message"].as_str().expect("message");
    for expected in [
        "Invalid device address configuration.",
        "Invalid register address configuration.",
        "Invalid value type configuration.",
        "Invalid divisor configuration.",
        "Invalid precision configuration.",
        "Invalid endianess configuration.",
        "Invalid response timeout configuration.",
    ] {
        assert!(
            message.contains(expected),
            "missing {expected:?} in {message}"
        );
    }
    let (status, answer) = transact(&on.gw, json!({"function": 7, "slave": 1, "address": 0})).await;
    assert_eq!(status, 400);
    assert!(
        answer["error"]["message"]
            .as_str()
            .is_some_and(|m| m.contains("Invalid function code configuration.")),
        "{answer}"
    );
    let (status, answer) = transact(
        &on.gw,
        json!({"function": 1, "slave": 1, "address": 0, "bit_count": 12}),
    )
    .await;
    assert_eq!(status, 400);
    assert!(
        answer["error"]["message"]
            .as_str()
            .is_some_and(|m| m.contains("Invalid endianess configuration.")),
        "more than one byte needs a byte order: {answer}"
    );
    let (status, answer) = on
        .gw
        .send(
            Method::POST,
            "/api/v1/links/rs232/transactions",
            json!({"function": 3, "slave": 1, "address": 0, "value_type": "FLOAT", "byte_order": "BigEndian"}).to_string(),
        )
        .await
        .expect("post");
    assert_eq!(status, 404, "the link is what is missing: {answer}");
    assert_eq!(answer["error"]["code"], "unknown_link");
    assert_eq!(answer["error"]["message"], "Missing RS485 configuration.");
    assert!(bus.seen().is_empty(), "nothing was sent: {:?}", bus.seen());
    on.gw.shutdown().await;
    on.task.abort();
}

#[tokio::test]
async fn a_link_without_its_port_answers_in_the_read_blocks_words() {
    let dir = iogate_tests::devices::temp_dir("tx-no-port");
    let gw = TestGateway::start(&format!(
        "links:\n  - {{ name: rs485, serial: {{ port: {}, baud: 19200 }} }}\n",
        dir.join("ttyGONE").display()
    ))
    .await
    .expect("gateway");
    let (status, answer) = transact(
        &gw,
        json!({"function": 3, "slave": 1, "address": 0, "value_type": "UNSIGNED_NUMBER16",
               "byte_order": "BigEndian"}),
    )
    .await;
    assert_eq!(status, 200, "{answer}");
    assert_eq!(answer["state"], -1, "{answer}");
    assert_eq!(answer["error"], "RS485 port missing.", "{answer}");
    gw.shutdown().await;
}

#[tokio::test]
async fn a_transaction_queued_while_the_line_is_polled_never_collides() {
    let bus = RtuBus::default();
    bus.slave(1, |s| s.counter = Some(0));
    bus.slave(5, |s| s.tables.holding[10] = 77);
    let on = on_bus(
        "tx-busy",
        &bus,
        "devices:\n  - { name: rack, profile: WaveshareAnalogInput, link: rs485, slave_id: 1, refresh_rate: 1ms }\n",
    )
    .await;
    on.gw
        .until("/api/v1/devices/rack", "polling", |b| {
            b["connected"] == true
        })
        .await
        .expect("polled");
    for _ in 0..20 {
        let (status, answer) = transact(
            &on.gw,
            json!({"function": 3, "slave": 5, "address": 10, "value_type": "UNSIGNED_NUMBER16",
                   "byte_order": "BigEndian", "timeout_ms": 200}),
        )
        .await;
        assert_eq!(status, 200);
        assert_eq!(answer["value"], 77.0, "{answer}");
    }
    let (_, rack) = on.gw.get("/api/v1/devices/rack").await.expect("rack");
    assert_eq!(rack["connected"], true, "polling went on: {rack}");
    assert_eq!(rack["error_code"], 0);
    on.gw.shutdown().await;
    on.task.abort();
}

#[tokio::test]
async fn grpc_transact_answers_the_same_way() {
    let bus = RtuBus::default();
    bus.slave(17, |s| s.tables.holding[0] = 215);
    let on = on_bus("tx-grpc", &bus, "").await;
    let mut client = on.gw.client().await.expect("client");
    let base = iogate_client::proto::TransactRequest {
        link: "rs485".into(),
        slave: 17,
        timeout_ms: 100,
        ..Default::default()
    };
    let write = client
        .transact(iogate_client::proto::TransactRequest {
            function: 6,
            address: 1,
            r#type: "uint8".into(),
            byte_order: "Big-endian".into(),
            values: vec![3.0],
            ..base.clone()
        })
        .await
        .expect("write");
    assert_eq!(write.request, "11 06 00 01 00 03 9A 9B");
    assert_eq!(write.response.as_deref(), Some("11 06 00 01 00 03 9A 9B"));
    assert!(write.actual);
    let read = client
        .transact(iogate_client::proto::TransactRequest {
            function: 3,
            value_type: "SIGNED_NUMBER16".into(),
            divisor: 10,
            precision: Some(1),
            byte_order: "BigEndian".into(),
            ..base.clone()
        })
        .await
        .expect("read");
    assert_eq!((read.value, read.state), (Some(21.5), 4));
    let refused = client
        .transact(iogate_client::proto::TransactRequest {
            function: 3,
            link: "nope".into(),
            ..base
        })
        .await;
    assert!(
        matches!(&refused, Err(iogate_client::Error::Status { code, message }) if *code == tonic::Code::InvalidArgument && message.contains("Invalid value type configuration.") && message.contains("Missing RS485 configuration.")),
        "{refused:?}"
    );
    on.gw.shutdown().await;
    on.task.abort();
}

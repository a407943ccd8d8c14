//! Raw transactions through the gateway (the write block of source document 002 and the
//! read block of source document 004), on a bus of slaves behind a pseudo-terminal, queued
//! in the link's task between polls.

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

#[tokio::test]
async fn standing_reads_and_writes_repeat_and_can_be_switched_and_triggered() {
    let bus = RtuBus::default();
    bus.slave(1, |s| s.tables.holding[0] = 215);
    bus.slave(17, |_| {});
    let on = on_bus(
        "tx-standing",
        &bus,
        "transactions:\n  - { name: temp, link: rs485, function: 3, slave: 1, address: 0, value_type: SIGNED_NUMBER16, divisor: 10, precision: 1, byte_order: BigEndian, timeout_ms: 100, refresh_interval: 50ms }\n  - { name: setpoint, link: rs485, function: 6, slave: 17, address: 1, type: uint16, byte_order: Big-endian, values: [7], timeout_ms: 100, polling_period: 50ms, enabled: false }\n",
    )
    .await;
    let gw = &on.gw;
    let temp = gw
        .until("/api/v1/transactions/temp", "temp read", |b| {
            b["value"] == 21.5 && b["runs"].as_u64().is_some_and(|r| r >= 3)
        })
        .await
        .expect("standing read");
    assert_eq!((&temp["actual"], &temp["state"]), (&json!(true), &json!(4)));
    assert_eq!(temp["kind"], "read");
    assert!(temp["timestamp"].is_string());
    // Streamed with the other changes.
    let mut events = iogate_tests::SseReader::open(gw, "/api/v1/events")
        .await
        .expect("events");
    let streamed = events
        .until(|name, data| name == "transaction" && data["name"] == "temp")
        .await
        .expect("a transaction event");
    assert_eq!(streamed["value"], 21.5);

    // A disabled write sends nothing until enabled, then its current values.
    let (_, setpoint) = gw.get("/api/v1/transactions/setpoint").await.expect("get");
    assert_eq!(
        (&setpoint["enabled"], &setpoint["runs"], &setpoint["state"]),
        (&json!(false), &json!(0), &json!(0))
    );
    let (status, _) = gw
        .send(Method::POST, "/api/v1/transactions/setpoint/enable", "")
        .await
        .expect("enable");
    assert_eq!(status, 200);
    gw.until("/api/v1/transactions/setpoint", "written", |b| {
        b["state"] == 4
    })
    .await
    .expect("written");
    assert_eq!(bus.read_slave(17, |s| s.tables.holding[1]), Some(7));
    let (status, _) = gw
        .send(
            Method::PUT,
            "/api/v1/transactions/setpoint/values",
            json!({"values": [9]}).to_string(),
        )
        .await
        .expect("values");
    assert_eq!(status, 200);
    iogate_tests::eventually("new value re-sent", || async {
        bus.read_slave(17, |s| s.tables.holding[1]) == Some(9)
    })
    .await
    .expect("re-sent");
    let (status, refused) = gw
        .send(
            Method::PUT,
            "/api/v1/transactions/setpoint/values",
            json!({"values": [70000]}).to_string(),
        )
        .await
        .expect("values");
    assert_eq!(status, 400, "{refused}");

    // Disabled: the runs stop.
    gw.send(Method::POST, "/api/v1/transactions/temp/disable", "")
        .await
        .expect("disable");
    let (_, before) = gw.get("/api/v1/transactions/temp").await.expect("get");
    tokio::time::sleep(std::time::Duration::from_millis(200)).await;
    let (_, after) = gw.get("/api/v1/transactions/temp").await.expect("get");
    assert!(
        after["runs"].as_u64() <= before["runs"].as_u64().map(|r| r + 1),
        "{before} {after}"
    );
    // A trigger of a disabled transaction would run nothing: refused, said why.
    let (status, refused) = gw
        .send(Method::POST, "/api/v1/transactions/temp/trigger", "")
        .await
        .expect("trigger");
    assert_eq!(status, 409, "{refused}");
    assert_eq!(
        refused["error"]["code"], "transaction_disabled",
        "{refused}"
    );

    // Declared at run time with no period: runs only when triggered, never by itself; a
    // declared cyclic read first runs about 2 s after its declaration (source document 004).
    let declared_at = std::time::Instant::now();
    let (status, declared) = gw
        .send(
            Method::PUT,
            "/api/v1/transactions/once",
            json!({"link": "rs485", "function": 3, "slave": 1, "address": 0, "value_type": "UNSIGNED_NUMBER16",
                   "byte_order": "BigEndian", "timeout_ms": 100}).to_string(),
        )
        .await
        .expect("declare");
    assert_eq!(status, 200, "{declared}");
    let (_, again) = gw
        .send(
            Method::PUT,
            "/api/v1/transactions/once",
            json!({"link": "rs485", "function": 3, "slave": 1, "address": 0, "value_type": "UNSIGNED_NUMBER16",
                   "byte_order": "BigEndian", "timeout_ms": 100}).to_string(),
        )
        .await
        .expect("again");
    assert_eq!(again["name"], "once", "idempotent");
    let (status, _) = gw
        .send(
            Method::PUT,
            "/api/v1/transactions/cyclic",
            json!({"link": "rs485", "function": 3, "slave": 1, "address": 0, "value_type": "UNSIGNED_NUMBER16",
                   "byte_order": "BigEndian", "timeout_ms": 100, "refresh_interval_ms": 50}).to_string(),
        )
        .await
        .expect("declare");
    assert_eq!(status, 200);
    gw.until("/api/v1/transactions/cyclic", "first cyclic read", |b| {
        b["runs"] == 1
    })
    .await
    .expect("a first cyclic read");
    let first = declared_at.elapsed();
    assert!(
        first >= std::time::Duration::from_millis(1900),
        "first read after {first:?}"
    );
    let (_, once) = gw.get("/api/v1/transactions/once").await.expect("get");
    assert_eq!(once["runs"], 0, "period 0 never runs by itself: {once}");
    gw.send(Method::POST, "/api/v1/transactions/once/trigger", "")
        .await
        .expect("trigger");
    gw.until("/api/v1/transactions/once", "triggered", |b| b["runs"] == 1)
        .await
        .expect("triggered");

    // A failed read keeps its last good value (the block's output 1) and says the error
    // beside it.
    bus.slave(1, |s| s.behaviour = Behaviour::Silent);
    let failed = gw
        .until("/api/v1/transactions/cyclic", "a failed read", |b| {
            b["actual"] == false
        })
        .await
        .expect("failed");
    assert_eq!(
        (&failed["value"], &failed["error"], &failed["state"]),
        (&json!(215.0), &json!("Slave timeout"), &json!(-2)),
        "{failed}"
    );
    bus.slave(1, |s| s.behaviour = Behaviour::Normal);
    let (_, list) = gw.get("/api/v1/transactions").await.expect("list");
    assert_eq!(list["transactions"].as_array().map(Vec::len), Some(4));
    let metrics = gw.metrics().await.expect("metrics");
    assert!(
        metrics.contains("iogate_transaction_runs_total{transaction=\"temp\",outcome=\"ok\"}"),
        "{metrics}"
    );
    let (status, _) = gw.get("/api/v1/transactions/nope").await.expect("get");
    assert_eq!(status, 404);
    on.gw.shutdown().await;
    on.task.abort();
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

#[tokio::test]
async fn the_read_block_reads_on_its_edge_keeps_its_value_on_error_and_ignores_triggers_in_flight()
{
    use iogate_client::fb::ModbusRead;
    let bus = RtuBus::default();
    bus.slave(1, |s| s.tables.holding[0] = 215);
    let on = on_bus("fb-read", &bus, "").await;
    let client = on.gw.client().await.expect("client");
    assert_eq!(
        ModbusRead::new(
            client.clone(),
            read_request(),
            "sideways",
            std::time::Duration::ZERO
        )
        .err(),
        Some(vec!["Invalid input edge configuration."])
    );
    let mut block = ModbusRead::new(
        client.clone(),
        read_request(),
        "rising",
        std::time::Duration::ZERO,
    )
    .expect("block");
    // No edge, no read.
    for _ in 0..5 {
        assert_eq!(block.call(Some(false)), (None, false));
    }
    assert!(!block.busy());
    block.call(Some(true));
    assert!(block.busy(), "a rising edge starts a read");
    cycles(|| block.call(Some(true)) == (Some(21.5), true)).await;
    assert_eq!(block.status(), "21.5");
    let reads = bus.seen().iter().filter(|s| s.slave == 1).count();
    assert_eq!(reads, 1, "held TRUE is no new edge");

    // An error keeps the last good value.
    bus.slave(1, |s| s.behaviour = Behaviour::Silent);
    block.call(Some(false));
    block.call(Some(true));
    cycles(|| {
        let (_, ok) = block.call(Some(true));
        !block.busy() && !ok
    })
    .await;
    assert_eq!(block.value(), Some(21.5));
    assert!(!block.ok());
    assert_eq!(block.status(), "Slave timeout");

    // `true` fires on every true input, but not while a read is in flight.
    bus.slave(1, |s| s.behaviour = Behaviour::Normal);
    bus.clear_seen();
    let mut every =
        ModbusRead::new(client, read_request(), "true", std::time::Duration::ZERO).expect("block");
    for _ in 0..20 {
        every.call(Some(true));
    }
    // Calls with a null input collect the outcome without firing again.
    cycles(|| {
        every.call(None);
        !every.busy()
    })
    .await;
    let sent = bus.seen().len();
    assert!(sent <= 2, "{sent} reads for 20 calls without waiting");

    // A refused configuration: the block's status is the message as it is, and a null
    // between false and true is ignored, so the rising edge fires.
    let client = on.gw.client().await.expect("client");
    let bad = iogate_client::proto::TransactRequest {
        precision: Some(9),
        ..read_request()
    };
    let mut refused =
        ModbusRead::new(client, bad, "rising", std::time::Duration::ZERO).expect("block");
    refused.call(Some(false));
    refused.call(None);
    refused.call(Some(true));
    assert!(refused.busy(), "false, null, true is a rising edge");
    cycles(|| {
        refused.call(Some(true));
        !refused.busy()
    })
    .await;
    assert_eq!(refused.status(), "Invalid precision configuration.");
    on.gw.shutdown().await;
    on.task.abort();
}

#[tokio::test]
async fn the_read_blocks_first_cyclic_read_comes_about_two_seconds_after_start() {
    use iogate_client::fb::ModbusRead;
    let bus = RtuBus::default();
    bus.slave(1, |s| s.tables.holding[0] = 42);
    let on = on_bus("fb-cyclic", &bus, "").await;
    let client = on.gw.client().await.expect("client");
    let started = std::time::Instant::now();
    let mut block = ModbusRead::new(
        client,
        read_request(),
        "none",
        std::time::Duration::from_millis(100),
    )
    .expect("block");
    cycles(|| block.call(None).1).await;
    assert!(
        started.elapsed() >= std::time::Duration::from_millis(1900),
        "{:?}",
        started.elapsed()
    );
    assert_eq!(block.value(), Some(4.2));
    on.gw.shutdown().await;
    on.task.abort();
}

#[tokio::test]
async fn the_write_block_walks_its_states_and_resends_while_enabled() {
    use iogate_client::fb::ModbusWrite;
    let bus = RtuBus::default();
    bus.slave(17, |_| {});
    let on = on_bus("fb-write", &bus, "").await;
    let client = on.gw.client().await.expect("client");
    let request = iogate_client::proto::TransactRequest {
        link: "rs485".into(),
        function: 6,
        slave: 17,
        address: 1,
        r#type: "uint16".into(),
        byte_order: "Big-endian".into(),
        timeout_ms: 100,
        ..Default::default()
    };
    let mut block = ModbusWrite::new(client, request, std::time::Duration::from_millis(100));
    assert_eq!(block.call(false, &[3.0]), (false, 0), "not active");
    let (_, first) = block.call(true, &[3.0]);
    assert_eq!(first, 1, "waiting for access to the interface");
    let mut states = vec![first];
    cycles(|| {
        let (_, s) = block.call(true, &[3.0]);
        if states.last() != Some(&s) {
            states.push(s);
        }
        s == 4
    })
    .await;
    assert!(block.actual());
    assert_eq!(states.first(), Some(&1));
    assert_eq!(states.last(), Some(&4));
    assert_eq!(bus.read_slave(17, |s| s.tables.holding[1]), Some(3));
    // Held TRUE: sent again after the polling period, with the current values.
    cycles(|| {
        block.call(true, &[5.0]);
        bus.read_slave(17, |s| s.tables.holding[1]) == Some(5)
    })
    .await;
    // Released: not active once the last transaction has ended (that cycle reports it).
    cycles(|| block.call(false, &[5.0]).1 == 0).await;
    assert_eq!(block.call(false, &[5.0]).1, 0);

    // A one-cycle pulse of `enable`: its write runs to the end and reports 4 for a cycle.
    let mut block = block;
    let (_, started) = block.call(true, &[9.0]);
    assert_eq!(started, 1, "the pulse starts a write");
    let mut seen = vec![started];
    cycles(|| {
        let (_, s) = block.call(false, &[9.0]);
        if seen.last() != Some(&s) {
            seen.push(s);
        }
        s == 4
    })
    .await;
    assert_eq!(bus.read_slave(17, |s| s.tables.holding[1]), Some(9));
    assert_eq!(block.call(false, &[9.0]).1, 0, "then not active: {seen:?}");
    on.gw.shutdown().await;
    on.task.abort();
}

#[tokio::test]
async fn standing_transactions_over_grpc_are_declared_switched_and_streamed() {
    use futures_util::StreamExt;
    use iogate_client::proto;
    let bus = RtuBus::default();
    bus.slave(1, |s| s.tables.holding[0] = 215);
    let on = on_bus("tx-grpc-standing", &bus, "").await;
    let mut client = on.gw.client().await.expect("client");
    let status = client
        .raw()
        .ensure_transaction(proto::EnsureTransactionRequest {
            name: "temp".into(),
            parameters: Some(read_request()),
            period_ms: 50,
            enabled: true,
        })
        .await
        .expect("declared")
        .into_inner();
    assert_eq!((status.kind.as_str(), status.enabled), ("read", true));
    let mut updates = client
        .raw()
        .subscribe(proto::SubscribeRequest {
            devices: vec![],
            fields: vec![],
            diagnostics: false,
            transactions: true,
        })
        .await
        .expect("subscribe")
        .into_inner();
    let mut streamed = None;
    while let Some(update) = updates.next().await {
        if let Some(proto::update::Kind::Transaction(t)) = update.expect("update").kind
            && t.last.as_ref().is_some_and(|l| l.value == Some(21.5))
        {
            streamed = Some(t);
            break;
        }
    }
    assert_eq!(streamed.map(|t| t.name), Some("temp".to_owned()));
    let disabled = client
        .raw()
        .set_transaction(proto::SetTransactionRequest {
            name: "temp".into(),
            enabled: Some(false),
            ..Default::default()
        })
        .await
        .expect("disable")
        .into_inner();
    assert!(!disabled.enabled);
    let listed = client
        .raw()
        .list_transactions(proto::ListTransactionsRequest {})
        .await
        .expect("list")
        .into_inner();
    assert_eq!(listed.transactions.len(), 1);
    // Removed: it runs no more and is gone from the list; removing it again is NOT_FOUND.
    client
        .raw()
        .remove_transaction(proto::RemoveTransactionRequest {
            name: "temp".into(),
        })
        .await
        .expect("removed");
    let listed = client
        .raw()
        .list_transactions(proto::ListTransactionsRequest {})
        .await
        .expect("list")
        .into_inner();
    assert!(listed.transactions.is_empty());
    let again = client
        .raw()
        .remove_transaction(proto::RemoveTransactionRequest {
            name: "temp".into(),
        })
        .await;
    assert_eq!(
        again.map(|_| ()).map_err(|s| s.code()),
        Err(tonic::Code::NotFound)
    );
    let missing = client
        .raw()
        .set_transaction(proto::SetTransactionRequest {
            name: "nope".into(),
            trigger: true,
            ..Default::default()
        })
        .await;
    assert_eq!(
        missing.map(|_| ()).map_err(|s| s.code()),
        Err(tonic::Code::NotFound)
    );
    on.gw.shutdown().await;
    on.task.abort();
}

#[tokio::test]
async fn every_function_type_and_order_over_a_modbus_tcp_link() {
    use iogate_tests::devices::{ModbusDevice, modbus_tcp_server};
    let device = ModbusDevice::default();
    {
        let mut t = device.tables.lock().expect("tables");
        t.discrete[3] = true;
        t.discrete[12] = true;
        // -100000 as SIGNED_NUMBER32 in SwapWords (CDAB) order.
        let v = (-100_000i32) as u32;
        t.input[0] = v as u16;
        t.input[1] = (v >> 16) as u16;
        // 0x01020304 as UNSIGNED_NUMBER32 in LittleEndian (DCBA) order.
        t.holding[20] = 0x0403;
        t.holding[21] = 0x0201;
    }
    let (port, server) = modbus_tcp_server(device.clone()).await;
    let gw = TestGateway::start(&format!(
        "links:\n  - {{ name: plc, tcp: {{ host: 127.0.0.1, port: {port} }} }}\n"
    ))
    .await
    .expect("gateway");
    let post = |body: Value| {
        let gw = &gw;
        async move {
            let (status, answer) = gw
                .send(
                    Method::POST,
                    "/api/v1/links/plc/transactions",
                    body.to_string(),
                )
                .await
                .expect("post");
            assert_eq!(status, 200, "{answer}");
            answer
        }
    };
    // FC02, 13 bits from 0 with LittleEndian: bits 3 and 12 set.
    let a = post(json!({"function": 2, "slave": 1, "address": 0, "bit_count": 13, "byte_order": "LittleEndian", "timeout_ms": 500})).await;
    assert_eq!(a["value"], json!(f64::from((1u32 << 3) | (1 << 12))), "{a}");
    assert_eq!(
        a["request"], "01 02 00 00 00 0D",
        "unit id and PDU on a Modbus TCP link"
    );
    let a = post(json!({"function": 4, "slave": 1, "address": 0, "value_type": "SIGNED_NUMBER32", "byte_order": "SwapWords", "divisor": 1000, "precision": 2, "timeout_ms": 500})).await;
    assert_eq!(a["value"], json!(-100.0), "{a}");
    let a = post(json!({"function": 3, "slave": 1, "address": 20, "value_type": "UNSIGNED_NUMBER32", "byte_order": "LittleEndian", "timeout_ms": 500})).await;
    assert_eq!(a["value"], json!(f64::from(0x0102_0304u32)), "{a}");
    // FC05, and int8/int16 with FC16.
    let a =
        post(json!({"function": 5, "slave": 1, "address": 7, "values": [true], "timeout_ms": 500}))
            .await;
    assert_eq!(a["state"], 4, "{a}");
    let a = post(json!({"function": 16, "slave": 1, "address": 30, "type": "int8", "values": [-2, 5], "timeout_ms": 500})).await;
    assert_eq!(a["state"], 4, "{a}");
    let a = post(json!({"function": 16, "slave": 1, "address": 32, "type": "int16", "byte_order": "Little-endian", "values": [-2], "timeout_ms": 500})).await;
    assert_eq!(a["state"], 4, "{a}");
    {
        let t = device.tables.lock().expect("tables");
        assert!(t.coils[7]);
        assert_eq!(&t.holding[30..33], &[0xFFFE, 5, 0xFEFF]);
    }
    // A value out of its type is refused before sending.
    let (status, answer) = gw
        .send(
            Method::POST,
            "/api/v1/links/plc/transactions",
            json!({"function": 6, "slave": 1, "address": 1, "type": "uint8", "values": [256]})
                .to_string(),
        )
        .await
        .expect("post");
    assert_eq!(status, 400, "{answer}");
    gw.shutdown().await;
    server.abort();
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

#[tokio::test]
async fn every_bit_count_under_every_byte_order_reads_every_coil_an_independent_master_set() {
    use tokio_modbus::client::Writer;
    let (gw, mut master, server) = with_tcp_device().await;
    // A pattern with no symmetry: bit i of 0x9E3779B97 on coil i.
    let pattern: Vec<bool> = (0..32).map(|i| 0x9E37_79B9u64 >> i & 1 == 1).collect();
    master
        .write_multiple_coils(0, &pattern)
        .await
        .expect("io")
        .expect("written");
    for n in 1..=32usize {
        for order in ["LittleEndian", "BigEndian", "SwapBytes", "SwapWords"] {
            let (status, answer) = gw
                .send(
                    Method::POST,
                    "/api/v1/links/rs485/transactions",
                    json!({"function": 1, "slave": 1, "address": 0, "bit_count": n,
                           "byte_order": order, "precision": 0, "timeout_ms": 500})
                    .to_string(),
                )
                .await
                .expect("transaction");
            assert_eq!(status, 200, "{answer}");
            let expected = expected_bits(&pattern[..n], order);
            assert_eq!(
                answer["value"].as_f64(),
                Some(expected as f64),
                "{n} bits, {order}: {answer}"
            );
        }
    }
    gw.shutdown().await;
    server.abort();
}

#[tokio::test]
async fn floats_keep_the_digits_the_device_meant_and_int32_is_always_an_integer() {
    use tokio_modbus::client::{Reader, Writer};
    let (gw, mut master, server) = with_tcp_device().await;
    let read = |address: u16, precision: u8| {
        json!({"function": 3, "slave": 1, "address": address, "value_type": "FLOAT",
               "byte_order": "BigEndian", "precision": precision, "timeout_ms": 500})
    };
    // Values packed by hand by the master, the documented losses before.
    for (k, (x, precision, shown)) in [
        (0.29f32, 2u8, 0.29f64),
        (100.1, 1, 100.1),
        (21.57, 3, 21.57),
        (23.987, 3, 23.987),
        (23.987, 2, 23.98),
        (-0.29, 2, -0.29),
    ]
    .into_iter()
    .enumerate()
    {
        let address = 2 * k as u16;
        let bits = x.to_bits();
        master
            .write_multiple_registers(address, &[(bits >> 16) as u16, bits as u16])
            .await
            .expect("io")
            .expect("written");
        let (status, answer) = transact(&gw, read(address, precision)).await;
        assert_eq!(status, 200, "{answer}");
        assert_eq!(
            answer["value"],
            json!(shown),
            "{x} with {precision}: {answer}"
        );
    }
    // The type decides the encoding, never the value.
    let write = |ty: &str, value: Value| {
        json!({"function": 16, "slave": 1, "address": 100, "type": ty,
               "byte_order": "BigEndian", "values": [value], "timeout_ms": 500})
    };
    let cases = [
        ("int32", json!(12), Some([0x0000, 0x000C])),
        ("int32", json!(12.0), Some([0x0000, 0x000C])),
        ("int32", json!(12.6), None),
        ("float", json!(12), Some([0x4140, 0x0000])),
        ("float", json!(12.6), Some([0x4149, 0x999A])),
        ("int32/float", json!(12), Some([0x0000, 0x000C])),
        (
            "int32/float",
            serde_json::from_str("12.0").expect("json"),
            Some([0x4140, 0x0000]),
        ),
    ];
    for (ty, value, registers) in cases {
        master
            .write_multiple_registers(100, &[0xDEAD, 0xBEEF])
            .await
            .expect("io")
            .expect("written");
        let (status, answer) = transact(&gw, write(ty, value.clone())).await;
        let held = master
            .read_holding_registers(100, 2)
            .await
            .expect("io")
            .expect("read");
        match registers {
            Some(r) => {
                assert_eq!((status, &answer["actual"]), (200, &json!(true)), "{answer}");
                assert_eq!(held, r.to_vec(), "{ty} {value}");
            }
            None => {
                assert_eq!(status, 400, "{ty} {value}: {answer}");
                assert_eq!(held, vec![0xDEAD, 0xBEEF], "nothing was written");
            }
        }
    }
    gw.shutdown().await;
    server.abort();
}

#[tokio::test]
async fn a_declared_transaction_is_removed_and_then_its_link_can_be() {
    use iogate_tests::devices::{ModbusDevice, modbus_tcp_server};
    let (port, server) = modbus_tcp_server(ModbusDevice::default()).await;
    let (other, other_server) = modbus_tcp_server(ModbusDevice::default()).await;
    let gw = TestGateway::start(&format!(
        "links:\n  - {{ name: plant, tcp: {{ host: 127.0.0.1, port: {port} }} }}\n\
         transactions:\n  - {{ name: configured, link: plant, function: 3, slave: 1, address: 0, \
         value_type: UNSIGNED_NUMBER16, byte_order: BigEndian, refresh_interval: 0s }}\n"
    ))
    .await
    .expect("gateway");
    let (status, body) = gw
        .send(
            Method::PUT,
            "/api/v1/links/rt",
            json!({"tcp": {"host": "127.0.0.1", "port": other}}).to_string(),
        )
        .await
        .expect("link");
    assert!(status == 200 || status == 201, "{body}");
    let (status, body) = gw
        .send(
            Method::PUT,
            "/api/v1/transactions/poll",
            json!({"link": "rt", "function": 3, "slave": 1, "address": 0, "value_type": "UNSIGNED_NUMBER16",
                   "byte_order": "BigEndian", "timeout_ms": 200, "refresh_interval_ms": 20}).to_string(),
        )
        .await
        .expect("declare");
    assert_eq!(status, 200, "{body}");
    let (status, refused) = gw
        .send(Method::DELETE, "/api/v1/links/rt", String::new())
        .await
        .expect("delete");
    assert_eq!(status, 409, "{refused}");
    assert!(
        refused["error"]["message"]
            .as_str()
            .is_some_and(|m| m.contains("transaction poll")),
        "{refused}"
    );
    let (status, body) = gw
        .send(Method::DELETE, "/api/v1/transactions/poll", String::new())
        .await
        .expect("delete");
    assert_eq!(status, 204, "{body}");
    let (status, _) = gw.get("/api/v1/transactions/poll").await.expect("get");
    assert_eq!(status, 404);
    let (status, body) = gw
        .send(Method::DELETE, "/api/v1/links/rt", String::new())
        .await
        .expect("delete");
    assert_eq!(status, 204, "{body}");
    // One from the config file stays, as configured devices do.
    let (status, body) = gw
        .send(
            Method::DELETE,
            "/api/v1/transactions/configured",
            String::new(),
        )
        .await
        .expect("delete");
    assert_eq!(status, 409, "{body}");
    assert!(
        body["error"]["message"]
            .as_str()
            .is_some_and(|m| m.contains("comes from the config file")),
        "{body}"
    );
    gw.shutdown().await;
    server.abort();
    other_server.abort();
}

#[tokio::test]
async fn a_request_whose_caller_is_gone_or_late_is_never_sent() {
    use iogate::cache::{Passthrough, PassthroughError};
    use iogate::link::frame::Request;
    use std::time::Duration;
    use tokio::time::Instant;
    let bus = RtuBus::default();
    bus.slave(3, |_| {});
    let on = on_bus("tx-gone", &bus, "").await;
    let link = on
        .gw
        .service()
        .expect("service")
        .cache
        .link("rs485")
        .expect("link");
    let read = |address| Request::ReadHoldingRegisters { address, count: 1 };
    // The caller gave up (its receiver is dropped) before the link reached it.
    let (gone, receiver) = tokio::sync::oneshot::channel();
    drop(receiver);
    link.submit(Passthrough {
        slave: 3,
        request: read(10),
        timeout: Duration::from_millis(100),
        deadline: Instant::now() + Duration::from_secs(5),
        reply: gone,
        stage: None,
    });
    // A deadline the slave's timeout would pass: answered, not sent.
    let (late, late_answer) = tokio::sync::oneshot::channel();
    link.submit(Passthrough {
        slave: 3,
        request: read(11),
        timeout: Duration::from_millis(100),
        deadline: Instant::now() + Duration::from_millis(50),
        reply: late,
        stage: None,
    });
    // And one that is sent.
    let (fine, fine_answer) = tokio::sync::oneshot::channel();
    link.submit(Passthrough {
        slave: 3,
        request: read(12),
        timeout: Duration::from_millis(100),
        deadline: Instant::now() + Duration::from_secs(5),
        reply: fine,
        stage: None,
    });
    assert!(matches!(
        late_answer.await.expect("answered"),
        Err(PassthroughError::Expired)
    ));
    assert!(fine_answer.await.expect("answered").is_ok());
    let sent: Vec<u16> = bus
        .seen()
        .into_iter()
        .filter(|s| s.slave == 3)
        .map(|s| s.address)
        .collect();
    assert_eq!(sent, vec![12], "only the request with a caller was sent");
    // A full inbox answers busy at once.
    let mut answers = Vec::new();
    for k in 0..(iogate::cache::INBOX_CAPACITY as u16 + 4) {
        let (reply, answer) = tokio::sync::oneshot::channel();
        link.submit(Passthrough {
            slave: 3,
            request: read(100 + k),
            timeout: Duration::from_millis(100),
            deadline: Instant::now() + Duration::from_secs(5),
            reply,
            stage: None,
        });
        answers.push(answer);
    }
    let mut busy = 0;
    for answer in answers {
        if matches!(answer.await.expect("answered"), Err(PassthroughError::Busy)) {
            busy += 1;
        }
    }
    assert!(busy >= 3, "{busy} answered busy");
    on.gw.shutdown().await;
    on.task.abort();
}

#[tokio::test]
async fn a_write_of_period_zero_runs_when_enabled_and_when_given_values() {
    let bus = RtuBus::default();
    bus.slave(17, |_| {});
    let on = on_bus(
        "tx-write-zero",
        &bus,
        "transactions:\n  - { name: once, link: rs485, function: 6, slave: 17, address: 1, type: uint16, byte_order: Big-endian, values: [5], timeout_ms: 100, enabled: false }\n",
    )
    .await;
    let gw = &on.gw;
    let (status, _) = gw
        .send(Method::POST, "/api/v1/transactions/once/enable", "")
        .await
        .expect("enable");
    assert_eq!(status, 200);
    gw.until("/api/v1/transactions/once", "sent when enabled", |b| {
        b["runs"] == 1 && b["state"] == 4
    })
    .await
    .expect("one run");
    assert_eq!(bus.read_slave(17, |s| s.tables.holding[1]), Some(5));
    gw.send(
        Method::PUT,
        "/api/v1/transactions/once/values",
        json!({"values": [6]}).to_string(),
    )
    .await
    .expect("values");
    gw.until(
        "/api/v1/transactions/once",
        "sent with its new values",
        |b| b["runs"] == 2,
    )
    .await
    .expect("a second run");
    assert_eq!(bus.read_slave(17, |s| s.tables.holding[1]), Some(6));
    on.gw.shutdown().await;
    on.task.abort();
}

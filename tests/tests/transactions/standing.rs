use super::*;

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

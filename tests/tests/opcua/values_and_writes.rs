use super::*;

#[tokio::test]
async fn every_iec_type_is_browsed_and_read_with_its_status_and_timestamps() {
    let dir = temp_dir("opcua-types");
    let gw = TestGateway::start(&format!("{PLANT}{}", opcua(&dir, "")))
        .await
        .expect("gateway");
    let mut ua = UaClient::connect(&url(&gw), &Options::default())
        .await
        .expect("asyncua connects");
    let devices = ua
        .cmd(json!({"cmd": "browse", "node": "/iogate/Devices"}))
        .await
        .expect("browse");
    assert_eq!(devices["children"][0]["id"], "Devices/plant", "{devices}");
    let fields = ua
        .cmd(json!({"cmd": "browse", "node": "Devices/plant"}))
        .await
        .expect("browse plant");
    let names: Vec<&str> = fields["children"]
        .as_array()
        .expect("children")
        .iter()
        .filter_map(|c| c["name"].as_str())
        .collect();
    assert_eq!(names.len(), 20, "19 fields and Diagnostics: {names:?}");
    assert!(names.contains(&"Diagnostics"), "{names:?}");
    // Each IEC type as its OPC UA built-in type (numeric DataType ids of Part 6), with
    // write access only for outputs.
    for (field, data_type, writable) in [
        ("PumpRunning", 1, false),
        ("PumpStart", 1, true),
        ("TrimOffset", 2, true),
        ("Recipe", 3, true),
        ("Pressure", 4, false),
        ("SpeedRpm", 5, false),
        ("BatchCount", 6, false),
        ("RunSeconds", 7, false),
        ("TotalCycles", 8, false),
        ("SerialNumber", 9, false),
        ("Level", 10, false),
        ("FlowTotal", 11, false),
        ("BatchName", 12, true),
        ("AlarmBits", 3, false),
        ("StatusWord", 5, false),
        ("ErrorMask", 7, true),
        ("Signature", 9, false),
        ("MixTime", 290, true),
    ] {
        let attrs = ua
            .cmd(json!({"cmd": "attrs", "node": format!("plant.{field}")}))
            .await
            .expect("attributes");
        assert_eq!(attrs["data_type"], data_type, "{field}: {attrs}");
        assert!(attrs["description"].is_string(), "{field}: {attrs}");
        let can_write = attrs["access"]
            .as_array()
            .is_some_and(|a| a.iter().any(|x| x == "CurrentWrite"));
        assert_eq!(can_write, writable, "{field}: {attrs}");
    }
    // A value set on the simulated device is read with Good, its source timestamp the time
    // it was read and a server timestamp.
    let (status, _) = gw
        .send(
            Method::PUT,
            "/api/v1/devices/plant/fields/Pressure/simulate",
            json!({"value": -1234}).to_string(),
        )
        .await
        .expect("simulate");
    assert!((200..300).contains(&status), "simulate: {status}");
    eventually("the new value read over OPC UA", || async {
        gw.get("/api/v1/devices/plant/fields/Pressure")
            .await
            .is_ok_and(|(_, v)| v["value"] == -1234)
    })
    .await
    .expect("simulated");
    let read = ua.read("plant.Pressure").await.expect("read");
    assert_eq!(read["value"], -1234, "{read}");
    assert_eq!(read["type"], "Int16", "{read}");
    assert_eq!(read["status"], "Good", "{read}");
    let (_, rest) = gw
        .get("/api/v1/devices/plant/fields/Pressure")
        .await
        .expect("rest");
    let source = read["source"].as_str().expect("a source timestamp");
    let rest_ts = rest["timestamp"].as_str().expect("REST timestamp");
    assert_eq!(
        &source[..19],
        &rest_ts[..19],
        "source timestamp is when the device was read: {read} / {rest}"
    );
    assert!(read["server"].is_string(), "{read}");
    let units = ua
        .read("plant.Level/EngineeringUnits")
        .await
        .expect("units");
    assert!(
        units["value"].as_str().is_some_and(|u| u.contains('%')),
        "{units}"
    );
    let connected = ua
        .read("Diagnostics/plant/connected")
        .await
        .expect("diagnostics");
    assert_eq!(connected["value"], true, "{connected}");
    let mix = ua.read("plant.MixTime").await.expect("TIME");
    assert_eq!(mix["type"], "Double", "TIME is a Duration (ms): {mix}");

    // A device declared at run time appears with a model change event, and goes with one.
    // A client that asks for model change events only (an event filter on the event
    // type, as asyncua and UaExpert write it) is told which nodes came and went.
    ua.cmd(json!({"cmd": "subscribe_events", "type": "GeneralModelChangeEventType"}))
        .await
        .expect("events");
    let (status, body) = gw
        .send(
            Method::PUT,
            "/api/v1/devices/extra",
            json!({"profile": "SimIo", "refresh_rate_ms": 100}).to_string(),
        )
        .await
        .expect("declare");
    assert_eq!(status, 201, "{body}");
    let event = next_event(&mut ua).await;
    assert_eq!(event["event"], 2133, "GeneralModelChangeEventType: {event}");
    assert_eq!(
        event["changes"],
        json!([{"affected": "Devices/extra", "verb": 1}, {"affected": "/iogate/Devices", "verb": 4}]),
        "NodeAdded, and ReferenceAdded on its folder: {event}"
    );
    let devices = ua
        .cmd(json!({"cmd": "browse", "node": "/iogate/Devices"}))
        .await
        .expect("browse");
    assert!(
        devices.to_string().contains("\"Devices/extra\""),
        "{devices}"
    );
    assert_eq!(
        ua.read("extra.DI_0").await.expect("read")["type"],
        "Boolean"
    );
    ua.cmd(json!({"cmd": "subscribe", "nodes": ["extra.DI_0"]}))
        .await
        .expect("monitor a field of it");
    let (status, _) = gw
        .send(Method::DELETE, "/api/v1/devices/extra", "")
        .await
        .expect("remove");
    assert!((200..300).contains(&status));
    // Its monitored item is told the node is gone, and a model change event follows.
    let mut seen = Vec::new();
    for _ in 0..5 {
        let changes = ua
            .cmd(json!({"cmd": "changes", "wait": 5}))
            .await
            .expect("changes");
        seen.extend(changes["changes"].as_array().cloned().unwrap_or_default());
        let gone = seen
            .iter()
            .any(|c| c["node"] == "extra.DI_0" && c["status"] == "BadNodeIdUnknown");
        let event = seen.iter().any(|c| c["event"] == 2133);
        if gone && event {
            break;
        }
    }
    assert!(
        seen.iter().any(|c| c["node"] == "extra.DI_0"
            && c["value"].is_null()
            && c["status"] == "BadNodeIdUnknown"),
        "{seen:?}"
    );
    assert!(
        seen.iter().any(|c| c["event"] == 2133
            && c["changes"]
                == json!([{"affected": "Devices/extra", "verb": 2}, {"affected": "/iogate/Devices", "verb": 8}])),
        "NodeDeleted, ReferenceDeleted: {seen:?}"
    );
    let devices = ua
        .cmd(json!({"cmd": "browse", "node": "/iogate/Devices"}))
        .await
        .expect("browse");
    assert!(
        !devices.to_string().contains("\"Devices/extra\""),
        "{devices}"
    );
    gw.shutdown().await;
}

#[tokio::test]
async fn writes_go_through_the_service_and_refusals_are_opc_ua_status_codes() {
    let dir = temp_dir("opcua-writes");
    let tokens = dir.join("tokens");
    std::fs::write(
        &tokens,
        "read reader-0123456789abcdef\nwrite writer-0123456789abcdef\n",
    )
    .expect("tokens");
    let config = format!(
        "{PLANT}security: {{ tokens_file: {} }}\n{}",
        tokens.display(),
        opcua(&dir, "")
    );
    let gw = TestGateway::start(&config).await.expect("gateway");
    let url = url(&gw);
    // Tokens configured: anonymous sessions and unknown tokens are refused.
    let anonymous = refused(&url, &Options::default()).await.expect("refused");
    assert!(anonymous.contains("Bad"), "{anonymous}");
    let wrong = Options {
        user: Some(("token".into(), "not-a-token-at-all".into())),
        ..Options::default()
    };
    refused(&url, &wrong).await.expect("unknown token refused");
    // A writer: an accepted write answers Good and is the field's latest write.
    let writer = Options {
        user: Some(("token".into(), "writer-0123456789abcdef".into())),
        ..Options::default()
    };
    let mut ua = UaClient::connect(&url, &writer).await.expect("writer");
    assert_eq!(
        ua.write("plant.PumpStart", json!(true), "Boolean")
            .await
            .expect("write"),
        "Good"
    );
    eventually("the write reaches the device", || async {
        rest(&gw, "/api/v1/devices/plant/fields/PumpStart")
            .await
            .is_ok_and(|v| v["value"] == true)
    })
    .await
    .expect("written");
    for (node, value, ty, expected) in [
        (
            "plant.PumpRunning",
            json!(true),
            "Boolean",
            "BadNotWritable",
        ),
        (
            "plant.TrimOffset",
            json!("fast"),
            "String",
            "BadTypeMismatch",
        ),
        ("plant.TrimOffset", json!(300), "Int16", "BadOutOfRange"),
        ("plant.Recipe", json!(2.5), "Double", "BadTypeMismatch"),
        (
            "Diagnostics/plant/io_cycles",
            json!(1),
            "UInt64",
            "BadNotWritable",
        ),
    ] {
        let status = ua.write(node, value.clone(), ty).await.expect("write");
        assert_eq!(status, expected, "{node} <- {value} ({ty})");
    }
    assert_eq!(
        ua.write("plant.TrimOffset", json!(-7), "SByte")
            .await
            .expect("write"),
        "Good"
    );
    // A reader: may read, not write.
    let reader = Options {
        user: Some(("token".into(), "reader-0123456789abcdef".into())),
        ..Options::default()
    };
    let mut ro = UaClient::connect(&url, &reader).await.expect("reader");
    assert_eq!(
        ro.read("plant.PumpStart").await.expect("read")["status"],
        "Good"
    );
    assert_eq!(
        ro.write("plant.PumpStart", json!(false), "Boolean")
            .await
            .expect("write"),
        "BadUserAccessDenied"
    );
    let field = rest(&gw, "/api/v1/devices/plant/fields/PumpStart")
        .await
        .expect("rest");
    assert_eq!(
        field["value"], true,
        "the reader's write changed nothing: {field}"
    );
    assert_eq!(field["last_write"]["status"], "written", "{field}");
    gw.shutdown().await;
}

#[tokio::test]
async fn a_device_on_a_pty_is_subscribed_written_and_turns_bad_and_back() {
    let bus = RtuBus::default();
    bus.slave(1, |s| s.tables.input[0] = 100);
    let dir = temp_dir("opcua-pty");
    let (gw, _pty, task, _) = bus_gateway_with(
        "opcua-pty",
        &bus,
        &[],
        // A timeout a loaded machine's pty keeps (the test's "bad" comes from a silent
        // slave, not from a slow answer).
        "  - { name: io, profile: MyIoModule, link: bus, slave_id: 1, refresh_rate: 50ms, timeout: 300ms, retries: 1 }\n",
        &opcua(&dir, ""),
    )
    .await;
    let mut ua = UaClient::connect(&url(&gw), &Options::default())
        .await
        .expect("asyncua");
    let subscribed = ua
        .cmd(json!({"cmd": "subscribe", "nodes": ["io.AI_0"], "interval": 50}))
        .await
        .expect("subscribe");
    assert_eq!(subscribed["subscribed"], 1);
    // The initial value, then each change once, with the time the device was read.
    let mut seen = Vec::new();
    for raw in [150u16, 200, 250] {
        bus.slave(1, |s| s.tables.input[0] = raw);
        let expected = f64::from(raw) / 10.0;
        loop {
            let changes = ua
                .cmd(json!({"cmd": "changes", "wait": 5}))
                .await
                .expect("changes");
            let batch = changes["changes"].as_array().cloned().unwrap_or_default();
            assert!(!batch.is_empty(), "no change for {expected}");
            seen.extend(batch);
            if seen
                .last()
                .is_some_and(|c| (c["value"].as_f64().unwrap_or(f64::NAN) - expected).abs() < 1e-3)
            {
                break;
            }
        }
    }
    let values: Vec<f64> = seen.iter().filter_map(|c| c["value"].as_f64()).collect();
    let mut deduped = values.clone();
    deduped.dedup();
    assert_eq!(values, deduped, "each change once: {seen:?}");
    assert!(
        seen.iter()
            .all(|c| c["source"].is_string() && c["status"] == "Good"),
        "{seen:?}"
    );
    // A write of an output reaches the slave.
    assert_eq!(
        ua.write("io.DO_0", json!(true), "Boolean")
            .await
            .expect("write"),
        "Good"
    );
    eventually("the coil written on the line", || async {
        bus.read_slave(1, |s| s.tables.coils[0]) == Some(true)
    })
    .await
    .expect("coil");
    // The device stops answering: the value turns Bad_CommunicationError (with no value, as
    // Part 4 asks of a Bad status), then Good again.
    bus.slave(1, |s| s.behaviour = Behaviour::Silent);
    let metrics = gw.metrics().await.expect("metrics");
    for line in [
        "iogate_opcua_sessions 1\n",
        "iogate_opcua_subscriptions 1\n",
        "iogate_opcua_monitored_items 1\n",
        "iogate_opcua_writes_total{outcome=\"accepted\"} 1\n",
    ] {
        assert!(metrics.contains(line), "{line}{metrics}");
    }
    assert!(
        !metrics.contains("iogate_opcua_value_updates_total 0\n"),
        "{metrics}"
    );
    let bad = wait_status(&mut ua, |s| s.starts_with("Bad")).await;
    assert_eq!(bad, "BadCommunicationError");
    bus.slave(1, |s| s.behaviour = Behaviour::Normal);
    let good = wait_status(&mut ua, |s| s == "Good").await;
    assert_eq!(good, "Good");
    gw.shutdown().await;
    task.abort();
}

#[tokio::test]
async fn a_change_of_status_alone_is_told() {
    // A device that never answers, with a long timeout: its fields wait for their first
    // value (Bad_WaitingForInitialData), then the poll times out (Bad_CommunicationError).
    // Neither has a value: only the status changes, and an item without a filter (whose
    // trigger is StatusValue) is told.
    let bus = RtuBus::default();
    bus.slave(1, |s| s.behaviour = Behaviour::Silent);
    let dir = temp_dir("opcua-status");
    let (gw, _pty, task, _) = bus_gateway_with(
        "opcua-status",
        &bus,
        &[],
        "  - { name: io, profile: MyIoModule, link: bus, slave_id: 1, refresh_rate: 100ms, timeout: 10s, retries: 0 }\n",
        &opcua(&dir, ""),
    )
    .await;
    let mut ua = UaClient::connect(&url(&gw), &Options::default())
        .await
        .expect("asyncua");
    ua.cmd(json!({"cmd": "subscribe", "nodes": ["io.AI_0"], "interval": 50}))
        .await
        .expect("subscribe");
    let first = wait_status(&mut ua, |_| true).await;
    assert_eq!(first, "BadWaitingForInitialData");
    let next = wait_status(&mut ua, |_| true).await;
    assert_eq!(next, "BadCommunicationError");
    gw.shutdown().await;
    task.abort();
}

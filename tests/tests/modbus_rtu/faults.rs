use super::*;

#[tokio::test]
async fn writing_one_bit_keeps_the_other_bits_of_the_register() {
    let bus = RtuBus::default();
    bus.slave(2, |s| s.tables.holding[0] = 0x0080);
    let (gw, _pty, task, _) = bus_gateway(
        "bits",
        &bus,
        &[],
        "  - { name: vfd, profile: GenericVfd, link: bus, slave_id: 2, refresh_rate: 50ms }\n",
    )
    .await;
    let (status, _) = gw
        .send(Method::PUT, "/api/v1/devices/vfd/fields/Run", "true")
        .await
        .expect("put");
    assert_eq!(status, 202);
    eventually("Run bit set", || async {
        bus.read_slave(2, |s| s.tables.holding[0]) == Some(0x0081)
    })
    .await
    .expect("bit 0 set, bit 7 kept");
    gw.send(
        Method::PATCH,
        "/api/v1/devices/vfd/fields",
        r#"{"Reverse": true, "FrequencySetpoint": 49.99, "AccelTime": "T#2s500ms"}"#,
    )
    .await
    .expect("patch");
    eventually("control word and setpoint", || async {
        bus.read_slave(2, |s| {
            (
                s.tables.holding[0],
                s.tables.holding[1],
                s.tables.holding[2],
                s.tables.holding[3],
            )
        }) == Some((0x0083, 4999, 0, 2500))
    })
    .await
    .expect("written");
    gw.until("/api/v1/devices/vfd/fields/Reverse", "read back", |b| {
        b["value"] == true
    })
    .await
    .expect("read back");
    gw.shutdown().await;
    task.abort();
}

#[tokio::test]
async fn a_refused_batch_is_split_and_the_other_fields_keep_working() {
    let bus = RtuBus::default();
    bus.slave(1, |s| {
        s.refused = vec![2];
        for i in 0..5 {
            s.tables.input[i] = 100 + i as u16;
        }
    });
    let profile = "name: Five\nfields:\n  - { name: A, type: UINT, direction: input, register: { address: 0, kind: input_register } }\n  - { name: B, type: UINT, direction: input, register: { address: 1, kind: input_register } }\n  - { name: C, type: UINT, direction: input, register: { address: 2, kind: input_register } }\n  - { name: D, type: UINT, direction: input, register: { address: 3, kind: input_register } }\n  - { name: E, type: UINT, direction: input, register: { address: 4, kind: input_register } }\n";
    let (gw, _pty, task, _) = bus_gateway(
        "split",
        &bus,
        &[("five.yaml", profile)],
        "  - { name: five, profile: Five, link: bus, slave_id: 1, refresh_rate: 20ms }\n",
    )
    .await;
    let body = gw
        .until("/api/v1/devices/five", "split", |b| {
            ["A", "B", "D", "E"]
                .iter()
                .all(|f| b["fields"][f]["quality"] == "good")
                && b["fields"]["C"]["quality"] == "bad"
        })
        .await
        .expect("fields");
    assert_eq!(body["fields"]["A"]["value"], 100);
    assert_eq!(body["fields"]["E"]["value"], 104);
    assert!(
        body["fields"]["C"]["error"]
            .as_str()
            .is_some_and(|e| e.contains("exception 02")),
        "{body}"
    );
    assert_eq!(body["connected"], true, "an exception is an answer");
    // The split is remembered: later cycles never ask for the whole range again.
    bus.clear_seen();
    gw.until("/api/v1/devices/five", "more cycles", |b| {
        b["io_cycles"].as_u64() >= Some(10)
    })
    .await
    .expect("cycles");
    assert!(bus.seen().iter().all(|s| s.count < 5), "{:?}", bus.seen());
    gw.shutdown().await;
    task.abort();
}

#[tokio::test]
async fn misbehaving_devices_are_contained_while_another_keeps_updating() {
    let bus = RtuBus::default();
    bus.slave(1, |s| s.counter = Some(0));
    bus.slave(2, |s| s.counter = Some(0));
    let (gw, _pty, task, _) = bus_gateway(
        "misbehave",
        &bus,
        &[("counter.yaml", COUNTER_PROFILE)],
        "  - { name: good, profile: Counter, link: bus, slave_id: 1, refresh_rate: 20ms, timeout: 100ms }\n  - { name: flaky, profile: Counter, link: bus, slave_id: 2, refresh_rate: 20ms, timeout: 100ms, retries: 1 }\n",
    )
    .await;
    gw.until("/api/v1/devices/flaky", "flaky connected", |b| {
        b["connected"] == true
    })
    .await
    .expect("up");

    let phases = [
        (Behaviour::Silent, "timeout"),
        (Behaviour::Late(Duration::from_millis(120)), "timeout"),
        (Behaviour::BadCrc, "CRC mismatch"),
        (Behaviour::WrongLength, "invalid response"),
        (Behaviour::Exception(4), "exception 04"),
    ];
    for (behaviour, error) in phases {
        bus.slave(2, |s| s.behaviour = behaviour.clone());
        let flaky = gw
            .until(
                "/api/v1/devices/flaky",
                &format!("{behaviour:?} noticed"),
                |b| {
                    b["fields"]["Count"]["error"]
                        .as_str()
                        .is_some_and(|e| e.contains(error))
                },
            )
            .await
            .expect("noticed");
        if matches!(behaviour, Behaviour::Exception(_)) {
            assert_eq!(flaky["connected"], true, "an exception is an answer");
        } else {
            assert_eq!(
                (flaky["connected"].clone(), flaky["error_code"].clone()),
                (json!(false), json!(10))
            );
        }
        // The good device keeps updating while the other misbehaves.
        let (_, good) = gw.get("/api/v1/devices/good").await.expect("get");
        let before = counter_value(&good).expect("count");
        for _ in 0..3 {
            let good = gw
                .until("/api/v1/devices/good", "good updates", |b| {
                    counter_value(b) > Some(before)
                })
                .await
                .expect("good keeps updating");
            assert_eq!(good["connected"], true);
            assert_ne!(counter_value(&good), Some(0xBAD0));
            let (_, flaky) = gw.get("/api/v1/devices/flaky").await.expect("get");
            assert_ne!(
                counter_value(&flaky),
                Some(0xBAD0),
                "a late reply was taken: {flaky}"
            );
        }
        bus.slave(2, |s| s.behaviour = Behaviour::Normal);
        gw.until("/api/v1/devices/flaky", "flaky recovers", |b| {
            b["connected"] == true && b["fields"]["Count"]["quality"] == "good"
        })
        .await
        .expect("recovers");
    }
    let metrics = gw.metrics().await.expect("metrics");
    for needle in [
        "iogate_device_timeouts_total{device=\"flaky\"}",
        "iogate_device_crc_errors_total{device=\"flaky\"}",
        "outcome=\"invalid_response\"",
        "iogate_device_exceptions_total{device=\"flaky\",code=\"04\"}",
        "iogate_link_discarded_bytes_total{link=\"bus\"}",
        "iogate_link_planned_utilisation_ratio{link=\"bus\"}",
        "iogate_link_utilisation_ratio{link=\"bus\"}",
    ] {
        let line = metrics
            .lines()
            .find(|l| l.contains(needle))
            .unwrap_or_else(|| panic!("{needle} missing:\n{metrics}"));
        let n: f64 = line
            .rsplit(' ')
            .next()
            .and_then(|v| v.parse().ok())
            .unwrap_or(0.0);
        assert!(n > 0.0, "{line}");
    }
    assert!(
        !metrics.contains("device=\"good\",function=\"fc04\",outcome=\"timeout\""),
        "the good device never timed out"
    );
    gw.shutdown().await;
    task.abort();
}

#[tokio::test]
async fn a_lost_port_is_reopened_and_the_latest_outputs_are_written_again() {
    let bus = RtuBus::default();
    bus.slave(1, |s| s.counter = Some(0));
    let (gw, pty, task, port) = bus_gateway(
        "reopen",
        &bus,
        &[("counter.yaml", COUNTER_PROFILE)],
        "  - { name: dev, profile: Counter, link: bus, slave_id: 1, refresh_rate: 20ms, timeout: 100ms }\n",
    )
    .await;
    gw.send(Method::PUT, "/api/v1/devices/dev/fields/Setpoint", "1234")
        .await
        .expect("put");
    eventually("setpoint written", || async {
        bus.read_slave(1, |s| s.tables.holding[0]) == Some(1234)
    })
    .await
    .expect("written");

    // Unplug: the device end goes away.
    task.abort();
    let _ = task.await;
    drop(pty);
    let link = gw
        .until("/api/v1/links/bus", "port lost", |b| {
            b["connected"] == false && b["error_code"] == 3
        })
        .await
        .expect("lost");
    assert_eq!(link["devices"], json!(["dev"]));
    gw.until("/api/v1/devices/dev", "device unreachable", |b| {
        b["connected"] == false && b["error_code"] == 10
    })
    .await
    .expect("unreachable");

    // Plug a new adapter in at the same path: a fresh device whose registers are all zero.
    let fresh = RtuBus::default();
    fresh.slave(1, |s| s.counter = Some(0));
    let (device_end, _holder) = pty_at(&port).expect("new pty");
    let task = fresh.serve(device_end);
    gw.until("/api/v1/links/bus", "link back", |b| {
        b["connected"] == true && b["error_code"] == 0
    })
    .await
    .expect("back");
    gw.until("/api/v1/devices/dev", "device back", |b| {
        b["connected"] == true && counter_value(b) > Some(0)
    })
    .await
    .expect("device back");
    eventually("setpoint written again", || async {
        fresh.read_slave(1, |s| s.tables.holding[0]) == Some(1234)
    })
    .await
    .expect("rewritten");
    let metrics = gw.metrics().await.expect("metrics");
    assert!(
        metrics.contains("iogate_link_reconnects_total{link=\"bus\"} 1"),
        "{metrics}"
    );
    gw.shutdown().await;
    task.abort();
}

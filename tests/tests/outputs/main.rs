//! Outputs that end as the client asked, against a device on a pseudo-terminal that answers
//! "busy", changes its own coil, and loses its registers: retries with attempts counted,
//! desired against read back, `write_mode: reconcile`, the gateway's own writes in the log
//! with their origin, and outcomes one client cannot flush.

mod replays;

use reqwest::Method;
use serde_json::{Value, json};

use iogate_tests::devices::RtuBus;
use iogate_tests::{TestGateway, bus_gateway};

async fn put(gw: &TestGateway, path: &str, value: Value) -> u64 {
    let (status, body) = gw
        .send(Method::PUT, path, json!({ "value": value }).to_string())
        .await
        .expect("put");
    assert_eq!(status, 202, "{body}");
    body["generation"].as_u64().expect("generation")
}

async fn outcome(gw: &TestGateway, generation: u64) -> Value {
    gw.until(
        &format!("/api/v1/writes/{generation}"),
        "the write ends",
        |b| b["status"] != "pending",
    )
    .await
    .expect("outcome")
}

#[tokio::test]
async fn busy_is_retried_with_attempts_counted_and_a_failed_write_is_never_applied_silently() {
    let bus = RtuBus::default();
    bus.slave(1, |s| s.busy_writes = 2);
    let (gw, _pty, task, _) = bus_gateway(
        "busy",
        &bus,
        &[],
        "  - { name: io, profile: MyIoModule, link: bus, slave_id: 1, refresh_rate: 50ms, retries: 3 }\n",
    )
    .await;
    gw.until("/api/v1/devices/io", "connected", |b| {
        b["connected"] == true
    })
    .await
    .expect("connected");

    // Busy twice, then written: three attempts.
    let g = put(&gw, "/api/v1/devices/io/fields/DO_0", json!(true)).await;
    let done = outcome(&gw, g).await;
    assert_eq!(done["status"], "written", "{done}");
    assert_eq!(
        (done["attempts"].as_u64(), &done["origin"]),
        (Some(3), &json!("client"))
    );
    assert_eq!(bus.read_slave(1, |s| s.tables.coils[0]), Some(true));

    // Busy more often than the retries allow: failed after 4 attempts; the device keeps
    // its value and the field says so.
    bus.slave(1, |s| s.busy_writes = 10);
    let g = put(&gw, "/api/v1/devices/io/fields/DO_0", json!(false)).await;
    let done = outcome(&gw, g).await;
    assert_eq!(done["status"], "failed", "{done}");
    assert_eq!(done["attempts"].as_u64(), Some(4), "{done}");
    assert!(
        done["error"].as_str().is_some_and(|e| e.contains("busy")),
        "{done}"
    );
    let field = gw
        .until("/api/v1/devices/io/fields/DO_0", "mismatch shown", |b| {
            b["mismatch"] == true
        })
        .await
        .expect("mismatch");
    assert_eq!(
        (&field["value"], &field["desired"]),
        (&json!(true), &json!(false))
    );
    let metrics = gw.metrics().await.expect("metrics");
    assert!(
        metrics.contains("iogate_device_mismatched_outputs{device=\"io\"} 1"),
        "{metrics}"
    );

    // The device is no longer busy: under on_change nothing is written behind the failed
    // outcome; the difference stays visible.
    bus.slave(1, |s| s.busy_writes = 0);
    bus.clear_seen();
    let cycles = |b: &Value| b["io_cycles"].as_u64().unwrap_or(0);
    let (_, now) = gw.get("/api/v1/devices/io").await.expect("device");
    let later = cycles(&now) + 5;
    gw.until("/api/v1/devices/io", "five more cycles", |b| {
        cycles(b) >= later
    })
    .await
    .expect("cycles");
    assert!(
        bus.seen().iter().all(|s| !matches!(s.function, 5 | 15)),
        "a coil was written behind a failed outcome: {:?}",
        bus.seen()
    );
    assert_eq!(bus.read_slave(1, |s| s.tables.coils[0]), Some(true));
    let (_, field) = gw
        .get("/api/v1/devices/io/fields/DO_0")
        .await
        .expect("field");
    assert_eq!(field["mismatch"], true);
    assert_eq!(field["last_write"]["generation"].as_u64(), Some(g));

    // A scan cycle that keeps sending the requested value is told the device holds another.
    let mut client = gw.client().await.expect("client");
    let mut exchange = client.exchange().await.expect("exchange");
    let reply = exchange
        .cycle(
            &[("io", "DO_0", iogate_client::Value::Bool(false))],
            &["io"],
        )
        .await
        .expect("cycle");
    assert!(
        reply.written.is_empty(),
        "the same value is not written again"
    );
    assert!(
        reply
            .errors
            .iter()
            .any(|e| e.contains("io.DO_0") && e.contains("holds TRUE") && e.contains("busy")),
        "{:?}",
        reply.errors
    );
    gw.shutdown().await;
    task.abort();
}

#[tokio::test]
async fn reconcile_writes_the_desired_value_back_after_the_device_changed_it_or_lost_power() {
    let bus = RtuBus::default();
    bus.slave(1, |_| {});
    let (gw, _pty, task, _) = bus_gateway(
        "reconcile",
        &bus,
        &[],
        "  - { name: io, profile: MyIoModule, link: bus, slave_id: 1, refresh_rate: 50ms, write_mode: reconcile }\n",
    )
    .await;
    gw.until("/api/v1/devices/io", "connected", |b| {
        b["connected"] == true
    })
    .await
    .expect("connected");
    let g = put(&gw, "/api/v1/devices/io/fields/DO_3", json!(true)).await;
    assert_eq!(outcome(&gw, g).await["status"], "written");
    let g = put(&gw, "/api/v1/devices/io/fields/AO_1", json!(2.5)).await;
    assert_eq!(outcome(&gw, g).await["status"], "written");

    // The device switches its own coil off: the gateway writes it back.
    bus.slave(1, |s| s.tables.coils[3] = false);
    let field = gw
        .until("/api/v1/devices/io/fields/DO_3", "reconciled", |b| {
            b["last_write"]["origin"] == "reconcile" && b["last_write"]["status"] == "written"
        })
        .await
        .expect("reconcile");
    assert_eq!(field["value"], true);
    assert_eq!(bus.read_slave(1, |s| s.tables.coils[3]), Some(true));

    // A power cycle: every register back to zero; both outputs are restored.
    bus.slave(1, |s| s.tables = Default::default());
    iogate_tests::eventually("outputs restored after the power cycle", || async {
        bus.read_slave(1, |s| s.tables.coils[3] && s.tables.holding[1] == 2500)
            .unwrap_or(false)
    })
    .await
    .expect("restored");
    let (_, device) = gw.get("/api/v1/devices/io").await.expect("device");
    for name in ["DO_3", "AO_1"] {
        let f = &device["fields"][name];
        assert_eq!(f["last_write"]["origin"], "reconcile", "{f}");
    }
    gw.until("/api/v1/devices/io/fields/AO_1", "no mismatch", |b| {
        b["mismatch"] == false
    })
    .await
    .expect("agree");
    gw.shutdown().await;
    task.abort();
}

#[tokio::test]
async fn a_burst_of_ten_thousand_writes_erases_no_other_writers_outcome() {
    let gw = TestGateway::demo().await.expect("demo");
    let mut waiting = gw.client().await.expect("client");
    let mine = waiting
        .write("sim", "DO_0", iogate_client::Value::Bool(true))
        .await
        .expect("write");
    // Other clients: 10,000 writes over the plant's outputs, in calls of up to 4,096 items.
    let fields = ["PumpStart", "Recipe"];
    let mut newest = std::collections::HashMap::new();
    let mut sent = 0;
    let mut clients = Vec::new();
    for _ in 0..3 {
        clients.push(gw.client().await.expect("client"));
    }
    let mut k = 0;
    while sent < 10_000 {
        let n = (10_000 - sent).min(4096);
        let items: Vec<iogate_client::proto::FieldWrite> = (0..n)
            .map(|i| {
                let field = fields[(sent + i) % fields.len()];
                let kind = if field == "Recipe" {
                    iogate_client::proto::value::Kind::UintValue((i % 200) as u64)
                } else {
                    iogate_client::proto::value::Kind::BoolValue(i % 2 == 0)
                };
                iogate_client::proto::FieldWrite {
                    device: "plant".into(),
                    field: field.into(),
                    value: Some(iogate_client::proto::Value {
                        r#type: 0,
                        kind: Some(kind),
                    }),
                    relinquish: false,
                }
            })
            .collect();
        let which = k % clients.len();
        let answer = clients[which]
            .raw()
            .write(iogate_client::proto::WriteRequest {
                writes: items.clone(),
            })
            .await
            .expect("write")
            .into_inner();
        for (item, ack) in items.iter().zip(answer.acks) {
            newest.insert(item.field.clone(), ack.generation);
        }
        sent += n;
        k += 1;
    }
    // The waiting writer still has its outcome, and every field its newest.
    let status = waiting.write_status(mine).await.expect("still known");
    assert_eq!(status.generation, mine);
    for (field, generation) in &newest {
        let (code, body) = gw
            .get(&format!("/api/v1/writes/{generation}"))
            .await
            .expect("get");
        assert_eq!(code, 200, "{field}: {body}");
    }
    // An aged-out generation is answered the same way over REST (410) and gRPC.
    let oldest = newest.values().min().copied().unwrap_or(2) - 4096;
    let (code, body) = gw
        .get(&format!("/api/v1/writes/{oldest}"))
        .await
        .expect("get");
    assert_eq!(
        (code, &body["error"]["code"]),
        (410, &json!("write_expired"))
    );
    let refused = waiting.write_status(oldest).await.expect_err("aged out");
    assert!(refused.to_string().contains("aged out"), "{refused}");
    gw.shutdown().await;
}

#[tokio::test]
async fn a_lost_scan_cycle_client_gets_its_outputs_safe_after_the_lease_and_not_before() {
    let bus = RtuBus::default();
    bus.slave(1, |_| {});
    let (gw, _pty, task, _) = bus_gateway(
        "client-loss",
        &bus,
        &[],
        "  - { name: io, profile: MyIoModule, link: bus, slave_id: 1, refresh_rate: 50ms, on_client_loss: { after: 400ms, safe: { DO_0: false, DO_1: false } } }\n",
    )
    .await;
    gw.until("/api/v1/devices/io", "connected", |b| {
        b["connected"] == true
    })
    .await
    .expect("connected");
    let mut client = gw.client().await.expect("client");
    let mut exchange = client.exchange().await.expect("exchange");
    let on = iogate_client::Value::Bool(true);
    let reply = exchange
        .cycle(&[("io", "DO_0", on.clone()), ("io", "DO_1", on)], &["io"])
        .await
        .expect("cycle");
    assert_eq!(reply.written.len(), 2);
    iogate_tests::eventually("both coils on", || async {
        bus.read_slave(1, |s| s.tables.coils[0] && s.tables.coils[1])
            .unwrap_or(false)
    })
    .await
    .expect("on");
    // Another client takes DO_1 over: its value stands when the runtime is lost.
    put(&gw, "/api/v1/devices/io/fields/DO_1", json!(true)).await;

    drop(exchange);
    let gone = std::time::Instant::now();
    iogate_tests::eventually("DO_0 safe", || async {
        bus.read_slave(1, |s| !s.tables.coils[0]).unwrap_or(false)
    })
    .await
    .expect("safe value written");
    let after = gone.elapsed();
    assert!(
        after >= std::time::Duration::from_millis(400),
        "the safe value came {after:?} after the client left, before its lease"
    );
    let (_, field) = gw
        .get("/api/v1/devices/io/fields/DO_0")
        .await
        .expect("field");
    assert_eq!(field["last_write"]["origin"], "safety", "{field}");
    let metrics = gw.metrics().await.expect("metrics");
    assert!(
        metrics.contains("iogate_device_safe_value_writes_total{device=\"io\"} 1"),
        "{metrics}"
    );
    assert_eq!(bus.read_slave(1, |s| s.tables.coils[1]), Some(true));
    let (_, other) = gw
        .get("/api/v1/devices/io/fields/DO_1")
        .await
        .expect("field");
    assert_eq!(other["last_write"]["origin"], "client", "{other}");
    gw.shutdown().await;
    task.abort();
}

#[test]
fn safe_values_are_checked_against_the_profile() {
    let problems = |safe: &str| {
        let yaml = format!(
            "links:\n  - {{ name: bus, serial: {{ port: /dev/ttyUSB0, baud: 9600 }} }}\ndevices:\n  - {{ name: io, profile: MyIoModule, link: bus, slave_id: 1, on_client_loss: {safe} }}\n"
        );
        iogate::drivers::register();
        let mut config = iogate::config::parse("t.yaml", &yaml).map_err(|p| p.to_string())?;
        config.profiles = Some(iogate_tests::profiles_dir());
        iogate::app::Setup::from_config(config, std::path::Path::new("."))
            .map(drop)
            .map_err(|p| p.to_string())
    };
    assert!(problems("hold").is_ok());
    assert!(problems("{ after: 2s, safe: { DO_0: false, AO_0: 0 } }").is_ok());
    let e = problems("{ after: 2s, safe: { DI_0: false } }").expect_err("input");
    assert!(e.contains("DI_0 is an input"), "{e}");
    let e = problems("{ after: 2s, safe: { DO_0: maybe } }").expect_err("value");
    assert!(e.contains("not a BOOL value"), "{e}");
    let e = problems("{ after: 2s, safe: { NOPE: 1 } }").expect_err("field");
    assert!(e.contains("no field `NOPE`"), "{e}");
    let e = problems("drop").expect_err("policy");
    assert!(e.contains("not a client-loss policy"), "{e}");
}

#[tokio::test]
async fn a_failed_write_shows_as_a_mismatch_on_the_event_stream_at_once() {
    let bus = RtuBus::default();
    bus.slave(1, |s| s.busy_writes = u32::MAX);
    let (gw, _pty, task, _) = bus_gateway(
        "mismatch-sse",
        &bus,
        &[],
        "  - { name: io, profile: MyIoModule, link: bus, slave_id: 1, refresh_rate: 50ms, retries: 0 }\n",
    )
    .await;
    gw.until("/api/v1/devices/io", "connected", |b| {
        b["connected"] == true
    })
    .await
    .expect("connected");
    let mut events = iogate_tests::SseReader::open(&gw, "/api/v1/events?device=io")
        .await
        .expect("events");
    let g = put(&gw, "/api/v1/devices/io/fields/DO_2", json!(true)).await;
    let event = tokio::time::timeout(
        iogate_tests::PATIENCE,
        events.until(|name, data| {
            name == "value" && data["field"] == "DO_2" && data["mismatch"] == true
        }),
    )
    .await
    .expect("in time")
    .expect("a value event with the mismatch");
    assert_eq!(event["desired"], true, "{event}");
    assert_eq!(event["value"], false, "{event}");
    let done = outcome(&gw, g).await;
    assert_eq!(done["status"], "failed", "{done}");
    gw.shutdown().await;
    task.abort();
}

#[tokio::test]
async fn a_patch_of_adjacent_outputs_is_always_one_write_group() {
    let bus = RtuBus::default();
    bus.slave(1, |_| {});
    let (gw, _pty, task, _) = bus_gateway(
        "one-group",
        &bus,
        &[],
        "  - { name: vfd, profile: GenericVfd, link: bus, slave_id: 1, refresh_rate: 1s }\n",
    )
    .await;
    gw.until("/api/v1/devices/vfd", "connected", |b| {
        b["connected"] == true
    })
    .await
    .expect("connected");
    // FrequencySetpoint (register 1), AccelTime (2-3), DecelTime (4-5): adjacent, so one
    // FC16 of 5 registers at 1 each time, however the request meets the device's task.
    let mut last = 0;
    for k in 0..40u64 {
        let (status, body) = gw
            .send(
                Method::PATCH,
                "/api/v1/devices/vfd/fields",
                json!({"FrequencySetpoint": 10 + k, "AccelTime": 1000 + k, "DecelTime": 2000 + k})
                    .to_string(),
            )
            .await
            .expect("patch");
        assert_eq!(status, 202, "{body}");
        last = body["writes"]
            .as_array()
            .and_then(|w| w.iter().filter_map(|w| w["generation"].as_u64()).max())
            .unwrap_or_else(|| panic!("generations: {body}"));
        // The task idle, waiting for the next request: it wakes at its first write.
        outcome(&gw, last).await;
    }
    outcome(&gw, last).await;
    let writes: Vec<_> = bus
        .seen()
        .into_iter()
        .filter(|s| matches!(s.function, 6 | 16))
        .collect();
    assert!(!writes.is_empty());
    for w in &writes {
        assert_eq!((w.function, w.address, w.count), (16, 1, 5), "{writes:?}");
    }
    assert_eq!(
        bus.read_slave(1, |s| s.tables.holding[1..6].to_vec()),
        Some(vec![4900, 0, 1039, 0, 2039]),
    );
    gw.shutdown().await;
    task.abort();
}

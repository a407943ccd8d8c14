use super::*;

#[tokio::test]
async fn a_device_on_a_pty_is_written_by_dcmd_and_set_dies_and_is_born_again() {
    let broker = Broker::start().await.expect("mosquitto");
    let bus = RtuBus::default();
    bus.slave(1, |s| s.tables.input[0] = 123);
    let extra = format!(
        "mqtt:
  url: mqtt://127.0.0.1:{}
  client_id: iogate-pty
  sparkplug: {{ group_id: plant1, edge_node_id: line1 }}
  json: {{ prefix: iogate/line1, qos: 1, retain: true }}
  writes: true
",
        broker.port
    );
    let mut peer = Peer::subscribe(&broker, "#").await.expect("paho");
    let (gw, _pty, task, _) = bus_gateway_with(
        "mqtt-pty",
        &bus,
        &[],
        "  - { name: io, profile: MyIoModule, link: bus, slave_id: 1, refresh_rate: 50ms }\n",
        &extra,
    )
    .await;
    let birth = peer
        .until(|m| m.topic == "spBv1.0/plant1/DBIRTH/line1/io")
        .await
        .expect("DBIRTH");
    let ai = metric(&birth, "AI_0").expect("AI_0");
    assert_eq!(ai["datatype"], "FLOAT", "{ai}");
    assert!(
        (ai["value"].as_f64().unwrap_or_default() - 12.3).abs() < 1e-4,
        "{ai}"
    );
    // The device's inputs change in one poll: one DDATA carries them, by alias (each
    // change goes as soon as it is seen, so a poll seen in two parts is tried again).
    let mut together = false;
    for attempt in 0..5u16 {
        let raw = [150 + attempt, 160 + attempt, 170 + attempt];
        bus.slave(1, |s| s.tables.input[..3].copy_from_slice(&raw));
        let mut seen = [false; 3];
        while !seen.iter().all(|s| *s) {
            let data = peer
                .until(|m| m.topic == "spBv1.0/plant1/DDATA/line1/io")
                .await
                .expect("DDATA");
            assert!(data.decode_error.is_none());
            let carried: Vec<usize> = (0..3)
                .filter(|&i| {
                    metric(&data, &format!("AI_{i}")).is_some_and(|x| {
                        (x["value"].as_f64().unwrap_or_default() - f64::from(raw[i]) / 10.0).abs()
                            < 1e-4
                    })
                })
                .collect();
            together |= carried.len() == 3;
            for i in carried {
                seen[i] = true;
            }
        }
        if together {
            break;
        }
    }
    assert!(together, "a poll's three changes never came in one DDATA");
    // A DCMD and a /set write reach the slave on the line.
    peer.command(
        "spBv1.0/plant1/DCMD/line1/io",
        serde_json::json!([{"name": "DO_0", "datatype": "BOOLEAN", "value": true}]),
    )
    .await
    .expect("DCMD");
    peer.publish("iogate/line1/io/DO_1/set", r#"{"value": true}"#)
        .await
        .expect("set");
    eventually("both coils written on the line", || async {
        bus.read_slave(1, |s| s.tables.coils[0] && s.tables.coils[1]) == Some(true)
    })
    .await
    .expect("written");
    // The device stops answering: DDEATH (and its $state says so); back: DBIRTH.
    bus.slave(1, |s| s.behaviour = Behaviour::Silent);
    peer.until(|m| m.topic == "spBv1.0/plant1/DDEATH/line1/io")
        .await
        .expect("DDEATH");
    let (_, state) = gw.get("/api/v1/devices/io").await.expect("device");
    assert_eq!(state["connected"], false, "{state}");
    bus.slave(1, |s| s.behaviour = Behaviour::Normal);
    let again = peer
        .until(|m| m.topic == "spBv1.0/plant1/DBIRTH/line1/io")
        .await
        .expect("DBIRTH again");
    assert_eq!(metric(&again, "DO_0").expect("DO_0")["value"], true);
    gw.shutdown().await;
    task.abort();
    peer.stop().await;
    broker.stop().await;
}

#[tokio::test]
async fn a_killed_gateway_dies_by_its_will_and_its_buffer_survives_a_kill() {
    const BIN: &str = env!("CARGO_BIN_EXE_gateway");
    let mut broker = Broker::start_persistent().await.expect("mosquitto");
    let dir = iogate_tests::devices::temp_dir("mqtt-kill");
    let config = process_config(broker.port, &dir);
    let mut peer = Peer::subscribe_kept(&broker, "#", &format!("kill-{}", broker.port))
        .await
        .expect("paho");
    // Killed while connected: the broker publishes the Will, NDEATH with the bdSeq of the
    // NBIRTH before it.
    let first = GatewayProcess::start(BIN, &dir, &config)
        .await
        .expect("gateway");
    let birth = peer
        .until(|m| m.topic == "spBv1.0/plant1/NBIRTH/line1")
        .await
        .expect("NBIRTH");
    let bd_seq = metric(&birth, "bdSeq").expect("bdSeq")["value"].clone();
    peer.until(|m| m.topic == "spBv1.0/plant1/DBIRTH/line1/sim")
        .await
        .expect("DBIRTH");
    first.kill().await.expect("kill");
    let death = peer
        .until(|m| m.topic == "spBv1.0/plant1/NDEATH/line1")
        .await
        .expect("NDEATH by the Will");
    assert_eq!(metric(&death, "bdSeq").expect("bdSeq")["value"], bd_seq);
    // Started again: the next bdSeq. The broker goes away, ten changes are buffered, the
    // gateway is killed.
    let second = GatewayProcess::start(BIN, &dir, &config)
        .await
        .expect("gateway again");
    let birth = peer
        .until(|m| m.topic == "spBv1.0/plant1/NBIRTH/line1")
        .await
        .expect("NBIRTH");
    assert_eq!(
        metric(&birth, "bdSeq").expect("bdSeq")["value"].as_u64(),
        bd_seq.as_u64().map(|b| b + 1)
    );
    let gw = &second.gateway;
    gw.until("/api/v1/mqtt", "nothing buffered", |s| {
        s["buffer"]["messages"] == 0 && s["sparkplug"]["born_devices"] == 1
    })
    .await
    .expect("born");
    broker.pause().await;
    let status = gw
        .until("/api/v1/mqtt", "disconnected", |s| s["connected"] == false)
        .await
        .expect("disconnected");
    let base = status["buffer"]["messages"].as_u64().unwrap_or_default();
    for n in 0..10u64 {
        let (status, body) = gw
            .send(
                Method::PUT,
                "/api/v1/devices/sim/fields/DI_0/simulate",
                format!(r#"{{"value": {}}}"#, n % 2 == 0),
            )
            .await
            .expect("simulate");
        assert!((200..300).contains(&status), "{status} {body}");
        gw.until("/api/v1/mqtt", "buffered", |s| {
            s["buffer"]["messages"].as_u64() == Some(base + 2 * (n + 1))
        })
        .await
        .expect("buffered");
    }
    second.kill().await.expect("kill");
    broker.resume().await.expect("mosquitto again");
    peer.resync("iogate-test/marker").await.expect("peer back");
    // A third start replays what the killed one kept, in order, as history.
    let third = GatewayProcess::start(BIN, &dir, &config)
        .await
        .expect("gateway a third time");
    let expected: Vec<serde_json::Value> =
        (0..10u64).map(|n| serde_json::json!(n % 2 == 0)).collect();
    let mut history_json = Vec::new();
    let mut history_sparkplug = Vec::new();
    while !history_json.ends_with(&expected) || !history_sparkplug.ends_with(&expected) {
        let m = match peer.next().await {
            Ok(m) => m,
            Err(e) => {
                let status = third.gateway.get("/api/v1/mqtt").await;
                panic!("{e}: JSON {history_json:?}, Sparkplug {history_sparkplug:?}; {status:?}")
            }
        };
        if m.topic == "iogate/line1/history/sim/DI_0" {
            history_json.push(m.json()["value"].clone());
        } else if m.topic == "spBv1.0/plant1/DDATA/line1/sim"
            && let Some(di) = metric(&m, "DI_0")
            && di["is_historical"] == true
        {
            history_sparkplug.push(di["value"].clone());
        }
    }
    third
        .gateway
        .until("/api/v1/mqtt", "the buffer emptied", |s| {
            s["buffer"]["messages"] == 0
        })
        .await
        .expect("emptied");
    third.kill().await.expect("kill");
    peer.stop().await;
    broker.stop().await;
}

#[tokio::test]
async fn two_gateways_are_two_edge_nodes_of_one_namespace() {
    let broker = Broker::start().await.expect("mosquitto");
    let mut peer = Peer::subscribe(&broker, "spBv1.0/plant1/#")
        .await
        .expect("paho");
    let node = |id: &str| {
        format!(
            "devices:
  - {{ name: sim, profile: SimIo, refresh_rate: 50ms }}
mqtt:
  url: mqtt://127.0.0.1:{}
  client_id: iogate-{id}
  sparkplug: {{ group_id: plant1, edge_node_id: {id} }}
  writes: true
",
            broker.port
        )
    };
    let line1 = TestGateway::start(&node("line1")).await.expect("line1");
    let line2 = TestGateway::start(&node("line2")).await.expect("line2");
    let mut births = std::collections::BTreeSet::new();
    while births.len() < 4 {
        let m = peer.next().await.expect("message");
        assert!(m.decode_error.is_none(), "{m:?}");
        if m.topic.contains("BIRTH") {
            births.insert(m.topic.clone());
        }
    }
    assert_eq!(
        births.into_iter().collect::<Vec<_>>(),
        [
            "spBv1.0/plant1/DBIRTH/line1/sim",
            "spBv1.0/plant1/DBIRTH/line2/sim",
            "spBv1.0/plant1/NBIRTH/line1",
            "spBv1.0/plant1/NBIRTH/line2",
        ]
    );
    // A command to one node's device reaches that gateway only.
    peer.command(
        "spBv1.0/plant1/DCMD/line2/sim",
        serde_json::json!([{"name": "DO_0", "datatype": "BOOLEAN", "value": true}]),
    )
    .await
    .expect("DCMD");
    line2
        .until("/api/v1/devices/sim/fields/DO_0", "written on line2", |f| {
            f["value"] == true
        })
        .await
        .expect("line2");
    let (_, on_line1) = line1
        .get("/api/v1/devices/sim/fields/DO_0")
        .await
        .expect("line1");
    assert_eq!(on_line1["value"], false);
    // One node stops: its NDEATH; the other keeps publishing.
    line1.shutdown().await;
    peer.until(|m| m.topic == "spBv1.0/plant1/NDEATH/line1")
        .await
        .expect("NDEATH line1");
    line2
        .send(
            Method::PUT,
            "/api/v1/devices/sim/fields/DI_0/simulate",
            r#"{"value": true}"#.to_owned(),
        )
        .await
        .expect("simulate");
    peer.until(|m| {
        m.topic == "spBv1.0/plant1/DDATA/line2/sim"
            && metric(m, "DI_0").is_some_and(|x| x["value"] == true)
    })
    .await
    .expect("DDATA line2");
    line2.shutdown().await;
    peer.stop().await;
    broker.stop().await;
}

#[tokio::test]
async fn births_wait_for_the_primary_host_and_follow_its_state() {
    let broker = Broker::start().await.expect("mosquitto");
    let mut peer = Peer::subscribe(&broker, "spBv1.0/#").await.expect("paho");
    let config = format!(
        "devices:
  - {{ name: sim, profile: SimIo, refresh_rate: 50ms }}
mqtt:
  url: mqtt://127.0.0.1:{}
  client_id: iogate-host
  sparkplug: {{ group_id: plant1, edge_node_id: line1, primary_host: scada }}
",
        broker.port
    );
    let gw = TestGateway::start(&config).await.expect("gateway");
    gw.until("/api/v1/mqtt", "connected, waiting for the host", |s| {
        s["connected"] == true
    })
    .await
    .expect("connected");
    // The host comes online (STATE is retained): NBIRTH and DBIRTH follow, nothing before.
    let state = |online: bool, at: u64| format!(r#"{{"online": {online}, "timestamp": {at}}}"#);
    peer.publish_retained("spBv1.0/STATE/scada", &state(true, 1000))
        .await
        .expect("STATE");
    let first = peer
        .until(|m| m.topic.starts_with("spBv1.0/plant1/"))
        .await
        .expect("birth");
    assert_eq!(first.topic, "spBv1.0/plant1/NBIRTH/line1");
    let bd_seq = metric(&first, "bdSeq").expect("bdSeq")["value"].clone();
    peer.until(|m| m.topic == "spBv1.0/plant1/DBIRTH/line1/sim")
        .await
        .expect("DBIRTH");
    gw.until("/api/v1/mqtt", "the host online", |s| {
        s["sparkplug"]["host_online"] == true && s["sparkplug"]["born"] == true
    })
    .await
    .expect("status");
    // An older STATE is no news; the host going offline: NDEATH, then a new session that
    // waits for it again.
    peer.publish_retained("spBv1.0/STATE/scada", &state(false, 999))
        .await
        .expect("old STATE");
    peer.publish_retained("spBv1.0/STATE/scada", &state(false, 2000))
        .await
        .expect("STATE offline");
    let m = peer
        .until(|m| m.topic.starts_with("spBv1.0/plant1/"))
        .await
        .expect("NDEATH");
    assert_eq!(m.topic, "spBv1.0/plant1/NDEATH/line1");
    assert_eq!(metric(&m, "bdSeq").expect("bdSeq")["value"], bd_seq);
    gw.until("/api/v1/mqtt", "a new session waiting", |s| {
        s["connected"] == true && s["sparkplug"]["born"] == false && s["reconnects"] == 1
    })
    .await
    .expect("waiting again");
    peer.publish_retained("spBv1.0/STATE/scada", &state(true, 3000))
        .await
        .expect("STATE online");
    let again = peer
        .until(|m| m.topic.starts_with("spBv1.0/plant1/"))
        .await
        .expect("birth again");
    assert_eq!(again.topic, "spBv1.0/plant1/NBIRTH/line1");
    assert_eq!(
        metric(&again, "bdSeq").expect("bdSeq")["value"].as_u64(),
        bd_seq.as_u64().map(|b| b + 1)
    );
    gw.shutdown().await;
    peer.stop().await;
    broker.stop().await;
}

#[tokio::test]
async fn mqtts_with_a_client_certificate_and_mqtt_5() {
    let ca = iogate_tests::pki::TestCa::new("mqtt-test-ca").expect("ca");
    let broker = Broker::start_tls(&ca.pem(), &ca.server().expect("server"))
        .await
        .expect("mosquitto");
    let tls_port = broker.tls_port.expect("tls port");
    let dir = iogate_tests::devices::temp_dir("mqtt-tls");
    let client = ca.client("iogate-line1").expect("client");
    std::fs::write(dir.join("ca.pem"), ca.pem()).expect("ca");
    std::fs::write(dir.join("client.pem"), &client.cert).expect("cert");
    std::fs::write(dir.join("client.key"), &client.key).expect("key");
    let mut peer = Peer::subscribe(&broker, "iogate/#").await.expect("paho");
    let config = |cert: bool| {
        let tls = if cert {
            format!(
                "{{ ca: {d}/ca.pem, cert: {d}/client.pem, key: {d}/client.key }}",
                d = dir.display()
            )
        } else {
            format!("{{ ca: {}/ca.pem }}", dir.display())
        };
        format!(
            "devices:
  - {{ name: sim, profile: SimIo, refresh_rate: 50ms }}
mqtt:
  url: mqtts://127.0.0.1:{tls_port}
  client_id: iogate-tls
  version: 5
  tls: {tls}
  json: {{ prefix: iogate/tls, qos: 1 }}
"
        )
    };
    // With its certificate: connected over TLS with MQTT 5, and what it publishes arrives
    // (the peer is on the broker's plain listener).
    let gw = TestGateway::start(&config(true)).await.expect("gateway");
    let di = peer
        .until(|m| m.topic == "iogate/tls/sim/DI_0")
        .await
        .expect("DI_0 over TLS");
    assert_eq!(di.json()["field"], "DI_0");
    gw.until("/api/v1/mqtt", "connected", |s| {
        s["connected"] == true && s["broker"] == format!("mqtts://127.0.0.1:{tls_port}")
    })
    .await
    .expect("connected");
    gw.shutdown().await;
    // Without one, the broker refuses it: not connected, and the status says why.
    let gw = TestGateway::start(&config(false)).await.expect("gateway");
    let status = gw
        .until("/api/v1/mqtt", "refused", |s| {
            s["connected"] == false && s["last_error"].is_string()
        })
        .await
        .expect("refused");
    assert_eq!(status["messages_out"], 0, "{status}");
    gw.shutdown().await;
    peer.stop().await;
    broker.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn connections_refused_before_any_connect_take_no_bd_seq() {
    let mut broker = Broker::start().await.expect("mosquitto");
    // Nothing listens on the broker's port: every attempt fails before a CONNECT is sent.
    broker.pause().await;
    let gw = TestGateway::start(&sparkplug_config("bdseq", broker.port, ""))
        .await
        .expect("gateway");
    gw.until("/api/v1/mqtt", "an attempt refused", |s| {
        s["connected"] == false && s["last_error"].is_string()
    })
    .await
    .expect("refused");
    broker.resume().await.expect("mosquitto again");
    gw.until("/api/v1/mqtt", "connected", |s| s["connected"] == true)
        .await
        .expect("connected");
    let mut peer = Peer::subscribe(&broker, "spBv1.0/plant1/#")
        .await
        .expect("paho");
    peer.command(
        "spBv1.0/plant1/NCMD/line1",
        serde_json::json!([{"name": "Node Control/Rebirth", "datatype": "BOOLEAN", "value": true}]),
    )
    .await
    .expect("NCMD");
    let birth = peer
        .until(|m| m.topic == "spBv1.0/plant1/NBIRTH/line1")
        .await
        .expect("NBIRTH");
    // The first CONNECT sent carries 0, however many attempts failed before it.
    assert_eq!(metric(&birth, "bdSeq").expect("bdSeq")["value"], 0);
    gw.shutdown().await;
}

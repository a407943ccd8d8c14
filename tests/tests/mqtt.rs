//! The MQTT front-end against a real Mosquitto, with paho-mqtt as the independent peer.

use iogate_tests::devices::{Behaviour, RtuBus};
use iogate_tests::mqtt::{Broker, Message, Peer, sparkplug_config};
use iogate_tests::{GatewayProcess, TestGateway, bus_gateway_with, eventually};
use reqwest::Method;

fn config(port: u16, writes: bool) -> String {
    format!(
        "devices:
  - {{ name: sim, profile: SimIo, refresh_rate: 100ms }}
mqtt:
  url: mqtt://127.0.0.1:{port}
  client_id: iogate-test-{port}
  json: {{ prefix: iogate/line1, qos: 1, retain: true }}
  writes: {writes}
"
    )
}

#[tokio::test]
async fn fields_are_published_as_their_rest_json_and_set_topics_write() {
    let broker = Broker::start().await.expect("mosquitto");
    let gw = TestGateway::start(&config(broker.port, true))
        .await
        .expect("gateway");
    let mut peer = Peer::subscribe(&broker, "iogate/line1/#")
        .await
        .expect("paho");
    // The gateway's state, retained, and every field's JSON, retained.
    let state = peer
        .until(|m| m.topic == "iogate/line1/$state")
        .await
        .expect("$state");
    assert_eq!(state.json()["online"], true);
    assert!(state.retain);
    let di = peer
        .until(|m| m.topic == "iogate/line1/sim/DI_0")
        .await
        .expect("DI_0");
    let (_, rest) = gw
        .get("/api/v1/devices/sim/fields/DI_0")
        .await
        .expect("rest");
    for key in ["device", "field", "type", "direction", "value", "quality"] {
        assert_eq!(di.json()[key], rest[key], "{key}: {} vs {rest}", di.payload);
    }
    // A change is published.
    let (status, _) = gw
        .send(
            Method::PUT,
            "/api/v1/devices/sim/fields/DI_0/simulate",
            r#"{"value": true}"#.to_owned(),
        )
        .await
        .expect("simulate");
    assert!((200..300).contains(&status), "{status}");
    peer.until(|m| m.topic == "iogate/line1/sim/DI_0" && m.json()["value"] == true)
        .await
        .expect("the change");
    // A write: accepted (pending), then its outcome; the field's new value is published.
    peer.publish("iogate/line1/sim/DO_0/set", r#"{"value": true}"#)
        .await
        .expect("publish");
    let accepted = peer
        .until(|m| m.topic == "iogate/line1/sim/DO_0/set/result")
        .await
        .expect("result");
    let generation = accepted.json()["generation"].as_u64().expect("generation");
    assert_eq!(accepted.json()["status"], "pending");
    let outcome = peer
        .until(|m| m.topic == "iogate/line1/sim/DO_0/set/result" && m.json()["status"] != "pending")
        .await
        .expect("outcome");
    assert_eq!(outcome.json()["status"], "written", "{}", outcome.payload);
    assert_eq!(outcome.json()["generation"], generation);
    let (_, rest) = gw.get("/api/v1/writes/1").await.expect("write");
    assert_eq!(rest["status"], "written");
    // Refused writes name the problem as REST does, and change nothing.
    peer.publish("iogate/line1/sim/DI_0/set", "false")
        .await
        .expect("publish");
    let refused = peer
        .until(|m| m.topic == "iogate/line1/sim/DI_0/set/result")
        .await
        .expect("refusal");
    assert_eq!(refused.json()["error"]["code"], "not_writable");
    peer.publish("iogate/line1/sim/DO_0/set", "{not json")
        .await
        .expect("publish");
    let refused = peer
        .until(|m| m.topic == "iogate/line1/sim/DO_0/set/result")
        .await
        .expect("refusal");
    assert_eq!(refused.json()["error"]["code"], "invalid_body");
    // Shutting down marks the gateway offline (retained).
    gw.shutdown().await;
    let offline = peer
        .until(|m| m.topic == "iogate/line1/$state")
        .await
        .expect("offline");
    assert_eq!(offline.json()["online"], false);
    peer.stop().await;
    broker.stop().await;
}

#[tokio::test]
async fn without_writes_enabled_nothing_is_written() {
    let broker = Broker::start().await.expect("mosquitto");
    let gw = TestGateway::start(&config(broker.port, false))
        .await
        .expect("gateway");
    let mut peer = Peer::subscribe(&broker, "iogate/line1/#")
        .await
        .expect("paho");
    peer.until(|m| m.topic == "iogate/line1/sim/DO_0")
        .await
        .expect("DO_0");
    peer.publish("iogate/line1/sim/DO_0/set", "true")
        .await
        .expect("publish");
    // The gateway does not subscribe to writes: the message reaches only the peer itself,
    // and no write is logged.
    peer.until(|m| m.topic == "iogate/line1/sim/DO_0/set")
        .await
        .expect("echo");
    let (status, _) = gw.get("/api/v1/writes/1").await.expect("write");
    assert_eq!(status, 404);
    gw.shutdown().await;
    peer.stop().await;
    broker.stop().await;
}

fn metric<'a>(m: &'a Message, name: &str) -> Option<&'a serde_json::Value> {
    m.sparkplug["metrics"]
        .as_array()?
        .iter()
        .find(|x| x["name"] == name)
}

/// The first message for which `f` holds; every message on the way is kept in `seen`.
async fn until(
    peer: &mut Peer,
    seen: &mut Vec<Message>,
    f: impl Fn(&Message) -> bool,
) -> anyhow::Result<Message> {
    loop {
        let m = peer.next().await?;
        seen.push(m.clone());
        if f(&m) {
            return Ok(m);
        }
    }
}

/// Every Sparkplug message of the node after an NBIRTH has the next `seq`, wrapping at 256.
fn assert_seq_follows(messages: &[Message]) {
    let mut expected: Option<u64> = None;
    for m in messages {
        let kind = m.sparkplug["type"].as_str().unwrap_or_default();
        if kind == "NDEATH" || kind.ends_with("CMD") {
            continue;
        }
        let seq = m.sparkplug["seq"].as_u64().expect("seq");
        if kind == "NBIRTH" {
            assert_eq!(seq, 0, "NBIRTH seq");
        } else if let Some(e) = expected {
            assert_eq!(seq, e, "{} seq", m.topic);
        }
        expected = Some((seq + 1) % 256);
    }
}

#[tokio::test]
async fn a_sparkplug_edge_node_births_reports_by_alias_rebirths_and_takes_commands() {
    let broker = Broker::start().await.expect("mosquitto");
    let mut peer = Peer::subscribe(&broker, "spBv1.0/#").await.expect("paho");
    let gw = TestGateway::start(&sparkplug_config("iogate-sp", broker.port, ""))
        .await
        .expect("gateway");
    // Every message seen, in order, for the `seq` check.
    let mut seen = Vec::new();
    let nbirth = until(&mut peer, &mut seen, |m| {
        m.topic == "spBv1.0/plant1/NBIRTH/line1"
    })
    .await
    .expect("NBIRTH");
    assert_eq!(nbirth.decode_error, None);
    assert!(!nbirth.retain);
    let bd_seq = metric(&nbirth, "bdSeq").expect("bdSeq")["value"].clone();
    assert_eq!(
        metric(&nbirth, "Node Control/Rebirth").expect("rebirth")["value"],
        false
    );
    let dbirth = until(&mut peer, &mut seen, |m| {
        m.topic == "spBv1.0/plant1/DBIRTH/line1/sim"
    })
    .await
    .expect("DBIRTH");
    assert_eq!(dbirth.decode_error, None);
    let di = metric(&dbirth, "DI_0").expect("DI_0");
    assert_eq!(di["datatype"], "BOOLEAN");
    assert!(di["alias"].as_u64().is_some(), "{di}");
    for d in ["connected", "error_code", "io_cycles", "last_response_ms"] {
        assert!(
            metric(&dbirth, &format!("Diagnostics/{d}")).is_some(),
            "{d}"
        );
    }
    assert_eq!(
        metric(&dbirth, "Diagnostics/connected").expect("connected")["value"],
        true
    );
    // A change: DDATA by alias, which pysparkplug resolves against the DBIRTH.
    gw.send(
        Method::PUT,
        "/api/v1/devices/sim/fields/DI_0/simulate",
        r#"{"value": true}"#.to_owned(),
    )
    .await
    .expect("simulate");
    let ddata = until(&mut peer, &mut seen, |m| {
        m.topic == "spBv1.0/plant1/DDATA/line1/sim"
            && metric(m, "DI_0").is_some_and(|x| x["value"] == true)
    })
    .await
    .expect("DDATA");
    let di = metric(&ddata, "DI_0").expect("DI_0");
    assert_eq!(di["is_historical"], false);
    assert!(ddata.decode_error.is_none());
    // A DCMD write goes through the service: the output takes the value.
    peer.command(
        "spBv1.0/plant1/DCMD/line1/sim",
        serde_json::json!([{"name": "DO_0", "datatype": "BOOLEAN", "value": true}]),
    )
    .await
    .expect("DCMD");
    gw.until("/api/v1/devices/sim/fields/DO_0", "DO_0 written", |f| {
        f["value"] == true
    })
    .await
    .expect("written");
    // A refused one (an input) is counted and changes nothing.
    peer.command(
        "spBv1.0/plant1/DCMD/line1/sim",
        serde_json::json!([{"name": "DI_0", "datatype": "BOOLEAN", "value": false}]),
    )
    .await
    .expect("DCMD");
    gw.until("/api/v1/mqtt", "the refusal counted", |s| {
        s["writes_refused"].as_u64() >= Some(1)
    })
    .await
    .expect("refused");
    let (_, di_now) = gw
        .get("/api/v1/devices/sim/fields/DI_0")
        .await
        .expect("DI_0");
    assert_eq!(di_now["value"], true);
    // Rebirth: NBIRTH (seq 0, same bdSeq) and the DBIRTH again, no death before.
    peer.command(
        "spBv1.0/plant1/NCMD/line1",
        serde_json::json!([{"name": "Node Control/Rebirth", "datatype": "BOOLEAN", "value": true}]),
    )
    .await
    .expect("NCMD");
    loop {
        let m = peer.next().await.expect("message");
        assert!(
            !m.topic.contains("DEATH"),
            "a death before the rebirth: {}",
            m.topic
        );
        let done = m.topic == "spBv1.0/plant1/NBIRTH/line1";
        if done {
            assert_eq!(metric(&m, "bdSeq").expect("bdSeq")["value"], bd_seq);
        }
        seen.push(m);
        if done {
            break;
        }
    }
    until(&mut peer, &mut seen, |m| {
        m.topic == "spBv1.0/plant1/DBIRTH/line1/sim"
    })
    .await
    .expect("DBIRTH again");
    assert_seq_follows(&seen);
    gw.until("/api/v1/mqtt", "one rebirth", |s| {
        s["sparkplug"]["rebirths"] == 1 && s["connected"] == true
    })
    .await
    .expect("status");
    // Stopping: NDEATH with the connection's bdSeq.
    gw.shutdown().await;
    let ndeath = until(&mut peer, &mut seen, |m| {
        m.topic == "spBv1.0/plant1/NDEATH/line1"
    })
    .await
    .expect("NDEATH");
    assert_eq!(metric(&ndeath, "bdSeq").expect("bdSeq")["value"], bd_seq);
    peer.stop().await;
    broker.stop().await;
}

#[tokio::test]
async fn while_the_broker_is_away_changes_are_kept_and_replayed_in_order_beside_live_data() {
    let mut broker = Broker::start_persistent().await.expect("mosquitto");
    let dir = iogate_tests::devices::temp_dir("mqtt-buffer");
    let extra = format!(
        "  json: {{ prefix: iogate/line1, qos: 1, retain: true }}
  buffer: {{ dir: {}, replay_rate: 20/s }}
",
        dir.display()
    );
    let mut peer = Peer::subscribe_kept(&broker, "#", &format!("peer-{}", broker.port))
        .await
        .expect("paho");
    // The gateway reaches the broker through a gate, so that after the outage it comes
    // back only once the peer has (what it replays must find the peer subscribed).
    let gate = iogate_tests::mqtt::Gate::to(broker.port)
        .await
        .expect("gate");
    let gw = TestGateway::start(&sparkplug_config("iogate-sp", gate.port, &extra))
        .await
        .expect("gateway");
    peer.until(|m| m.topic == "spBv1.0/plant1/DBIRTH/line1/sim")
        .await
        .expect("DBIRTH");
    // What was read before the first connection is replayed first.
    gw.until("/api/v1/mqtt", "the first replay", |s| {
        s["buffer"]["messages"] == 0
    })
    .await
    .expect("first replay");
    gate.shut();
    broker.pause().await;
    let status = gw
        .until("/api/v1/mqtt", "disconnected", |s| s["connected"] == false)
        .await
        .expect("disconnected");
    let base = status["buffer"]["messages"].as_u64().unwrap_or_default();
    // Ten changes while the broker is away; each reaches the buffer (one JSON message and
    // one Sparkplug metric per change) before the next is made (a value overwritten
    // within one poll cycle is never seen).
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
    broker.resume().await.expect("mosquitto again");
    peer.resync("iogate-test/marker").await.expect("peer back");
    gate.open();
    gw.until("/api/v1/mqtt", "reconnected", |s| s["connected"] == true)
        .await
        .expect("reconnected");
    // A live change right after: it must not wait behind the replay (20 messages at 20/s).
    gw.send(
        Method::PUT,
        "/api/v1/devices/sim/fields/DO_0/simulate",
        r#"{"value": true}"#.to_owned(),
    )
    .await
    .ok();
    gw.send(
        Method::PUT,
        "/api/v1/devices/sim/fields/DI_0/simulate",
        r#"{"value": true}"#.to_owned(),
    )
    .await
    .expect("simulate");
    let mut history_json = Vec::new();
    let mut history_sparkplug = Vec::new();
    let mut live_at = None;
    let mut index = 0;
    let expected: Vec<serde_json::Value> =
        (0..10u64).map(|n| serde_json::json!(n % 2 == 0)).collect();
    // The replay ends with the ten changes in order (a message unconfirmed when the broker
    // went away may come before them).
    while !history_json.ends_with(&expected) || !history_sparkplug.ends_with(&expected) {
        let m = match peer.next().await {
            Ok(m) => m,
            Err(e) => {
                let status = gw.get("/api/v1/mqtt").await;
                panic!("{e}: JSON {history_json:?}, Sparkplug {history_sparkplug:?}; {status:?}")
            }
        };
        index += 1;
        if m.topic == "iogate/line1/history/sim/DI_0" {
            assert!(!m.retain, "a replay must not be retained");
            history_json.push(m.json()["value"].clone());
        } else if m.topic == "spBv1.0/plant1/DDATA/line1/sim"
            && let Some(di) = metric(&m, "DI_0")
        {
            if di["is_historical"] == true {
                history_sparkplug.push(di["value"].clone());
            } else if live_at.is_none() {
                live_at = Some(index);
            }
        }
    }
    assert!(
        live_at.is_some_and(|at| at < index),
        "the live value came after the whole replay ({live_at:?} of {index})"
    );
    gw.until("/api/v1/mqtt", "the buffer emptied", |s| {
        s["buffer"]["messages"] == 0 && s["buffer"]["replayed"].as_u64() >= Some(20)
    })
    .await
    .expect("emptied");
    gw.shutdown().await;
    peer.stop().await;
    broker.stop().await;
}

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
    // The device's input changes: DDATA by alias.
    bus.slave(1, |s| s.tables.input[0] = 150);
    let data = peer
        .until(|m| {
            m.topic == "spBv1.0/plant1/DDATA/line1/io"
                && metric(m, "AI_0").is_some_and(|x| x["value"].as_f64() == Some(15.0))
        })
        .await
        .expect("DDATA");
    assert!(data.decode_error.is_none());
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

fn process_config(port: u16, dir: &std::path::Path) -> String {
    sparkplug_config(
        "iogate-sp",
        port,
        &format!(
            "  json: {{ prefix: iogate/line1, qos: 1, retain: true }}
  buffer: {{ dir: {}, replay_rate: 100/s }}
",
            dir.join("buffer").display()
        ),
    )
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

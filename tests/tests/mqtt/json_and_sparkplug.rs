use super::*;

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

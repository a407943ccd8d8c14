//! A retained `/set` or DCMD is a message the broker stored, not a command now: the gateway
//! does not execute it when it subscribes (at every start and reconnect).

use super::*;

#[tokio::test]
async fn retained_writes_and_commands_are_not_executed_at_subscribe() {
    let broker = Broker::start().await.expect("mosquitto");
    let mut peer = Peer::subscribe(&broker, "iogate/line1/#")
        .await
        .expect("paho");
    // Stored on the broker before the gateway starts (or while it is away).
    peer.publish_retained("iogate/line1/sim/DO_0/set", "true")
        .await
        .expect("retained /set");
    peer.command_retained(
        "spBv1.0/plant1/DCMD/line1/sim",
        serde_json::json!([{"name": "DO_0", "datatype": "BOOLEAN", "value": true}]),
    )
    .await
    .expect("retained DCMD");
    let config = sparkplug_config(
        "retained",
        broker.port,
        "  json: { prefix: iogate/line1, qos: 1, retain: true }\n",
    );
    let gw = TestGateway::start(&config).await.expect("gateway");
    gw.until("/api/v1/mqtt", "both stored messages seen", |m| {
        m["retained_ignored"].as_u64().unwrap_or(0) >= 2
    })
    .await
    .expect("counted");
    let (_, field) = gw
        .get("/api/v1/devices/sim/fields/DO_0")
        .await
        .expect("field");
    assert_eq!(field["value"], false, "{field}");
    assert!(field["last_write"].is_null(), "nothing written: {field}");
    let (status, _) = gw.get("/api/v1/writes/1").await.expect("write");
    assert_eq!(status, 404, "no write was asked");
    // A command now (not retained) is executed.
    peer.publish("iogate/line1/sim/DO_0/set", "true")
        .await
        .expect("publish");
    gw.until("/api/v1/devices/sim/fields/DO_0", "written", |f| {
        f["value"] == true
    })
    .await
    .expect("written");
    let metrics = gw.metrics().await.expect("metrics");
    assert!(
        metrics.contains("iogate_mqtt_writes_total{outcome=\"retained\"} 2"),
        "{metrics}"
    );
    gw.shutdown().await;
    peer.stop().await;
    broker.stop().await;
}

#[tokio::test]
async fn one_ncmd_of_thirty_thousand_rebirth_metrics_is_one_rebirth() {
    let broker = Broker::start().await.expect("mosquitto");
    let mut peer = Peer::subscribe(&broker, "spBv1.0/plant1/#")
        .await
        .expect("paho");
    let config = sparkplug_config(
        "rebirths",
        broker.port,
        "  json: { prefix: iogate/line1, qos: 1, retain: true }\n",
    );
    let gw = TestGateway::start(&config).await.expect("gateway");
    peer.until(|m| m.topic == "spBv1.0/plant1/DBIRTH/line1/sim")
        .await
        .expect("born");
    let rebirth =
        serde_json::json!({"name": "Node Control/Rebirth", "datatype": "BOOLEAN", "value": true});
    let many = serde_json::Value::Array(vec![rebirth; 30_000]);
    peer.command("spBv1.0/plant1/NCMD/line1", many)
        .await
        .expect("NCMD");
    // The NCMD is taken in one turn of the front-end's task, and its counts are copied out
    // after it: the first count seen is the whole NCMD's.
    let status = gw
        .until("/api/v1/mqtt", "the rebirth", |m| {
            m["sparkplug"]["rebirths"].as_u64().unwrap_or(0) >= 1
        })
        .await
        .expect("rebirth");
    assert_eq!(status["sparkplug"]["rebirths"], 1, "{status}");
    let nbirths = std::cell::Cell::new(0);
    peer.until(|m| {
        if m.topic == "spBv1.0/plant1/NBIRTH/line1" {
            nbirths.set(nbirths.get() + 1);
        }
        m.topic == "spBv1.0/plant1/DBIRTH/line1/sim"
    })
    .await
    .expect("born again");
    assert_eq!(nbirths.get(), 1);
    gw.shutdown().await;
    peer.stop().await;
    broker.stop().await;
}

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

//! The MQTT front-end against a real Mosquitto, with paho-mqtt as the independent peer.

use iogate_tests::TestGateway;
use iogate_tests::mqtt::{Broker, Peer};
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

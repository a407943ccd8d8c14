//! A Logix controller's tags (cpppo's simulator) through the MQTT front-end (Mosquitto,
//! paho) and the OPC UA server (asyncua) as any other device's: read there, written from
//! there, and what was written read back from the controller by pylogix.

use iogate_tests::TestGateway;
use iogate_tests::devices::temp_dir;
use iogate_tests::eip::LogixPlc;
use iogate_tests::mqtt::{Broker, Peer};
use iogate_tests::opcua::{Options, UaClient};
use serde_json::json;

const PROFILE: &str = r#"name: Cell
protocol: ab-eip
fields:
  - { name: Speed, type: REAL, direction: inout, tag: Speed }
  - { name: Count, type: DINT, direction: inout, tag: "Counts[2]" }
"#;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn mqtt_and_the_opcua_server_read_and_write_a_logix_device() {
    let plc = LogixPlc::start(None, &["Speed=REAL", "Counts=DINT[4]"])
        .await
        .expect("controller");
    plc.write(&["Speed=2.5", "Counts[2]=40"])
        .await
        .expect("pylogix");
    let broker = Broker::start().await.expect("mosquitto");
    let dir = temp_dir("eip-doors");
    std::fs::create_dir_all(dir.join("profiles")).expect("dir");
    std::fs::write(dir.join("profiles/cell.yaml"), PROFILE).expect("profile");
    let gw = TestGateway::start(&format!(
        "profiles: {}\nlinks:\n  - {{ name: plc, eip: {{ host: 127.0.0.1, port: {} }} }}\ndevices:\n  - {{ name: cell, profile: Cell, link: plc, refresh_rate: 100ms }}\nmqtt:\n  url: mqtt://127.0.0.1:{}\n  client_id: iogate-eip-{}\n  json: {{ prefix: plant, qos: 1, retain: true }}\n  writes: true\nopcua:\n  listen: 127.0.0.1:0\n  pki_dir: {}\n",
        dir.join("profiles").display(),
        plc.port,
        broker.port,
        broker.port,
        dir.join("pki").display()
    ))
    .await
    .expect("gateway");
    // MQTT: the tag's value published; a write on its set topic reaches the controller.
    let mut peer = Peer::subscribe(&broker, "plant/cell/#")
        .await
        .expect("paho");
    peer.until(|m| m.topic == "plant/cell/Speed" && m.json()["value"] == 2.5)
        .await
        .expect("Speed published");
    peer.publish("plant/cell/Count/set", r#"{"value": 41}"#)
        .await
        .expect("publish");
    let outcome = peer
        .until(|m| m.topic == "plant/cell/Count/set/result" && m.json()["status"] != "pending")
        .await
        .expect("outcome");
    assert_eq!(outcome.json()["status"], "written", "{}", outcome.payload);
    // OPC UA: the same device's variables; a write reaches the controller.
    let url = format!("opc.tcp://{}/", gw.opcua.expect("an OPC UA server"));
    let mut ua = UaClient::connect(&url, &Options::default())
        .await
        .expect("asyncua");
    let speed = ua.read("cell.Speed").await.expect("read");
    assert_eq!(
        (speed["value"].clone(), speed["status"].clone()),
        (json!(2.5), json!("Good")),
        "{speed}"
    );
    let status = ua
        .write("cell.Speed", json!(7.25), "Float")
        .await
        .expect("write");
    assert_eq!(status, "Good");
    gw.until(
        "/api/v1/devices/cell/fields/Speed",
        "the written value read",
        |f| f["value"] == 7.25,
    )
    .await
    .expect("read back");
    assert_eq!(
        plc.read(&["Speed", "Counts[2]"]).await.expect("pylogix"),
        json!({"Speed": 7.25, "Counts[2]": 41})
    );
    ua.close().await.expect("close");
    gw.shutdown().await;
    plc.kill().await.expect("kill");
}

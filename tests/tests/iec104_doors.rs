//! An IEC 104 station's points (c104's, `tests/iec104/rtu.py`) through the doors as any
//! other device's: a spontaneous change seen as an SSE event, published on MQTT (Mosquitto,
//! paho) and read on the OPC UA server (asyncua); a set-point written from MQTT and a
//! selected set-point written from OPC UA, each reaching the station as its command.

use iogate_tests::devices::temp_dir;
use iogate_tests::iec104::Rtu;
use iogate_tests::mqtt::{Broker, Peer};
use iogate_tests::opcua::{Options, UaClient};
use iogate_tests::{SseReader, TestGateway};
use serde_json::json;

const PROFILE: &str = r#"name: Station
protocol: iec104
fields:
  - { name: flow, type: REAL, direction: input, ioa: 102 }
  - { name: setpoint, type: REAL, direction: output, ioa: 200, select: true }
  - { name: limit, type: INT, direction: output, ioa: 202 }
"#;

/// The station's next line that starts with `word`, the others passed over.
async fn next_said(rtu: &mut Rtu, word: &str) -> anyhow::Result<String> {
    loop {
        let line = rtu.said().await?;
        if line.starts_with(word) {
            return Ok(line);
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sse_mqtt_and_the_opcua_server_read_and_write_an_iec104_station() -> anyhow::Result<()> {
    let mut rtu = Rtu::start().await?;
    let broker = Broker::start().await?;
    let dir = temp_dir("iec104-doors");
    std::fs::create_dir_all(dir.join("profiles"))?;
    std::fs::write(dir.join("profiles/station.yaml"), PROFILE)?;
    let gw = TestGateway::start(&format!(
        "profiles: {}\nlinks:\n  - name: rtu\n    iec104: {{ host: 127.0.0.1, port: {}, t1: 3s, t2: 1s, t3: 5s }}\ndevices:\n  - {{ name: station, profile: Station, link: rtu, refresh_rate: 200ms }}\nmqtt:\n  url: mqtt://127.0.0.1:{}\n  client_id: iogate-iec104-{}\n  json: {{ prefix: plant, qos: 1, retain: false }}\n  writes: true\nopcua:\n  listen: 127.0.0.1:0\n  pki_dir: {}\n",
        dir.join("profiles").display(),
        rtu.port,
        broker.port,
        broker.port,
        dir.join("pki").display()
    ))
    .await?;
    gw.until("/api/v1/devices/station/fields/flow", "interrogated", |f| {
        f["quality"] == "good"
    })
    .await?;
    let mut peer = Peer::subscribe(&broker, "plant/station/#").await?;
    let mut sse = SseReader::open(&gw, "/api/v1/events?device=station").await?;

    // A spontaneous change: an SSE event, an MQTT message, the OPC UA variable.
    rtu.cmd("set 102 20.25").await?;
    loop {
        let Some((event, v)) = sse.next().await? else {
            anyhow::bail!("the event stream ended");
        };
        if event == "value" && v["field"] == "flow" && v["value"] == 20.25 {
            assert_eq!(v["quality"], "good", "{v}");
            break;
        }
    }
    peer.until(|m| m.topic == "plant/station/flow" && m.json()["value"] == 20.25)
        .await?;
    let url = format!("opc.tcp://{}/", gw.opcua.expect("an OPC UA server"));
    let mut ua = UaClient::connect(&url, &Options::default()).await?;
    let flow = ua.read("station.flow").await?;
    assert_eq!(
        (flow["value"].clone(), flow["status"].clone()),
        (json!(20.25), json!("Good")),
        "{flow}"
    );

    // A set-point from MQTT: the station's command, the outcome on the result topic.
    peer.publish("plant/station/limit/set", r#"{"value": -3}"#)
        .await?;
    let outcome = peer
        .until(|m| m.topic == "plant/station/limit/set/result" && m.json()["status"] != "pending")
        .await?;
    assert_eq!(outcome.json()["status"], "written", "{}", outcome.payload);
    assert_eq!(next_said(&mut rtu, "cmd").await?, "cmd 202 -3");

    // A selected set-point from OPC UA: selected, then executed at the station.
    let status = ua.write("station.setpoint", json!(2.5), "Float").await?;
    assert_eq!(status, "Good");
    // (c104 takes the select itself and tells the execute.)
    assert_eq!(next_said(&mut rtu, "cmd").await?, "cmd 200 2.5");
    gw.until("/api/v1/devices/station/fields/setpoint", "written", |f| {
        f["value"] == 2.5
    })
    .await?;
    ua.close().await?;
    gw.shutdown().await;
    peer.stop().await;
    broker.stop().await;
    Ok(())
}

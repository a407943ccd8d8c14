use super::*;

use iogate_tests::devices::{ModbusDevice, modbus_tcp_server, temp_dir};

/// A config of a device of 400 fields (`wide`, Modbus TCP) and a simulated one (`sim`),
/// with `mqtt` (the `mqtt:` section's lines); the Modbus server's task.
async fn two_devices(mqtt: &str) -> (String, tokio::task::JoinHandle<()>) {
    let dir = temp_dir("mqtt-limits");
    let profiles = dir.join("profiles");
    std::fs::create_dir_all(&profiles).expect("dir");
    let profile = iogate_tests::devices::input_register_profile("Wide", 400);
    std::fs::write(profiles.join("wide.yaml"), profile).expect("profile");
    std::fs::copy(
        iogate_tests::profiles_dir().join("sim_io.yaml"),
        profiles.join("sim_io.yaml"),
    )
    .expect("SimIo");
    let (port, server) = modbus_tcp_server(ModbusDevice::default()).await;
    let config = format!(
        "profiles: {}
links:
  - {{ name: l, tcp: {{ host: 127.0.0.1, port: {port} }} }}
devices:
  - {{ name: wide, profile: Wide, link: l, slave_id: 1, refresh_rate: 100ms }}
  - {{ name: sim, profile: SimIo, refresh_rate: 50ms }}
mqtt:
  version: 5
  sparkplug: {{ group_id: plant1, edge_node_id: line1 }}
{mqtt}",
        profiles.display(),
    );
    (config, server)
}

async fn simulate(gw: &TestGateway, value: bool) {
    let (status, body) = gw
        .send(
            Method::PUT,
            "/api/v1/devices/sim/fields/DI_0/simulate",
            format!(r#"{{"value": {value}}}"#),
        )
        .await
        .expect("simulate");
    assert!((200..300).contains(&status), "{status} {body}");
}

/// A broker whose Maximum Packet Size (4,096 bytes, MQTT 5) is smaller than one device's
/// DBIRTH (400 fields): that message is not sent and is counted dropped; the connection is
/// kept (a broker ends a connection that sends it a larger packet), and the other device is
/// born and its changes come.
#[tokio::test]
async fn a_message_larger_than_the_brokers_maximum_packet_size_is_dropped_and_the_session_goes_on()
{
    let broker = Broker::start_with_config("max_packet_size 4096\n")
        .await
        .expect("mosquitto");
    let mqtt = format!(
        "  url: mqtt://127.0.0.1:{}\n  client_id: iogate-limits\n",
        broker.port
    );
    let (config, server) = two_devices(&mqtt).await;
    let mut peer = Peer::subscribe(&broker, "spBv1.0/#").await.expect("paho");
    let gw = TestGateway::start(&config).await.expect("gateway");
    peer.until(|m| m.topic == "spBv1.0/plant1/DBIRTH/line1/sim")
        .await
        .expect("the small device's DBIRTH");
    gw.until("/api/v1/mqtt", "the large DBIRTH dropped", |s| {
        s["buffer"]["dropped"].as_u64().is_some_and(|n| n >= 1)
    })
    .await
    .expect("dropped");
    simulate(&gw, true).await;
    let data = peer
        .until(|m| {
            m.topic == "spBv1.0/plant1/DDATA/line1/sim"
                && metric(m, "DI_0").is_some_and(|x| x["value"] == true)
        })
        .await
        .expect("DDATA after the dropped DBIRTH");
    assert!(data.decode_error.is_none());
    let (_, status) = gw.get("/api/v1/mqtt").await.expect("status");
    assert_eq!(status["connected"], true, "{status}");
    assert_eq!(status["reconnects"], 0, "{status}");
    gw.shutdown().await;
    server.abort();
    peer.stop().await;
    broker.stop().await;
}

/// Back after an outage, with the broker taking one QoS 1 publish at a time (Receive
/// Maximum 1) and 400 JSON current values ahead of the births: the buffered changes are
/// replayed only after NBIRTH and the device's DBIRTH, and `seq` follows from NBIRTH's 0.
#[tokio::test]
async fn after_a_reconnect_nothing_replayed_goes_before_the_births() {
    let mut broker = Broker::start_with_config("max_inflight_messages 1\n")
        .await
        .expect("mosquitto");
    let gate = iogate_tests::mqtt::Gate::to(broker.port)
        .await
        .expect("gate");
    let dir = temp_dir("mqtt-replay-births");
    let mqtt = format!(
        "  url: mqtt://127.0.0.1:{}
  client_id: iogate-replay
  json: {{ prefix: iogate/line1, qos: 1, retain: true }}
  buffer: {{ dir: {}, replay_rate: 1000/s }}
",
        gate.port,
        dir.display()
    );
    let (config, server) = two_devices(&mqtt).await;
    let mut peer = Peer::subscribe(&broker, "#").await.expect("paho");
    let gw = TestGateway::start(&config).await.expect("gateway");
    peer.until(|m| m.topic == "spBv1.0/plant1/DBIRTH/line1/sim")
        .await
        .expect("DBIRTH");
    gate.shut();
    broker.pause().await;
    let status = gw
        .until("/api/v1/mqtt", "disconnected", |s| s["connected"] == false)
        .await
        .expect("disconnected");
    let base = status["buffer"]["messages"].as_u64().unwrap_or_default();
    for n in 0..10u64 {
        simulate(&gw, n % 2 == 0).await;
        gw.until("/api/v1/mqtt", "buffered", |s| {
            s["buffer"]["messages"].as_u64() >= Some(base + 2 * (n + 1))
        })
        .await
        .expect("buffered");
    }
    broker.resume().await.expect("mosquitto again");
    peer.resync("iogate-test/marker").await.expect("peer back");
    gate.open();
    let mut spark = Vec::new();
    let mut replayed = 0;
    while replayed < 10 {
        let m = peer.next().await.expect("message");
        let line1 = m.topic.starts_with("spBv1.0/plant1/") && !m.topic.contains("/NDEATH/");
        if !line1 {
            continue;
        }
        if m.topic.ends_with("/DDATA/line1/sim")
            && metric(&m, "DI_0").is_some_and(|x| x["is_historical"] == true)
        {
            replayed += 1;
        }
        spark.push(m);
    }
    let kinds: Vec<&str> = spark
        .iter()
        .map(|m| m.sparkplug["type"].as_str().unwrap_or_default())
        .collect();
    assert_eq!(kinds[0], "NBIRTH", "{kinds:?}");
    let birth = spark
        .iter()
        .position(|m| m.topic == "spBv1.0/plant1/DBIRTH/line1/sim")
        .expect("DBIRTH of sim");
    let data = spark
        .iter()
        .position(|m| m.topic == "spBv1.0/plant1/DDATA/line1/sim")
        .expect("DDATA of sim");
    assert!(
        birth < data,
        "DDATA at {data} before the DBIRTH at {birth}: {kinds:?}"
    );
    assert_seq_follows(&spark);
    gw.shutdown().await;
    server.abort();
    peer.stop().await;
    broker.stop().await;
}

use super::*;

use iogate_tests::devices::{ModbusDevice, modbus_tcp_server, temp_dir};

/// A broker whose Maximum Packet Size (4,096 bytes, MQTT 5) is smaller than one device's
/// DBIRTH (400 fields): that message is not sent and is counted dropped; the connection is
/// kept (a broker ends a connection that sends it a larger packet), and the other device is
/// born and its changes come.
#[tokio::test]
async fn a_message_larger_than_the_brokers_maximum_packet_size_is_dropped_and_the_session_goes_on()
{
    let broker = Broker::start_limited(4096).await.expect("mosquitto");
    let dir = temp_dir("mqtt-limits");
    let profiles = dir.join("profiles");
    std::fs::create_dir_all(&profiles).expect("dir");
    let mut profile = String::from("name: Wide\nprotocol: modbus-tcp\nfields:\n");
    for i in 0..400 {
        profile.push_str(&format!(
            "  - {{ name: R{i}, type: UINT, direction: input, register: {{ address: {i}, kind: input_register }} }}\n"
        ));
    }
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
  url: mqtt://127.0.0.1:{}
  version: 5
  client_id: iogate-limits
  sparkplug: {{ group_id: plant1, edge_node_id: line1 }}
",
        profiles.display(),
        broker.port
    );
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
    gw.send(
        Method::PUT,
        "/api/v1/devices/sim/fields/DI_0/simulate",
        r#"{"value": true}"#.to_owned(),
    )
    .await
    .expect("simulate");
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

//! What another client on the broker can send the gateway, against a real Mosquitto with
//! paho-mqtt and pysparkplug as the independent peers: nothing it sends ends the session.

use iogate_tests::TestGateway;
use iogate_tests::mqtt::{Broker, Message, Peer, sparkplug_config};

#[tokio::test]
async fn a_retained_command_too_big_to_keep_is_read_past_and_the_session_lives_on() {
    too_big_a_command("").await;
}

#[tokio::test]
async fn over_mqtt_5_the_broker_is_told_the_maximum_packet_size_and_drops_it_itself() {
    too_big_a_command("  version: 5\n").await;
}

/// A retained command over 1 MiB and then a command: the first is dropped (by the gateway
/// over MQTT 3.1.1, by the broker over MQTT 5, which was told the Maximum Packet Size), the
/// second taken, the session never ended.
async fn too_big_a_command(extra: &str) {
    let v5 = !extra.is_empty();
    let broker = Broker::start().await.expect("mosquitto");
    let mut watcher = Peer::subscribe(&broker, "spBv1.0/plant1/NDEATH/#")
        .await
        .expect("paho");
    // The sender hears nothing back: paho takes seconds over a 1 MiB message it receives.
    let mut sender = Peer::subscribe(&broker, "iogate-test/quiet")
        .await
        .expect("paho");
    let gw = TestGateway::start(&sparkplug_config("iogate-hostile", broker.port, extra))
        .await
        .expect("gateway");
    gw.until("/api/v1/mqtt", "born", |s| {
        s["sparkplug"]["born_devices"] == 1
    })
    .await
    .expect("born");
    // Over the 1 MiB the gateway keeps, retained, on the node's own command topic.
    let big = "x".repeat((1 << 20) + 1024);
    sender
        .publish_retained("spBv1.0/plant1/NCMD/line1", &big)
        .await
        .expect("publish");
    if !v5 {
        let status = gw
            .until("/api/v1/mqtt", "the packet reported", |s| {
                s["dropped_in"] == 1
            })
            .await
            .expect("dropped and counted");
        assert_eq!(status["connected"], true, "{status:#}");
    }
    // The session goes on: a command after it is taken.
    sender
        .command(
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
    let metrics = gw.metrics().await.expect("metrics");
    let dropped = if v5 { 0 } else { 1 };
    assert!(
        metrics.contains(&format!("iogate_mqtt_incoming_dropped_total {dropped}")),
        "{metrics}"
    );
    let (_, status) = gw.get("/api/v1/mqtt").await.expect("status");
    assert_eq!(status["reconnects"], 0, "{status:#}");
    // One death, at the stop, and not a second one by the Will.
    gw.shutdown().await;
    let deaths = deaths_until_marker(&mut watcher).await;
    assert_eq!(deaths.len(), 1, "{deaths:?}");
    watcher.stop().await;
    sender.stop().await;
    broker.stop().await;
}

/// The `bdSeq` of every NDEATH the watcher (subscribed to NDEATH) sees before a marker it
/// publishes itself.
async fn deaths_until_marker(watcher: &mut Peer) -> Vec<serde_json::Value> {
    let marker = "spBv1.0/plant1/NDEATH/iogate-test-marker";
    watcher.publish(marker, "end").await.expect("marker");
    let mut deaths = Vec::new();
    loop {
        let m = watcher.next().await.expect("message");
        if m.topic == marker {
            return deaths;
        }
        deaths.push(metric(&m, "bdSeq").expect("bdSeq")["value"].clone());
    }
}

fn metric<'a>(m: &'a Message, name: &str) -> Option<&'a serde_json::Value> {
    m.sparkplug["metrics"]
        .as_array()?
        .iter()
        .find(|x| x["name"] == name)
}

/// A proxy to the broker that passes the first connection's CONNECT and then drops the
/// connection before the CONNACK reaches the client (a lost answer); every later connection
/// it passes whole.
async fn losing_first_connack(broker: u16) -> u16 {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
        .await
        .expect("bind");
    let port = listener.local_addr().expect("addr").port();
    tokio::spawn(async move {
        let mut first = true;
        while let Ok((mut client, _)) = listener.accept().await {
            let Ok(mut upstream) = tokio::net::TcpStream::connect(("127.0.0.1", broker)).await
            else {
                continue;
            };
            if first {
                first = false;
                tokio::spawn(async move {
                    use tokio::io::AsyncReadExt;
                    let (mut from_client, mut to_broker) = (client, upstream);
                    let mut buf = vec![0u8; 4096];
                    // Pass the CONNECT, read the CONNACK, then close both sides.
                    if let Ok(n) = from_client.read(&mut buf).await {
                        use tokio::io::AsyncWriteExt;
                        let _ = to_broker.write_all(&buf[..n]).await;
                        let _ = to_broker.read(&mut buf).await;
                    }
                });
            } else {
                tokio::spawn(async move {
                    let _ = tokio::io::copy_bidirectional(&mut client, &mut upstream).await;
                });
            }
        }
    });
    port
}

#[tokio::test]
async fn a_connect_whose_connack_was_lost_never_lends_its_bd_seq_to_the_next_session() {
    let broker = Broker::start().await.expect("mosquitto");
    let mut watcher = Peer::subscribe(&broker, "spBv1.0/#").await.expect("paho");
    let proxy = losing_first_connack(broker.port).await;
    let gw = TestGateway::start(&sparkplug_config("iogate-hostile", proxy, ""))
        .await
        .expect("gateway");
    // The abandoned attempt's Will arrives, and the live session's birth, in either order.
    let mut will = None;
    let mut birth = None;
    while will.is_none() || birth.is_none() {
        let m = watcher.next().await.expect("message");
        let bd_seq = metric(&m, "bdSeq").map(|b| b["value"].clone());
        if m.topic == "spBv1.0/plant1/NDEATH/line1" {
            will = bd_seq;
        } else if m.topic == "spBv1.0/plant1/NBIRTH/line1" {
            birth = bd_seq;
        }
    }
    let (will, birth) = (will.expect("will"), birth.expect("birth"));
    assert_ne!(
        will, birth,
        "the Will of the lost attempt would kill the live session"
    );
    let (_, status) = gw.get("/api/v1/mqtt").await.expect("status");
    assert_eq!(status["connected"], true, "{status:#}");
    gw.shutdown().await;
    watcher.stop().await;
    broker.stop().await;
}

#[tokio::test]
async fn a_clean_stop_is_one_death_with_json_beside_sparkplug() {
    let broker = Broker::start().await.expect("mosquitto");
    let mut watcher = Peer::subscribe(&broker, "spBv1.0/plant1/NDEATH/#")
        .await
        .expect("paho");
    let gw = TestGateway::start(&sparkplug_config(
        "iogate-hostile",
        broker.port,
        "  json: { prefix: iogate/line1, qos: 1, retain: true }\n",
    ))
    .await
    .expect("gateway");
    gw.until("/api/v1/mqtt", "born", |s| {
        s["sparkplug"]["born_devices"] == 1
    })
    .await
    .expect("born");
    gw.shutdown().await;
    let deaths = deaths_until_marker(&mut watcher).await;
    assert_eq!(
        deaths.len(),
        1,
        "one NDEATH, not the Will beside it: {deaths:?}"
    );
    watcher.stop().await;
    broker.stop().await;
}

/// A proxy to the broker that passes a connection's CONNECT and CONNACK and then nothing
/// more, either way, keeping both sockets open: a broker that stalls (its acknowledgements
/// and pings' answers never come).
async fn stalling_after_connack(broker: u16) -> u16 {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
        .await
        .expect("bind");
    let port = listener.local_addr().expect("addr").port();
    tokio::spawn(async move {
        while let Ok((mut client, _)) = listener.accept().await {
            let Ok(mut upstream) = tokio::net::TcpStream::connect(("127.0.0.1", broker)).await
            else {
                continue;
            };
            tokio::spawn(async move {
                let mut buf = vec![0u8; 4096];
                let Ok(n) = client.read(&mut buf).await else {
                    return;
                };
                let _ = upstream.write_all(&buf[..n]).await;
                let Ok(n) = upstream.read(&mut buf).await else {
                    return;
                };
                let _ = client.write_all(&buf[..n]).await;
                // Nothing more is passed; what the client sends is read and dropped.
                while let Ok(n) = client.read(&mut buf).await {
                    if n == 0 {
                        break;
                    }
                }
                drop(upstream);
            });
        }
    });
    port
}

#[tokio::test]
async fn first_values_unconfirmed_when_a_connection_ends_are_not_kept_as_changes() {
    let broker = Broker::start().await.expect("mosquitto");
    let proxy = stalling_after_connack(broker.port).await;
    let dir = iogate_tests::devices::temp_dir("mqtt-first-values");
    let gw = TestGateway::start(&format!(
        "devices:\n  - {{ name: sim, profile: SimIo, refresh_rate: 50ms }}\nmqtt:\n  url: mqtt://127.0.0.1:{proxy}\n  client_id: iogate-first-{proxy}\n  keep_alive: 1s\n  json: {{ prefix: iogate/line1, qos: 1, retain: true }}\n  buffer: {{ dir: {} }}\n",
        dir.display()
    ))
    .await
    .expect("gateway");
    // Connected, its first values published and never acknowledged, then the keep-alive
    // ends the connection.
    let status = gw
        .until("/api/v1/mqtt", "the stalled connection ended", |s| {
            s["last_error"].as_str().is_some_and(|e| e.contains("ping"))
        })
        .await
        .expect("ended");
    assert_eq!(
        status["buffer"]["messages"], 0,
        "no change happened, so nothing is kept for replay: {status:#}"
    );
    gw.shutdown().await;
    broker.stop().await;
}

/// A broker of our own speaking MQTT 5: its CONNACK says Receive Maximum 3, then it reads
/// and never acknowledges. Answers its port and the QoS 1 publishes it has received.
async fn receiving_three_at_most() -> (u16, std::sync::Arc<std::sync::atomic::AtomicUsize>) {
    use std::sync::atomic::Ordering;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
        .await
        .expect("bind");
    let port = listener.local_addr().expect("addr").port();
    let received = std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let count = received.clone();
    tokio::spawn(async move {
        let Ok((mut client, _)) = listener.accept().await else {
            return;
        };
        let mut buf = Vec::new();
        let mut chunk = vec![0u8; 65536];
        let mut answered = false;
        while let Ok(n) = client.read(&mut chunk).await {
            if n == 0 {
                break;
            }
            buf.extend_from_slice(&chunk[..n]);
            // Whole packets: the first byte, the remaining length, the body.
            loop {
                let (mut len, mut i) = (0usize, 1);
                while let Some(b) = buf.get(i) {
                    len |= usize::from(b & 0x7F) << (7 * (i - 1));
                    i += 1;
                    if b & 0x80 == 0 {
                        break;
                    }
                }
                if buf.len() < 2 || buf.len() < i + len {
                    break;
                }
                let first = buf[0];
                buf.drain(..i + len);
                if first >> 4 == 1 && !answered {
                    // CONNACK: accepted, properties: Receive Maximum 3.
                    let _ = client.write_all(&[0x20, 6, 0, 0, 3, 0x21, 0, 3]).await;
                    answered = true;
                } else if first >> 4 == 3 && (first >> 1) & 3 == 1 {
                    count.fetch_add(1, Ordering::SeqCst);
                }
            }
        }
    });
    (port, received)
}

#[tokio::test]
async fn an_mqtt_5_brokers_receive_maximum_is_never_exceeded() {
    let (port, received) = receiving_three_at_most().await;
    let gw = TestGateway::start(&format!(
        "devices:\n  - {{ name: sim, profile: SimPlant, refresh_rate: 20ms }}\nmqtt:\n  url: mqtt://127.0.0.1:{port}\n  version: 5\n  client_id: iogate-receive-max\n  json: {{ prefix: iogate/line1, qos: 1, retain: true }}\n"
    ))
    .await
    .expect("gateway");
    gw.until("/api/v1/mqtt", "connected", |s| s["connected"] == true)
        .await
        .expect("connected");
    // Nineteen fields' first values wait to be published: without the broker's maximum
    // they would all be sent at once.
    gw.until("/api/v1/devices/sim", "a second of changes", |d| {
        d["io_cycles"].as_u64().is_some_and(|c| c > 50)
    })
    .await
    .expect("cycles");
    assert_eq!(received.load(std::sync::atomic::Ordering::SeqCst), 3);
    gw.shutdown().await;
}

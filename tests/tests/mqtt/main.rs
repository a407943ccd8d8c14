//! The MQTT front-end against a real Mosquitto, with paho-mqtt as the independent peer.

mod json_and_sparkplug;
mod limits;
mod retained;
mod sessions;

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

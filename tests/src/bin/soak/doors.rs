//! The soak's clients, one at each door, each checking every value it is told against the
//! register it came from; each reconnects by itself when its connection ends.

use std::sync::Arc;
use std::time::Duration;

use futures_util::StreamExt;
use iogate_tests::TestGateway;
use iogate_tests::mqtt::Peer;
use iogate_tests::opcua::{Options, UaClient};
use serde_json::Value;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio_util::sync::CancellationToken;

use crate::field::Expected;
use crate::tally::Tally;

/// What every client shares.
#[derive(Clone)]
pub struct Ctx {
    pub gw: Arc<TestGateway>,
    pub expected: Arc<Expected>,
    pub tally: Arc<Tally>,
    pub stop: CancellationToken,
}

impl Ctx {
    /// Waits `d`, or less when the soak ends; whether it goes on.
    async fn pause(&self, d: Duration) -> bool {
        tokio::select! {
            _ = self.stop.cancelled() => false,
            _ = tokio::time::sleep(d) => true,
        }
    }
}

/// REST: every device's fields, twice a second.
pub async fn rest(ctx: Ctx) {
    let mut devices: Vec<String> = ctx.expected.keys().map(|(d, _)| d.clone()).collect();
    devices.sort();
    devices.dedup();
    while ctx.pause(Duration::from_millis(500)).await {
        for device in &devices {
            match ctx.gw.get(&format!("/api/v1/devices/{device}")).await {
                Ok((200, body)) => {
                    for (field, v) in body["fields"].as_object().into_iter().flatten() {
                        let (value, quality) = (&v["value"], &v["quality"]);
                        ctx.tally
                            .check("rest", &ctx.expected, device, field, value, quality);
                    }
                }
                _ => ctx.tally.add("rest errors", 1),
            }
        }
    }
}

/// Server-Sent Events: every change.
pub async fn sse(ctx: Ctx) {
    while !ctx.stop.is_cancelled() {
        let Ok(mut events) = iogate_tests::SseReader::open(&ctx.gw, "/api/v1/events").await else {
            ctx.tally.add("sse errors", 1);
            ctx.pause(Duration::from_secs(1)).await;
            continue;
        };
        loop {
            let next = tokio::select! {
                _ = ctx.stop.cancelled() => return,
                n = events.next() => n,
            };
            match next {
                Ok(Some((_, data))) => ctx.tally.check_json("sse", &ctx.expected, &data),
                Ok(None) => break,
                // No change for a while (every source stopped): open it again.
                Err(_) => break,
            }
        }
    }
}

/// gRPC `Subscribe`: every change.
pub async fn grpc(ctx: Ctx) {
    while !ctx.stop.is_cancelled() {
        let stream = match ctx.gw.client().await {
            Ok(mut c) => c
                .subscribe(&iogate_client::Selection::default(), false)
                .await
                .map_err(anyhow::Error::from),
            Err(e) => Err(e),
        };
        let stream = match stream {
            Ok(s) => Some(s),
            Err(e) => {
                ctx.tally.note(format!("grpc: {e:#}"));
                None
            }
        };
        let Some(stream) = stream else {
            ctx.tally.add("grpc errors", 1);
            ctx.pause(Duration::from_secs(1)).await;
            continue;
        };
        tokio::pin!(stream);
        loop {
            let next = tokio::select! {
                _ = ctx.stop.cancelled() => return,
                n = stream.next() => n,
            };
            match next {
                Some(Ok(iogate_client::Update::Value(v))) => {
                    let json = serde_json::to_value(&v).unwrap_or_default();
                    ctx.tally.check_json("grpc", &ctx.expected, &json);
                }
                Some(Ok(_)) => {}
                _ => break,
            }
        }
    }
}

/// The Modbus TCP server: each bound input register read once a second.
pub async fn modbus(ctx: Ctx, listen: String) {
    let Ok((_, map)) = ctx.gw.get("/api/v1/map").await else {
        return;
    };
    let bound: Vec<(u16, String, String)> = map["bindings"]
        .as_array()
        .into_iter()
        .flatten()
        .filter(|b| b["table"] == "input register")
        .filter_map(|b| {
            let address = u16::try_from(b["address"].as_u64()?).ok()?;
            Some((
                address,
                b["device"].as_str()?.into(),
                b["field"].as_str()?.into(),
            ))
        })
        .collect();
    while ctx.pause(Duration::from_secs(1)).await {
        let mut socket = match tokio::net::TcpStream::connect(&listen).await {
            Ok(s) => s,
            Err(e) => {
                ctx.tally.add("modbus errors", 1);
                ctx.tally.note(format!("modbus: {listen}: {e}"));
                continue;
            }
        };
        for (address, device, field) in &bound {
            match read_input(&mut socket, *address).await {
                // Before its first read a field serves 0.
                Some(0) => {}
                Some(value) => ctx.tally.check(
                    "modbus",
                    &ctx.expected,
                    device,
                    field,
                    &Value::from(value),
                    &Value::from("good"),
                ),
                None => ctx.tally.add("modbus errors", 1),
            }
        }
    }
}

/// FC04 of one register.
async fn read_input(socket: &mut tokio::net::TcpStream, address: u16) -> Option<u16> {
    let [hi, lo] = address.to_be_bytes();
    socket
        .write_all(&[0, 7, 0, 0, 0, 6, 1, 4, hi, lo, 0, 1])
        .await
        .ok()?;
    let mut answer = [0u8; 11];
    tokio::time::timeout(Duration::from_secs(5), socket.read_exact(&mut answer))
        .await
        .ok()?
        .ok()?;
    (answer[7] == 4).then(|| u16::from_be_bytes([answer[9], answer[10]]))
}

/// MQTT: every message of the JSON topics, through a broker that is killed and restarted.
pub async fn mqtt(ctx: Ctx, broker: u16) {
    while !ctx.stop.is_cancelled() {
        let Ok(mut peer) = Peer::subscribe_port(broker, "soak/#").await else {
            ctx.tally.add("mqtt errors", 1);
            ctx.pause(Duration::from_secs(2)).await;
            continue;
        };
        loop {
            let next = tokio::select! {
                _ = ctx.stop.cancelled() => return,
                n = peer.next() => n,
            };
            let Ok(message) = next else { break };
            if message.topic.contains('$') || message.topic.ends_with("/set") {
                continue;
            }
            ctx.tally.check_json("mqtt", &ctx.expected, &message.json());
        }
    }
}

/// The OPC UA server: each field read through asyncua once a second.
pub async fn opcua(ctx: Ctx, url: String) {
    let fields: Vec<(String, String)> = ctx.expected.keys().cloned().collect();
    while !ctx.stop.is_cancelled() {
        let Ok(mut ua) = UaClient::connect(&url, &Options::default()).await else {
            ctx.tally.add("opcua errors", 1);
            ctx.pause(Duration::from_secs(2)).await;
            continue;
        };
        while ctx.pause(Duration::from_secs(1)).await {
            let mut failed = false;
            for (device, field) in &fields {
                let Ok(read) = ua.read(&format!("{device}.{field}")).await else {
                    failed = true;
                    break;
                };
                let quality = if read["status"] == "Good" {
                    "good"
                } else {
                    "bad"
                };
                let (value, quality) = (&read["value"], Value::from(quality));
                ctx.tally
                    .check("opcua", &ctx.expected, device, field, value, &quality);
            }
            if failed {
                ctx.tally.add("opcua errors", 1);
                break;
            }
        }
        let _ = ua.close().await;
    }
}

//! The gateway-wide bounds on what clients can make it hold (the README's table): a client
//! that reaches one is refused in its protocol's terms, the refusal is counted in
//! `iogate_bound_*`, and the other clients and the polling go on as before.

use std::time::Duration;

use iogate_tests::devices::{ModbusDevice, modbus_tcp_server};
use iogate_tests::{SseReader, TestGateway, config_files, start_file};
use reqwest::Method;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

const REG: &str = "name: Reg\nfields:\n  - { name: N, type: UINT, direction: input, register: { address: 0, kind: input_register } }\n";

/// A gateway polling one Modbus TCP device every 20 ms, with `listen` extra keys; answers
/// it and the device.
async fn polling(name: &str, listen: &str) -> (TestGateway, ModbusDevice) {
    let device = ModbusDevice::default();
    device.tables.lock().expect("tables").input[0] = 1;
    let (port, _server) = modbus_tcp_server(device.clone()).await;
    let config = format!(
        "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0{listen} }}\nprofiles: profiles\n\
         links:\n  - {{ name: plc, tcp: {{ host: 127.0.0.1, port: {port} }} }}\n\
         devices:\n  - {{ name: meter, profile: Reg, link: plc, slave_id: 1, refresh_rate: 20ms }}\n\
         security:\n  declare: {{ tcp_hosts: [\"127.0.0.0/8\"] }}\n"
    );
    let (_, path) = config_files(name, &[("reg.yaml", REG)], &config);
    let gw = start_file(&path).await;
    read_until(&gw, 1).await;
    (gw, device)
}

/// Waits until the gateway has polled `value` from the device.
async fn read_until(gw: &TestGateway, value: u16) {
    gw.until("/api/v1/devices/meter/fields/N", "polled", |v| {
        v["value"] == value && v["quality"] == "good"
    })
    .await
    .expect("the device is polled");
}

/// The value of the series `name{bound="bound"}` in `metrics`.
fn bound_metric(metrics: &str, name: &str, bound: &str) -> Option<u64> {
    let series = format!("{name}{{bound=\"{bound}\"}} ");
    metrics
        .lines()
        .find_map(|l| l.strip_prefix(&series))
        .and_then(|v| v.trim().parse::<f64>().ok())
        .map(|v| v as u64)
}

/// Whether the gateway closes a new connection to `addr` without a word.
async fn closed_at_once(addr: &str) -> bool {
    let Ok(mut socket) = TcpStream::connect(addr).await else {
        return false;
    };
    let _ = socket
        .write_all(b"GET /livez HTTP/1.1\r\nHost: x\r\n\r\n")
        .await;
    let mut buf = [0u8; 64];
    matches!(
        tokio::time::timeout(Duration::from_secs(5), socket.read(&mut buf)).await,
        Ok(Ok(0) | Err(_))
    )
}

#[tokio::test]
async fn connections_past_the_bound_are_closed_and_the_connected_clients_and_polling_go_on() {
    let (gw, device) = polling("bounds-connections", ", max_connections: 4").await;
    let http = gw.base.trim_start_matches("http://").to_owned();
    // The test's own client holds one connection (kept alive); three idle sockets that sent
    // a byte hold the rest.
    let (status, _) = gw.get("/readyz").await.expect("readyz");
    assert_eq!(status, 200);
    let mut idle = Vec::new();
    for _ in 0..3 {
        let mut socket = TcpStream::connect(&http).await.expect("idle");
        socket.write_all(b"G").await.expect("a byte");
        idle.push(socket);
    }
    assert!(closed_at_once(&http).await, "a fifth connection is closed");
    // The connected client is served, and the device still polled.
    device.tables.lock().expect("tables").input[0] = 2;
    read_until(&gw, 2).await;
    let metrics = gw.metrics().await.expect("metrics");
    assert_eq!(
        bound_metric(&metrics, "iogate_bound_limit", "http_connections"),
        Some(4)
    );
    assert_eq!(
        bound_metric(&metrics, "iogate_bound_used", "http_connections"),
        Some(4)
    );
    assert!(
        bound_metric(&metrics, "iogate_bound_refused_total", "http_connections") >= Some(1),
        "{metrics}"
    );
    // A freed place is taken again.
    idle.clear();
    iogate_tests::eventually("a new connection is served", || async {
        reqwest::get(gw.url("/livez"))
            .await
            .is_ok_and(|r| r.status().is_success())
    })
    .await
    .expect("served");
    // The gRPC listener has its own four places: a client connected first keeps its calls.
    let mut client = gw.client().await.expect("grpc");
    client.devices().await.expect("a first call");
    let grpc = gw.grpc.trim_start_matches("http://").to_owned();
    let mut held = Vec::new();
    for _ in 0..3 {
        let mut socket = TcpStream::connect(&grpc).await.expect("idle");
        socket.write_all(b"P").await.expect("a byte");
        held.push(socket);
    }
    assert!(
        closed_at_once(&grpc).await,
        "a fifth gRPC connection is closed"
    );
    let devices = client
        .devices()
        .await
        .expect("the connected client is served");
    assert_eq!(devices.len(), 1);
    gw.shutdown().await;
}

#[tokio::test]
async fn change_streams_past_the_bound_are_refused_and_the_open_ones_keep_their_changes() {
    let (gw, device) = polling("bounds-streams", ", max_streams: 2").await;
    let mut first = SseReader::open(&gw, "/api/v1/events?device=meter")
        .await
        .expect("first stream");
    let _second = SseReader::open(&gw, "/api/v1/events")
        .await
        .expect("second stream");
    let refused = gw
        .client
        .get(gw.url("/api/v1/events"))
        .send()
        .await
        .expect("answered");
    assert_eq!(refused.status().as_u16(), 429);
    let body: serde_json::Value = refused.json().await.expect("the API's JSON");
    assert_eq!(body["error"]["code"], "too_many_streams", "{body}");
    let mut client = gw.client().await.expect("grpc");
    let selection = iogate_client::Selection::default();
    let grpc = client.subscribe(&selection, false).await.err();
    assert!(
        matches!(
            grpc,
            Some(iogate_client::Error::Status {
                code: tonic::Code::ResourceExhausted,
                ..
            })
        ),
        "{grpc:?}"
    );
    // The open stream is told the next change; polling goes on.
    device.tables.lock().expect("tables").input[0] = 3;
    first
        .until(|_, data| data["field"] == "N" && data["value"] == 3)
        .await
        .expect("the change");
    let metrics = gw.metrics().await.expect("metrics");
    assert_eq!(
        bound_metric(&metrics, "iogate_bound_used", "streams"),
        Some(2)
    );
    assert_eq!(
        bound_metric(&metrics, "iogate_bound_refused_total", "streams"),
        Some(2),
        "{metrics}"
    );
    // A stream closed frees its place.
    drop(first);
    iogate_tests::eventually("a place again", || async {
        SseReader::open(&gw, "/api/v1/events").await.is_ok()
    })
    .await
    .expect("a new stream");
    gw.shutdown().await;
}

#[tokio::test]
async fn one_client_at_its_streams_bound_leaves_the_others_theirs() {
    let (gw, device) = polling(
        "bounds-client-streams",
        ", max_streams: 8, max_streams_per_client: 2",
    )
    .await;
    let _first = SseReader::open(&gw, "/api/v1/events").await.expect("first");
    let _second = SseReader::open(&gw, "/api/v1/events")
        .await
        .expect("second");
    let third = gw
        .client
        .get(gw.url("/api/v1/events"))
        .send()
        .await
        .expect("answered");
    assert_eq!(third.status().as_u16(), 429);
    let body: serde_json::Value = third.json().await.expect("the API's JSON");
    assert_eq!(body["error"]["code"], "too_many_streams", "{body}");
    assert!(
        body["error"]["message"]
            .as_str()
            .is_some_and(|m| m.contains("max_streams_per_client")),
        "{body}"
    );
    // Another client (another address of this machine) gets its own places.
    let other = reqwest::Client::builder()
        .local_address(std::net::IpAddr::from([127, 0, 0, 2]))
        .build()
        .expect("client");
    let response = other
        .get(gw.url("/api/v1/events?device=meter"))
        .send()
        .await
        .expect("answered");
    assert_eq!(response.status().as_u16(), 200);
    let mut events = response.bytes_stream();
    device.tables.lock().expect("tables").input[0] = 5;
    let told = async {
        use futures_util::StreamExt;
        let mut text = String::new();
        while let Some(Ok(chunk)) = events.next().await {
            text.push_str(&String::from_utf8_lossy(&chunk));
            if text.contains("\"value\":5") {
                return true;
            }
        }
        false
    };
    assert!(
        tokio::time::timeout(Duration::from_secs(30), told)
            .await
            .unwrap_or(false),
        "the other client is told the change"
    );
    let metrics = gw.metrics().await.expect("metrics");
    assert_eq!(
        bound_metric(&metrics, "iogate_bound_refused_total", "streams_per_client"),
        Some(1),
        "{metrics}"
    );
    assert_eq!(
        bound_metric(&metrics, "iogate_bound_used", "streams_per_client"),
        Some(2)
    );
    gw.shutdown().await;
}

#[tokio::test]
async fn declarations_past_the_bound_are_refused_429_and_change_nothing_else() {
    let (gw, device) = polling("bounds-declarations", "").await;
    let transaction = |n: usize| {
        serde_json::json!({
            "link": "plc", "function": 3, "slave": 1, "address": n % 100,
            "value_type": "UNSIGNED_NUMBER16", "byte_order": "BigEndian",
            "refresh_interval_ms": 1000, "enabled": false,
        })
        .to_string()
    };
    for n in 0..256 {
        let path = format!("/api/v1/transactions/t{n}");
        let (status, body) = gw
            .send(Method::PUT, &path, transaction(n))
            .await
            .expect("put");
        assert_eq!(status, 200, "{body}");
    }
    let (status, body) = gw
        .send(Method::PUT, "/api/v1/transactions/one-more", transaction(0))
        .await
        .expect("put");
    assert_eq!(status, 429, "{body}");
    assert_eq!(body["error"]["code"], "too_many_declared", "{body}");
    assert!(
        body["error"]["message"]
            .as_str()
            .is_some_and(|m| m.contains("at most 256")),
        "{body}"
    );
    // Declaring an existing one again is still answered (idempotent), and one removed
    // makes room.
    let (status, _) = gw
        .send(Method::PUT, "/api/v1/transactions/t0", transaction(0))
        .await
        .expect("put");
    assert_eq!(status, 200);
    let (status, _) = gw
        .send(Method::DELETE, "/api/v1/transactions/t0", "")
        .await
        .expect("delete");
    assert_eq!(status, 204);
    let (status, body) = gw
        .send(Method::PUT, "/api/v1/transactions/one-more", transaction(0))
        .await
        .expect("put");
    assert_eq!(status, 200, "{body}");
    // Links: 64, then 429; polling goes on.
    // Each link its own endpoint: listeners that never answer.
    let ends: Vec<std::net::TcpListener> = (0..65)
        .map(|_| std::net::TcpListener::bind("127.0.0.1:0").expect("bind"))
        .collect();
    let link = |n: usize| {
        let port = ends[n].local_addr().expect("addr").port();
        format!("{{\"tcp\": {{\"host\": \"127.0.0.1\", \"port\": {port}}}}}")
    };
    for n in 0..64 {
        let (status, answer) = gw
            .send(Method::PUT, &format!("/api/v1/links/l{n}"), link(n))
            .await
            .expect("put");
        assert_eq!(status, 201, "{answer}");
    }
    let (status, answer) = gw
        .send(Method::PUT, "/api/v1/links/l64", link(64))
        .await
        .expect("put");
    assert_eq!(status, 429, "{answer}");
    device.tables.lock().expect("tables").input[0] = 4;
    read_until(&gw, 4).await;
    let metrics = gw.metrics().await.expect("metrics");
    for (bound, used, limit) in [
        ("declared_transactions", 256, 256),
        ("declared_links", 64, 64),
        ("declared_devices", 0, 1024),
        // One scan a link at a time; 128 outcomes kept for the meter's one field.
        ("scans", 0, 65),
        ("write_outcomes", 0, 128),
    ] {
        assert_eq!(
            bound_metric(&metrics, "iogate_bound_used", bound),
            Some(used),
            "{bound}"
        );
        assert_eq!(
            bound_metric(&metrics, "iogate_bound_limit", bound),
            Some(limit),
            "{bound}"
        );
    }
    assert_eq!(
        bound_metric(&metrics, "iogate_bound_refused_total", "declared_links"),
        Some(1)
    );
    assert_eq!(
        bound_metric(
            &metrics,
            "iogate_bound_refused_total",
            "declared_transactions"
        ),
        Some(1)
    );
    gw.shutdown().await;
}

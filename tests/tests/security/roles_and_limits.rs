use super::*;

#[tokio::test]
async fn every_route_needs_its_role_over_rest() {
    let gw = gateway("").await;
    let write = json!({"value": true}).to_string();
    let declare = json!({"profile": "SimIo"}).to_string();
    let cases: [(Method, &str, &str, [u16; 4]); 6] = [
        // no token, read, write, admin
        (Method::GET, "/api/v1/devices", "", [401, 200, 200, 200]),
        (
            Method::GET,
            "/api/v1/events?bogus=1",
            "",
            [401, 400, 400, 400],
        ),
        (
            Method::PUT,
            "/api/v1/devices/sim/fields/DO_0",
            &write,
            [401, 403, 202, 202],
        ),
        (
            Method::PUT,
            "/api/v1/devices/sim/fields/DI_0/simulate",
            &write,
            [401, 403, 202, 202],
        ),
        (
            Method::PUT,
            "/api/v1/devices/sim2",
            &declare,
            [401, 403, 403, 201],
        ),
        (Method::GET, "/livez", "", [200, 200, 200, 200]),
    ];
    for (method, path, body, expected) in cases {
        for (token, want) in [None, Some(READ), Some(WRITE), Some(ADMIN)]
            .into_iter()
            .zip(expected)
        {
            let (status, answer) = call(&gw, method.clone(), path, token, body).await;
            assert_eq!(status, want, "{method} {path} with {token:?}: {answer}");
            if status == 401 {
                assert_eq!(answer["error"]["code"], "unauthenticated");
            }
            if status == 403 {
                assert_eq!(answer["error"]["code"], "forbidden");
                assert!(!answer.to_string().contains(READ) && !answer.to_string().contains(WRITE));
            }
        }
    }
    assert_eq!(
        call(&gw, Method::GET, "/metrics", None, "").await.0,
        200,
        "metrics stay open"
    );
    assert_eq!(
        call(
            &gw,
            Method::GET,
            "/api/v1/devices",
            Some("Bearer-less-guess-0123456789"),
            ""
        )
        .await
        .0,
        401
    );
    gw.shutdown().await;
}

#[tokio::test]
async fn every_rpc_needs_its_role_over_grpc() {
    let gw = gateway("").await;
    let channel = tonic::transport::Endpoint::from_shared(gw.grpc.clone())
        .expect("endpoint")
        .connect()
        .await
        .expect("channel");
    let with = |token: Option<&'static str>| {
        iogate_client::proto::gateway_client::GatewayClient::with_interceptor(
            channel.clone(),
            move |mut r: tonic::Request<()>| {
                if let Some(t) = token {
                    r.metadata_mut().insert(
                        "authorization",
                        format!("Bearer {t}").parse().expect("ascii"),
                    );
                }
                Ok(r)
            },
        )
    };
    let list = iogate_client::proto::ListDevicesRequest {};
    assert_eq!(
        with(None)
            .list_devices(list)
            .await
            .map(|_| ())
            .map_err(|s| s.code()),
        Err(tonic::Code::Unauthenticated)
    );
    assert!(with(Some(READ)).list_devices(list).await.is_ok());
    let write = || iogate_client::proto::WriteRequest {
        writes: vec![iogate_client::proto::FieldWrite {
            device: "sim".into(),
            field: "DO_0".into(),
            value: Some(iogate_client::proto::Value {
                r#type: 0,
                kind: Some(iogate_client::proto::value::Kind::BoolValue(true)),
            }),
            relinquish: false,
        }],
    };
    assert_eq!(
        with(Some(READ))
            .write(write())
            .await
            .map(|_| ())
            .map_err(|s| s.code()),
        Err(tonic::Code::PermissionDenied)
    );
    assert!(with(Some(WRITE)).write(write()).await.is_ok());
    let declare = || iogate_client::proto::EnsureDeviceRequest {
        name: "sim3".into(),
        profile: "SimIo".into(),
        refresh_rate_ms: 100,
        ..Default::default()
    };
    assert_eq!(
        with(Some(WRITE))
            .ensure_device(declare())
            .await
            .map(|_| ())
            .map_err(|s| s.code()),
        Err(tonic::Code::PermissionDenied)
    );
    assert!(with(Some(ADMIN)).ensure_device(declare()).await.is_ok());
    let mut health = tonic_health::pb::health_client::HealthClient::new(channel.clone());
    assert!(
        health
            .check(tonic_health::pb::HealthCheckRequest {
                service: String::new()
            })
            .await
            .is_ok(),
        "health checks stay open"
    );
    gw.shutdown().await;
}

#[tokio::test]
async fn read_only_refuses_every_write_everywhere() {
    let gw = gateway("  read_only: true\n").await;
    let (status, answer) = call(
        &gw,
        Method::PUT,
        "/api/v1/devices/sim/fields/DO_0",
        Some(ADMIN),
        &json!({"value": true}).to_string(),
    )
    .await;
    assert_eq!(
        (status, &answer["error"]["code"]),
        (403, &json!("read_only")),
        "{answer}"
    );
    let (status, _) = call(
        &gw,
        Method::PUT,
        "/api/v1/devices/sim/fields/DI_0/simulate",
        Some(ADMIN),
        &json!({"value": true}).to_string(),
    )
    .await;
    assert_eq!(status, 403);
    assert_eq!(
        call(&gw, Method::GET, "/api/v1/devices/sim", Some(READ), "")
            .await
            .0,
        200
    );
    // The Modbus server: writes to the map (coil 0) and to the memory (coil 800) are
    // exception 01; reads still answer.
    use tokio_modbus::prelude::*;
    let mut master =
        tokio_modbus::client::tcp::connect_slave(gw.modbus.expect("modbus server"), Slave(1))
            .await
            .expect("connect");
    for coil in [0, 800] {
        assert_eq!(
            master.write_single_coil(coil, true).await.expect("answer"),
            Err(tokio_modbus::ExceptionCode::IllegalFunction),
            "coil {coil}"
        );
    }
    assert_eq!(
        master
            .write_multiple_registers(0, &[1, 2])
            .await
            .expect("answer"),
        Err(tokio_modbus::ExceptionCode::IllegalFunction)
    );
    assert!(master.read_coils(0, 1).await.expect("answer").is_ok());
    gw.shutdown().await;
}

#[test]
fn without_tokens_the_listeners_stay_on_loopback_unless_insecure() {
    let check = |text: &str| {
        let mut c = iogate::config::parse("c.yaml", text).expect("parses");
        c.profiles = Some(iogate_tests::profiles_dir());
        iogate::app::Setup::from_config(c, std::path::Path::new("."))
            .err()
            .map(|p| p.to_string())
    };
    let problems = check("listen: { http: 0.0.0.0:8080 }\n").expect("refused");
    assert!(
        problems.contains(
            "listen.http: 0.0.0.0:8080 is not a loopback address and no tokens are configured"
        ),
        "{problems}"
    );
    assert_eq!(
        check("listen: { http: 0.0.0.0:8080 }\nsecurity: { insecure: true }\n"),
        None
    );
    assert_eq!(check("listen: { http: 127.0.0.1:8080 }\n"), None);
}

#[tokio::test]
async fn a_client_slow_with_its_headers_or_idle_between_requests_is_dropped() {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let gw = TestGateway::start("listen: { header_timeout: 300ms }\n")
        .await
        .expect("gateway");
    let addr = gw.base.trim_start_matches("http://").to_owned();
    let mut slow = tokio::net::TcpStream::connect(&addr)
        .await
        .expect("connect");
    slow.write_all(b"GET /livez HTTP/1.1\r\nHost: x\r\n")
        .await
        .expect("partial");
    let started = std::time::Instant::now();
    let mut buf = [0u8; 256];
    let read = tokio::time::timeout(std::time::Duration::from_secs(5), slow.read(&mut buf))
        .await
        .expect("the server closes it, not this test's patience");
    // Closed (nothing more, or a reset), not answered, well before the test's patience.
    match read {
        Ok(0) | Err(_) => {}
        Ok(n) => panic!("answered: {:?}", String::from_utf8_lossy(&buf[..n])),
    }
    assert!(started.elapsed() >= std::time::Duration::from_millis(250));
    assert!(started.elapsed() < std::time::Duration::from_secs(4));
    // Others are served meanwhile.
    assert_eq!(gw.get("/livez").await.expect("livez").0, 200);

    // A kept-alive connection that sends nothing after its answer is closed the same way.
    let mut idle = tokio::net::TcpStream::connect(&addr)
        .await
        .expect("connect");
    idle.write_all(b"GET /livez HTTP/1.1\r\nHost: x\r\n\r\n")
        .await
        .expect("request");
    let mut answer = Vec::new();
    while !answer.ends_with(b"ok") && !answer.windows(4).any(|w| w == b"\r\n\r\n") {
        let n = idle.read(&mut buf).await.expect("answer");
        assert!(n > 0, "closed before answering");
        answer.extend_from_slice(&buf[..n]);
    }
    assert!(answer.starts_with(b"HTTP/1.1 200"), "{answer:?}");
    let started = std::time::Instant::now();
    let mut rest = Vec::new();
    let closed = tokio::time::timeout(std::time::Duration::from_secs(5), async {
        loop {
            match idle.read(&mut buf).await {
                Ok(0) | Err(_) => break,
                Ok(n) => rest.extend_from_slice(&buf[..n]),
            }
        }
    })
    .await;
    assert!(closed.is_ok(), "an idle connection is closed by the server");
    assert!(started.elapsed() >= std::time::Duration::from_millis(250));

    // A socket on the gRPC listener that never sends its preface is closed the same way.
    let grpc_addr = gw.grpc.trim_start_matches("http://").to_owned();
    let mut silent = tokio::net::TcpStream::connect(&grpc_addr)
        .await
        .expect("connect");
    let started = std::time::Instant::now();
    let read = tokio::time::timeout(std::time::Duration::from_secs(5), silent.read(&mut buf))
        .await
        .expect("the gRPC listener closes a silent socket");
    assert!(matches!(read, Ok(0) | Err(_)), "{read:?}");
    assert!(started.elapsed() >= std::time::Duration::from_millis(250));
    gw.client()
        .await
        .expect("gRPC still serves")
        .devices()
        .await
        .expect("ListDevices");
    gw.shutdown().await;
}

#[tokio::test]
async fn a_link_stuck_past_its_bound_is_reported_not_connected() {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
        .await
        .expect("bind");
    let port = listener.local_addr().expect("addr").port();
    let gw = TestGateway::start(&format!(
        "links:\n  - {{ name: line, tcp: {{ host: 127.0.0.1, port: {port} }} }}\n"
    ))
    .await
    .expect("gateway");
    let _accepted = tokio::time::timeout(iogate_tests::PATIENCE, listener.accept())
        .await
        .expect("the link connects");
    gw.until("/api/v1/links/line", "link open", |b| {
        b["connected"] == true
    })
    .await
    .expect("open");
    let link = gw.service().expect("running").link("line").expect("link");
    // The task reports a transaction whose bound passed long ago, and never ends it.
    let long_ago = tokio::time::Instant::now()
        .checked_sub(std::time::Duration::from_secs(60))
        .expect("an instant a minute ago");
    link.progress.started(long_ago);
    gw.until("/api/v1/links/line", "link reported stalled", |b| {
        b["connected"] == false && b["error_code"] == 3
    })
    .await
    .expect("stalled");
    let response = gw
        .client
        .get(gw.url("/readyz"))
        .send()
        .await
        .expect("readyz");
    assert_eq!(response.status().as_u16(), 503);
    let body: serde_json::Value = response.json().await.expect("json");
    assert_eq!(body["stalled_links"], json!(["line"]), "{body}");
    let metrics = gw.metrics().await.expect("metrics");
    assert!(
        metrics.contains("iogate_link_stalled{link=\"line\"} 1"),
        "{metrics}"
    );

    link.progress.ended();
    gw.until("/api/v1/links/line", "link connected again", |b| {
        b["connected"] == true && b["error_code"] == 0
    })
    .await
    .expect("moves on");
    assert_eq!(gw.get("/readyz").await.expect("readyz").0, 200);
    gw.shutdown().await;
}

#[tokio::test]
async fn a_request_body_that_does_not_arrive_in_time_is_answered_and_dropped() {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let gw = TestGateway::start(
        "listen: { body_timeout: 300ms }\ndevices:\n  - { name: sim, profile: SimIo, refresh_rate: 20ms }\n",
    )
    .await
    .expect("gateway");
    let addr = gw.base.trim_start_matches("http://").to_owned();
    let mut slow = tokio::net::TcpStream::connect(&addr)
        .await
        .expect("connect");
    slow.write_all(
        b"PUT /api/v1/devices/sim/fields/DO_0 HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nContent-Length: 15\r\n\r\n{\"val",
    )
    .await
    .expect("partial body");
    let started = std::time::Instant::now();
    let mut answer = Vec::new();
    let read = tokio::time::timeout(
        std::time::Duration::from_secs(5),
        slow.read_to_end(&mut answer),
    )
    .await
    .expect("answered and closed by the server, not this test's patience");
    assert!(read.is_ok(), "{read:?}");
    assert!(started.elapsed() >= std::time::Duration::from_millis(250));
    let text = String::from_utf8_lossy(&answer);
    assert!(text.starts_with("HTTP/1.1 408"), "{text}");
    assert!(text.contains("\"request_timeout\""), "{text}");
    // Nothing was written.
    let (_, field) = gw
        .get("/api/v1/devices/sim/fields/DO_0")
        .await
        .expect("field");
    assert!(field["last_write"].is_null(), "{field}");
    gw.shutdown().await;
}

use super::*;

#[tokio::test]
async fn events_stream_current_values_then_changes() {
    let gw = demo().await;
    let mut events = SseReader::open(&gw, "/api/v1/events?device=sim")
        .await
        .expect("open");
    // The current state comes first: both fields and the diagnostics, in any order.
    let mut initial = std::collections::BTreeSet::new();
    while initial.len() < 3 {
        let (name, data) = events.next().await.expect("event").expect("not ended");
        assert_eq!(data["device"], "sim");
        initial.insert(format!("{name}:{}", data["field"].as_str().unwrap_or("")));
    }
    assert_eq!(
        initial.into_iter().collect::<Vec<_>>(),
        ["diagnostics:", "value:DI_0", "value:DO_0"]
    );
    gw.until("/api/v1/devices/sim", "sim polled", |b| {
        b["connected"] == true
    })
    .await
    .expect("connected");
    let (status, _) = gw
        .send(
            Method::PUT,
            "/api/v1/devices/sim/fields/DI_0/simulate",
            "true",
        )
        .await
        .expect("simulate");
    assert_eq!(status, 202);
    let change = events
        .until(|name, d| name == "value" && d["field"] == "DI_0" && d["value"] == true)
        .await
        .expect("DI_0 change");
    assert_eq!(change["quality"], "good");
    assert_eq!(change["type"], "BOOL");

    // Shutdown ends the stream instead of holding the server open.
    let started = std::time::Instant::now();
    gw.shutdown().await;
    assert!(started.elapsed() < std::time::Duration::from_secs(2));
    let ended = loop {
        match events.next().await {
            Ok(Some(_)) => continue,
            Ok(None) => break true,
            // A connection closed mid-chunk ends the stream too; waiting in vain does not.
            Err(e) => break !e.to_string().contains("no event within"),
        }
    };
    assert!(ended, "the event stream ends on shutdown");
}

#[tokio::test]
async fn profiles_show_their_function_block_layout() {
    let gw = demo().await;
    let (status, body) = gw.get("/api/v1/profiles").await.expect("get");
    assert_eq!(status, 200);
    assert_eq!(body["profiles"].as_array().map(Vec::len), Some(8));
    let (status, body) = gw
        .get("/api/v1/profiles/WaveshareAnalogInput")
        .await
        .expect("get");
    assert_eq!(status, 200);
    let layout: Vec<(String, String, String)> = body["layout"]
        .as_array()
        .expect("layout")
        .iter()
        .map(|e| {
            (
                e["name"].as_str().unwrap_or_default().to_owned(),
                e["type"].as_str().unwrap_or_default().to_owned(),
                e["section"].as_str().unwrap_or_default().to_owned(),
            )
        })
        .collect();
    let expected_head = [
        ("link", "STRING", "VAR_INPUT"),
        ("slave_id", "INT", "VAR_INPUT"),
        ("refresh_rate", "TIME", "VAR_INPUT"),
        ("connected", "BOOL", "VAR"),
        ("error_code", "INT", "VAR"),
        ("io_cycles", "UDINT", "VAR"),
        ("last_response_ms", "REAL", "VAR"),
        ("AI1", "INT", "VAR"),
    ];
    for (got, want) in layout.iter().zip(expected_head) {
        assert_eq!((got.0.as_str(), got.1.as_str(), got.2.as_str()), want);
    }
    assert_eq!(layout.len(), 7 + 8);
    assert_eq!(body["fields"][0]["register"]["kind"], "input_register");
    let (_, sim) = gw.get("/api/v1/profiles/SimIo").await.expect("get");
    assert_eq!(
        sim["layout"][0]["name"], "refresh_rate",
        "simulated: no link"
    );
    gw.shutdown().await;
}

#[tokio::test]
async fn links_and_modbus_devices_from_a_config_are_listed() {
    // A TCP endpoint that accepts connections but never answers.
    let silent = tokio::net::TcpListener::bind("127.0.0.1:0")
        .await
        .expect("bind");
    let tcp_port = silent.local_addr().expect("addr").port();
    let gw = TestGateway::start(&format!(
        "links:\n  - {{ name: rs485, serial: {{ port: /nonexistent/ttyIOGATE, baud: 19200, parity: E }} }}\n  - {{ name: plant, tcp: {{ host: 127.0.0.1, port: {tcp_port} }} }}\ndevices:\n  - {{ name: meter, profile: EastronSDM630, link: rs485, slave_id: 3, refresh_rate: 1s }}\n  - {{ name: vfd, profile: GenericVfd, link: rs485, slave_id: 4 }}\n  - {{ name: sim, profile: SimIo }}\n",
    ))
    .await
    .expect("start");
    let (status, body) = gw.get("/api/v1/links").await.expect("get");
    assert_eq!(status, 200);
    let links = body["links"].as_array().expect("links");
    assert_eq!(links.len(), 2);
    assert_eq!(links[0]["kind"], "serial");
    assert_eq!(links[0]["baud"], 19200);
    assert_eq!(links[0]["parity"], "E");
    assert_eq!(links[0]["devices"], json!(["meter", "vfd"]));
    assert_eq!(links[1]["kind"], "tcp");
    assert_eq!(links[1]["tcp_port"], tcp_port);
    // The port does not exist: the link reports "open failed", its devices a communication
    // error, and their fields say why they have no value.
    let link = gw
        .until("/api/v1/links/rs485", "open failed", |b| {
            b["error_code"] == 2
        })
        .await
        .expect("link state");
    assert_eq!(link["connected"], false);
    let meter = gw
        .until("/api/v1/devices/meter", "unreachable", |b| {
            b["error_code"] == 10
        })
        .await
        .expect("device state");
    assert_eq!(meter["slave_id"], 3);
    assert_eq!(meter["link"], "rs485");
    assert_eq!(meter["connected"], false);
    let frequency = &meter["fields"]["Frequency"];
    assert_eq!(frequency["quality"], "bad");
    assert_eq!(frequency["value"], Value::Null);
    assert!(
        frequency["error"]
            .as_str()
            .is_some_and(|e| e.contains("/nonexistent/ttyIOGATE")),
        "{frequency}"
    );
    // A write while the link is down is accepted, then fails at once with the reason.
    let (status, body) = gw
        .send(
            Method::PUT,
            "/api/v1/devices/vfd/fields/FrequencySetpoint",
            "12.5",
        )
        .await
        .expect("put");
    assert_eq!(status, 202, "{body}");
    let generation = body["generation"].as_u64().expect("generation");
    let started = std::time::Instant::now();
    let write = gw
        .until(
            &format!("/api/v1/writes/{generation}"),
            "write failed",
            |b| b["status"] == "failed",
        )
        .await
        .expect("failed");
    assert!(
        started.elapsed() < std::time::Duration::from_secs(1),
        "{:?}",
        started.elapsed()
    );
    assert!(
        write["error"]
            .as_str()
            .is_some_and(|e| e.contains("cannot open /nonexistent/ttyIOGATE")),
        "{write}"
    );
    let (status, body) = gw
        .send(Method::PUT, "/api/v1/devices/meter/fields/Frequency", "50")
        .await
        .expect("put");
    assert_eq!((status, error_code(&body)), (409, "not_writable"));
    let (status, body) = gw
        .send(
            Method::PUT,
            "/api/v1/devices/meter/fields/Frequency/simulate",
            "50",
        )
        .await
        .expect("put");
    assert_eq!((status, error_code(&body)), (409, "not_simulated"));
    gw.shutdown().await;
}

#[tokio::test]
async fn health_and_openapi_are_served() {
    let gw = demo().await;
    assert_eq!(gw.get("/livez").await.expect("livez").0, 200);
    assert_eq!(
        gw.get("/readyz").await.expect("readyz").1["status"],
        "ready"
    );
    let (status, doc) = gw.get("/api/v1/openapi.json").await.expect("openapi");
    assert_eq!(status, 200);
    let paths = doc["paths"].as_object().expect("paths");
    for path in [
        "/api/v1/devices",
        "/api/v1/devices/{device}",
        "/api/v1/devices/{device}/fields",
        "/api/v1/devices/{device}/fields/{field}",
        "/api/v1/devices/{device}/fields/{field}/simulate",
        "/api/v1/writes/{generation}",
        "/api/v1/links",
        "/api/v1/links/{link}",
        "/api/v1/profiles",
        "/api/v1/profiles/{profile}",
        "/api/v1/events",
        "/livez",
        "/readyz",
    ] {
        assert!(
            paths.contains_key(path),
            "{path} missing from the OpenAPI document"
        );
    }
    assert!(paths["/api/v1/devices/{device}/fields/{field}"]["put"].is_object());
    gw.shutdown().await;
}

#[tokio::test]
async fn malformed_requests_never_cause_a_server_error() {
    let gw = demo().await;
    let bodies: Vec<Vec<u8>> = vec![
        b"".to_vec(),
        b"{".to_vec(),
        b"null".to_vec(),
        b"[]".to_vec(),
        b"{\"value\": {\"nested\": 1}}".to_vec(),
        b"{\"value\": 1e400}".to_vec(),
        b"{\"value\": -0}".to_vec(),
        b"{\"value\": 18446744073709551616}".to_vec(),
        b"\xff\xfe\x00garbage".to_vec(),
        vec![b'['; 10_000],
        format!("{{\"value\": \"{}\"}}", "x".repeat(100_000)).into_bytes(),
        b"{\"value\": true, \"extra\": 1}".to_vec(),
    ];
    let fields = [
        "sim/fields/DO_0",
        "plant/fields/BatchName",
        "plant/fields/MixTime",
        "plant/fields/ErrorMask",
    ];
    for field in fields {
        for body in &bodies {
            for (method, suffix) in [(Method::PUT, ""), (Method::PUT, "/simulate")] {
                let path = format!("/api/v1/devices/{field}{suffix}");
                let response = gw
                    .client
                    .request(method.clone(), gw.url(&path))
                    .body(body.clone())
                    .send()
                    .await
                    .expect("request");
                let status = response.status().as_u16();
                assert!(status < 500, "{method} {path} answered {status}");
            }
        }
        let device = field.split('/').next().unwrap_or_default();
        for body in &bodies {
            let path = format!("/api/v1/devices/{device}/fields");
            let response = gw
                .client
                .patch(gw.url(&path))
                .body(body.clone())
                .send()
                .await
                .expect("request");
            assert!(response.status().as_u16() < 500);
        }
    }
    assert_eq!(gw.get("/livez").await.expect("still alive").0, 200);
    gw.shutdown().await;
}

#[tokio::test]
async fn every_error_is_the_apis_json_and_echoes_little_of_its_input() {
    let gw = demo().await;
    for (method, path, status, code) in [
        (
            Method::DELETE,
            "/api/v1/devices".to_owned(),
            405,
            "method_not_allowed",
        ),
        (
            Method::GET,
            "/api/v1/devices/%ff".to_owned(),
            400,
            "bad_request",
        ),
        (Method::GET, "/nope".to_owned(), 404, "no_route"),
        (
            Method::GET,
            format!("/api/v1/devices/{}", "x".repeat(5000)),
            404,
            "unknown_device",
        ),
    ] {
        let response = gw
            .client
            .request(method.clone(), gw.url(&path))
            .send()
            .await
            .expect("request");
        assert_eq!(
            response.status().as_u16(),
            status,
            "{method} {}",
            &path[..path.len().min(40)]
        );
        assert!(
            response
                .headers()
                .get("content-type")
                .is_some_and(|v| v.to_str().is_ok_and(|t| t.starts_with("application/json"))),
            "{method} {path}"
        );
        let body: serde_json::Value = response.json().await.expect("JSON");
        assert_eq!(body["error"]["code"], code, "{body}");
        assert!(body.to_string().len() < 400, "a short answer: {body}");
    }
    let keys: serde_json::Map<String, serde_json::Value> = (0..10_000)
        .map(|i| (format!("nope{i}"), serde_json::Value::from(1)))
        .collect();
    let (status, body) = gw
        .send(
            Method::PATCH,
            "/api/v1/devices/plant/fields",
            serde_json::Value::Object(keys).to_string(),
        )
        .await
        .expect("patch");
    assert_eq!(status, 404);
    assert!(
        body.to_string().len() < 2000,
        "{} bytes",
        body.to_string().len()
    );
    assert!(
        body["error"]["message"]
            .as_str()
            .is_some_and(|m| m.ends_with("and 9990 more"))
    );
    gw.shutdown().await;
}

#[tokio::test]
async fn events_without_values_carry_only_diagnostics() {
    let gw = demo().await;
    let mut events = SseReader::open(&gw, "/api/v1/events?values=false")
        .await
        .expect("open");
    // Both devices' diagnostics come first; a change of a value does not follow.
    let mut seen = std::collections::BTreeSet::new();
    while seen.len() < 2 {
        let (name, data) = events.next().await.expect("event").expect("not ended");
        assert_eq!(name, "diagnostics", "{data}");
        seen.insert(data["device"].as_str().unwrap_or("").to_owned());
    }
    let (status, _) = gw
        .send(
            Method::PUT,
            "/api/v1/devices/sim/fields/DI_0/simulate",
            json!({"value": true}).to_string(),
        )
        .await
        .expect("simulate");
    assert!((200..300).contains(&status), "{status}");
    let next = tokio::time::timeout(std::time::Duration::from_millis(500), events.next()).await;
    if let Ok(Ok(Some((name, data)))) = next {
        assert_ne!(name, "value", "{data}");
    }
    let (status, body) = gw.get("/api/v1/events?values=maybe").await.expect("get");
    assert_eq!(status, 400);
    assert!(
        body["error"]["message"]
            .as_str()
            .unwrap_or("")
            .contains("values must be true or false"),
        "{body}"
    );
    gw.shutdown().await;
}

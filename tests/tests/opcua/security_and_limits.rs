use super::*;

#[tokio::test]
async fn the_demo_serves_its_devices_as_the_readme_shows() {
    let gw = TestGateway::demo().await.expect("demo");
    let mut ua = UaClient::connect(&url(&gw), &Options::default())
        .await
        .expect("asyncua, anonymous, no security");
    let read = ua.read("sim.DI_0").await.expect("read");
    assert_eq!(
        (read["type"].as_str(), read["status"].as_str()),
        (Some("Boolean"), Some("Good")),
        "{read}"
    );
    assert_eq!(
        ua.write("sim.DO_0", json!(true), "Boolean")
            .await
            .expect("write"),
        "Good"
    );
    eventually("the write on the simulated device", || async {
        rest(&gw, "/api/v1/devices/sim/fields/DO_0")
            .await
            .is_ok_and(|f| f["value"] == true)
    })
    .await
    .expect("written");
    gw.shutdown().await;
}

#[tokio::test]
async fn sign_and_encrypt_with_a_trusted_certificate_and_an_untrusted_one_rejected() {
    let dir = temp_dir("opcua-security");
    let gw = TestGateway::start(&format!(
        "{PLANT}{}",
        opcua(
            &dir,
            "  security: [basic256sha256_sign_encrypt, aes256_sha256_rsapss_sign_encrypt]\n"
        )
    ))
    .await
    .expect("gateway");
    let url = url(&gw);
    // The server's certificate was made on first start.
    assert!(dir.join("pki/own/cert.der").is_file());
    // No unsecured endpoint is offered.
    let plain = refused(&url, &Options::default())
        .await
        .expect("no None endpoint");
    assert!(!plain.is_empty());
    // An unknown client certificate is rejected and kept for review.
    let options = |name: &str| Options {
        security: Some((
            "Basic256Sha256,SignAndEncrypt".into(),
            dir.join(format!("{name}.der")),
            dir.join(format!("{name}.pem")),
        )),
        user: None,
    };
    let rejected = refused(&url, &options("client"))
        .await
        .expect("untrusted refused");
    assert!(rejected.contains("Bad"), "{rejected}");
    let saved: Vec<_> = std::fs::read_dir(dir.join("pki/rejected"))
        .expect("rejected dir")
        .filter_map(Result::ok)
        .collect();
    assert_eq!(
        saved.len(),
        1,
        "the rejected certificate is kept: {saved:?}"
    );
    let metrics = gw.metrics().await.expect("metrics");
    assert!(
        metrics.contains("iogate_opcua_rejected_certificates 1\n"),
        "{metrics}"
    );
    // Trusted (moved into trusted/ as an operator does), it connects and reads.
    let cert = saved[0].path();
    std::fs::create_dir_all(dir.join("pki/trusted")).expect("trusted dir");
    std::fs::rename(
        &cert,
        dir.join("pki/trusted")
            .join(cert.file_name().expect("name")),
    )
    .expect("trust");
    let mut ua = UaClient::connect(&url, &options("client"))
        .await
        .expect("a trusted client connects");
    assert_eq!(
        ua.read("plant.PumpStart").await.expect("read")["status"],
        "Good"
    );
    // The same certificate on the other policy offered.
    let pss = Options {
        security: Some((
            "Aes256Sha256RsaPss,SignAndEncrypt".into(),
            dir.join("client.der"),
            dir.join("client.pem"),
        )),
        user: None,
    };
    let mut ua = UaClient::connect(&url, &pss)
        .await
        .expect("Aes256_Sha256_RsaPss SignAndEncrypt");
    assert_eq!(
        ua.read("plant.PumpStart").await.expect("read")["status"],
        "Good"
    );
    gw.shutdown().await;
}

#[tokio::test]
async fn absolute_and_percent_deadbands_filter_changes() {
    let dir = temp_dir("opcua-deadband");
    let gw = TestGateway::start(&format!("{PLANT}{}", opcua(&dir, "")))
        .await
        .expect("gateway");
    let mut ua = UaClient::connect(&url(&gw), &Options::default())
        .await
        .expect("asyncua");
    // Pressure is an INT: its EURange is -32768..32767, so 10 % is 6553.5.
    let range = ua.read("plant.Pressure/EURange").await.expect("EURange");
    assert!(range["value"].is_string(), "{range}");
    ua.cmd(json!({"cmd": "deadband", "node": "plant.Pressure", "value": 10.0, "type": 2}))
        .await
        .expect("percent deadband");
    ua.cmd(json!({"cmd": "deadband", "node": "plant.SpeedRpm", "value": 50.0, "type": 1}))
        .await
        .expect("absolute deadband");
    let simulate = |field: &'static str, value: i64| {
        let gw = &gw;
        async move {
            let (status, body) = gw
                .send(
                    Method::PUT,
                    &format!("/api/v1/devices/plant/fields/{field}/simulate"),
                    json!({ "value": value }).to_string(),
                )
                .await
                .expect("simulate");
            assert!((200..300).contains(&status), "{body}");
            eventually("the simulated value read", || async {
                gw.get(&format!("/api/v1/devices/plant/fields/{field}"))
                    .await
                    .is_ok_and(|(_, v)| v["value"] == value)
            })
            .await
            .expect("read");
        }
    };
    for (field, value) in [
        ("Pressure", 100),
        ("SpeedRpm", 20),
        ("Pressure", 9000),
        ("SpeedRpm", 100),
    ] {
        simulate(field, value).await;
    }
    let mut seen = Vec::new();
    for _ in 0..5 {
        let changes = ua
            .cmd(json!({"cmd": "changes", "wait": 2}))
            .await
            .expect("changes");
        seen.extend(changes["changes"].as_array().cloned().unwrap_or_default());
        let values = |node: &str| -> Vec<serde_json::Value> {
            seen.iter()
                .filter(|c| c["node"] == node)
                .map(|c| c["value"].clone())
                .collect()
        };
        if values("plant.Pressure").contains(&json!(9000))
            && values("plant.SpeedRpm").contains(&json!(100))
        {
            break;
        }
    }
    let values = |node: &str| -> Vec<serde_json::Value> {
        seen.iter()
            .filter(|c| c["node"] == node)
            .map(|c| c["value"].clone())
            .collect()
    };
    assert_eq!(
        values("plant.Pressure"),
        vec![json!(0), json!(9000)],
        "100 is within 10 % of the range, 9000 is not: {seen:?}"
    );
    assert_eq!(
        values("plant.SpeedRpm"),
        vec![json!(0), json!(100)],
        "20 is within 50 of 0, 100 is not: {seen:?}"
    );
    gw.shutdown().await;
}

#[tokio::test]
async fn sessions_over_the_limit_are_refused_and_the_others_go_on() {
    let dir = temp_dir("opcua-limit");
    let gw = TestGateway::start(&format!("{PLANT}{}", opcua(&dir, "  max_sessions: 2\n")))
        .await
        .expect("gateway");
    let url = url(&gw);
    let mut first = UaClient::connect(&url, &Options::default())
        .await
        .expect("first session");
    let mut second = UaClient::connect(&url, &Options::default())
        .await
        .expect("second session");
    let third = refused(&url, &Options::default())
        .await
        .expect("third refused");
    assert!(third.contains("BadTooManySessions"), "{third}");
    for ua in [&mut first, &mut second] {
        assert_eq!(
            ua.read("plant.PumpStart").await.expect("read")["status"],
            "Good"
        );
    }
    // One leaves (CloseSession): a new session takes its place. A client that vanishes
    // without closing holds its place until the session timeout (at most 60 s).
    second.close().await.expect("closed");
    let mut again = None;
    for _ in 0..50 {
        if let Ok(ua) = UaClient::connect(&url, &Options::default()).await {
            again = Some(ua);
            break;
        }
        tokio::time::sleep(std::time::Duration::from_millis(200)).await;
    }
    let mut again = again.expect("a session after one left");
    assert_eq!(
        again.read("plant.PumpStart").await.expect("read")["status"],
        "Good"
    );
    let metrics = gw.metrics().await.expect("metrics");
    assert!(metrics.contains("iogate_opcua_sessions 2\n"), "{metrics}");
    gw.shutdown().await;
}

/// A TCP connection from `from` that says Hello: the server's first answer's message type
/// and, for an Error, its status code.
async fn hello(
    server: std::net::SocketAddr,
    from: &str,
) -> (tokio::net::TcpStream, String, Option<u32>) {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let socket = tokio::net::TcpSocket::new_v4().expect("socket");
    socket
        .bind(format!("{from}:0").parse().expect("address"))
        .expect("bind");
    let mut stream = socket.connect(server).await.expect("connects");
    let url = format!("opc.tcp://{server}/");
    let mut m = b"HELF\0\0\0\0".to_vec();
    for n in [0u32, 65_536, 65_536, 0, 0] {
        m.extend_from_slice(&n.to_le_bytes());
    }
    m.extend_from_slice(&(url.len() as i32).to_le_bytes());
    m.extend_from_slice(url.as_bytes());
    let len = (m.len() as u32).to_le_bytes();
    m[4..8].copy_from_slice(&len);
    stream.write_all(&m).await.expect("hello sent");
    let mut head = [0u8; 12];
    tokio::time::timeout(
        std::time::Duration::from_secs(10),
        stream.read_exact(&mut head),
    )
    .await
    .expect("an answer in time")
    .expect("an answer");
    let kind = String::from_utf8_lossy(&head[..3]).to_string();
    let code = (kind == "ERR").then(|| u32::from_le_bytes([head[8], head[9], head[10], head[11]]));
    (stream, kind, code)
}

#[tokio::test]
async fn connections_are_bounded_per_address_and_in_all_in_opcuas_own_terms() {
    let dir = temp_dir("opcua-connections");
    let gw = TestGateway::start(&format!(
        "{PLANT}{}",
        opcua(
            &dir,
            "  max_connections: 5\n  max_connections_per_client: 3\n"
        )
    ))
    .await
    .expect("gateway");
    let server = gw.opcua.expect("an OPC UA server");
    const TOO_BUSY: u32 = 0x807D_0000;
    // Three from one address are taken; its fourth is Bad_TcpServerTooBusy.
    let mut held = Vec::new();
    for _ in 0..3 {
        let (stream, kind, _) = hello(server, "127.0.0.1").await;
        assert_eq!(kind, "ACK");
        held.push(stream);
    }
    let (_, kind, code) = hello(server, "127.0.0.1").await;
    assert_eq!((kind.as_str(), code), ("ERR", Some(TOO_BUSY)));
    // Another address is served: two more fill the server, the next is refused.
    for _ in 0..2 {
        let (stream, kind, _) = hello(server, "127.0.0.2").await;
        assert_eq!(kind, "ACK");
        held.push(stream);
    }
    let (_, kind, code) = hello(server, "127.0.0.3").await;
    assert_eq!((kind.as_str(), code), ("ERR", Some(TOO_BUSY)));
    let metrics = gw.metrics().await.expect("metrics");
    for line in [
        "iogate_bound_limit{bound=\"opcua_connections\"} 5\n",
        "iogate_bound_used{bound=\"opcua_connections\"} 5\n",
        "iogate_bound_refused_total{bound=\"opcua_connections\"} 1\n",
        "iogate_bound_limit{bound=\"opcua_connections_per_client\"} 3\n",
        "iogate_bound_used{bound=\"opcua_connections_per_client\"} 3\n",
        "iogate_bound_refused_total{bound=\"opcua_connections_per_client\"} 1\n",
    ] {
        assert!(metrics.contains(line), "{line}\n{metrics}");
    }
    // Polling went on; once connections close, an independent client is served again.
    let (_, plant) = gw.get("/api/v1/devices/plant").await.expect("plant");
    assert_eq!(plant["connected"], true, "{plant:#}");
    held.clear();
    eventually("the connections closed", || async {
        gw.metrics()
            .await
            .is_ok_and(|m| m.contains("iogate_bound_used{bound=\"opcua_connections\"} 0\n"))
    })
    .await
    .expect("closed");
    let mut ua = UaClient::connect(&url(&gw), &Options::default())
        .await
        .expect("asyncua connects");
    assert_eq!(
        ua.read("plant.Level").await.expect("read")["status"],
        "Good"
    );
    ua.close().await.expect("closed");
    gw.shutdown().await;
}

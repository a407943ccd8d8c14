use super::*;

#[tokio::test]
async fn a_device_without_link_or_slave_reports_1_or_2_and_polls_once_declared_again() {
    let device = ModbusDevice::default();
    device.tables.lock().expect("tables").input[0] = 1234;
    let (port, server) = modbus_tcp_server(device).await;
    let gw = TestGateway::demo().await.expect("demo");
    let mut client = gw.client().await.expect("client");

    // No link yet: accepted, error 1, not connected.
    let (info, created) = client.ensure_device(&adc("", 1)).await.expect("accepted");
    assert!(created);
    assert_eq!(info.link, None);
    assert_eq!(diagnostics(&mut client, "adc").await, (false, 1));

    let request = iogate_client::proto::EnsureLinkRequest {
        name: "plc".into(),
        transport: Some(iogate_client::proto::ensure_link_request::Transport::Tcp(
            iogate_client::proto::TcpSettings {
                host: "127.0.0.1".into(),
                port: port.into(),
                framing: String::new(),
            },
        )),
        guard_time_ms: 0,
    };
    client.raw().ensure_link(request).await.expect("link");

    // Declared again with its link: the same device, now polled.
    let (info, created) = client.ensure_device(&adc("plc", 1)).await.expect("bound");
    assert!(!created, "the device is bound, not made anew");
    assert_eq!(info.link.as_deref(), Some("plc"));
    reads(&client, "adc", 1234).await;
    assert_eq!(diagnostics(&mut client, "adc").await, (true, 0));
    assert_eq!(
        client.links().await.expect("links")[0].devices,
        ["adc"],
        "a member of its link"
    );

    // Slave 0: accepted, error 2, not polled; declared again with a slave id, it reads.
    let (_, created) = client
        .ensure_device(&DeviceDeclaration {
            name: "adc2".into(),
            ..adc("plc", 0)
        })
        .await
        .expect("accepted");
    assert!(created);
    assert_eq!(diagnostics(&mut client, "adc2").await, (false, 2));
    assert!(
        !client.links().await.expect("links")[0]
            .devices
            .contains(&"adc2".to_owned()),
        "a device without a slave id is not polled"
    );
    client
        .ensure_device(&DeviceDeclaration {
            name: "adc2".into(),
            ..adc("plc", 1)
        })
        .await
        .expect("bound");
    reads(&client, "adc2", 1234).await;
    assert_eq!(diagnostics(&mut client, "adc2").await, (true, 0));

    // Once bound, another link or slave id is a conflict again.
    let refused = client.ensure_device(&adc("plc", 9)).await;
    assert!(
        matches!(&refused, Err(iogate_client::Error::Status { code, message }) if *code == tonic::Code::FailedPrecondition && message.contains("slave_id 1 (declared 9)")),
        "{refused:?}"
    );
    gw.shutdown().await;
    server.abort();
}

#[tokio::test]
async fn a_serial_link_without_a_port_reports_1_until_declared_with_one() {
    let device = ModbusDevice::default();
    device.tables.lock().expect("tables").input[0] = 77;
    let dir = temp_dir("declare-port");
    let path = dir.join("ttyLATE");
    let (device_end, _holder) = pty_at(&path).expect("pty");
    let server = tokio::spawn(
        tokio_modbus::server::rtu::Server::new(device_end).serve_forever(device.clone()),
    );
    let gw = TestGateway::demo().await.expect("demo");
    let mut client = gw.client().await.expect("client");
    let mut line = SerialLink {
        port: String::new(),
        baud: 19_200,
        parity: 'N',
        data_bits: 8,
        stop_bits: 1,
    };

    // Without a name there is nothing to call the link by: refused.
    let unnamed = client.ensure_serial_link(&line).await;
    assert!(
        matches!(&unnamed, Err(iogate_client::Error::Status { code, message }) if *code == tonic::Code::InvalidArgument && message.contains("no port configured")),
        "{unnamed:?}"
    );

    let (info, created) = client
        .ensure_named_serial_link("line1", &line)
        .await
        .expect("accepted");
    assert!(created);
    assert_eq!(info.name, "line1");
    eventually("link error 1", || {
        let mut c = client.clone();
        async move {
            c.links()
                .await
                .is_ok_and(|l| l[0].name == "line1" && l[0].error_code == 1 && !l[0].connected)
        }
    })
    .await
    .expect("no port configured");
    client
        .ensure_device(&adc("line1", 1))
        .await
        .expect("device on the link");

    line.port = path.display().to_string();
    let (info, created) = client
        .ensure_named_serial_link("line1", &line)
        .await
        .expect("given its port");
    assert!(!created, "the same link, given its port");
    assert_eq!(info.name, "line1");
    reads(&client, "adc", 77).await;
    let links = client.links().await.expect("links");
    assert_eq!((links[0].connected, links[0].error_code), (true, 0));
    gw.shutdown().await;
    server.abort();
}

#[tokio::test]
async fn rest_declarations_report_the_same_states_and_recover() {
    let device = ModbusDevice::default();
    device.tables.lock().expect("tables").input[0] = 4321;
    let (port, server) = modbus_tcp_server(device).await;
    let gw = TestGateway::demo().await.expect("demo");

    let body = json!({"profile": "WaveshareAnalogInput", "refresh_rate_ms": 50});
    let (status, answer) = gw
        .send(Method::PUT, "/api/v1/devices/adc", body.to_string())
        .await
        .expect("put");
    assert_eq!(status, 201, "{answer}");
    assert_eq!(answer["created"], true);
    assert_eq!(answer["device"]["error_code"], 1);
    assert_eq!(answer["device"]["connected"], false);
    let (status, again) = gw
        .send(Method::PUT, "/api/v1/devices/adc", body.to_string())
        .await
        .expect("put");
    assert_eq!((status, &again["created"]), (200, &json!(false)), "{again}");

    let link = json!({"tcp": {"host": "127.0.0.1", "port": port}});
    let (status, answer) = gw
        .send(Method::PUT, "/api/v1/links/plc", link.to_string())
        .await
        .expect("put link");
    assert_eq!(status, 201, "{answer}");
    assert_eq!(answer["link"]["name"], "plc");

    let bound = json!({"profile": "WaveshareAnalogInput", "link": "plc", "slave_id": 1, "refresh_rate_ms": 50});
    let (status, answer) = gw
        .send(Method::PUT, "/api/v1/devices/adc", bound.to_string())
        .await
        .expect("bind");
    assert_eq!(status, 200, "{answer}");
    assert_eq!(answer["device"]["link"], "plc");
    gw.until("/api/v1/devices/adc", "adc polled", |b| {
        b["connected"] == true && b["error_code"] == 0 && b["fields"]["AI1"]["value"] == 4321
    })
    .await
    .expect("polled");

    // Slave 0 reports error 2.
    let (status, answer) = gw
        .send(
            Method::PUT,
            "/api/v1/devices/adc2",
            json!({"profile": "WaveshareAnalogInput", "link": "plc"}).to_string(),
        )
        .await
        .expect("put");
    assert_eq!(status, 201, "{answer}");
    assert_eq!(answer["device"]["error_code"], 2);

    // A serial link without a port reports error 1.
    let (status, answer) = gw
        .send(
            Method::PUT,
            "/api/v1/links/line1",
            json!({"serial": {"baud": 9600}}).to_string(),
        )
        .await
        .expect("put link");
    assert_eq!(status, 201, "{answer}");
    gw.until("/api/v1/links/line1", "link error 1", |b| {
        b["error_code"] == 1
    })
    .await
    .expect("error 1");
    // An ASCII line, listed with its framing.
    let (status, answer) = gw
        .send(
            Method::PUT,
            "/api/v1/links/line2",
            json!({"serial": {"baud": 9600, "data_bits": 7, "parity": "E", "framing": "ascii"}})
                .to_string(),
        )
        .await
        .expect("put link");
    assert_eq!(status, 201, "{answer}");
    let (_, listed) = gw.get("/api/v1/links/line2").await.expect("link");
    assert_eq!(listed["framing"], "ascii", "{listed}");
    assert_eq!(listed["data_bits"], 7, "{listed}");

    // Refusals in the API's words.
    for (path, body, expected, code) in [
        (
            "/api/v1/devices/x",
            json!({"profile": "Nope"}),
            404,
            "unknown_profile",
        ),
        (
            "/api/v1/devices/x",
            json!({"profile": "WaveshareAnalogInput", "link": "rs232", "slave_id": 1}),
            404,
            "unknown_link",
        ),
        (
            "/api/v1/devices/adc",
            json!({"profile": "WaveshareAnalogInput", "link": "plc", "slave_id": 2, "refresh_rate_ms": 50}),
            409,
            "declaration_conflict",
        ),
        (
            "/api/v1/devices/x",
            json!({"profile": "WaveshareAnalogInput", "colour": "red"}),
            400,
            "invalid_body",
        ),
        (
            "/api/v1/links/bad",
            json!({"serial": {"port": "/dev/ttyS9", "baud": 5}}),
            400,
            "invalid_declaration",
        ),
        (
            "/api/v1/links/bad",
            json!({"serial": {"port": "/dev/ttyS9", "baud": 9600, "framing": "mbap"}}),
            400,
            "invalid_declaration",
        ),
    ] {
        let (status, answer) = gw
            .send(Method::PUT, path, body.to_string())
            .await
            .expect("put");
        assert_eq!(status, expected, "{path} {body}: {answer}");
        assert_eq!(answer["error"]["code"], code, "{answer}");
    }
    gw.shutdown().await;
    server.abort();
}

#[tokio::test]
async fn declarations_reach_only_what_the_security_policy_allows() {
    let gw = TestGateway::start(
        "security:\n  declare:\n    serial_ports: [\"/dev/shm*\", \"/dev/serial/*\"]\n    tcp_hosts: [\"192.0.2.0/24\"]\n",
    )
    .await
    .expect("gateway");
    let mut client = gw.client().await.expect("client");
    let serial = |port: &str| SerialLink {
        port: port.into(),
        baud: 9600,
        parity: 'N',
        data_bits: 8,
        stop_bits: 1,
    };
    let denied =
        |r: Result<(iogate_client::LinkInfo, bool), iogate_client::Error>, what: &str| match r {
            Err(iogate_client::Error::Status { code, message }) => {
                assert_eq!(code, tonic::Code::PermissionDenied, "{message}");
                assert!(message.contains(what), "{message}");
            }
            other => panic!("expected a refusal, got {other:?}"),
        };
    // Allowed by a pattern, but no serial port: a directory.
    denied(
        client.ensure_serial_link(&serial("/dev/shm")).await,
        "is not a character device",
    );
    // `..` would lead an allowed pattern anywhere.
    denied(
        client
            .ensure_serial_link(&serial("/dev/serial/../../etc/passwd"))
            .await,
        "a path with `..` is not allowed",
    );
    let (_other_end, pty) = tokio_serial::SerialStream::pair().expect("pty");
    let pty_path = tokio_serial::SerialPort::name(&pty).expect("pty name");
    denied(
        client.ensure_serial_link(&serial(&pty_path)).await,
        "does not match security.declare.serial_ports",
    );
    let tcp = |host: &str| iogate_client::proto::EnsureLinkRequest {
        name: String::new(),
        transport: Some(iogate_client::proto::ensure_link_request::Transport::Tcp(
            iogate_client::proto::TcpSettings {
                host: host.into(),
                port: 502,
                framing: String::new(),
            },
        )),
        guard_time_ms: 0,
    };
    let refused = client.raw().ensure_link(tcp("127.0.0.1")).await;
    assert_eq!(
        refused.map(|_| ()).map_err(|s| s.code()),
        Err(tonic::Code::PermissionDenied),
        "the gateway's own ports are not a target"
    );
    assert!(client.raw().ensure_link(tcp("192.0.2.7")).await.is_ok());
    // A device may not hold its link for longer than 10 s.
    let (_, answer) = gw
        .send(
            Method::PUT,
            "/api/v1/devices/slow",
            json!({"profile": "WaveshareAnalogInput", "link": "192.0.2.7_502", "slave_id": 1, "timeout_ms": 4_294_967_295u64}).to_string(),
        )
        .await
        .expect("put");
    assert_eq!(answer["error"]["code"], "invalid_declaration", "{answer}");
    assert!(
        answer["error"]["message"]
            .as_str()
            .is_some_and(|m| m.contains("10 ms - 10 s"))
    );
    // Over REST, a refusal is 403 in the API's JSON.
    let (status, answer) = gw
        .send(
            Method::PUT,
            "/api/v1/links/bad",
            json!({"tcp": {"host": "10.1.2.3"}}).to_string(),
        )
        .await
        .expect("put");
    assert_eq!(
        (status, &answer["error"]["code"]),
        (403, &json!("not_allowed")),
        "{answer}"
    );
    gw.shutdown().await;
}

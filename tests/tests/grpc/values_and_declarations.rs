use super::*;

#[tokio::test]
async fn a_snapshot_carries_typed_values_with_quality_and_time() {
    let (gw, mut client) = demo().await;
    eventually("plant polled", || {
        let mut c = client.clone();
        async move {
            c.get("plant", "Level")
                .await
                .is_ok_and(|v| v.quality == Quality::Good)
        }
    })
    .await
    .expect("polled");
    let all = client.read(&Selection::all()).await.expect("read");
    assert_eq!(all.len(), 2 + 19, "every field of both demo devices");
    let level = client
        .get("plant", "level")
        .await
        .expect("field names ignore case");
    assert_eq!(level.field, "Level");
    assert_eq!(level.ty, Some(IecType::Real));
    assert_eq!(level.value, Some(Value::Real(0.0)));
    assert!(level.timestamp.is_some());
    let name = client.get("plant", "BatchName").await.expect("get");
    assert_eq!(name.ty, Some(IecType::String));

    let (c, message) = code(client.get("nope", "X").await);
    assert_eq!(c, Code::NotFound);
    assert!(message.contains("unknown device `nope`"), "{message}");
    assert_eq!(code(client.get("sim", "NOPE").await).0, Code::NotFound);
    gw.shutdown().await;
}

#[tokio::test]
async fn a_write_changes_the_simulated_output_and_reports_its_outcome() {
    let (gw, mut client) = demo().await;
    let generation = client
        .write("sim", "DO_0", Value::Bool(true))
        .await
        .expect("write");
    let status = client
        .wait_write(generation, Duration::from_secs(5))
        .await
        .expect("status");
    assert_eq!(status.outcome, WriteOutcome::Written);
    assert_eq!(status.value, Some(Value::Bool(true)));
    eventually("DO_0 true", || {
        let mut c = client.clone();
        async move {
            c.get("sim", "DO_0")
                .await
                .is_ok_and(|v| v.value == Some(Value::Bool(true)))
        }
    })
    .await
    .expect("output changed");

    // Numbers convert when they fit; the rest is refused with the reason, and a refused
    // write in a batch stops the whole batch.
    let g = client
        .write("plant", "TemperatureSetpoint", Value::Int(65))
        .await
        .expect("int to REAL");
    assert!(g > generation);
    let (c, message) = code(client.write("plant", "Recipe", Value::Int(300)).await);
    assert_eq!(c, Code::InvalidArgument);
    assert!(
        message.contains("300 is out of range for USINT"),
        "{message}"
    );
    let (c, _) = code(client.write("sim", "DI_0", Value::Bool(true)).await);
    assert_eq!(c, Code::FailedPrecondition, "an input cannot be written");
    let (c, message) = code(
        client
            .write_many(&[
                ("plant", "PumpStart", Value::Bool(true)),
                ("plant", "MixTime", Value::String("soon".into())),
            ])
            .await,
    );
    assert_eq!(c, Code::InvalidArgument);
    assert!(message.starts_with("nothing was written"), "{message}");
    let pump = client.get("plant", "PumpStart").await.expect("get");
    assert_eq!(pump.value, Some(Value::Bool(false)));
    assert_eq!(code(client.write_status(999_999).await).0, Code::NotFound);
    gw.shutdown().await;
}

#[tokio::test]
async fn a_subscriber_sees_current_values_then_changes_in_order() {
    let (gw, mut client) = demo().await;
    let mut updates = client
        .subscribe(&Selection::field("plant", "Recipe"), false)
        .await
        .expect("subscribe");
    let first = updates.next().await.expect("current value").expect("ok");
    assert!(
        matches!(&first, Update::Value(v) if v.field == "Recipe"),
        "{first:?}"
    );

    for n in 1..=3u64 {
        let g = client
            .write("plant", "Recipe", Value::UInt(n))
            .await
            .expect("write");
        let status = client
            .wait_write(g, Duration::from_secs(5))
            .await
            .expect("status");
        assert_eq!(status.outcome, WriteOutcome::Written);
    }
    let mut seen = Vec::new();
    while seen.last() != Some(&3) {
        let update = tokio::time::timeout(iogate_tests::PATIENCE, updates.next())
            .await
            .expect("an update in time")
            .expect("stream open")
            .expect("ok");
        if let Update::Value(v) = update
            && let Some(Value::UInt(n)) = v.value
            && n > 0
        {
            seen.push(n);
        }
    }
    assert_eq!(seen, vec![1, 2, 3]);

    // The stream ends when the gateway shuts down.
    gw.shutdown().await;
    let end = tokio::time::timeout(iogate_tests::PATIENCE, async {
        while let Some(item) = updates.next().await {
            if item.is_err() {
                break;
            }
        }
    })
    .await;
    assert!(end.is_ok(), "the subscription ended");
}

#[tokio::test]
async fn scan_cycles_exchange_outputs_for_inputs_and_diagnostics() {
    let (gw, mut client) = demo().await;
    let mut exchange = client.exchange().await.expect("exchange");
    let reply = exchange
        .cycle(&[("sim", "DO_0", Value::Bool(true))], &["sim"])
        .await
        .expect("cycle 1");
    assert_eq!(reply.cycle, 1);
    assert_eq!(reply.written.len(), 1, "a changed output is written");
    assert_eq!(
        reply
            .inputs
            .iter()
            .map(|v| v.field.as_str())
            .collect::<Vec<_>>(),
        ["DI_0"]
    );
    assert_eq!(reply.diagnostics[0].device, "sim");
    assert!(reply.errors.is_empty());

    let reply = exchange
        .cycle(&[("sim", "DO_0", Value::Bool(true))], &[])
        .await
        .expect("cycle 2");
    assert_eq!(reply.cycle, 2);
    assert!(
        reply.written.is_empty(),
        "an unchanged output is not written again"
    );

    // An input set on the simulator shows in a later cycle.
    let (status, _) = gw
        .send(
            Method::PUT,
            "/api/v1/devices/sim/fields/DI_0/simulate",
            "true",
        )
        .await
        .expect("simulate");
    assert_eq!(status, 202);
    let mut cycles = 0;
    loop {
        let reply = exchange
            .cycle(&[("sim", "DO_0", Value::Bool(true))], &[])
            .await
            .expect("cycle");
        cycles += 1;
        if reply.inputs[0].value == Some(Value::Bool(true)) {
            break;
        }
        assert!(cycles < 200, "DI_0 never showed");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }

    // A bad output is reported; the stream goes on.
    let reply = exchange
        .cycle(
            &[
                ("sim", "DI_0", Value::Bool(false)),
                ("sim", "DO_0", Value::Bool(false)),
            ],
            &[],
        )
        .await
        .expect("cycle with an error");
    assert_eq!(reply.errors.len(), 1, "{:?}", reply.errors);
    assert!(
        reply.errors[0].contains("is an input"),
        "{:?}",
        reply.errors
    );
    assert_eq!(reply.written.len(), 1);
    gw.shutdown().await;
}

#[tokio::test]
async fn declarations_are_idempotent_and_conflicts_are_named() {
    let (gw, mut client) = demo().await;
    let serial = SerialLink {
        port: "/nonexistent/ttyIOGATE0".into(),
        baud: 9600,
        parity: 'N',
        data_bits: 8,
        stop_bits: 1,
    };
    let (link, created) = client.ensure_serial_link(&serial).await.expect("link");
    assert!(created);
    assert_eq!(link.name, "nonexistent_ttyIOGATE0");
    let (again, created) = client.ensure_serial_link(&serial).await.expect("again");
    assert!(!created, "the same declaration is fine");
    assert_eq!(again.name, link.name);
    let (c, message) = code(
        client
            .ensure_serial_link(&SerialLink {
                baud: 19_200,
                parity: 'E',
                ..serial.clone()
            })
            .await,
    );
    assert_eq!(c, Code::FailedPrecondition);
    assert!(
        message.contains(
            "Baudrate configuration mismatch.\n/nonexistent/ttyIOGATE0: 19200 declared, 9600 in use"
        ),
        "{message}"
    );
    assert!(
        message.contains("Parity configuration mismatch"),
        "{message}"
    );
    let (c, message) = code(
        client
            .ensure_serial_link(&SerialLink {
                port: String::new(),
                ..serial.clone()
            })
            .await,
    );
    assert_eq!(c, Code::InvalidArgument);
    assert!(message.contains("no port configured"), "{message}");

    // A simulated device declared at run time is polled at once.
    let sim = DeviceDeclaration {
        name: "sim2".into(),
        profile: "SimIo".into(),
        link: String::new(),
        slave_id: 0,
        refresh_rate: Duration::from_millis(50),
    };
    let (device, created) = client.ensure_device(&sim).await.expect("device");
    assert!(created);
    assert_eq!(device.name, "sim2");
    assert!(!client.ensure_device(&sim).await.expect("again").1);
    eventually("sim2 polled", || {
        let mut c = client.clone();
        async move {
            c.get("sim2", "DI_0")
                .await
                .is_ok_and(|v| v.quality == Quality::Good)
        }
    })
    .await
    .expect("polled");
    let (c, message) = code(
        client
            .ensure_device(&DeviceDeclaration {
                refresh_rate: Duration::from_millis(80),
                ..sim.clone()
            })
            .await,
    );
    assert_eq!(c, Code::FailedPrecondition);
    assert!(
        message.contains("refresh_rate 50 ms (declared 80 ms)"),
        "{message}"
    );

    // A Modbus device binds to a link by its port, as `link := serial.port` does.
    let meter = DeviceDeclaration {
        name: "meter".into(),
        profile: "EastronSDM630".into(),
        link: "/nonexistent/ttyIOGATE0".into(),
        slave_id: 4,
        refresh_rate: Duration::from_secs(1),
    };
    let (device, created) = client.ensure_device(&meter).await.expect("meter");
    assert!(created);
    assert_eq!(device.link.as_deref(), Some("nonexistent_ttyIOGATE0"));
    let links = client.links().await.expect("links");
    assert_eq!(links[0].devices, ["meter"]);
    let (c, message) = code(
        client
            .ensure_device(&DeviceDeclaration {
                slave_id: 5,
                ..meter.clone()
            })
            .await,
    );
    assert_eq!(c, Code::FailedPrecondition);
    assert!(message.contains("slave_id 4 (declared 5)"), "{message}");
    // Slave 0 is a state, not a refusal: the device reports error 2 (no slave configured).
    let (m2, created) = client
        .ensure_device(&DeviceDeclaration {
            name: "m2".into(),
            slave_id: 0,
            ..meter.clone()
        })
        .await
        .expect("accepted");
    assert!(created);
    let diagnostics = m2.diagnostics.expect("diagnostics");
    assert_eq!((diagnostics.connected, diagnostics.error_code), (false, 2));
    let (c, message) = code(
        client
            .ensure_device(&DeviceDeclaration {
                name: "m3".into(),
                link: "rs232".into(),
                ..meter.clone()
            })
            .await,
    );
    assert_eq!(c, Code::NotFound);
    assert!(
        message.contains("declare it with EnsureLink first"),
        "{message}"
    );
    let (c, _) = code(
        client
            .ensure_device(&DeviceDeclaration {
                name: "m4".into(),
                profile: "Nope".into(),
                ..meter
            })
            .await,
    );
    assert_eq!(c, Code::NotFound);
    gw.shutdown().await;
}

#[tokio::test]
async fn a_runtime_declares_a_tcp_link_and_device_and_reads_it() {
    let device = ModbusDevice::default();
    device.tables.lock().expect("tables").input[0] = 1234;
    let (port, server) = modbus_tcp_server(device.clone()).await;
    let (gw, mut client) = demo().await;
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
    let created = client
        .raw()
        .ensure_link(request)
        .await
        .expect("link")
        .into_inner();
    assert!(created.created);
    client
        .ensure_device(&DeviceDeclaration {
            name: "adc".into(),
            profile: "WaveshareAnalogInput".into(),
            link: "plc".into(),
            slave_id: 1,
            refresh_rate: Duration::from_millis(50),
        })
        .await
        .expect("device");
    eventually("adc read", || {
        let mut c = client.clone();
        async move {
            c.get("adc", "AI1")
                .await
                .is_ok_and(|v| v.value == Some(Value::Int(1234)))
        }
    })
    .await
    .expect("read over the declared link");
    gw.shutdown().await;
    server.abort();
}

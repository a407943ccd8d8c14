use super::*;

#[tokio::test]
async fn with_tokens_the_page_asks_for_one_and_uses_it() -> anyhow::Result<()> {
    let dir = iogate_tests::devices::temp_dir("ui-tokens");
    let tokens = dir.join("tokens");
    std::fs::write(&tokens, "read reader-0123456789abcdef\n")?;
    let gw = TestGateway::start(&format!(
        "devices:\n  - {{ name: sim, profile: SimIo, refresh_rate: 100ms }}\nsecurity:\n  tokens_file: {}\n",
        tokens.display()
    ))
    .await?;
    // The page's files need no token; the API does.
    let (status, _) = gw.get("/api/v1/devices").await?;
    assert_eq!(status, 401);
    let browser = Browser::start(DESKTOP.0, DESKTOP.1).await?;
    browser.goto(&gw.url("/ui")).await?;
    let input = browser.wait_for("dialog[open] #login-token").await?;
    browser.type_text(&input, "reader-0123456789abcdef").await?;
    let submit = browser
        .wait_for("dialog[open] button[type='submit']")
        .await?;
    browser.click(&submit).await?;
    browser.wait_for("tr[data-device='sim']").await?;
    browser
        .until_text("#connection", Duration::from_secs(5), |t| t == "live")
        .await?;
    // A reader cannot write: the page shows the API's refusal.
    browser.goto(&gw.url("/ui#/devices/sim")).await?;
    let toggle = browser
        .wait_for("tr[data-field='DO_0'] button.toggle")
        .await?;
    browser.click(&toggle).await?;
    let refused = outcome(&browser, "DO_0", |t| t.contains("role")).await?;
    assert!(refused.contains("write"), "{refused}");
    Ok(())
}

#[tokio::test]
async fn the_overview_shows_the_mqtt_connection_and_its_buffer() -> anyhow::Result<()> {
    let mut broker = iogate_tests::mqtt::Broker::start().await?;
    let dir = iogate_tests::devices::temp_dir("ui-mqtt");
    let config = format!(
        "devices:
  - {{ name: sim, profile: SimIo, refresh_rate: 100ms }}
mqtt:
  url: mqtt://127.0.0.1:{}
  client_id: iogate-ui
  sparkplug: {{ group_id: plant1, edge_node_id: line1 }}
  json: {{ prefix: iogate/line1 }}
  buffer: {{ dir: {} }}
",
        broker.port,
        dir.display()
    );
    let gw = TestGateway::start(&config).await?;
    let browser = Browser::start(DESKTOP.0, DESKTOP.1).await?;
    browser.goto(&gw.url("/")).await?;
    browser
        .until_text(
            "#mqtt tr[data-mqtt='State']",
            Duration::from_secs(10),
            |t| t.contains("connected") && !t.contains("disconnected"),
        )
        .await?;
    browser
        .until_text(
            "#mqtt tr[data-mqtt='Sparkplug B']",
            Duration::from_secs(10),
            |t| t.contains("spBv1.0/plant1/…/line1") && t.contains("born, 1 device"),
        )
        .await?;
    // The broker goes away and a change waits in the buffer: the page says both.
    broker.pause().await;
    gw.until("/api/v1/mqtt", "disconnected", |s| s["connected"] == false)
        .await?;
    gw.send(
        Method::PUT,
        "/api/v1/devices/sim/fields/DI_0/simulate",
        json!({ "value": true }).to_string(),
    )
    .await?;
    browser
        .until_text(
            "#mqtt tr[data-mqtt='State']",
            Duration::from_secs(10),
            |t| t.contains("disconnected") && t.contains("cannot connect"),
        )
        .await?;
    browser
        .until_text(
            "#mqtt tr[data-mqtt='Buffer']",
            Duration::from_secs(10),
            |t| t.contains("2 waiting"),
        )
        .await?;
    browser
        .screenshot(&screenshots_dir().join("overview-mqtt.png"))
        .await?;
    assert_eq!(console_errors(&browser).await?, Vec::<String>::new());
    gw.shutdown().await;
    broker.stop().await;
    Ok(())
}

#[tokio::test]
async fn the_overview_shows_the_last_reload_and_a_refused_one() -> anyhow::Result<()> {
    let dir = iogate_tests::devices::temp_dir("ui-reload");
    let path = dir.join("iogate.yaml");
    let config = |rate: &str| {
        format!(
            "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0 }}\nprofiles: {}\ndevices:\n  - {{ name: sim, profile: SimIo, refresh_rate: {rate} }}\n",
            std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("../profiles")
                .display()
        )
    };
    std::fs::write(&path, config("100ms"))?;
    let setup = iogate::app::Setup::from_file(&path).map_err(|e| anyhow::anyhow!("{e}"))?;
    let gw = TestGateway::start_setup(setup).await?;
    let browser = Browser::start(DESKTOP.0, DESKTOP.1).await?;
    browser.goto(&gw.url("/")).await?;
    browser
        .until_text(
            "#config tr[data-config='File']",
            Duration::from_secs(10),
            |t| t.contains("iogate.yaml"),
        )
        .await?;
    // On a phone the row is a card: its name once (the header), not again as a cell label.
    browser.resize(PHONE.0, PHONE.1).await?;
    let labels = browser
        .run(
            "return [...document.querySelectorAll(\"#config tr[data-config='File'] th, #config tr[data-config='File'] td\")].map((e) => (e.innerText + ' ' + getComputedStyle(e, '::before').content))",
            serde_json::json!([]),
        )
        .await?;
    let text = labels.to_string();
    assert_eq!(text.matches("File").count(), 1, "{text}");
    browser.resize(DESKTOP.0, DESKTOP.1).await?;
    std::fs::write(&path, config("40ms"))?;
    let (status, body) = gw.send(Method::POST, "/api/v1/config/reload", "").await?;
    assert_eq!(status, 200, "{body}");
    let shown = browser
        .until_text(
            "#config tr[data-config='Last reload']",
            Duration::from_secs(10),
            |t| t.contains("1 change (api)"),
        )
        .await?;
    assert!(
        shown.contains("device sim") && shown.contains("refresh_rate: 100ms -> 40ms"),
        "{shown}"
    );
    // A refused reload: the page names the problem with its file and line.
    std::fs::write(&path, config("40ms").replace("SimIo", "NoSuchProfile"))?;
    let (status, _) = gw.send(Method::POST, "/api/v1/config/reload", "").await?;
    assert_eq!(status, 400);
    browser
        .until_text(
            "#config tr[data-config='Refused']",
            Duration::from_secs(10),
            |t| t.contains("iogate.yaml:4") && t.contains("unknown profile `NoSuchProfile`"),
        )
        .await?;
    browser
        .screenshot(&screenshots_dir().join("overview-reload.png"))
        .await?;
    assert_eq!(console_errors(&browser).await?, Vec::<String>::new());
    gw.shutdown().await;
    Ok(())
}

#[tokio::test]
async fn the_overview_shows_the_modbus_servers_serial_ports_and_their_frames() -> anyhow::Result<()>
{
    // The browser first: its processes must not inherit the pty (a pty's end held by
    // Chromium would never hang up).
    let browser = Browser::start(DESKTOP.0, DESKTOP.1).await?;
    let dir = iogate_tests::devices::temp_dir("ui-serial");
    let path = dir.join("ttySLAVE");
    let (mut master, holder) = iogate_tests::devices::pty_at(&path)?;
    let gw = TestGateway::start(&format!(
        "devices:\n  - {{ name: sim, profile: SimIo, refresh_rate: 100ms }}\nmodbus_server:\n  auto: true\n  serial:\n    - {{ port: {}, baud: 19200, parity: E, unit_id: 4 }}\n",
        path.display()
    ))
    .await?;
    gw.until("/api/v1/map", "the port open", |m| {
        m["serial"][0]["state"] == "open"
    })
    .await?;
    drop(holder);
    // A master reads a coil through the port.
    let mut request = vec![4u8, 0x01, 0x00, 0x00, 0x00, 0x01];
    let crc = iogate_tests::devices::crc16(&request);
    request.extend_from_slice(&crc.to_le_bytes());
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    master.write_all(&request).await?;
    let mut answer = [0u8; 6];
    tokio::time::timeout(iogate_tests::PATIENCE, master.read_exact(&mut answer)).await??;
    browser.goto(&gw.url("/")).await?;
    let row = format!("#serial tr[data-serial='{}']", path.display());
    browser
        .until_text(&row, Duration::from_secs(10), |t| {
            t.contains("open") && t.contains("RTU 19200 8E1") && t.contains("1 answered")
        })
        .await?;
    // Unplugged: the page says the port is lost.
    drop(master);
    gw.until("/api/v1/map", "the port lost", |m| {
        m["serial"][0]["state"] == "lost"
    })
    .await?;
    browser
        .until_text(&row, Duration::from_secs(10), |t| t.contains("lost"))
        .await?;
    assert_eq!(console_errors(&browser).await?, Vec::<String>::new());
    gw.shutdown().await;
    Ok(())
}

#[tokio::test]
async fn a_link_is_scanned_from_its_page_with_progress_and_the_devices_found() -> anyhow::Result<()>
{
    let browser = Browser::start(DESKTOP.0, DESKTOP.1).await?;
    let bus = RtuBus::default();
    bus.slave(1, |_| {});
    bus.slave(5, |s| s.tables.input[0] = 77);
    let (gw, _pty, task, _) = bus_gateway(
        "ui-scan",
        &bus,
        &[],
        "  - { name: rack, profile: MyIoModule, link: bus, slave_id: 1, refresh_rate: 50ms, timeout: 100ms }\n",
    )
    .await;
    gw.until("/api/v1/devices/rack", "connected", |b| {
        b["connected"] == true
    })
    .await?;
    browser.goto(&gw.url("/ui#/links/bus")).await?;
    let ids = browser.wait_for("#scan-ids").await?;
    browser.clear(&ids).await?;
    browser.type_text(&ids, "1-8").await?;
    let start = browser.wait_for("#scan-start").await?;
    browser.click(&start).await?;
    let status = browser
        .until_text("#scan-status", Duration::from_secs(20), |t| {
            t.starts_with("Done")
        })
        .await?;
    assert!(status.contains("2 devices found"), "{status}");
    let found = browser.text("#scan-found").await?;
    assert!(
        found.contains("slave 1") && found.contains("slave 5"),
        "{found}"
    );
    assert!(found.contains("MyIoModule"), "{found}");
    let config = browser.text("#scan-config").await?;
    assert!(config.contains("link: bus, slave_id: 5"), "{config}");
    assert_eq!(console_errors(&browser).await?, Vec::<String>::new());
    task.abort();
    gw.shutdown().await;
    Ok(())
}

#[tokio::test]
async fn an_opcua_links_page_shows_its_endpoint_state_and_subscriptions() -> anyhow::Result<()> {
    let browser = Browser::start(DESKTOP.0, DESKTOP.1).await?;
    let plc = iogate_tests::plc::UaPlc::start(&[]).await?;
    let dir = iogate_tests::devices::temp_dir("ui-opcua");
    std::fs::create_dir_all(dir.join("profiles"))?;
    std::fs::write(
        dir.join("profiles/press.yaml"),
        "name: Press\nprotocol: opcua\nfields:\n  - { name: Speed, type: LREAL, direction: input, node: \"ns=2;s=Line1.Speed\" }\n",
    )?;
    let config = format!(
        "profiles: {}\nlinks:\n  - name: press\n    opcua: {{ url: \"{}\", pki_dir: {} }}\ndevices:\n  - {{ name: press1, profile: Press, link: press, refresh_rate: 250ms }}\n",
        dir.join("profiles").display(),
        plc.url,
        dir.join("pki").display()
    );
    let gw = TestGateway::start(&config).await?;
    gw.until("/api/v1/devices/press1", "read", |d| {
        d["fields"]["Speed"]["quality"] == "good"
    })
    .await?;
    browser.goto(&gw.url("/ui#/links/press")).await?;
    let facts = browser
        .until_text("dl.facts", Duration::from_secs(10), |t| t.contains("opcua"))
        .await?;
    assert!(facts.contains(&format!("opcua {}", plc.url)), "{facts}");
    assert!(facts.contains("0 —"), "{facts}");
    let plan = browser
        .until_text("#plan", Duration::from_secs(10), |t| {
            t.contains("subscription")
        })
        .await?;
    assert!(
        plan.contains("a subscription publishing every 250 ms, 1 monitored item(s)"),
        "{plan}"
    );
    assert!(
        browser.find("#scan-ids").await?.is_none(),
        "no scan on an OPC UA link"
    );
    assert_eq!(console_errors(&browser).await?, Vec::<String>::new());
    gw.shutdown().await;
    plc.kill().await
}

#[tokio::test]
async fn an_s7_links_page_shows_the_plcs_identity_and_its_jobs() -> anyhow::Result<()> {
    let browser = Browser::start(DESKTOP.0, DESKTOP.1).await?;
    let plc = iogate_tests::s7::S7Plc::start(None).await?;
    let dir = iogate_tests::devices::temp_dir("ui-s7");
    std::fs::create_dir_all(dir.join("profiles"))?;
    std::fs::write(
        dir.join("profiles/press.yaml"),
        "name: Press\nprotocol: s7\nfields:\n  - { name: Count, type: INT, direction: input, address: DB1.DBW2 }\n",
    )?;
    let config = format!(
        "profiles: {}\nlinks:\n  - name: press\n    s7: {{ host: 127.0.0.1, port: {} }}\ndevices:\n  - {{ name: press1, profile: Press, link: press, refresh_rate: 250ms }}\n",
        dir.join("profiles").display(),
        plc.port,
    );
    let gw = TestGateway::start(&config).await?;
    gw.until("/api/v1/devices/press1", "read", |d| {
        d["fields"]["Count"]["quality"] == "good"
    })
    .await?;
    browser.goto(&gw.url("/ui#/links/press")).await?;
    let facts = browser
        .until_text("dl.facts", Duration::from_secs(10), |t| {
            t.contains("Order number")
        })
        .await?;
    for shown in [
        "s7 127.0.0.1",
        "6ES7 315-2EH14-0AB0",
        "CPU 315-2 PN/DP",
        "PDU size",
        "960",
        "run",
    ] {
        assert!(facts.contains(shown), "{shown}: {facts}");
    }
    let plan = browser
        .until_text("#plan", Duration::from_secs(10), |t| t.contains("job"))
        .await?;
    assert!(plan.contains("DB1 bytes 2-3: Count"), "{plan}");
    assert!(
        browser.find("#scan-ids").await?.is_none(),
        "no scan on an S7 link"
    );
    assert_eq!(console_errors(&browser).await?, Vec::<String>::new());
    gw.shutdown().await;
    plc.kill().await
}

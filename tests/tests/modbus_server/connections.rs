use super::*;

#[tokio::test]
async fn a_new_master_closes_the_connection_idle_longest_and_is_served_at_once() {
    let gw = TestGateway::start(
        "devices:\n  - { name: sim, profile: SimIo }\nmodbus_server:\n  listen: 127.0.0.1:0\n  max_connections: 3\n  auto: true\n",
    )
    .await
    .expect("gateway");
    let addr = gw.modbus.expect("server");
    let request = |id: u8| [0, id, 0, 0, 0, 6, 1, 1, 0, 0, 0, 1];
    // Three slots: a master that polls, one that was served once and went quiet, and a
    // socket that never sent a byte (a slow loris), all within the idle timeout (60 s).
    let mut active = TcpStream::connect(addr).await.expect("connect");
    assert_eq!(raw(&mut active, &request(1)).await.len(), 10);
    let mut quiet = TcpStream::connect(addr).await.expect("connect");
    assert_eq!(raw(&mut quiet, &request(2)).await.len(), 10);
    let mut loris = TcpStream::connect(addr).await.expect("connect");
    loris.write_all(&[0, 3, 0]).await.expect("half a header");
    assert_eq!(raw(&mut active, &request(4)).await.len(), 10);
    // A fresh master is served at once: the socket that never sent a request goes first.
    let mut fresh = TcpStream::connect(addr).await.expect("connect");
    assert_eq!(raw(&mut fresh, &request(5)).await.len(), 10);
    assert!(closed(&mut loris).await, "the slow loris is closed");
    // The next one closes the quiet master, never the one that polls.
    assert_eq!(raw(&mut active, &request(6)).await.len(), 10);
    assert_eq!(raw(&mut fresh, &request(7)).await.len(), 10);
    let mut next = TcpStream::connect(addr).await.expect("connect");
    assert_eq!(raw(&mut next, &request(8)).await.len(), 10);
    assert!(closed(&mut quiet).await, "the quiet master is closed");
    assert_eq!(raw(&mut active, &request(9)).await.len(), 10);
    let metrics = gw.metrics().await.expect("metrics");
    assert!(
        metrics.contains("iogate_modbus_server_evicted_connections_total 2"),
        "{metrics}"
    );
    assert!(
        metrics.contains("iogate_modbus_server_refused_connections_total 0"),
        "{metrics}"
    );
    for line in [
        "iogate_bound_limit{bound=\"modbus_connections\"} 3\n",
        "iogate_bound_refused_total{bound=\"modbus_connections\"} 2\n",
    ] {
        assert!(metrics.contains(line), "{line}\n{metrics}");
    }
    gw.shutdown().await;
}

#[tokio::test]
async fn a_master_that_never_reads_its_answers_loses_its_connection() {
    let gw = TestGateway::start(
        "devices:\n  - { name: sim, profile: SimIo }\nmodbus_server:\n  listen: 127.0.0.1:0\n  idle_timeout: 1s\n  auto: true\n",
    )
    .await
    .expect("gateway");
    let addr = gw.modbus.expect("server");
    let mut greedy = TcpStream::connect(addr).await.expect("connect");
    // FC03 x125 pipelined without reading an answer (each answer 259 bytes), until the
    // socket buffers are full both ways and the gateway's write waits for this master.
    let mut requests = Vec::new();
    for id in 0..1000u16 {
        let [hi, lo] = id.to_be_bytes();
        requests.extend_from_slice(&[hi, lo, 0, 0, 0, 6, 1, 3, 0, 0, 0, 125]);
    }
    let sent = async {
        loop {
            if greedy.write_all(&requests).await.is_err() {
                return;
            }
        }
    };
    // Its writes fail once the gateway has closed the connection (the answer it could not
    // hand over within the write timeout); before, the connection stayed for ever.
    tokio::time::timeout(Duration::from_secs(30), sent)
        .await
        .expect("the gateway closed the connection of a master that does not read");
    eventually("the connection gone", || async {
        gw.metrics()
            .await
            .is_ok_and(|m| m.contains("iogate_modbus_server_connections 0\n"))
    })
    .await
    .expect("no connection left");
    gw.shutdown().await;
}

#[test]
fn invalid_located_addresses_are_config_errors_with_their_reasons() {
    let config = "\
devices:
  - { name: sim, profile: SimIo }
  - { name: plant, profile: SimPlant }
modbus_server:
  listen: 127.0.0.1:0
  map:
    - { at: \"%IX0.8\", field: sim.DI_0 }
    - { at: \"%QX0.0.1\", field: sim.DO_0 }
    - { at: \"%IB1.1\", field: sim.DI_0 }
    - { at: \"%IB1\", field: sim.DI_0 }
    - { at: \"%MD0\", field: sim.DI_0 }
    - { at: \"%IW0\", field: plant.BatchName }
    - { at: \"%QX1.0\", field: sim.DI_0 }
    - { at: \"%MW1024\", field: plant.Pressure }
    - { at: \"%IW5\", field: plant.Pressure }
    - { at: \"%IW5\", field: plant.SpeedRpm }
";
    iogate::drivers::register();
    let mut parsed = iogate::config::parse("c.yaml", config);
    let problems = match &mut parsed {
        Err(p) => p.to_string(),
        Ok(c) => {
            c.profiles = Some(iogate_tests::profiles_dir());
            match iogate::app::Setup::from_config(c.clone(), std::path::Path::new(".")) {
                Err(p) => p.to_string(),
                Ok(_) => String::from("no problems"),
            }
        }
    };
    for needle in [
        "c.yaml:7: modbus_server.map[0].at: `%IX0.8`: the least significant index is greater than 7",
        "c.yaml:8: modbus_server.map[1].at: `%QX0.0.1`: three part hierarchy is not permitted",
        "c.yaml:9: modbus_server.map[2].at: `%IB1.1`: two part hierarchy is only permitted for X data size",
    ] {
        assert!(
            problems.contains(needle),
            "missing {needle:?} in\n{problems}"
        );
    }
    // The map is checked once the addresses parse.
    let config = config
        .lines()
        .filter(|l| !l.contains("%IX0.8") && !l.contains("%QX0.0.1") && !l.contains("%IB1.1"))
        .collect::<Vec<_>>()
        .join("\n");
    let mut c = iogate::config::parse("c.yaml", &config).expect("parses");
    c.profiles = Some(iogate_tests::profiles_dir());
    let problems = iogate::app::Setup::from_config(c, std::path::Path::new("."))
        .expect_err("bad map")
        .to_string();
    for needle in [
        "%IB1 has no Modbus address in the linux address space",
        "a BOOL does not fit %MD0",
        "a STRING does not fit %IW0",
        "%QX1.0 is an output location that masters write",
        "%MW1024 is past the end of the linux address space",
        "%IW5: overlaps %IW5",
    ] {
        assert!(
            problems.contains(needle),
            "missing {needle:?} in\n{problems}"
        );
    }
}

#[tokio::test]
async fn grpc_and_the_client_accept_located_addresses() {
    let gw = TestGateway::start(SIM_MAP).await.expect("gateway");
    let mut client = gw.client().await.expect("client");
    let generation = client
        .write("", "%QW2", iogate_client::Value::UInt(9))
        .await
        .expect("write by location");
    let status = client
        .wait_write(generation, Duration::from_secs(5))
        .await
        .expect("outcome");
    assert_eq!(status.field, "Recipe");
    assert_eq!(status.outcome, iogate_client::WriteOutcome::Written);
    let value = client.get("", "%QW2").await.expect("read by location");
    assert_eq!(
        (value.device.as_str(), value.field.as_str()),
        ("plant", "Recipe")
    );
    let unbound = client.get("", "%QW900").await;
    assert!(
        matches!(&unbound, Err(iogate_client::Error::Status { code, message }) if *code == tonic::Code::NotFound && message.contains("no field is bound to %QW900")),
        "{unbound:?}"
    );
    let invalid = client.get("", "%QX0.8").await;
    assert!(
        matches!(&invalid, Err(iogate_client::Error::Status { code, message }) if *code == tonic::Code::InvalidArgument && message.contains("the least significant index is greater than 7")),
        "{invalid:?}"
    );
    let at: iogate_client::Location = "%QX2.6".parse().expect("the client parses locations");
    assert_eq!(at.bit_number(), Some(22));
    gw.shutdown().await;
}

#[tokio::test]
async fn an_idle_master_is_closed_after_idle_timeout() {
    let gw = TestGateway::start("modbus_server:\n  listen: 127.0.0.1:0\n  idle_timeout: 200ms\n")
        .await
        .expect("gateway");
    let mut idle = TcpStream::connect(gw.modbus.expect("server"))
        .await
        .expect("connect");
    let started = std::time::Instant::now();
    let mut buf = [0u8; 8];
    let read = tokio::time::timeout(Duration::from_secs(5), idle.read(&mut buf))
        .await
        .expect("closed by the server, not by this test's patience");
    assert!(matches!(read, Ok(0)), "{read:?}");
    assert!(started.elapsed() >= Duration::from_millis(150));
    gw.shutdown().await;
}

#[tokio::test]
async fn a_time_that_does_not_fit_its_double_word_is_an_exception_not_a_clamped_number() {
    let gw = TestGateway::start(
        "devices:\n  - { name: plant, profile: SimPlant, refresh_rate: 20ms }\n\
         modbus_server:\n  listen: 127.0.0.1:0\n  map:\n    - { at: \"%MD3\", field: plant.MixTime }\n",
    )
    .await
    .expect("gateway");
    let mut ctx = master(gw.modbus.expect("modbus server"), 1).await;
    // T#24d20h31m23s647ms fits: 0x7FFFFFFF.
    let (status, body) = gw
        .send(
            Method::PUT,
            "/api/v1/devices/plant/fields/MixTime",
            json!({"value": 2_147_483_647i64}).to_string(),
        )
        .await
        .expect("write");
    assert_eq!(status, 202, "{body}");
    until("the largest TIME a double word holds", async || {
        matches!(ctx.read_holding_registers(2054, 2).await, Ok(Ok(v)) if v == [0x7FFF, 0xFFFF])
    })
    .await;
    // T#30d does not: exception 0B, never 2147483647.
    gw.send(
        Method::PUT,
        "/api/v1/devices/plant/fields/MixTime",
        json!({"value": "T#30d"}).to_string(),
    )
    .await
    .expect("write");
    until("T#30d refused", async || {
        matches!(
            ctx.read_holding_registers(2054, 2).await,
            Ok(Err(ExceptionCode::GatewayTargetDevice))
        )
    })
    .await;
    gw.shutdown().await;
}

#[tokio::test]
async fn masters_forwarding_to_a_slow_slave_never_get_each_others_registers() {
    // A slave answering 300 ms late (the forward's timeout is 200 ms): its late answer to one
    // master's read must never be taken as the answer to the other master's read.
    let bus = RtuBus::default();
    bus.slave(2, |s| {
        s.behaviour = iogate_tests::devices::Behaviour::Slow(Duration::from_millis(300));
        s.tables.holding[0] = 1000;
        s.tables.holding[500] = 5000;
    });
    let dir = temp_dir("mbs-slow-forward");
    let port = dir.join("ttySLOW");
    let (device_end, _holder) = pty_at(&port).expect("pty");
    let task = bus.serve(device_end);
    let gw = TestGateway::start(&format!(
        "links:\n  - {{ name: rs485, serial: {{ port: {}, baud: 115200 }} }}\nmodbus_server:\n  listen: 127.0.0.1:0\n  max_connections_per_client: 16\n  forward:\n    - {{ unit_ids: \"2\", link: rs485 }}\n",
        port.display()
    ))
    .await
    .expect("gateway");
    let addr = gw.modbus.expect("modbus server");
    let reader = |address: u16, value: u16| async move {
        let mut ctx = master(addr, 2).await;
        let mut wrong = 0;
        let mut answered = 0;
        for _ in 0..4 {
            match ctx.read_holding_registers(address, 1).await {
                Ok(Ok(v)) if v == [value] => answered += 1,
                Ok(Ok(_)) => wrong += 1,
                Ok(Err(_)) | Err(_) => {}
            }
        }
        (wrong, answered)
    };
    let (a, b) = tokio::join!(reader(0, 1000), reader(500, 5000));
    assert_eq!(
        (a.0, b.0),
        (0, 0),
        "answers taken for another read: {a:?} {b:?}"
    );
    gw.shutdown().await;
    task.abort();
}

#[tokio::test]
async fn a_flood_of_forwarded_writes_gets_busy_answers_and_never_starves_polling() {
    // A slave answering writes after 120 ms, forwarded to by 12 masters at once, on a line
    // that also polls a device every 10 ms.
    let bus = RtuBus::default();
    bus.slave(1, |_| {});
    bus.slave(2, |s| {
        s.behaviour = iogate_tests::devices::Behaviour::Slow(Duration::from_millis(120));
    });
    let dir = temp_dir("mbs-flood");
    let port = dir.join("ttyFLOOD");
    let (device_end, _holder) = pty_at(&port).expect("pty");
    let task = bus.serve(device_end);
    // Twelve masters, all from this machine's one address: its per-client bound lifted.
    let gw = TestGateway::start(&format!(
        "links:\n  - {{ name: rs485, serial: {{ port: {}, baud: 115200 }} }}\ndevices:\n  - {{ name: io, profile: MyIoModule, link: rs485, slave_id: 1, refresh_rate: 10ms }}\nmodbus_server:\n  listen: 127.0.0.1:0\n  max_connections_per_client: 16\n  forward:\n    - {{ unit_ids: \"2\", link: rs485 }}\n",
        port.display()
    ))
    .await
    .expect("gateway");
    gw.until("/api/v1/devices/io", "polled", |b| b["connected"] == true)
        .await
        .expect("polled");
    let cycles = |b: &serde_json::Value| b["io_cycles"].as_u64().unwrap_or(0);
    let before = cycles(&gw.get("/api/v1/devices/io").await.expect("io").1);
    let addr = gw.modbus.expect("modbus server");
    let masters = (0..12u16).map(|m| async move {
        let mut ctx = master(addr, 2).await;
        let mut answers = Vec::new();
        for k in 0..4u16 {
            let value = 1000 * (m + 1) + k;
            let answer =
                tokio::time::timeout(Duration::from_secs(10), ctx.write_single_register(m, value))
                    .await
                    .expect("the gateway answers");
            answers.push((value, answer.expect("io")));
        }
        answers
    });
    let answers: Vec<(u16, Result<(), ExceptionCode>)> = futures_util::future::join_all(masters)
        .await
        .into_iter()
        .flatten()
        .collect();
    let after = cycles(&gw.get("/api/v1/devices/io").await.expect("io").1);
    let executed: Vec<u16> = bus
        .seen()
        .into_iter()
        .filter(|s| s.slave == 2 && s.function == 6)
        .filter_map(|s| s.value)
        .collect();
    let busy = answers
        .iter()
        .filter(|(_, a)| *a == Err(ExceptionCode::ServerDeviceBusy))
        .count();
    assert!(busy > 0, "the inbox filled up: {answers:?}");
    for (value, answer) in &answers {
        match answer {
            Ok(()) => assert!(
                executed.contains(value),
                "{value} answered OK but not written"
            ),
            Err(_) => assert!(
                !executed.contains(value),
                "{value} answered {answer:?} but written"
            ),
        }
    }
    // At most one forwarded request between two poll cycles while polls are due.
    let polled = after - before;
    eprintln!(
        "{} writes: {} OK, {busy} busy, {} executed; {polled} poll cycles meanwhile",
        answers.len(),
        answers.iter().filter(|(_, a)| a.is_ok()).count(),
        executed.len()
    );
    assert!(
        polled as usize >= executed.len() / 2,
        "{polled} poll cycles for {} forwarded writes",
        executed.len()
    );
    let metrics = gw.metrics().await.expect("metrics");
    assert!(
        metrics.contains("iogate_link_inbox_dropped_total{link=\"rs485\",reason=\"busy\"}"),
        "{metrics}"
    );
    assert!(
        metrics.contains("iogate_link_inbox_requests{link=\"rs485\"} 0"),
        "{metrics}"
    );
    gw.shutdown().await;
    task.abort();
}

#[tokio::test]
async fn a_master_at_its_own_limit_closes_its_own_idle_connection_not_anothers() {
    let gw = TestGateway::start(
        "devices:\n  - { name: sim, profile: SimIo }\nmodbus_server:\n  listen: 127.0.0.1:0\n  max_connections: 4\n  max_connections_per_client: 2\n  auto: true\n",
    )
    .await
    .expect("gateway");
    let addr = gw.modbus.expect("server");
    let request = |id: u8| [0, id, 0, 0, 0, 6, 1, 1, 0, 0, 0, 1];
    // Another master (127.0.0.2), served once and then quiet: the longest waiting of all.
    let socket = tokio::net::TcpSocket::new_v4().expect("socket");
    socket
        .bind(([127, 0, 0, 2], 0).into())
        .expect("bind 127.0.0.2");
    let mut other = socket.connect(addr).await.expect("other");
    assert_eq!(raw(&mut other, &request(1)).await.len(), 10);
    // 127.0.0.1 holds its two: one quiet, one polling.
    let mut quiet = TcpStream::connect(addr).await.expect("quiet");
    assert_eq!(raw(&mut quiet, &request(2)).await.len(), 10);
    let mut active = TcpStream::connect(addr).await.expect("active");
    assert_eq!(raw(&mut active, &request(3)).await.len(), 10);
    // Its third closes its own quiet one, not the other master's older one.
    let mut third = TcpStream::connect(addr).await.expect("third");
    assert_eq!(raw(&mut third, &request(4)).await.len(), 10);
    assert!(
        closed(&mut quiet).await,
        "its own quiet connection is closed"
    );
    assert_eq!(
        raw(&mut other, &request(5)).await.len(),
        10,
        "the other master keeps its"
    );
    assert_eq!(raw(&mut active, &request(6)).await.len(), 10);
    let metrics = gw.metrics().await.expect("metrics");
    for line in [
        "iogate_bound_limit{bound=\"modbus_connections_per_client\"} 2\n",
        "iogate_bound_refused_total{bound=\"modbus_connections_per_client\"} 1\n",
        "iogate_bound_refused_total{bound=\"modbus_connections\"} 0\n",
    ] {
        assert!(metrics.contains(line), "{line}\n{metrics}");
    }
    gw.shutdown().await;
}

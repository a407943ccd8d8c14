//! The IEC 104 outstation against masters written here from the standard, a frame at a
//! time: the masters bounded in all and per address, a stale time-tagged command and a
//! pulse refused, an interrogation under way answered whole and a second refused, a
//! selection reserving its point from another master, a map file's problems named each on
//! its own by `check`, and a changed map file alone reloaded and served.

use iogate_tests::devices::temp_dir;
use iogate_tests::{TestGateway, eventually};

/// A master's connection from `from`, started (STARTDT confirmed), or `None` when the
/// outstation closes it at once.
async fn started_from(
    from: &str,
    to: std::net::SocketAddr,
) -> anyhow::Result<Option<tokio::net::TcpStream>> {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let socket = tokio::net::TcpSocket::new_v4()?;
    socket.bind(format!("{from}:0").parse()?)?;
    let mut io = socket.connect(to).await?;
    io.write_all(&[0x68, 4, 0x07, 0, 0, 0]).await?;
    let mut answer = [0u8; 6];
    match tokio::time::timeout(iogate_tests::PATIENCE, io.read_exact(&mut answer)).await? {
        Ok(_) => {
            assert_eq!(answer, [0x68, 4, 0x0B, 0, 0, 0], "STARTDT con");
            Ok(Some(io))
        }
        Err(_) => Ok(None),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn masters_are_bounded_in_all_and_per_address() -> anyhow::Result<()> {
    let gw = TestGateway::start(
        "devices:\n  - { name: sim, profile: SimIo, refresh_rate: 100ms }\niec104_server:\n  listen: 127.0.0.1:0\n  max_connections: 2\n  max_connections_per_client: 1\n",
    )
    .await?;
    let at = gw.iec104.expect("listening");
    let first = started_from("127.0.0.1", at).await?;
    assert!(first.is_some(), "the first master is served");
    assert!(
        started_from("127.0.0.1", at).await?.is_none(),
        "a second from one address is closed at once"
    );
    let second = started_from("127.0.0.2", at).await?;
    assert!(second.is_some(), "another address is served");
    assert!(
        started_from("127.0.0.3", at).await?.is_none(),
        "past max_connections a master is closed at once"
    );
    let metrics = gw.metrics().await?;
    for line in [
        "iogate_bound_limit{bound=\"iec104_connections\"} 2",
        "iogate_bound_used{bound=\"iec104_connections\"} 2",
        "iogate_bound_refused_total{bound=\"iec104_connections\"} 1",
        "iogate_bound_refused_total{bound=\"iec104_connections_per_client\"} 1",
        "iogate_iec104_server_masters{data_transfer=\"started\"} 2",
    ] {
        assert!(metrics.lines().any(|l| l == line), "{line} in\n{metrics}");
    }
    let (_, ready) = gw.get("/readyz").await?;
    assert_eq!(
        ready["iec104_server"],
        serde_json::json!({ "masters": 2, "started": 2 }),
        "{ready}"
    );
    // A place given back is taken again.
    drop(first);
    eventually("a place given back", || async {
        started_from("127.0.0.4", at)
            .await
            .is_ok_and(|s| s.is_some())
    })
    .await?;
    drop(second);
    gw.shutdown().await;
    Ok(())
}

/// The `n`th I-frame a master sends (N(S) `n`, nothing acknowledged), carrying `asdu`.
fn i_frame(n: usize, asdu: &[u8]) -> Vec<u8> {
    let mut frame = vec![0x68, (asdu.len() + 4) as u8];
    frame.extend_from_slice(&((n as u16) << 1).to_le_bytes());
    frame.extend_from_slice(&[0, 0]);
    frame.extend_from_slice(asdu);
    frame
}

/// The next I-frame's ASDU on `io`, S- and U-frames read past.
async fn next_asdu(io: &mut tokio::net::TcpStream) -> anyhow::Result<Vec<u8>> {
    use tokio::io::AsyncReadExt;
    loop {
        let mut head = [0u8; 2];
        tokio::time::timeout(iogate_tests::PATIENCE, io.read_exact(&mut head)).await??;
        let mut rest = vec![0u8; usize::from(head[1])];
        io.read_exact(&mut rest).await?;
        if rest[0] & 1 == 0 {
            return Ok(rest[4..].to_vec());
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stale_time_tagged_command_and_a_pulse_are_refused_and_not_written() -> anyhow::Result<()>
{
    use tokio::io::AsyncWriteExt;
    let gw = TestGateway::start(
        "devices:\n  - { name: sim, profile: SimIo, refresh_rate: 100ms }\niec104_server:\n  listen: 127.0.0.1:0\n",
    )
    .await?;
    let mut io = started_from("127.0.0.1", gw.iec104.expect("listening"))
        .await?
        .expect("served");
    // DI_0 at 1, DO_0 at 2 and its command at 3 (`map: auto`).
    let cp56_2020 = [0, 0, 0, 0, 1, 1, 20];
    let mut stale = vec![58, 1, 6, 0, 1, 0, 3, 0, 0, 0x01];
    stale.extend_from_slice(&cp56_2020);
    // C_SC_NA_1 ON as a short pulse (QU 1).
    let pulse = vec![45, 1, 6, 0, 1, 0, 3, 0, 0, 0x01 | (1 << 2)];
    for (n, asdu) in [stale, pulse].into_iter().enumerate() {
        io.write_all(&i_frame(n, &asdu)).await?;
        let answer = next_asdu(&mut io).await?;
        assert_eq!(answer[0], asdu[0], "the command mirrored: {answer:?}");
        assert_eq!(answer[2], 7 | 0x40, "a negative ACTCON: {answer:?}");
    }
    let (_, f) = gw.get("/api/v1/devices/sim/fields/DO_0").await?;
    assert_eq!(f["value"], false, "{f}");
    assert!(f["last_write"].is_null(), "nothing written: {f}");
    let metrics = gw.metrics().await?;
    let refused = "iogate_iec104_server_commands_total{outcome=\"refused\"} 2";
    assert!(metrics.lines().any(|l| l == refused), "{metrics}");
    gw.shutdown().await;
    Ok(())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_interrogation_under_way_is_answered_whole_and_a_second_of_its_kind_refused()
-> anyhow::Result<()> {
    use tokio::io::AsyncWriteExt;
    let gw = TestGateway::start(
        "devices:\n  - { name: sim, profile: SimIo, refresh_rate: 100ms }\niec104_server:\n  listen: 127.0.0.1:0\n",
    )
    .await?;
    let mut io = started_from("127.0.0.1", gw.iec104.expect("listening"))
        .await?
        .expect("served");
    let gi = [100, 1, 6, 0, 1, 0, 0, 0, 0, 20];
    let ci = [101, 1, 6, 0, 1, 0, 0, 0, 0, 5];
    // Clock synchronisation with a cause other than activation: 45.
    let cs = [103, 1, 3, 0, 1, 0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 20];
    let segment: Vec<u8> = [&gi[..], &gi, &ci, &cs]
        .into_iter()
        .enumerate()
        .flat_map(|(n, asdu)| i_frame(n, asdu))
        .collect();
    io.write_all(&segment).await?;
    let mut said = Vec::new();
    while said.len() < 7 {
        let a = next_asdu(&mut io).await?;
        said.push((a[0], a[2]));
    }
    let (neg, actcon, actterm) = (0x40, 7, 10);
    assert_eq!(
        said,
        [
            (100, actcon),
            (100, actcon | neg),
            (101, actcon),
            (103, 45 | neg),
            (1, 20),
            (100, actterm),
            (101, actterm),
        ],
        "the first interrogation whole, the second refused, the counters' after"
    );
    gw.shutdown().await;
    Ok(())
}

#[test]
fn check_names_every_problem_of_a_map_file_each_on_its_own() -> anyhow::Result<()> {
    let dir = temp_dir("iec104-map-problems");
    std::fs::create_dir_all(dir.join("profiles"))?;
    std::fs::write(
        dir.join("profiles/pump.yaml"),
        iogate_tests::iec104::PUMP_PROFILE,
    )?;
    std::fs::write(
        dir.join("points.yaml"),
        "- { ioa: 1, field: pump.temp }\n- { ioa: 2, field: pump.nothing }\n- { ioa: 1, field: pump.speed }\n- { ioa: 3, field: nobody.temp }\n",
    )?;
    std::fs::write(
        dir.join("iogate.yaml"),
        format!(
            "profiles: {}\nlinks:\n  - {{ name: line, tcp: {{ host: 127.0.0.1, port: 502 }} }}\ndevices:\n  - {{ name: pump, profile: Pump, link: line, slave_id: 1 }}\niec104_server:\n  listen: 127.0.0.1:0\n  map: {}\n",
            dir.join("profiles").display(),
            dir.join("points.yaml").display()
        ),
    )?;
    iogate::drivers::register();
    let Err(problems) = iogate::app::Setup::load(Some(&dir.join("iogate.yaml"))) else {
        anyhow::bail!("a map with three bad entries passed");
    };
    let text: Vec<String> = problems.iter().map(ToString::to_string).collect();
    assert_eq!(text.len(), 3, "{text:#?}");
    for (line, what) in [(2, "pump.nothing"), (3, "IOA 1"), (4, "nobody.temp")] {
        assert!(
            text.iter().any(|t| {
                (t.contains(&format!("line {line}:"))
                    || t.contains(&format!("points.yaml:{line}:")))
                    && t.contains(what)
            }),
            "line {line} ({what}) in {text:#?}"
        );
    }
    Ok(())
}

/// The IOAs of the objects a general interrogation on a new connection to `at` answers.
async fn interrogated(at: std::net::SocketAddr) -> anyhow::Result<Vec<u32>> {
    use tokio::io::AsyncWriteExt;
    let mut io = started_from("127.0.0.1", at)
        .await?
        .ok_or_else(|| anyhow::anyhow!("not served"))?;
    io.write_all(&i_frame(0, &[100, 1, 6, 0, 1, 0, 0, 0, 0, 20]))
        .await?;
    let mut ioas = Vec::new();
    loop {
        let asdu = next_asdu(&mut io).await?;
        if asdu[0] == 100 && asdu[2] & 0x3F == 10 {
            return Ok(ioas);
        }
        if asdu[0] != 100 {
            // One object each for these small points (SQ = 0): the IOA after the header.
            ioas.push(u32::from_le_bytes([asdu[6], asdu[7], asdu[8], 0]));
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_changed_map_file_alone_is_reloaded_and_served() -> anyhow::Result<()> {
    const SIM: &str = "name: SimOne\nprotocol: simulated\nfields:\n  - { name: X, type: INT, direction: input, register: { address: 0, kind: virtual } }\n";
    let port = std::net::TcpListener::bind("127.0.0.1:0")?
        .local_addr()?
        .port();
    let config = format!(
        "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0 }}\nprofiles: profiles\ndevices:\n  - {{ name: sim, profile: SimOne, refresh_rate: 100ms }}\niec104_server:\n  listen: 127.0.0.1:{port}\n  map: points.yaml\n"
    );
    let (dir, path) =
        iogate_tests::config_files("iec104-map-reload", &[("sim.yaml", SIM)], &config);
    std::fs::write(dir.join("points.yaml"), "- { ioa: 100, field: sim.X }\n")?;
    let gw = iogate_tests::start_file(&path).await;
    let at = std::net::SocketAddr::from(([127, 0, 0, 1], port));
    assert_eq!(interrogated(at).await?, vec![100]);
    std::fs::write(dir.join("points.yaml"), "- { ioa: 200, field: sim.X }\n")?;
    let (status, body) = gw
        .send(reqwest::Method::POST, "/api/v1/config/reload", "")
        .await?;
    assert_eq!(status, 200, "{body}");
    let changes = body["report"]["changes"].to_string();
    assert!(
        changes.contains("iec104_server") && changes.contains("map file"),
        "{body}"
    );
    eventually("the new map served", || async move {
        interrogated(at).await.is_ok_and(|ioas| ioas == [200])
    })
    .await?;
    gw.shutdown().await;
    Ok(())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_selection_reserves_its_point_from_another_master() -> anyhow::Result<()> {
    use tokio::io::AsyncWriteExt;
    let gw = TestGateway::start(
        "devices:\n  - { name: sim, profile: SimIo, refresh_rate: 100ms }\niec104_server:\n  listen: 127.0.0.1:0\n",
    )
    .await?;
    let at = gw.iec104.expect("listening");
    let mut a = started_from("127.0.0.1", at).await?.expect("served");
    let mut b = started_from("127.0.0.2", at).await?.expect("served");
    // DO_0's command at IOA 3 (`map: auto`): C_SC_NA_1 ON, selected (S/E) and executed.
    let select = [45, 1, 6, 0, 1, 0, 3, 0, 0, 0x81];
    let execute = [45, 1, 6, 0, 1, 0, 3, 0, 0, 0x01];
    let positive = 7;
    let negative = 7 | 0x40;
    a.write_all(&i_frame(0, &select)).await?;
    assert_eq!(
        next_asdu(&mut a).await?[2],
        positive,
        "A's select confirmed"
    );
    // B can neither select nor execute the point A holds.
    b.write_all(&i_frame(0, &select)).await?;
    assert_eq!(next_asdu(&mut b).await?[2], negative, "B's select refused");
    b.write_all(&i_frame(1, &execute)).await?;
    assert_eq!(next_asdu(&mut b).await?[2], negative, "B's execute refused");
    let (_, f) = gw.get("/api/v1/devices/sim/fields/DO_0").await?;
    assert_eq!(f["value"], false, "nothing written for B: {f}");
    // A's execute goes, and gives the point back.
    a.write_all(&i_frame(1, &execute)).await?;
    assert_eq!(
        next_asdu(&mut a).await?[2],
        positive,
        "A's execute confirmed"
    );
    gw.until("/api/v1/devices/sim/fields/DO_0", "written", |f| {
        f["value"] == true
    })
    .await?;
    b.write_all(&i_frame(2, &select)).await?;
    // The written value came to B spontaneously first (M_SP, cause 3).
    let answer = loop {
        let asdu = next_asdu(&mut b).await?;
        if asdu[0] == 45 {
            break asdu;
        }
    };
    assert_eq!(answer[2], positive, "free again for B");
    gw.shutdown().await;
    Ok(())
}

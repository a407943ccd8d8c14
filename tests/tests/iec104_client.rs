//! The IEC 104 driver against an independent controlled station (c104, lib60870's Python
//! binding, `tests/iec104/rtu.py`): every monitored type read through general and counter
//! interrogation with its time tag, a spontaneous change seen, an invalid value never shown
//! as good, an IOA the station does not have named, commands direct and selected before
//! executed reaching the station, and the station killed and restarted.

use iogate_tests::TestGateway;
use iogate_tests::cable::Cable;
use iogate_tests::devices::temp_dir;
use iogate_tests::eventually;
use iogate_tests::iec104::Rtu;
use serde_json::{Value, json};

async fn gateway(name: &str, rtu: &Rtu) -> anyhow::Result<TestGateway> {
    let dir = temp_dir(name);
    std::fs::create_dir_all(dir.join("profiles"))?;
    std::fs::write(
        dir.join("profiles/station.yaml"),
        iogate_tests::iec104::STATION_PROFILE,
    )?;
    let config = format!(
        "profiles: {}\nlinks:\n  - name: rtu\n    iec104: {{ host: 127.0.0.1, port: {}, t0: 2s, t1: 3s, t2: 1s, t3: 5s }}\ndevices:\n  - {{ name: station, profile: Station, link: rtu, refresh_rate: 200ms }}\n",
        dir.join("profiles").display(),
        rtu.port,
    );
    TestGateway::start(&config).await
}

fn field<'a>(device: &'a Value, name: &str) -> &'a Value {
    &device["fields"][name]
}

const INPUTS: [&str; 10] = [
    "breaker", "switch", "flow", "level", "ratio", "energy", "tap", "bits", "pressure", "current",
];

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_monitored_type_is_read_and_commands_reach_the_station() -> anyhow::Result<()> {
    let mut rtu = Rtu::start().await?;
    let gw = gateway("iec104-values", &rtu).await?;
    let d = gw
        .until("/api/v1/devices/station", "interrogated", |d| {
            INPUTS.iter().all(|f| field(d, f)["quality"] == "good")
                && field(d, "missing")["quality"] == "bad"
        })
        .await?;
    let v = |n: &str| field(&d, n)["value"].clone();
    assert_eq!(v("breaker"), json!(true));
    assert_eq!(v("switch"), json!(true), "a double point ON");
    assert_eq!(v("flow"), json!(12.5));
    assert_eq!(v("level"), json!(-7));
    assert_eq!(v("ratio"), json!(0.5), "normalized 0.5");
    assert_eq!(v("energy"), json!(42), "by counter interrogation");
    assert_eq!(v("tap"), json!(3));
    assert_eq!(v("bits"), json!(0xA5));
    assert_eq!(v("pressure"), json!(1.25));
    assert_eq!(
        v("current"),
        json!(12.3),
        "a scaled value 123 at a scale of 0.1"
    );
    let missing = field(&d, "missing")["error"]
        .as_str()
        .unwrap_or_default()
        .to_owned();
    assert!(missing.contains("IOA 999"), "{missing}");

    // A spontaneous change is seen; an invalid value is not shown as good.
    rtu.cmd("set 102 20.25").await?;
    gw.until("/api/v1/devices/station", "the change", |d| {
        field(d, "flow")["value"] == json!(20.25) && field(d, "flow")["quality"] == "good"
    })
    .await?;
    rtu.cmd("invalid 102").await?;
    let d = gw
        .until("/api/v1/devices/station", "invalid", |d| {
            field(d, "flow")["quality"] == "bad"
        })
        .await?;
    let why = field(&d, "flow")["error"]
        .as_str()
        .unwrap_or_default()
        .to_owned();
    assert!(why.contains("invalid (IV)"), "{why}");

    // Commands: direct, and selected before executed.
    for (name, value, said) in [
        ("enable", json!(true), "cmd 201 True"),
        ("limit", json!(-12), "cmd 202 -12"),
        ("setpoint", json!(2.5), "cmd 200 2.5"),
        // 5.55 at a scale of 0.1: C_SE_NB_1 (its raw INT) of 56.
        ("trip", json!(5.55), "cmd 204 56"),
    ] {
        let outcome = gw
            .write_outcome("station", name, value)
            .await?
            .map_err(|e| anyhow::anyhow!("{name}: {e}"))?;
        assert_eq!(outcome["status"], "written", "{name}: {outcome}");
        // The station's point 200 takes only a selected command (c104 answers an execute
        // without a select negatively), and tells its execute.
        assert_eq!(rtu.said().await?, said);
    }
    // A command confirmed 2.5 s late (within t1, 3 s): written, and the inputs the
    // connection vouches for are good again after it, not left stale.
    let outcome = gw.write_outcome("station", "slow", json!(true)).await?;
    assert!(
        outcome.as_ref().is_ok_and(|o| o["status"] == "written"),
        "{outcome:?}"
    );
    assert_eq!(rtu.said().await?, "cmd 205 True");
    gw.until(
        "/api/v1/devices/station",
        "good after a slow command",
        |d| field(d, "breaker")["quality"] == "good",
    )
    .await?;
    // The written value is shown as the station holds it (5.6), not as asked (5.55).
    let d = gw.get("/api/v1/devices/station").await?.1;
    assert_eq!(field(&d, "trip")["value"], json!(5.6), "{d}");
    // A command the station confirms and does not terminate (c104 terminates only its
    // selected ones), where the field waits for the termination: not `written`.
    let outcome = gw
        .write_outcome("station", "enable_terminated", json!(false))
        .await?;
    assert!(
        outcome.as_ref().is_ok_and(|o| o["status"] != "written"),
        "{outcome:?}"
    );
    assert_eq!(rtu.said().await?, "cmd 203 False");
    // A value the command cannot carry is refused before anything is sent.
    let refused = gw.write_outcome("station", "limit", json!(40000)).await?;
    assert!(
        refused.is_err() || refused.as_ref().is_ok_and(|o| o["status"] != "written"),
        "{refused:?}"
    );

    let (_, link) = gw.get("/api/v1/links/rtu").await?;
    assert_eq!(link["peer"]["windows"], "k 12, w 8", "{link}");
    assert_eq!(
        link["peer"]["data_transfer"], "started (STARTDT confirmed)",
        "{link}"
    );
    assert!(
        link["peer"]["i_frames"]
            .as_str()
            .is_some_and(|f| f.contains("0 malformed")),
        "{link}"
    );

    // The station killed: the link goes down; started again, it is interrogated again.
    let port = rtu.port;
    rtu.kill().await?;
    gw.until("/api/v1/links/rtu", "down", |l| l["connected"] == false)
        .await?;
    let _again = Rtu::start_on(Some(port)).await?;
    gw.until("/api/v1/devices/station", "read again", |d| {
        field(d, "flow")["value"] == json!(12.5) && field(d, "flow")["quality"] == "good"
    })
    .await?;
    gw.shutdown().await;
    Ok(())
}

/// The station's next line that starts with `word`, the others passed over.
async fn next_said(rtu: &mut Rtu, word: &str) -> anyhow::Result<String> {
    loop {
        let line = rtu.said().await?;
        if line.starts_with(word) {
            return Ok(line);
        }
    }
}

/// Whether what the gateway sent on a connection holds a STARTDT act.
fn started(sent: &[u8]) -> bool {
    sent.windows(6).any(|w| w == [0x68, 4, 0x07, 0, 0, 0])
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_redundancy_group_holds_its_standby_stopped_and_starts_it_when_the_other_is_lost()
-> anyhow::Result<()> {
    let mut rtu = Rtu::start().await?;
    // Two addresses of the one station: a cable to it each, either of which can be pulled.
    let primary = Cable::to(rtu.port).await?;
    let backup = Cable::to(rtu.port).await?;
    let dir = temp_dir("iec104-redundancy");
    std::fs::create_dir_all(dir.join("profiles"))?;
    std::fs::write(
        dir.join("profiles/station.yaml"),
        iogate_tests::iec104::STATION_PROFILE,
    )?;
    let config = format!(
        "profiles: {}\nlinks:\n  - name: rtu\n    iec104: {{ host: 127.0.0.1, port: {}, backup: '127.0.0.1:{}', clock_sync: true, t0: 2s, t1: 3s, t2: 1s, t3: 2s }}\ndevices:\n  - {{ name: station, profile: Station, link: rtu, refresh_rate: 200ms }}\n",
        dir.join("profiles").display(),
        primary.port,
        backup.port,
    );
    let gw = TestGateway::start(&config).await?;
    gw.until("/api/v1/devices/station", "interrogated", |d| {
        field(d, "flow")["quality"] == "good"
    })
    .await?;
    // The station's clock was set to the gateway's at connect.
    let clock = next_said(&mut rtu, "clock").await?;
    let set: f64 = clock.trim_start_matches("clock").trim().parse()?;
    let now = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH)?;
    assert!((now.as_secs_f64() - set).abs() < 30.0, "{clock} at {now:?}");
    let (_, link) = gw.get("/api/v1/links/rtu").await?;
    assert!(
        link["peer"]["clock"]
            .as_str()
            .is_some_and(|c| c.ends_with("confirmed")),
        "{link}"
    );

    // The backup is held open, data transfer stopped, and tested (t3 2 s).
    let link = gw
        .until("/api/v1/links/rtu", "the standby held", |l| {
            l["peer"]["standby"]
                .as_str()
                .is_some_and(|s| s.contains("data transfer stopped"))
        })
        .await?;
    assert_eq!((primary.open(), backup.open()), (1, 1), "{link}");
    // Tested on its quiet connection after t3: TESTFR act at open and again.
    let testfr = [0x68u8, 4, 0x43, 0, 0, 0];
    eventually("the standby tested after t3", || async {
        backup.sent()[0].windows(6).filter(|w| *w == testfr).count() >= 2
    })
    .await?;
    assert!(started(&primary.sent()[0]));
    let standby = backup.sent()[0].clone();
    assert!(!started(&standby), "STARTDT on the standby: {standby:02x?}");

    // The started connection lost: the standby is started and read, a change comes on it,
    // and a command goes on it.
    primary.pull();
    gw.until("/api/v1/links/rtu", "the standby took over", |l| {
        l["connected"] == true
            && l["peer"]["station"]
                .as_str()
                .is_some_and(|s| s.contains(&format!(":{} (took over", backup.port)))
    })
    .await?;
    assert!(started(&backup.sent()[0]), "STARTDT on the standby now");
    assert_eq!(
        backup.accepted(),
        1,
        "the standby's own connection, no other"
    );
    rtu.cmd("set 102 30.5").await?;
    gw.until("/api/v1/devices/station", "a change on the standby", |d| {
        field(d, "flow")["value"] == json!(30.5) && field(d, "flow")["quality"] == "good"
    })
    .await?;
    let outcome = gw
        .write_outcome("station", "enable", json!(true))
        .await?
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    assert_eq!(outcome["status"], "written", "{outcome}");
    assert_eq!(next_said(&mut rtu, "cmd").await?, "cmd 201 True");

    // The lost address back: it is held as the standby again, stopped.
    primary.plug();
    gw.until("/api/v1/links/rtu", "the other held again", |l| {
        l["peer"]["standby"]
            .as_str()
            .is_some_and(|s| s.contains(&format!(":{} (connected", primary.port)))
    })
    .await?;
    let again = primary.sent();
    let last = again.last().cloned().unwrap_or_default();
    assert!(!started(&last), "STARTDT on the new standby: {last:02x?}");
    assert_eq!(primary.open(), 1);
    gw.shutdown().await;
    Ok(())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_standby_address_that_accepts_and_then_fails_is_tried_less_and_less_often()
-> anyhow::Result<()> {
    let rtu = Rtu::start().await?;
    // The backup takes the connection and closes it at the gateway's first frame.
    let backup = Cable::failing_after(rtu.port, Some(0)).await?;
    let dir = temp_dir("iec104-standby-fails");
    std::fs::create_dir_all(dir.join("profiles"))?;
    std::fs::write(
        dir.join("profiles/station.yaml"),
        iogate_tests::iec104::STATION_PROFILE,
    )?;
    let config = format!(
        "profiles: {}\nlinks:\n  - name: rtu\n    iec104: {{ host: 127.0.0.1, port: {}, backup: '127.0.0.1:{}', t0: 2s, t1: 3s, t2: 1s, t3: 5s }}\ndevices:\n  - {{ name: station, profile: Station, link: rtu, refresh_rate: 200ms }}\n",
        dir.join("profiles").display(),
        rtu.port,
        backup.port,
    );
    let gw = TestGateway::start(&config).await?;
    let began = std::time::Instant::now();
    let link = gw
        .until("/api/v1/links/rtu", "three attempts", |l| {
            l["peer"]["standby"]
                .as_str()
                .is_some_and(|s| s.contains("attempt 4 in 4s"))
        })
        .await?;
    // Attempts after 1 s and 2 s: three connections in three seconds at least.
    assert!(
        began.elapsed() >= std::time::Duration::from_secs(3),
        "{link}"
    );
    assert!(
        backup.accepted() <= 3,
        "{} connections: {link}",
        backup.accepted()
    );
    assert!(
        link["peer"]["standby"]
            .as_str()
            .is_some_and(|s| s.contains("closed")),
        "{link}"
    );
    // The started connection is not disturbed by its standby's failures.
    let d = gw.get("/api/v1/devices/station").await?.1;
    assert_eq!(field(&d, "flow")["quality"], "good", "{d}");
    gw.shutdown().await;
    Ok(())
}

/// A station that keeps one connection at a time, the newest: a proxy to `upstream` that
/// closes the connection it holds when another comes. Counts the connections it took.
async fn evicting(
    upstream: u16,
) -> anyhow::Result<(
    u16,
    std::sync::Arc<std::sync::atomic::AtomicUsize>,
    tokio::task::JoinHandle<()>,
)> {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
    let port = listener.local_addr()?.port();
    let taken = std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let count = taken.clone();
    let task = tokio::spawn(async move {
        let mut held: Option<tokio::task::JoinHandle<()>> = None;
        while let Ok((mut client, _)) = listener.accept().await {
            count.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
            if let Some(old) = held.take() {
                old.abort();
            }
            held = Some(tokio::spawn(async move {
                if let Ok(mut up) = tokio::net::TcpStream::connect(("127.0.0.1", upstream)).await {
                    let _ = tokio::io::copy_bidirectional(&mut client, &mut up).await;
                }
            }));
        }
    });
    Ok((port, taken, task))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_station_that_keeps_one_connection_gets_no_standby_and_is_read_on() -> anyhow::Result<()>
{
    let mut rtu = Rtu::start().await?;
    let (port, taken, proxy) = evicting(rtu.port).await?;
    let dir = temp_dir("iec104-one-connection");
    std::fs::create_dir_all(dir.join("profiles"))?;
    std::fs::write(
        dir.join("profiles/station.yaml"),
        iogate_tests::iec104::STATION_PROFILE,
    )?;
    // Its two addresses reach the one slot.
    let config = format!(
        "profiles: {}\nlinks:\n  - name: rtu\n    iec104: {{ host: 127.0.0.1, port: {port}, backup: 'localhost:{port}', t0: 2s, t1: 3s, t2: 1s, t3: 5s }}\ndevices:\n  - {{ name: station, profile: Station, link: rtu, refresh_rate: 200ms }}\n",
        dir.join("profiles").display(),
    );
    let gw = TestGateway::start(&config).await?;
    gw.until("/api/v1/links/rtu", "the standby given up", |l| {
        l["peer"]["standby"]
            .as_str()
            .is_some_and(|s| s.contains("keeps one connection at a time"))
    })
    .await?;
    rtu.cmd("set 102 40.5").await?;
    gw.until("/api/v1/devices/station", "read on", |d| {
        field(d, "flow")["value"] == json!(40.5) && field(d, "flow")["quality"] == "good"
    })
    .await?;
    let (_, link) = gw.get("/api/v1/links/rtu").await?;
    assert_eq!(link["connected"], true, "{link}");
    // The started connection and the standby that took its place: no other.
    assert_eq!(taken.load(std::sync::atomic::Ordering::SeqCst), 2, "{link}");
    gw.shutdown().await;
    proxy.abort();
    Ok(())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_started_connection_lost_while_a_command_is_confirmed_is_taken_over_at_once()
-> anyhow::Result<()> {
    let mut rtu = Rtu::start().await?;
    let primary = Cable::to(rtu.port).await?;
    let backup = Cable::to(rtu.port).await?;
    let dir = temp_dir("iec104-lost-while-asked");
    std::fs::create_dir_all(dir.join("profiles"))?;
    std::fs::write(
        dir.join("profiles/station.yaml"),
        iogate_tests::iec104::STATION_PROFILE,
    )?;
    // t1 of 12 s: a loss seen only at t1's end would take that long.
    let config = format!(
        "profiles: {}\nlinks:\n  - name: rtu\n    iec104: {{ host: 127.0.0.1, port: {}, backup: '127.0.0.1:{}', t0: 2s, t1: 12s, t2: 1s, t3: 20s }}\ndevices:\n  - {{ name: station, profile: Station, link: rtu, refresh_rate: 200ms }}\n",
        dir.join("profiles").display(),
        primary.port,
        backup.port,
    );
    let gw = TestGateway::start(&config).await?;
    gw.until("/api/v1/links/rtu", "the standby held", |l| {
        l["peer"]["standby"]
            .as_str()
            .is_some_and(|s| s.contains("data transfer stopped"))
    })
    .await?;
    let (status, w) = gw
        .send(
            reqwest::Method::PUT,
            "/api/v1/devices/station/fields/slow",
            json!({ "value": true }).to_string(),
        )
        .await?;
    assert!((200..300).contains(&status), "{w}");
    assert_eq!(next_said(&mut rtu, "cmd").await?, "cmd 205 True");
    // The station executes; its confirmation is 2.5 s away when its cable is pulled.
    let pulled = std::time::Instant::now();
    primary.pull();
    gw.until("/api/v1/links/rtu", "taken over", |l| {
        l["peer"]["station"]
            .as_str()
            .is_some_and(|s| s.contains("took over"))
    })
    .await?;
    let took = pulled.elapsed();
    assert!(
        took < std::time::Duration::from_secs(6),
        "taken over after {took:?}"
    );
    // The command's outcome is unknown (a timeout), never written twice.
    let generation = w["generation"].as_u64().unwrap_or_default();
    let outcome = gw
        .until(&format!("/api/v1/writes/{generation}"), "an outcome", |w| {
            w["status"] != "pending"
        })
        .await?;
    assert_ne!(outcome["status"], "written", "{outcome}");
    // What the station holds now is not known: the field says so, never good.
    let (_, f) = gw.get("/api/v1/devices/station/fields/slow").await?;
    assert_ne!(f["quality"], "good", "{f}");
    assert!(
        f["error"]
            .as_str()
            .is_some_and(|e| e.contains("was not answered")),
        "{f}"
    );
    gw.shutdown().await;
    while let Some(line) = rtu.said_within(std::time::Duration::from_millis(500)).await {
        assert_ne!(line, "cmd 205 True", "executed again");
    }
    Ok(())
}

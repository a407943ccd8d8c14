//! Scanning a line of independent slaves (pymodbus, on ptys joined by `iogate_tests::line`):
//! each found at its id and baud rate, identification read, a shared id reported as a
//! collision, the right profile suggested.

use std::sync::Arc;
use std::time::Duration;

use iogate::scan::{self, Found, Plan, Progress};
use iogate_tests::devices::temp_dir;
use iogate_tests::{repo_file, run_installer};
use serde_json::json;
use tokio_util::sync::CancellationToken;

/// Starts a pymodbus slave on `path` at `baud` serving `spec`; waits until it serves.
async fn slave(path: &std::path::Path, baud: u32, spec: serde_json::Value) -> iogate_tests::Piped {
    let mut command = tokio::process::Command::new(iogate_tests::python());
    command
        .arg(repo_file("serial/scan_slave.py"))
        .arg(path)
        .arg(baud.to_string())
        .arg(spec.to_string());
    let mut piped = iogate_tests::spawn_piped(command).expect("slave");
    let first = tokio::time::timeout(Duration::from_secs(20), piped.lines.next_line())
        .await
        .expect("slave in time")
        .expect("slave output");
    assert_eq!(first.as_deref(), Some("serving"));
    piped
}

fn profiles(dir: &std::path::Path) -> Vec<Arc<iogate::profile::Profile>> {
    let profiles = dir.join("profiles");
    std::fs::create_dir_all(&profiles).expect("dir");
    for entry in std::fs::read_dir(iogate_tests::profiles_dir()).expect("profiles") {
        let path = entry.expect("entry").path();
        std::fs::copy(&path, profiles.join(path.file_name().expect("name"))).expect("copy");
    }
    std::fs::write(
        profiles.join("acme_x1.yaml"),
        "name: AcmeX1\nvendor: ACME\ndescription: \"a device that says who it is\"\n\
         identification: { vendor: ACME, product_code: X1 }\nfields:\n  \
         - { name: Level, type: UINT, direction: input, register: { address: 0, kind: holding_register } }\n",
    )
    .expect("profile");
    iogate::profile::load_dir(&profiles)
        .expect("profiles load")
        .into_iter()
        .map(Arc::new)
        .collect()
}

async fn scan(
    port: &std::path::Path,
    bauds: &[u32],
    ids: &str,
    profiles: &[Arc<iogate::profile::Profile>],
) -> (Vec<Found>, Vec<String>) {
    let plan = Plan {
        settings: scan::settings(bauds, &[iogate::config::Parity::None]),
        ids: scan::parse_ids(ids).expect("ids"),
        timeout: Duration::from_millis(60),
    };
    plan.check().expect("plan");
    let mut prober = scan::port::PortProber::new(&port.display().to_string(), plan.timeout);
    let mut told = Vec::new();
    let mut progress = |p: Progress| match p {
        Progress::Setting { setting, .. } => told.push(format!("setting {}", setting.label())),
        Progress::Found(d) => told.push(format!("found {}", d.slave_id)),
        Progress::Tried { .. } => {}
    };
    let found = scan::run(
        &mut prober,
        &plan,
        profiles,
        &mut progress,
        &CancellationToken::new(),
    )
    .await
    .expect("scan");
    (found.devices, told)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_scan_finds_each_slave_its_identification_a_shared_id_and_the_right_profile() {
    run_installer("serial/install.sh").expect("serial peers");
    let dir = temp_dir("scan-line");
    let port = dir.join("ttyLINE");
    let line = iogate_tests::line::line(
        &dir,
        &port,
        &[(3, 9600), (7, 9600), (9, 9600), (9, 9600), (12, 19200)],
    )
    .expect("line");
    let _s3 = slave(
        &line.slaves[0].path,
        9600,
        json!({
            "unit": 3, "holding": {"0": [42]},
            "identity": {"VendorName": "ACME", "ProductCode": "X1", "MajorMinorRevision": "2.1"}
        }),
    )
    .await;
    // The Waveshare 8-channel analog input's published map: input registers 0-7 the
    // channels, holding 0x1000-0x1007 their ranges.
    let _s7 = slave(
        &line.slaves[1].path,
        9600,
        json!({
            "unit": 7, "input": {"0": [100, 200, 300, 400, 500, 600, 700, 800]},
            "holding": {"4096": [0, 0, 0, 0, 0, 0, 0, 0]}
        }),
    )
    .await;
    let _s9a = slave(
        &line.slaves[2].path,
        9600,
        json!({"unit": 9, "holding": {"0": [1]}}),
    )
    .await;
    let _s9b = slave(
        &line.slaves[3].path,
        9600,
        json!({"unit": 9, "holding": {"0": [2]}}),
    )
    .await;
    let _s12 = slave(
        &line.slaves[4].path,
        19200,
        json!({"unit": 12, "holding": {"0": [5]}}),
    )
    .await;
    let profiles = profiles(&dir);

    let started = std::time::Instant::now();
    let (found, told) = scan(&port, &[9600], "1-15", &profiles).await;
    let took = started.elapsed();
    let ids: Vec<u8> = found.iter().map(|d| d.slave_id).collect();
    assert_eq!(ids, vec![3, 7, 9], "{found:#?}");
    assert_eq!(
        told.first().map(String::as_str),
        Some("setting 9600 8N1"),
        "{told:?}"
    );

    let acme = &found[0];
    let id = acme.identification.as_ref().expect("identification");
    assert_eq!(id.vendor.as_deref(), Some("ACME"));
    assert_eq!(id.product_code.as_deref(), Some("X1"));
    assert_eq!(id.revision.as_deref(), Some("2.1"));
    assert_eq!(acme.profiles[0].profile, "AcmeX1", "{:#?}", acme.profiles);
    assert!(acme.profiles[0].identified);
    assert!(acme.collision.is_none());
    assert_eq!(acme.reads[0].values, vec![42]);

    let waveshare = &found[1];
    assert_eq!(
        waveshare.profiles[0].profile, "WaveshareAnalogInput",
        "{:#?}",
        waveshare.profiles
    );
    assert!(waveshare.identification.is_none());
    assert!(
        waveshare.profiles.iter().all(|s| s.profile != "AcmeX1"),
        "a profile that states an identification fits only a device that says it"
    );

    let shared = &found[2];
    assert!(
        shared
            .collision
            .as_deref()
            .is_some_and(|c| c.contains("two answers")),
        "{shared:#?}"
    );
    let config = scan::report::config(&found, Some("/dev/ttyUSB0"), "line");
    assert!(
        config.contains("profile: AcmeX1, link: line, slave_id: 3"),
        "{config}"
    );
    assert!(
        config.contains("# slave 9 on line: two answers"),
        "{config}"
    );

    // One slot per id: 15 ids at 60 ms, plus the follow-up probes of three devices.
    assert!(took < Duration::from_secs(10), "{took:?}");

    // A second run at both rates finds the 19200 baud slave too, at its rate.
    let (found, _) = scan(&port, &[19200, 9600], "10-13", &profiles).await;
    let at: Vec<(u8, u32)> = found.iter().map(|d| (d.slave_id, d.setting.baud)).collect();
    assert_eq!(at, vec![(12, 19200)], "{found:#?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_scan_of_a_configured_link_runs_between_polls_and_reports_over_rest() {
    run_installer("serial/install.sh").expect("serial peers");
    let dir = temp_dir("scan-rest");
    let port = dir.join("ttyLINE");
    let line = iogate_tests::line::line(&dir, &port, &[(3, 9600), (7, 9600)]).expect("line");
    let _s3 = slave(
        &line.slaves[0].path,
        9600,
        json!({"unit": 3, "holding": {"0": [42, 43]},
               "identity": {"VendorName": "ACME", "ProductCode": "X1", "MajorMinorRevision": "2.1"}}),
    )
    .await;
    let _s7 = slave(
        &line.slaves[1].path,
        9600,
        json!({"unit": 7, "input": {"0": [1, 2, 3, 4, 5, 6, 7, 8]}, "holding": {"4096": [0, 0, 0, 0, 0, 0, 0, 0]}}),
    )
    .await;
    profiles(&dir);
    std::fs::write(
        dir.join("profiles/acme_pair.yaml"),
        "name: AcmePair\nfields:\n  \
         - { name: A, type: UINT, direction: input, register: { address: 0, kind: holding_register } }\n  \
         - { name: B, type: UINT, direction: input, register: { address: 1, kind: holding_register } }\n",
    )
    .expect("profile");
    let gw = iogate_tests::TestGateway::start(&format!(
        "profiles: {}\nlinks:\n  - {{ name: line, serial: {{ port: {}, baud: 9600 }} }}\n\
         devices:\n  - {{ name: acme, profile: AcmePair, link: line, slave_id: 3, refresh_rate: 10ms, timeout: 100ms }}\n",
        dir.join("profiles").display(),
        port.display()
    ))
    .await
    .expect("gateway");
    gw.until("/api/v1/devices/acme", "polled", |b| b["connected"] == true)
        .await
        .expect("polled");

    let (status, bad) = gw
        .send(
            reqwest::Method::POST,
            "/api/v1/links/line/scan",
            r#"{"ids": "0-3"}"#,
        )
        .await
        .expect("post");
    assert_eq!(status, 400, "{bad}");
    let (status, missing) = gw
        .send(reqwest::Method::POST, "/api/v1/links/nowhere/scan", "")
        .await
        .expect("post");
    assert_eq!(status, 404, "{missing}");

    let (status, started) = gw
        .send(
            reqwest::Method::POST,
            "/api/v1/links/line/scan",
            r#"{"ids": "1-10", "timeout": "60ms"}"#,
        )
        .await
        .expect("post");
    assert_eq!(status, 202, "{started}");
    assert_eq!(started["state"], "running");
    assert_eq!(
        started["estimate_ms"], 600,
        "said before it starts: {started}"
    );
    let id = started["id"].as_u64().expect("id");
    let (status, twice) = gw
        .send(reqwest::Method::POST, "/api/v1/links/line/scan", "")
        .await
        .expect("post");
    assert_eq!(status, 409, "one scan a link at a time: {twice}");
    let metrics = gw.metrics().await.expect("metrics");
    for series in [
        "iogate_bound_used{bound=\"scans\"} 1\n",
        "iogate_bound_refused_total{bound=\"scans\"} 1\n",
    ] {
        assert!(metrics.contains(series), "{series}\n{metrics}");
    }
    line.sent.lock().expect("sent").clear();

    // Its events: the state as it goes, the stream ending with the last one.
    let events = gw
        .client
        .get(gw.url(&format!("/api/v1/scans/{id}/events")))
        .send()
        .await
        .expect("events")
        .text()
        .await
        .expect("the stream ends with the scan");
    let states: Vec<serde_json::Value> = events
        .split("\n\n")
        .filter(|e| e.starts_with("event: scan\n"))
        .filter_map(|e| e.lines().find_map(|l| l.strip_prefix("data: ")))
        .map(|d| serde_json::from_str(d).expect("a state"))
        .collect();
    let last = states.last().expect("at least one state");
    assert_eq!(last["state"], "done", "{events}");
    assert_eq!(last["probed"], 10, "{events}");
    assert!(
        states.iter().any(|s| s["state"] == "running"),
        "progress before the end: {events}"
    );

    let done = gw
        .until(&format!("/api/v1/scans/{id}"), "done", |b| {
            b["state"] != "running"
        })
        .await
        .expect("scan");
    assert_eq!(done["state"], "done", "{done:#}");
    let ids: Vec<u64> = done["devices"]
        .as_array()
        .expect("devices")
        .iter()
        .filter_map(|d| d["slave_id"].as_u64())
        .collect();
    assert_eq!(ids, vec![3, 7], "{done:#}");
    assert_eq!(done["devices"][0]["identification"]["vendor"], "ACME");
    assert_eq!(
        done["devices"][1]["profiles"][0]["profile"],
        "WaveshareAnalogInput"
    );
    // Two profiles fit slave 7: the one with more probe reads answered is offered, the
    // other named with what it answered.
    assert!(
        done["config"].as_str().is_some_and(|c| {
            c.contains("profile: WaveshareAnalogInput, link: line, slave_id: 7")
                && c.contains("also fits: EastronSDM630 (1 probe read(s) answered)")
        }),
        "{done:#}"
    );
    assert_eq!(done["probed"], 10);

    // Polling went on: a due poll waits for one probe at most (a 60 ms slot), never for
    // the scan (600 ms and more).
    let poll = [3u8, 3, 0, 0, 0, 2];
    let sent = line.sent.lock().expect("sent").clone();
    let polls: Vec<std::time::Instant> = sent
        .iter()
        .filter(|(_, f)| f.starts_with(&poll))
        .map(|(at, _)| *at)
        .collect();
    let probes = sent.len() - polls.len();
    assert!(
        polls.len() >= 10 && probes >= 10,
        "{} polls, {probes} probes",
        polls.len()
    );
    let widest = polls.windows(2).map(|w| w[1] - w[0]).max().expect("gaps");
    assert!(
        widest < Duration::from_millis(250),
        "a poll waited {widest:?}: {sent:02x?}"
    );
    let (_, acme) = gw.get("/api/v1/devices/acme").await.expect("device");
    assert_eq!(acme["connected"], true, "{acme}");
    gw.shutdown().await;
}

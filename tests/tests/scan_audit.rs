//! What a scan says of devices that do not tell who they are: one that answers every
//! address (pymodbus with a full memory) is offered no profile on the strength of its
//! registers alone, and one that answers with bad CRCs (a misbehaving device of our own) is
//! one device with a damaged line, never two devices on one id.

use std::sync::Arc;
use std::time::Duration;

use iogate::scan::{self, Found, Plan};
use iogate_tests::devices::{Behaviour, RtuBus, pty_at, temp_dir};
use iogate_tests::{repo_file, run_installer};
use serde_json::json;
use tokio_util::sync::CancellationToken;

fn profiles() -> Vec<Arc<iogate::profile::Profile>> {
    iogate::drivers::register();
    iogate::profile::load_dir(&iogate_tests::profiles_dir())
        .expect("profiles load")
        .into_iter()
        .map(Arc::new)
        .collect()
}

async fn scan(port: &std::path::Path, ids: &str) -> Vec<Found> {
    scanned(port, ids).await.devices
}

async fn scanned(port: &std::path::Path, ids: &str) -> scan::Scanned {
    let plan = Plan {
        settings: scan::settings(&[9600], &[iogate::config::Parity::None]),
        ids: scan::parse_ids(ids).expect("ids"),
        timeout: Duration::from_millis(60),
    };
    plan.check().expect("plan");
    let mut prober = scan::port::PortProber::new(&port.display().to_string(), plan.timeout);
    scan::run(
        &mut prober,
        &plan,
        &profiles(),
        &mut |_| {},
        &CancellationToken::new(),
    )
    .await
    .expect("scan")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_device_that_answers_every_address_is_offered_no_profile_by_its_registers() {
    run_installer("serial/install.sh").expect("serial peers");
    let dir = temp_dir("scan-everywhere");
    let port = dir.join("ttyLINE");
    let line = iogate_tests::line::line(&dir, &port, &[(4, 9600)]).expect("line");
    let mut command = tokio::process::Command::new(iogate_tests::python());
    command
        .arg(repo_file("serial/scan_slave.py"))
        .arg(&line.slaves[0].path)
        .arg("9600")
        .arg(json!({"unit": 4, "everywhere": true}).to_string());
    let mut slave = iogate_tests::spawn_piped(command).expect("slave");
    let first = tokio::time::timeout(Duration::from_secs(30), slave.lines.next_line())
        .await
        .expect("slave in time")
        .expect("slave output");
    assert_eq!(first.as_deref(), Some("serving"));
    // Its full memory takes pymodbus a while to set up after it says it serves: scan until
    // it answers (a bounded wait for the condition, not for a time).
    let deadline = tokio::time::Instant::now() + Duration::from_secs(60);
    let found = loop {
        let found = scan(&port, "4").await;
        if !found.is_empty() || tokio::time::Instant::now() > deadline {
            break found;
        }
    };
    assert_eq!(found.len(), 1, "{found:#?}");
    let device = &found[0];
    assert!(
        device.profiles.iter().all(|s| !s.telling),
        "registers alone tell nothing: {:#?}",
        device.profiles
    );
    let config = scan::report::config(&found, None, "line");
    assert!(!config.contains("profile: Waveshare"), "{config}");
    assert!(
        config.contains("nothing tells which device it is"),
        "{config}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_device_answering_with_bad_crcs_is_one_damaged_device_not_a_collision() {
    let bus = RtuBus::default();
    bus.slave(6, |s| {
        s.tables.holding[0] = 1;
        s.behaviour = Behaviour::BadCrc;
    });
    let dir = temp_dir("scan-bad-crc");
    let port = dir.join("ttyBUS");
    let (device_end, _holder) = pty_at(&port).expect("pty");
    let serving = bus.serve(device_end);
    let found = scan(&port, "5-7").await;
    assert_eq!(found.len(), 1, "{found:#?}");
    let device = &found[0];
    assert_eq!(device.slave_id, 6);
    assert!(device.collision.is_none(), "{device:#?}");
    assert!(
        device
            .garbled
            .as_deref()
            .is_some_and(|g| g.contains("CRC is wrong") && g.contains("not two devices")),
        "{device:#?}"
    );
    let config = scan::report::config(&found, None, "line");
    assert!(
        config.contains("its answers cannot be read") && !config.contains("another id"),
        "{config}"
    );
    serving.abort();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_device_answering_as_another_id_is_said_so() {
    let bus = RtuBus::default();
    bus.slave(6, |s| {
        s.tables.holding[0] = 1;
        s.behaviour = Behaviour::AnswersAs(9);
    });
    let dir = temp_dir("scan-answers-as");
    let port = dir.join("ttyBUS");
    let (device_end, _holder) = pty_at(&port).expect("pty");
    let serving = bus.serve(device_end);
    let found = scanned(&port, "5-7").await;
    assert!(found.devices.is_empty(), "{found:#?}");
    assert_eq!(found.strangers.len(), 1, "{found:#?}");
    assert_eq!(
        (
            found.strangers[0].answered_as,
            found.strangers[0].asked.as_str()
        ),
        (9, "6")
    );
    let line = scan::report::stranger_line(&found.strangers[0]);
    assert!(line.contains("answered as slave 9"), "{line}");
    serving.abort();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_device_garbling_every_second_answer_is_listed_with_a_warning() {
    let bus = RtuBus::default();
    bus.slave(6, |s| {
        s.tables.holding[0] = 1;
        s.behaviour = Behaviour::EverySecondGarbled;
    });
    let dir = temp_dir("scan-flaky");
    let port = dir.join("ttyBUS");
    let (device_end, _holder) = pty_at(&port).expect("pty");
    let serving = bus.serve(device_end);
    let found = scan(&port, "6").await;
    assert_eq!(found.len(), 1, "{found:#?}");
    let warned = found[0].unsteady.as_deref().unwrap_or_default();
    assert!(warned.contains("garbled"), "{found:#?}");
    let config = scan::report::config(&found, None, "line");
    assert!(config.contains("warning:"), "{config}");
    serving.abort();
}

//! The files under `deploy/`, each checked by the tool of its ecosystem (promtool, a real
//! Prometheus, kubernetes-validate, systemd-analyze), and against a running gateway: every
//! metric the dashboard and the alert rules use is one `/metrics` exports.

mod files;
mod prometheus;

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::OnceLock;
use std::time::Duration;

use iogate_tests::devices::RtuBus;
use iogate_tests::{TestGateway, bus_gateway_with, eventually};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .canonicalize()
        .expect("repository")
}

fn deploy(path: &str) -> PathBuf {
    repo().join("deploy").join(path)
}

/// Installs the tools once (the project's own script; idempotent).
fn tools() {
    static DONE: OnceLock<()> = OnceLock::new();
    DONE.get_or_init(|| {
        let status = Command::new("bash")
            .arg(deploy("check/install-tools.sh"))
            .status()
            .expect("run install-tools.sh");
        assert!(status.success(), "deploy/check/install-tools.sh failed");
    });
}

fn run(program: &str, args: &[&str]) -> String {
    let out = Command::new(program)
        .args(args)
        .current_dir(repo())
        .output()
        .unwrap_or_else(|e| panic!("{program}: {e}"));
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success(), "{program} {args:?}:\n{text}");
    text
}

/// Metric names a running gateway exports (samples, with their `_total`, `_bucket`, ...).
async fn exported(gw: &TestGateway) -> BTreeSet<String> {
    let text = gw.metrics().await.expect("metrics");
    text.lines()
        .filter(|l| !l.starts_with('#') && !l.is_empty())
        .filter_map(|l| l.split(['{', ' ']).next())
        .map(str::to_owned)
        .collect()
}

fn used_names(text: &str) -> BTreeSet<String> {
    let mut names = BTreeSet::new();
    let mut rest = text;
    while let Some(at) = rest.find("iogate_") {
        let tail = &rest[at..];
        let end = tail
            .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
            .unwrap_or(tail.len());
        names.insert(tail[..end].to_owned());
        rest = &tail[end..];
    }
    names
}

async fn busy_gateway() -> iogate_tests::OnBus {
    let bus = RtuBus::default();
    // One address refused, so exceptions are counted too.
    bus.slave(1, |s| s.refused = vec![3]);
    // An MQTT front-end too (its broker away: its series are there all the same), and a
    // Modbus server on a serial port that is not there (its port's series likewise).
    let nobody = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("port")
        .port();
    let on_bus = bus_gateway_with(
        "deploy-metrics",
        &bus,
        &[],
        "  - { name: io, profile: MyIoModule, link: bus, slave_id: 1, refresh_rate: 20ms }\n",
        &format!(
            "mqtt: {{ url: 'mqtt://127.0.0.1:{nobody}', json: {{ prefix: iogate }} }}\n\
             modbus_server:\n  serial:\n    - {{ port: /nonexistent/ttyIOGATE-deploy, baud: 9600 }}\n"
        ),
    )
    .await;
    let gw = &on_bus.0;
    eventually("every kind of series", || async {
        let names = exported(gw).await;
        [
            "iogate_device_exceptions_total",
            "iogate_device_requests_total",
            "iogate_device_response_time_seconds_bucket",
            "iogate_modbus_serial_port_up",
        ]
        .iter()
        .all(|n| names.contains(*n))
    })
    .await
    .expect("series");
    let (status, _) = gw
        .send(
            reqwest::Method::PUT,
            "/api/v1/devices/io/fields/DO_0",
            "true".to_owned(),
        )
        .await
        .expect("write");
    assert_eq!(status, 202);
    on_bus
}

/// Runs `program` with `input` on its standard input; its exit status and output.
fn piped(program: &str, args: &[&str], input: &str) -> (bool, String) {
    use std::io::Write;
    let mut child = Command::new(program)
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("{program}: {e}"));
    if let Some(mut stdin) = child.stdin.take() {
        stdin.write_all(input.as_bytes()).expect("stdin");
    }
    let out = child.wait_with_output().expect("output");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    (out.status.success(), text)
}

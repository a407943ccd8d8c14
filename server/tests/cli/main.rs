//! The `iogate` binary as a user runs it.

mod check_and_serve;
#[path = "../common/mod.rs"]
mod common;
mod other_commands;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::check_text;

fn iogate() -> Command {
    Command::new(env!("CARGO_BIN_EXE_iogate"))
}

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("iogate-cli-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
}

/// A workspace: `ws/profiles/` shared by `ws/proj/iogate.yaml` and `ws/proj/sub/iogate.yaml`.
fn workspace(name: &str) -> PathBuf {
    let ws = temp_dir(name);
    let proj = ws.join("proj");
    std::fs::create_dir_all(proj.join("sub")).expect("mkdir");
    std::fs::create_dir_all(ws.join("profiles")).expect("mkdir");
    std::fs::copy(
        repo().join("profiles/sim_io.yaml"),
        ws.join("profiles/sim_io.yaml"),
    )
    .expect("copy profile");
    let config = "devices:\n  - { name: sim, profile: SimIo, refresh_rate: 100ms }\n";
    std::fs::write(proj.join("iogate.yaml"), config).expect("write");
    std::fs::write(proj.join("sub/iogate.yaml"), config).expect("write");
    ws
}

/// blark (an IEC 61131-3 ST parser, from PyPI), in the tests' own Python.
fn blark() -> PathBuf {
    static MADE: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    MADE.get_or_init(|| common::python().with_file_name("blark"))
        .clone()
}

/// Whether blark parses `text` as ST source; its report.
fn parses(name: &str, text: &str) -> (bool, String) {
    let dir = temp_dir("st");
    let file = dir.join(format!("{name}.st"));
    std::fs::write(&file, text).expect("write");
    let out = Command::new(blark())
        .arg("parse")
        .arg(&file)
        .output()
        .expect("run blark");
    let report = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    (
        out.status.success() && !report.contains("Failed to parse"),
        report,
    )
}

/// A gateway process, killed when dropped.
struct Serving(std::process::Child);

impl Drop for Serving {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Starts `iogate serve --config config` and answers its HTTP base URL.
fn serve(config: &Path) -> (Serving, String) {
    let mut child = iogate()
        .args(["serve", "--config"])
        .arg(config)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("starts");
    let rx = common::printed_lines(&mut child);
    let serving = Serving(child);
    let line = rx
        .recv_timeout(Duration::from_secs(20))
        .expect("prints its URLs");
    let url = line
        .strip_prefix("Web page:  ")
        .and_then(|l| l.strip_suffix("/ui"))
        .expect("the web page's URL")
        .to_owned();
    (serving, url)
}

fn check_diff(args: &[&str], config: &Path) -> (Option<i32>, String, String) {
    let out = iogate()
        .args(["check", "--diff", "--config"])
        .arg(config)
        .args(args)
        .output()
        .expect("runs");
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

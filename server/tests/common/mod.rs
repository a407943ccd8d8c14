//! What the command-line tests share (each test binary uses some of it).
#![allow(dead_code)]

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command};
use std::sync::mpsc;

/// The lines a started `iogate` (its standard output piped) prints, as they come, read on a
/// thread of their own so that a test can wait for them with a bound. The pipe is read to
/// its end whether or not anyone still takes the lines, so the gateway's output never
/// meets a closed pipe.
pub fn printed_lines(child: &mut Child) -> mpsc::Receiver<String> {
    let stdout = child.stdout.take().expect("the standard output is piped");
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            let _ = tx.send(line);
        }
    });
    rx
}

/// `iogate check` on `text`, written to `dir/{name}.yaml`: its exit code and its errors.
pub fn check_text(dir: &Path, name: &str, text: &str) -> (Option<i32>, String) {
    let config = dir.join(format!("{name}.yaml"));
    std::fs::write(&config, text).expect("config");
    let out = Command::new(env!("CARGO_BIN_EXE_iogate"))
        .args(["check", "--config"])
        .arg(&config)
        .output()
        .expect("runs");
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

mod python;
#[allow(unused_imports)]
pub use python::python;

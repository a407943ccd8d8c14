//! The tests' own Python, shared by the command-line tests and the benchmarks.

use std::process::Command;

/// The tests' own Python (`tests/.venv`, made from `tests/python/requirements.txt` by
/// `tests/python/venv.sh` when missing), which runs the Python peers; the user's own Python
/// is neither used nor changed.
pub fn python() -> std::path::PathBuf {
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/../tests/python/venv.sh");
    let out = Command::new("bash")
        .arg(script)
        .stderr(std::process::Stdio::inherit())
        .output()
        .expect("running tests/python/venv.sh");
    assert!(
        out.status.success(),
        "tests/python/venv.sh failed: {}",
        out.status
    );
    std::path::PathBuf::from(String::from_utf8_lossy(&out.stdout).trim())
}

//! `iogatectl` as a user meets its errors: each cause said once.

use std::process::Command;

#[test]
fn a_gateway_that_cannot_be_reached_is_said_once_per_cause() {
    // A port nothing listens on: bound, noted, released.
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("a free port");
    let out = Command::new(env!("CARGO_BIN_EXE_iogatectl"))
        .args(["-s", &format!("http://127.0.0.1:{port}"), "devices"])
        .output()
        .expect("runs");
    assert!(!out.status.success());
    let text = String::from_utf8_lossy(&out.stderr);
    assert!(
        text.starts_with(&format!(
            "iogatectl: cannot connect to http://127.0.0.1:{port}"
        )),
        "{text}"
    );
    for part in ["transport error", "tcp connect error"] {
        assert_eq!(text.matches(part).count(), 1, "{part} once: {text}");
    }
}

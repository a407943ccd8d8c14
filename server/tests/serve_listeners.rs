//! `iogate serve` moves its listeners from the command line: the demo on ports of its own
//! when the usual ones are taken, port 0 for any free one, printed as bound.

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

#[test]
fn the_demo_serves_on_the_ports_the_command_line_gives() {
    // Its usual REST port taken, the demo moves every listener to a free port.
    let taken = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
    let taken_port = taken.local_addr().expect("addr").port();
    let dir = std::env::temp_dir().join(format!("iogate-serve-listen-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("dir");
    let refused = Command::new(env!("CARGO_BIN_EXE_iogate"))
        .current_dir(&dir)
        .args(["serve", "--http", &format!("127.0.0.1:{taken_port}")])
        .output()
        .expect("runs");
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert!(!refused.status.success(), "{stderr}");
    assert!(
        stderr.contains("or serve --http ADDR; port 0 takes any free one"),
        "the refusal says how to move it: {stderr}"
    );
    let mut child = Command::new(env!("CARGO_BIN_EXE_iogate"))
        .current_dir(&dir)
        .args([
            "serve",
            "--http",
            "127.0.0.1:0",
            "--grpc",
            "127.0.0.1:0",
            "--modbus",
            "127.0.0.1:0",
            "--opcua",
            "127.0.0.1:0",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("starts");
    let stdout = child.stdout.take().expect("stdout");
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            let _ = tx.send(line);
        }
    });
    let mut printed = Vec::new();
    while let Ok(line) = rx.recv_timeout(Duration::from_secs(30)) {
        let done = line.starts_with("Health:");
        printed.push(line);
        if done {
            break;
        }
    }
    let text = printed.join("\n");
    for (what, prefix) in [
        ("REST", "REST API:  http://127.0.0.1:"),
        ("OPC UA", "OPC UA:    opc.tcp://127.0.0.1:"),
    ] {
        let line = printed
            .iter()
            .find(|l| l.starts_with(prefix))
            .unwrap_or_else(|| panic!("{what} not printed:\n{text}"));
        assert!(!line.contains(":0/"), "the bound port, not 0: {line}");
        assert!(
            !line.contains(&format!(":{taken_port}/")),
            "not the taken port: {line}"
        );
    }
    let _ = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status();
    let status = child.wait().expect("ends");
    assert!(status.success(), "{status}");
    drop(taken);
    std::fs::remove_dir_all(&dir).expect("cleanup");
}

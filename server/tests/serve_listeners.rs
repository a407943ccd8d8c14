//! `iogate serve` moves its listeners from the command line: the demo on ports of its own
//! when the usual ones are taken, port 0 for any free one, printed as bound.
#![allow(clippy::too_many_lines)]

mod common;

use std::io::{Read, Write};
use std::process::{Command, Stdio};
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
    let rx = common::printed_lines(&mut child);
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
    // The demo's plant moves: started, its pump runs and the level rises.
    let rest = printed
        .iter()
        .find_map(|l| l.strip_prefix("REST API:  http://"))
        .and_then(|l| l.split('/').next())
        .expect("REST address")
        .to_owned();
    let level = |rest: &str| -> f64 {
        let body = http(rest, "GET", "/api/v1/devices/plant/fields/Level", "");
        let at = body.find("\"value\":").expect("a value") + 8;
        body[at..]
            .split([',', '}'])
            .next()
            .and_then(|v| v.trim().parse().ok())
            .unwrap_or(f64::NAN)
    };
    let answer = http(
        &rest,
        "PUT",
        "/api/v1/devices/plant/fields/PumpStart",
        "{\"value\": true}",
    );
    assert!(answer.contains("generation"), "{answer}");
    let deadline = std::time::Instant::now() + Duration::from_secs(60);
    while !http(&rest, "GET", "/api/v1/devices/plant/fields/PumpRunning", "")
        .contains("\"value\":true")
    {
        assert!(std::time::Instant::now() < deadline, "the pump never ran");
        std::thread::sleep(Duration::from_millis(100));
    }
    let before = level(&rest);
    while level(&rest) <= before {
        assert!(
            std::time::Instant::now() < deadline,
            "the level never rose from {before}"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    let _ = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status();
    let status = child.wait().expect("ends");
    assert!(status.success(), "{status}");
    drop(taken);
    std::fs::remove_dir_all(&dir).expect("cleanup");
}

/// One HTTP/1.0 request; the answer's body.
fn http(addr: &str, method: &str, path: &str, body: &str) -> String {
    let mut stream = std::net::TcpStream::connect(addr).expect("connect");
    let request = format!(
        "{method} {path} HTTP/1.0\r\nHost: x\r\nContent-Type: application/json\r\nContent-Length: {}\r\n\r\n{body}",
        body.len()
    );
    stream.write_all(request.as_bytes()).expect("send");
    let mut answer = String::new();
    stream.read_to_string(&mut answer).expect("read");
    answer
        .split_once("\r\n\r\n")
        .map(|(_, b)| b.to_owned())
        .unwrap_or_default()
}

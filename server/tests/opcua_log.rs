//! `iogate serve` with an OPC UA server whose endpoints are all without security: a client
//! (asyncua, an independent implementation) connects and reads, and the log says nothing
//! about certificates the server has by design none of.

mod common;

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("a free port")
}

#[test]
fn a_server_without_security_logs_no_certificate_error() {
    let python = common::python();
    let dir = std::env::temp_dir().join(format!("iogate-opcua-log-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("dir");
    let port = free_port();
    let config = dir.join("iogate.yaml");
    std::fs::write(
        &config,
        format!(
            "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0 }}\nprofiles: {}\ndevices:\n  - {{ name: sim, profile: SimIo, refresh_rate: 50ms }}\nopcua: {{ listen: 127.0.0.1:{port}, security: [none], pki_dir: {} }}\n",
            repo().join("profiles").display(),
            dir.join("pki").display()
        ),
    )
    .expect("config");
    let mut child = Command::new(env!("CARGO_BIN_EXE_iogate"))
        .args(["serve", "--config"])
        .arg(&config)
        .env("RUST_LOG", "info")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("starts");
    let rx = common::printed_lines(&mut child);
    // Its URLs are printed once it serves, the OPC UA server's among them.
    loop {
        let line = rx
            .recv_timeout(Duration::from_secs(30))
            .expect("prints its URLs");
        if line.contains("opc.tcp://") {
            break;
        }
    }
    let read = Command::new(&python)
        .arg("-c")
        .arg(format!(
            "import asyncio\nfrom asyncua import Client\nasync def main():\n    for _ in range(2):\n        async with Client('opc.tcp://127.0.0.1:{port}/') as c:\n            print(await c.get_node('ns=2;s=sim.DI_0').read_value())\nasyncio.run(main())\n"
        ))
        .output()
        .expect("python runs");
    assert!(
        read.status.success(),
        "{}",
        String::from_utf8_lossy(&read.stderr)
    );
    let _ = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status();
    let _ = child.wait();
    let mut log = String::new();
    if let Some(mut stderr) = child.stderr.take() {
        let _ = stderr.read_to_string(&mut log);
    }
    let noise: Vec<&str> = log
        .lines()
        .filter(|l| l.contains("ERROR") && (l.contains("certificate") || l.contains("private key")))
        .collect();
    assert!(
        noise.is_empty(),
        "two connections, no certificate errors: {noise:#?}"
    );
    assert!(log.contains("serving OPC UA"), "{log}");
    std::fs::remove_dir_all(&dir).expect("cleanup");
}

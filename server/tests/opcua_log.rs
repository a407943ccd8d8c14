//! `iogate serve` with an OPC UA server whose endpoints are all without security: a client
//! (asyncua, an independent implementation) connects and reads, and so does the gateway's
//! own OPC UA client on a link without security, and the log says nothing about
//! certificates neither side has by design, nor warns of anything.
#![allow(clippy::too_many_lines)]

mod common;

use std::io::{BufRead, BufReader};
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
    // The gateway reads its own server through a link: `self` reads `sim`'s DI_0.
    let profiles = dir.join("profiles");
    std::fs::create_dir_all(&profiles).expect("profiles");
    std::fs::copy(
        repo().join("profiles/sim_io.yaml"),
        profiles.join("sim_io.yaml"),
    )
    .expect("SimIo");
    std::fs::write(
        profiles.join("own.yaml"),
        "name: Own\nprotocol: opcua\nfields:\n  - { name: DI, type: BOOL, direction: input, node: \"ns=2;s=sim.DI_0\" }\n",
    )
    .expect("profile");
    std::fs::write(
        &config,
        format!(
            "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0 }}\nprofiles: {}\nlinks:\n  - {{ name: own, opcua: {{ url: \"opc.tcp://127.0.0.1:{port}/\", pki_dir: {} }} }}\ndevices:\n  - {{ name: sim, profile: SimIo, refresh_rate: 50ms }}\n  - {{ name: mirror, profile: Own, link: own, refresh_rate: 100ms }}\nopcua: {{ listen: 127.0.0.1:{port}, security: [none], pki_dir: {} }}\n",
            profiles.display(),
            dir.join("client-pki").display(),
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
    // An import from a root the server does not have says so (and closes its session).
    let import = Command::new(env!("CARGO_BIN_EXE_iogate"))
        .args(["profile", "import", "--from", "opcua"])
        .arg(format!("opc.tcp://127.0.0.1:{port}/"))
        .args(["--node", "ns=2;s=Nope", "--out"])
        .arg(dir.join("imported"))
        .output()
        .expect("import runs");
    let said = String::from_utf8_lossy(&import.stderr);
    assert_eq!(import.status.code(), Some(1), "{said}");
    assert!(said.contains("no such node on the server"), "{said}");
    // The gateway's own client has opened its link (the log said so) before it stops.
    let mut log = String::new();
    let stderr = child.stderr.take().expect("piped");
    let (tx, logged) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            let _ = tx.send(line);
        }
    });
    while !log.contains("link open") {
        let line = logged
            .recv_timeout(Duration::from_secs(30))
            .expect("the link opens");
        log.push_str(&line);
        log.push('\n');
    }
    let _ = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status();
    let _ = child.wait();
    for line in logged.iter() {
        log.push_str(&line);
        log.push('\n');
    }
    let noise: Vec<&str> = log
        .lines()
        .filter(|l| l.contains("ERROR") && (l.contains("certificate") || l.contains("private key")))
        .collect();
    assert!(
        noise.is_empty(),
        "three connections, no certificate errors: {noise:#?}"
    );
    // Until the gateway stops (its server then halts under its own client).
    let warned: Vec<&str> = log
        .lines()
        .take_while(|l| !l.contains("shutting down"))
        .filter(|l| l.contains(" WARN ") && l.contains("opcua_client"))
        .collect();
    assert!(
        warned.is_empty(),
        "the client warns of nothing: {warned:#?}"
    );
    assert!(log.contains("serving OPC UA"), "{log}");
    std::fs::remove_dir_all(&dir).expect("cleanup");
}

use super::*;

#[test]
fn check_lists_every_problem_and_exits_64() {
    let out = iogate()
        .args(["check", "--config"])
        .arg(repo().join("tests/fixtures/bad_configs/bad_devices.yaml"))
        .output()
        .expect("runs");
    assert_eq!(out.status.code(), Some(64));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("bad_devices.yaml:13: device io: unknown profile `NoSuchProfile`"),
        "{stderr}"
    );
    assert!(
        stderr.contains("bad_devices.yaml:16: device sim: a simulated device has no slave_id"),
        "{stderr}"
    );
    assert!(stderr.contains("6 problems found"), "{stderr}");
}

#[test]
fn check_refuses_what_the_gateway_would_trip_over_later_naming_the_line() {
    let dir = temp_dir("trip");
    std::fs::create_dir_all(dir.join("profiles")).expect("profiles dir");
    std::fs::copy(
        repo().join("profiles/generic_io_module.yaml"),
        dir.join("profiles/io.yaml"),
    )
    .expect("profile");
    std::fs::write(
        dir.join("tokens"),
        "read same-token-0123456789\nadmin same-token-0123456789\n",
    )
    .expect("tokens");
    let link = "links:\n  - { name: a, tcp: { host: 127.0.0.1, port: 1502 } }\n  - { name: b, tcp: { host: 127.0.0.1, port: 1503 } }\n";
    let cases: [(&str, String, &str); 6] = [
        (
            "forward",
            format!(
                "{link}modbus_server:\n  listen: 127.0.0.1:0\n  forward:\n    - {{ unit_ids: \"2-9\", link: a }}\n    - {{ unit_ids: \"5-12\", link: b }}\n"
            ),
            "forward.yaml:8: modbus_server.forward[1].unit_ids: 5-12 overlaps modbus_server.forward[0] (2-9 to link a, line 7)",
        ),
        (
            "tokens",
            "security:\n  tokens_file: tokens\n".to_owned(),
            "tokens:2: security.tokens_file: this token is given on line 1 already (as read): a token has one role",
        ),
        (
            "safe",
            format!(
                "{link}devices:\n  - {{ name: io, profile: MyIoModule, link: a, slave_id: 1, on_client_loss: {{ after: 1s, safe: {{ AO_0: 99999 }} }} }}\n"
            ),
            "safe.yaml:5: device io: on_client_loss.safe.AO_0: `99999` would be refused by a write: 99999000 after scaling does not fit the raw register value (0 to 65535)",
        ),
        (
            "ports",
            "security:\n  declare:\n    serial_ports:\n      - 42\n      - /etc/passwd\n"
                .to_owned(),
            "ports.yaml:5: security.declare.serial_ports: `/etc/passwd` is not a pattern of serial device paths",
        ),
        (
            "memory",
            "modbus_server:\n  listen: 127.0.0.1:0\n  memory_file: no/such/dir/memory.bin\n"
                .to_owned(),
            "memory.yaml:3: modbus_server.memory_file:",
        ),
        (
            "duplicate",
            "devices:\n  - { name: sim, profile: SimIo }\ndevices: []\n".to_owned(),
            "duplicate.yaml:3: duplicate key `devices`: a key may appear once in a mapping (keep one)",
        ),
    ];
    for (name, text, expected) in cases {
        let (code, stderr) = check_text(&dir, name, &text);
        assert_eq!(code, Some(64), "{name}: {stderr}");
        assert!(stderr.contains(expected), "{name}: {stderr}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn check_refuses_serial_framings_and_server_ports_that_cannot_work() {
    let dir = temp_dir("serial-check");
    let cases: [(&str, &str, &str); 6] = [
        (
            "mbap",
            "links:\n  - name: a\n    serial: { port: /dev/ttyUSB0, baud: 9600, framing: mbap }\n",
            "mbap.yaml:3: link a: serial.framing: `mbap` is no framing of a serial line (expected rtu or ascii; mbap is Modbus TCP's)",
        ),
        (
            "tcp",
            "links:\n  - name: a\n    tcp: { host: 127.0.0.1, framing: binary }\n",
            "tcp.yaml:3: link a: tcp.framing: unknown framing `binary` (expected mbap, rtu or ascii)",
        ),
        (
            "neither",
            "modbus_server:\n  auto: true\n",
            "neither.yaml:2: modbus_server: missing `listen` (the Modbus TCP address) or `serial` (ports to serve as a slave): give one or both",
        ),
        (
            "twice",
            "modbus_server:\n  serial:\n    - { port: /dev/ttyS1, baud: 9600 }\n    - { port: /dev/ttyS1, baud: 19200, unit_id: 2 }\n",
            "twice.yaml:4: modbus_server.serial[1].port: /dev/ttyS1 is served by modbus_server.serial[0] already (line 3): a port is served once",
        ),
        (
            "link",
            "links:\n  - { name: bus, serial: { port: /dev/ttyS1, baud: 9600 } }\nmodbus_server:\n  serial:\n    - { port: /dev/ttyS1, baud: 9600 }\n",
            "link.yaml:5: modbus_server.serial[0].port: /dev/ttyS1 is link bus's port (line 2): a port is either polled by iogate as a master or served as a slave, not both",
        ),
        (
            "turnaround",
            "modbus_server:\n  serial:\n    - { port: /dev/ttyS1, baud: 9600, unit_id: 248, turnaround_delay: 2s, parity: X }\n",
            "turnaround.yaml:3: modbus_server.serial[0].turnaround_delay: 2000 ms is longer than the 500 ms allowed",
        ),
    ];
    for (name, text, expected) in cases {
        let (code, stderr) = check_text(&dir, name, text);
        assert_eq!(code, Some(64), "{name}: {stderr}");
        assert!(stderr.contains(expected), "{name}: {stderr}");
        if name == "turnaround" {
            // Every problem of the entry at once.
            assert!(
                stderr.contains("modbus_server.serial[0].unit_id"),
                "{stderr}"
            );
            assert!(
                stderr.contains("modbus_server.serial[0].parity"),
                "{stderr}"
            );
        }
    }
    // A server on serial ports alone, ASCII at 7E1, and an ASCII link pass.
    let (code, stderr) = check_text(
        &dir,
        "good",
        "links:\n  - { name: old, serial: { port: /dev/ttyS2, baud: 9600, parity: E, data_bits: 7, framing: ascii } }\n\
         modbus_server:\n  serial:\n    - { port: /dev/ttyS1, baud: 19200, parity: E, unit_id: 3, turnaround_delay: 5ms }\n    \
         - { port: /dev/ttyS3, baud: 9600, data_bits: 7, parity: E, framing: ascii }\n",
    );
    assert_eq!(code, Some(0), "{stderr}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn an_invalid_log_filter_is_a_configuration_error_naming_it() {
    let out = iogate()
        .arg("check")
        .env("RUST_LOG", "iogate=loud")
        .output()
        .expect("runs");
    assert_eq!(out.status.code(), Some(64));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("RUST_LOG `iogate=loud` is not a log filter"),
        "{stderr}"
    );
    let fine = iogate()
        .arg("check")
        .env("RUST_LOG", "iogate=debug,warn")
        .output()
        .expect("runs");
    assert_eq!(fine.status.code(), Some(0), "{fine:?}");
}

#[test]
fn check_accepts_the_example_and_the_demo() {
    let out = iogate()
        .args(["check", "--config"])
        .arg(repo().join("examples/demo.yaml"))
        .output()
        .expect("runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(String::from_utf8_lossy(&out.stdout).contains("ok (8 profiles, 1 link, 4 devices)"));

    // With nothing configured, the built-in demo is checked.
    let empty = temp_dir("empty");
    let out = iogate()
        .arg("check")
        .current_dir(&empty)
        .output()
        .expect("runs");
    assert!(out.status.success());
    assert!(String::from_utf8_lossy(&out.stdout).starts_with("built-in demo: ok"));
}

#[test]
fn profiles_are_found_in_a_parent_from_relative_and_absolute_config_paths() {
    let ws = workspace("parents");
    let proj = ws.join("proj");
    let ok = |out: std::process::Output| {
        let (stdout, stderr) = (
            String::from_utf8_lossy(&out.stdout).into_owned(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        );
        assert!(out.status.success(), "{stdout}{stderr}");
        assert!(
            stdout.contains("ok (1 profile, 0 links, 1 device)"),
            "{stdout}"
        );
    };
    // The default ./iogate.yaml, from the project folder.
    ok(iogate()
        .arg("check")
        .current_dir(&proj)
        .output()
        .expect("runs"));
    // A relative --config, from the project folder and from a subdirectory.
    ok(iogate()
        .args(["check", "--config", "sub/iogate.yaml"])
        .current_dir(&proj)
        .output()
        .expect("runs"));
    ok(iogate()
        .args(["check", "--config", "../iogate.yaml"])
        .current_dir(proj.join("sub"))
        .output()
        .expect("runs"));
    ok(iogate()
        .args(["check", "--config", "iogate.yaml"])
        .current_dir(proj.join("sub"))
        .output()
        .expect("runs"));
    // An absolute one, from anywhere.
    ok(iogate()
        .args(["check", "--config"])
        .arg(proj.join("sub/iogate.yaml"))
        .current_dir(std::env::temp_dir())
        .output()
        .expect("runs"));
    let _ = std::fs::remove_dir_all(&ws);
}

#[test]
fn check_warns_about_wide_fields_that_rely_on_the_default_word_count() {
    let ws = workspace("widths");
    std::fs::write(
        ws.join("profiles/meter.yaml"),
        "name: Meter\nfields:\n  - { name: Energy, type: UDINT, direction: input, register: { address: 0, kind: input_register } }\n  - { name: Power, type: REAL, direction: input, register: { address: 2, kind: input_register, word_count: 2 } }\n",
    )
    .expect("write");
    let out = iogate()
        .arg("check")
        .current_dir(ws.join("proj"))
        .output()
        .expect("runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(
        out.status.code(),
        Some(0),
        "a warning, not an error: {stderr}"
    );
    assert!(
        stderr.contains("meter.yaml:3: field Energy: UDINT with no `word_count` reads one register as a 16-bit value (the default is 1); to read the full 32-bit value, add `word_count: 2` to its register"),
        "{stderr}"
    );
    assert!(!stderr.contains("field Power"), "{stderr}");
    let _ = std::fs::remove_dir_all(&ws);
}

#[test]
fn check_warns_about_a_time_bound_at_a_double_word() {
    let dir = temp_dir("time-md");
    let config = dir.join("iogate.yaml");
    std::fs::write(
        &config,
        format!(
            "profiles: {}\ndevices:\n  - {{ name: plant, profile: SimPlant, refresh_rate: 50ms }}\nmodbus_server:\n  listen: 127.0.0.1:0\n  map:\n    - {{ at: \"%MD7\", field: plant.MixTime }}\n",
            repo().join("profiles").display()
        ),
    )
    .expect("write");
    let out = iogate()
        .args(["check", "--config"])
        .arg(&config)
        .output()
        .expect("runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(0), "a warning: {stderr}");
    assert!(
        stderr.contains("iogate.yaml:7: modbus_server.map: %MD7: plant.MixTime: TIME is 64-bit milliseconds; %MD7 holds -2147483648 to 2147483647 ms"),
        "{stderr}"
    );
    let out = iogate()
        .arg("map")
        .arg("--config")
        .arg(&config)
        .output()
        .expect("runs");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("%MD7"), "{stdout}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn serve_refuses_a_broken_config() {
    let out = iogate()
        .args(["serve", "--config"])
        .arg(repo().join("tests/fixtures/bad_configs/serial_mismatch.yaml"))
        .output()
        .expect("runs");
    assert_eq!(out.status.code(), Some(64));
    assert!(String::from_utf8_lossy(&out.stderr).contains("Baudrate configuration mismatch"));
    assert!(out.stdout.is_empty(), "nothing was started");
}

#[test]
fn serve_runs_until_sigterm_and_exits_promptly() {
    let dir = temp_dir("serve");
    let config = dir.join("iogate.yaml");
    std::fs::write(
        &config,
        format!(
            "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0 }}\nprofiles: {}\ndevices:\n  - {{ name: sim, profile: SimIo, refresh_rate: 50ms }}\n",
            repo().join("profiles").display()
        ),
    )
    .expect("write config");
    let mut child = iogate()
        .args(["serve", "--config"])
        .arg(&config)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("starts");
    let rx = common::printed_lines(&mut child);
    let line = rx
        .recv_timeout(Duration::from_secs(20))
        .expect("prints its URLs");
    assert!(line.starts_with("Web page:  http://127.0.0.1:"), "{line}");
    assert!(line.ends_with("/ui"), "{line}");
    assert!(!line.contains(":0/"), "prints the bound port: {line}");
    let line = rx.recv_timeout(Duration::from_secs(5)).expect("REST");
    assert!(line.starts_with("REST API:  http://127.0.0.1:"), "{line}");

    let killed = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .expect("kill");
    assert!(killed.success());
    let started = Instant::now();
    loop {
        if let Some(status) = child.try_wait().expect("wait") {
            assert!(status.success(), "{status}");
            break;
        }
        assert!(
            started.elapsed() < Duration::from_secs(2),
            "still running 2 s after SIGTERM"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn serve_that_cannot_listen_stops_before_it_touches_a_bus() {
    // A device's TCP endpoint that records whether the gateway ever connected.
    let device = std::net::TcpListener::bind("127.0.0.1:0").expect("device");
    device.set_nonblocking(true).expect("nonblocking");
    let device_port = device.local_addr().expect("addr").port();
    // The HTTP port, taken.
    let taken = std::net::TcpListener::bind("127.0.0.1:0").expect("taken");
    let taken_port = taken.local_addr().expect("addr").port();
    let dir = temp_dir("no-listen");
    let config = dir.join("iogate.yaml");
    std::fs::write(
        &config,
        format!(
            "listen: {{ http: 127.0.0.1:{taken_port}, grpc: 127.0.0.1:0 }}\nprofiles: {}\nlinks:\n  - {{ name: plant, tcp: {{ host: 127.0.0.1, port: {device_port} }} }}\ndevices:\n  - {{ name: meter, profile: EastronSDM630, link: plant, slave_id: 1, refresh_rate: 10ms }}\n",
            repo().join("profiles").display()
        ),
    )
    .expect("write config");
    let out = iogate()
        .args(["serve", "--config"])
        .arg(&config)
        .output()
        .expect("runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{stderr}");
    assert!(
        stderr.contains(&format!(
            "cannot listen on 127.0.0.1:{taken_port} (listen.http, or serve --http ADDR"
        )),
        "{stderr}"
    );
    assert!(out.stdout.is_empty(), "no URLs printed");
    match device.accept() {
        Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {}
        other => panic!("the gateway connected to the device: {other:?}"),
    }
    drop(taken);
    let _ = std::fs::remove_dir_all(&dir);
}

//! The `iogate` binary as a user runs it.

mod common;

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

/// Installs blark (an IEC 61131-3 ST parser, from PyPI) once, with the project's script.
fn blark() -> &'static str {
    static DONE: std::sync::OnceLock<()> = std::sync::OnceLock::new();
    DONE.get_or_init(|| {
        let status = Command::new("bash")
            .arg(repo().join("tests/st/install.sh"))
            .status()
            .expect("run tests/st/install.sh");
        assert!(status.success(), "tests/st/install.sh failed");
    });
    "blark"
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

#[test]
fn every_generated_st_declaration_parses_with_an_independent_iec_parser() {
    let out = iogate().args(["fb", "st"]).output().expect("runs");
    let blocks = String::from_utf8_lossy(&out.stdout).into_owned();
    let (ok, report) = parses("blocks", &blocks);
    assert!(ok, "iogate fb st:\n{report}\n{blocks}");
    for keyword in ["function :", "type :", "interface :"] {
        assert!(!blocks.contains(keyword), "{keyword} in\n{blocks}");
    }
    // Every shipped profile's function block.
    let profiles: Vec<String> = std::fs::read_dir(repo().join("profiles"))
        .expect("profiles")
        .filter_map(Result::ok)
        .filter_map(|e| std::fs::read_to_string(e.path()).ok())
        .filter_map(|text| {
            text.lines()
                .find_map(|l| l.strip_prefix("name: ").map(|n| n.trim().to_owned()))
        })
        .collect();
    assert!(profiles.len() >= 5, "{profiles:?}");
    for name in &profiles {
        let out = iogate()
            .args(["profile", "st", name])
            .arg("--config")
            .arg(repo().join("examples/demo.yaml"))
            .output()
            .expect("runs");
        let st = String::from_utf8_lossy(&out.stdout).into_owned();
        assert!(
            out.status.success(),
            "{name}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let (ok, report) = parses(name, &st);
        assert!(ok, "{name}:\n{report}\n{st}");
    }
    // The Modbus map's AT declarations for the demo (every field of every type).
    let out = iogate().args(["map", "--st"]).output().expect("runs");
    let map = String::from_utf8_lossy(&out.stdout).into_owned();
    let (ok, report) = parses("map", &map);
    assert!(ok, "iogate map --st:\n{report}\n{map}");
    // And the parser does refuse a keyword as a name, so the checks above mean something.
    let (ok, _) = parses(
        "keyword",
        "FUNCTION_BLOCK X\nVAR\n    TYPE : BOOL;\nEND_VAR\nEND_FUNCTION_BLOCK\n",
    );
    assert!(!ok, "blark took TYPE as a name");
}

#[test]
fn plan_prints_transactions_wire_time_and_utilisation() {
    let dir = temp_dir("plan");
    let config = dir.join("iogate.yaml");
    std::fs::write(
        &config,
        format!(
            "profiles: {}\nlinks:\n  - {{ name: rs485, serial: {{ port: /dev/ttyUSB0, baud: 9600, parity: E }} }}\ndevices:\n  - {{ name: meter, profile: EastronSDM630, link: rs485, slave_id: 1, refresh_rate: 100ms }}\n  - {{ name: io, profile: MyIoModule, link: rs485, slave_id: 2, refresh_rate: 50ms }}\n",
            repo().join("profiles").display()
        ),
    )
    .expect("write config");
    let out = iogate()
        .args(["plan", "--config"])
        .arg(&config)
        .output()
        .expect("runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("link rs485: serial /dev/ttyUSB0 9600 8E1 (11 bits per character"),
        "{text}"
    );
    // The meter's floats sit in 8 runs of input registers: 0-17, 30-35, 52-53, 56-57, 60-63,
    // 70-75, 200-205, 342-343.
    assert!(text.contains("device meter (profile EastronSDM630, slave 1, every 100 ms): 8 transaction(s) per cycle"), "{text}");
    assert!(
        text.contains("FC04 slave   1 address     0 count   18"),
        "{text}"
    );
    assert!(
        text.contains(
            "device io (profile MyIoModule, slave 2, every 50 ms): 4 transaction(s) per cycle"
        ),
        "{text}"
    );
    assert!(text.contains("bus utilisation:"), "{text}");
    assert!(
        text.contains("WARNING"),
        "9600 baud cannot carry these rates: {text}"
    );

    // `check` accepts the config but says so.
    let out = iogate()
        .args(["check", "--config"])
        .arg(&config)
        .output()
        .expect("runs");
    assert!(out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("warning: link rs485: the refresh rates need"),
        "{stderr}"
    );
}

#[test]
fn profile_st_prints_the_function_block() {
    let out = iogate()
        .args(["profile", "st", "SimIo", "--config"])
        .arg(repo().join("examples/demo.yaml"))
        .output()
        .expect("runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("FUNCTION_BLOCK SimIo\nVAR_INPUT\n    refresh_rate : TIME;"),
        "{text}"
    );
    assert!(
        text.contains("    DO_0 : BOOL; (* output virtual 1 *)\nEND_VAR\nEND_FUNCTION_BLOCK\n"),
        "{text}"
    );
    let out = iogate()
        .args(["profile", "st", "Nope"])
        .current_dir(temp_dir("st"))
        .output()
        .expect("runs");
    assert_eq!(out.status.code(), Some(64));
    assert!(String::from_utf8_lossy(&out.stderr).contains("unknown profile `Nope`"));
}

#[test]
fn version_and_json_logs_for_log_collectors() {
    let out = iogate().arg("--version").output().expect("run");
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.starts_with("iogate "), "{text}");

    // A gateway whose HTTP port is taken fails to start and says why in a log line: one
    // JSON object.
    let taken = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
    let port = taken.local_addr().expect("addr").port();
    let dir = temp_dir("json-logs");
    let config = dir.join("iogate.yaml");
    std::fs::write(
        &config,
        format!(
            "listen: {{ http: 127.0.0.1:{port}, grpc: 127.0.0.1:0 }}\nprofiles: {}\ndevices:\n  - {{ name: sim, profile: SimIo }}\n",
            repo().join("profiles").display()
        ),
    )
    .expect("config");
    for json in [true, false] {
        let mut command = iogate();
        if json {
            command.args(["--log-format", "json"]);
        } else {
            command.env("IOGATE_LOG_FORMAT", "text");
        }
        let out = command
            .args(["serve", "--config"])
            .arg(&config)
            .output()
            .expect("run");
        assert!(!out.status.success(), "the port is taken");
        let stderr = String::from_utf8_lossy(&out.stderr);
        let line = stderr
            .lines()
            .find(|l| l.contains("could not start"))
            .unwrap_or_else(|| panic!("no log line: {stderr}"));
        assert!(
            line.contains("(listen.http, or serve --http ADDR"),
            "{line}"
        );
        let parsed = serde_json::from_str::<serde_json::Value>(line);
        if json {
            let object = parsed.unwrap_or_else(|e| panic!("{e}: {line}"));
            assert_eq!(object["level"], "ERROR", "{object}");
            assert!(object["timestamp"].is_string(), "{object}");
        } else {
            assert!(parsed.is_err(), "text, not JSON: {line}");
            assert!(line.contains("ERROR"), "{line}");
        }
    }
    drop(taken);
    let refused = iogate()
        .args(["--log-format", "yaml", "check"])
        .output()
        .expect("run");
    assert!(!refused.status.success());
    assert!(String::from_utf8_lossy(&refused.stderr).contains("possible values: text, json"));
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

#[test]
fn check_diff_prints_what_a_reload_would_change_and_applies_nothing() {
    let dir = temp_dir("diff");
    let config = dir.join("iogate.yaml");
    let text = |rate: &str, extra: &str| {
        format!(
            "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0 }}\nprofiles: {}\ndevices:\n  - {{ name: sim, profile: SimIo, refresh_rate: {rate} }}\n{extra}",
            repo().join("profiles").display()
        )
    };
    std::fs::write(&config, text("50ms", "")).expect("write config");
    let (_gateway, url) = serve(&config);
    let edited = text(
        "20ms",
        "  - { name: sim2, profile: SimIo, refresh_rate: 100ms }\n",
    );
    std::fs::write(&config, &edited).expect("edit");
    // Asked twice: the first dry run applied nothing, so the second sees the same changes.
    for _ in 0..2 {
        let (code, stdout, stderr) = check_diff(&["--server", &url], &config);
        assert_eq!(code, Some(0), "{stdout}{stderr}");
        assert!(
            stdout.contains("2 changes; nothing was applied"),
            "{stdout}"
        );
        assert!(
            stdout.contains("device sim changed: refresh_rate: 50ms -> 20ms"),
            "{stdout}"
        );
        assert!(stdout.contains("device sim2 added"), "{stdout}");
    }
    let (code, stdout, stderr) = check_diff(&["--server", &url, "--json"], &config);
    assert_eq!(code, Some(0), "{stdout}{stderr}");
    let report: serde_json::Value = serde_json::from_str(&stdout).expect("JSON report");
    assert_eq!(report["dry_run"], true, "{report}");
    assert_eq!(
        report["changes"].as_array().map(Vec::len),
        Some(2),
        "{report}"
    );

    // A file with a problem: checked first, as `check` does, with file and line; exit 64.
    std::fs::write(
        &config,
        edited.replace("sim2, profile: SimIo", "sim2, profile: Nope"),
    )
    .expect("break");
    let (code, _, stderr) = check_diff(&["--server", &url], &config);
    assert_eq!(code, Some(64), "{stderr}");
    assert!(
        stderr.contains("iogate.yaml:5: device sim2: unknown profile `Nope`"),
        "{stderr}"
    );

    // Another file than the one the gateway runs is not what its reload would load.
    let other = dir.join("other.yaml");
    std::fs::write(&other, &edited).expect("other");
    let (code, _, stderr) = check_diff(&["--server", &url], &other);
    assert_eq!(code, Some(1), "{stderr}");
    assert!(stderr.contains("runs `"), "{stderr}");
    assert!(stderr.contains("--against"), "{stderr}");

    // Two files compared, nothing asked.
    let running = dir.join("running.yaml");
    std::fs::write(&running, text("50ms", "")).expect("running");
    let (code, stdout, stderr) =
        check_diff(&["--against", running.to_str().expect("path")], &other);
    assert_eq!(code, Some(0), "{stderr}");
    assert!(
        stdout.contains("device sim changed: refresh_rate: 50ms -> 20ms"),
        "{stdout}"
    );
    let (code, stdout, _) = check_diff(&["--against", running.to_str().expect("path")], &running);
    assert_eq!(code, Some(0));
    assert!(stdout.contains("no changes"), "{stdout}");
}

#[test]
fn scan_names_a_bad_option_and_a_port_it_cannot_open() {
    let run = |args: &[&str]| {
        let out = iogate().arg("scan").args(args).output().expect("scan");
        (
            out.status.code(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    };
    let (code, err) = run(&["--port", "/dev/null", "--ids", "0-5"]);
    assert_eq!(code, Some(64), "{err}");
    assert!(
        err.contains("`0` in `0-5` is not a slave id (1-247)"),
        "{err}"
    );
    let (code, err) = run(&["--port", "/dev/null", "--baud", "1200", "--timeout", "20ms"]);
    assert_eq!(code, Some(64), "{err}");
    assert!(
        err.contains("timeout 20 ms is too short at 1200 baud"),
        "{err}"
    );
    let (code, err) = run(&["--port", "/dev/null", "--parity", "X"]);
    assert_eq!(code, Some(64), "{err}");
    assert!(err.contains("`X` is not a parity"), "{err}");
    let missing = temp_dir("scan-missing").join("ttyNONE");
    let (code, err) = run(&[
        "--port",
        &missing.display().to_string(),
        "--baud",
        "9600",
        "--parity",
        "N",
        "--ids",
        "1-2",
        "--profiles",
        &repo().join("profiles").display().to_string(),
    ]);
    assert_eq!(code, Some(1), "{err}");
    assert!(
        err.contains("at most 0.1 s"),
        "the duration is said first: {err}"
    );
    assert!(err.contains("ttyNONE"), "{err}");
}

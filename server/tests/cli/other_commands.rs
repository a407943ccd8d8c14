use super::*;

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

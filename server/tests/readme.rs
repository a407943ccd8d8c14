//! Every command line of the README runs as written, in order, against the demo that the
//! README's own `iogate serve --http 127.0.0.1:0 ...` line starts, and an answer the README
//! shows (a `# {...}` or `# [...]` line under its command) is the answer given. The only liberties: the
//! demo's listeners are on free ports, so the usual port numbers in a line (8080, 50051,
//! 5020, 4840) are replaced with the ones bound, and `iogatectl` is told its server by
//! `IOGATE_SERVER`; `iogate` and `iogatectl` are the ones this build made (what `cargo
//! install` would put on the `PATH`); a stream the README says Ctrl-C ends is ended (a
//! SIGTERM: a Ctrl-C may be ignored by a process started in the background) once it has run.
//! The set-up lines (`cargo run`, `cargo test`, `cargo install`) are the ones this test is
//! part of, and are named here so that any other line is run.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

/// Lines the test does not run: the set-up it is itself part of.
const SET_UP: &[&str] = &[
    "cargo run -p iogate -- serve",
    "cargo test --workspace",
    "cargo install --locked --path server",
    "cargo install --locked --path client",
];

/// How long a stream runs before it is ended.
const STREAM: Duration = Duration::from_secs(3);

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// A command line of the README and the answer shown under it, if any.
#[derive(Debug)]
struct Line {
    number: usize,
    command: String,
    shown: Option<String>,
    /// Whether the line or the comment above it says that Ctrl-C ends it.
    stream: bool,
}

/// The command lines of the README's `sh` blocks (a line ending in `\` continues on the
/// next), each with the `# {...}` answer shown right under it.
fn command_lines(readme: &str) -> Vec<Line> {
    let mut lines = Vec::new();
    let mut in_sh = false;
    let mut pending = String::new();
    let mut comment = "";
    for (i, text) in readme.lines().enumerate() {
        if text.starts_with("```") {
            in_sh = !in_sh && text.trim() == "```sh";
            continue;
        }
        if !in_sh {
            continue;
        }
        let trimmed = text.trim();
        if let Some(answer) = trimmed.strip_prefix("# ")
            && (answer.starts_with('{') || answer.starts_with('['))
            && pending.is_empty()
        {
            if let Some(last) = lines.last_mut() {
                let last: &mut Line = last;
                last.shown = Some(answer.to_owned());
            }
            continue;
        }
        if trimmed.is_empty() || trimmed.starts_with('#') {
            comment = trimmed;
            continue;
        }
        match trimmed.strip_suffix('\\') {
            Some(part) => {
                pending.push_str(part);
                pending.push(' ');
            }
            None => {
                pending.push_str(trimmed);
                let stream = pending.contains("Ctrl-C ends") || comment.contains("Ctrl-C ends");
                lines.push(Line {
                    number: i + 1,
                    command: std::mem::take(&mut pending),
                    shown: None,
                    stream,
                });
                comment = "";
            }
        }
    }
    lines
}

/// The command without its trailing comment.
fn bare(command: &str) -> &str {
    command.split(" #").next().unwrap_or(command).trim()
}

/// The demo started by the README's line, with the addresses it printed.
struct Demo {
    child: Child,
    ports: Vec<(&'static str, u16)>,
    grpc: String,
}

impl Drop for Demo {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn start_demo(line: &str, bin: &Path) -> Demo {
    let args: Vec<&str> = line.split_whitespace().skip(1).collect();
    let mut child = Command::new(bin.join("iogate"))
        .args(&args)
        .current_dir(repo())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("the demo starts");
    let rx = common::printed_lines(&mut child);
    let mut banner = Vec::new();
    while !banner.iter().any(|l: &String| l.starts_with("Health:")) {
        match rx.recv_timeout(Duration::from_secs(60)) {
            Ok(line) => banner.push(line),
            Err(e) => panic!("the demo printed no addresses ({e}): {banner:?}"),
        }
    }
    let port_after = |prefix: &str, marker: &str| -> u16 {
        let line = banner
            .iter()
            .find(|l| l.starts_with(prefix))
            .unwrap_or_else(|| panic!("no {prefix} line in {banner:?}"));
        let rest = &line[line.find(marker).expect("an address") + marker.len()..];
        let digits: String = rest.chars().take_while(char::is_ascii_digit).collect();
        digits.parse().expect("a port")
    };
    let http = port_after("REST API:", "127.0.0.1:");
    let grpc = port_after("gRPC:", "127.0.0.1:");
    let modbus = port_after("Modbus TCP:", "127.0.0.1:");
    let opcua = port_after("OPC UA:", "127.0.0.1:");
    Demo {
        child,
        ports: vec![
            ("8080", http),
            ("50051", grpc),
            ("5020", modbus),
            ("4840", opcua),
        ],
        grpc: format!("http://127.0.0.1:{grpc}"),
    }
}

/// The line with the usual ports replaced by the demo's.
fn on_demo_ports(command: &str, demo: &Demo) -> String {
    let mut out = command.to_owned();
    for (usual, bound) in &demo.ports {
        let mut replaced = String::new();
        let mut rest = out.as_str();
        while let Some(at) = rest.find(usual) {
            let before = rest[..at].chars().last();
            let after = rest[at + usual.len()..].chars().next();
            let whole = !before.is_some_and(|c| c.is_ascii_alphanumeric())
                && !after.is_some_and(|c| c.is_ascii_digit());
            replaced.push_str(&rest[..at]);
            replaced.push_str(&if whole {
                bound.to_string()
            } else {
                usual.to_string()
            });
            rest = &rest[at + usual.len()..];
        }
        replaced.push_str(rest);
        out = replaced;
    }
    out
}

/// Runs a line in the clone's root; a stream is ended after [`STREAM`].
fn run(line: &Line, demo: &Demo, bin: &Path) -> (bool, String, String) {
    let stream = line.stream;
    let command = on_demo_ports(&line.command, demo);
    let path = format!(
        "{}:{}",
        bin.display(),
        std::env::var("PATH").unwrap_or_default()
    );
    let mut shell = match stream {
        true => {
            let mut timeout = Command::new("timeout");
            timeout
                .args(["-k", "2s"])
                .arg(format!("{}s", STREAM.as_secs()))
                .arg("bash");
            timeout
        }
        false => Command::new("bash"),
    };
    let out = shell
        .arg("-c")
        .arg(&command)
        .current_dir(repo())
        .env("PATH", path)
        .env("IOGATE_SERVER", &demo.grpc)
        .stdin(Stdio::null())
        .output()
        .unwrap_or_else(|e| panic!("line {}: {e}", line.number));
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    // A stream ended says so in its status; it must have said something.
    let ok = if stream {
        !stdout.trim().is_empty()
    } else {
        out.status.success()
    };
    (ok, stdout, stderr)
}

/// The answer given is the answer shown: for JSON the same keys, the same values but for
/// times; for text (mbpoll's `[2051]: 65.5`), the shown line among the lines given (spacing
/// aside).
fn same_answer(shown: &str, given: &str) -> Result<(), String> {
    if !shown.starts_with('{') {
        let words = |t: &str| t.split_whitespace().collect::<Vec<_>>().join(" ");
        return match given.lines().any(|l| words(l) == words(shown)) {
            true => Ok(()),
            false => Err(format!(
                "`{shown}` shown, not among the lines given: {given}"
            )),
        };
    }
    let shown: serde_json::Value =
        serde_json::from_str(shown).map_err(|e| format!("the README's answer: {e}"))?;
    let given: serde_json::Value = serde_json::from_str(given.trim())
        .map_err(|e| format!("the answer is not JSON ({e}): {given}"))?;
    let (Some(shown), Some(given)) = (shown.as_object(), given.as_object()) else {
        return Err("not JSON objects".into());
    };
    let keys =
        |o: &serde_json::Map<String, serde_json::Value>| o.keys().cloned().collect::<Vec<_>>();
    if keys(shown) != keys(given) {
        return Err(format!(
            "keys {:?} shown, {:?} given",
            keys(shown),
            keys(given)
        ));
    }
    for (key, value) in shown {
        let time = matches!(key.as_str(), "timestamp" | "requested" | "finished");
        if !time && given.get(key) != Some(value) {
            return Err(format!("{key}: {value} shown, {:?} given", given.get(key)));
        }
    }
    Ok(())
}

/// What the README's commands may leave in the clone: nothing `git status` would show.
fn clone_state() -> Option<String> {
    let out = Command::new("git")
        .args(["status", "--porcelain", "--untracked-files=all"])
        .current_dir(repo())
        .output()
        .ok()?;
    out.status
        .success()
        .then(|| String::from_utf8_lossy(&out.stdout).into_owned())
}

#[test]
fn every_command_line_of_the_readme_runs_as_written() {
    let installed = Command::new("bash")
        .arg(repo().join("tests/serial/install.sh"))
        .status()
        .expect("the installer runs");
    assert!(installed.success(), "tests/serial/install.sh (mbpoll)");
    let iogate = PathBuf::from(env!("CARGO_BIN_EXE_iogate"));
    let bin = iogate.parent().expect("the binaries' directory").to_owned();
    assert!(
        bin.join("iogatectl").is_file(),
        "iogatectl is built beside iogate by `cargo test --workspace`"
    );
    let readme = std::fs::read_to_string(repo().join("README.md")).expect("README.md");
    let lines = command_lines(&readme);
    let starts: Vec<&Line> = lines
        .iter()
        .filter(|l| bare(&l.command).starts_with("iogate serve --http 127.0.0.1:0"))
        .collect();
    assert_eq!(starts.len(), 1, "the README's demo line on free ports");
    let demo = start_demo(bare(&starts[0].command), &bin);
    let before = clone_state();
    let mut failures = Vec::new();
    let mut ran = 0;
    for line in &lines {
        let command = bare(&line.command);
        if SET_UP.contains(&command) || std::ptr::eq(line, starts[0]) {
            continue;
        }
        ran += 1;
        eprintln!("line {}: {}", line.number, line.command);
        let (ok, stdout, stderr) = run(line, &demo, &bin);
        if !ok {
            failures.push(format!(
                "line {}: `{}` failed: {stdout}{stderr}",
                line.number, line.command
            ));
            continue;
        }
        if let Some(shown) = &line.shown
            && let Err(e) = same_answer(shown, &stdout)
        {
            failures.push(format!("line {}: `{}`: {e}", line.number, line.command));
        }
    }
    assert!(ran >= 20, "{ran} lines run: {lines:?}");
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    assert_eq!(
        clone_state(),
        before,
        "the README's commands leave the clone as it was"
    );
}

#[test]
fn the_readme_shows_the_set_up_lines_it_is_not_run_for() {
    let readme = std::fs::read_to_string(repo().join("README.md")).expect("README.md");
    let lines = command_lines(&readme);
    for set_up in SET_UP {
        assert!(
            lines.iter().any(|l| bare(&l.command) == *set_up),
            "the README shows `{set_up}`"
        );
    }
}

//! `iogate profile import` as a user runs it on a library that keeps deprecated templates
//! beside their successors.

use std::path::{Path, PathBuf};
use std::process::Command;

fn template(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../tests/fixtures/import/wb")
        .join(name)
}

#[test]
fn the_current_template_is_written_whatever_the_order_and_the_deprecated_one_is_named() {
    let out = std::env::temp_dir().join(format!("iogate-import-cli-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    // File names sort the deprecated one first, as a shell's `*.json` gives them.
    let output = Command::new(env!("CARGO_BIN_EXE_iogate"))
        .args(["profile", "import", "--out"])
        .arg(&out)
        .arg(template("config-onokom-air-aux-1-mb-b-depricated.json"))
        .arg(template("config-onokom-air-aux-1-mb-b.json"))
        .output()
        .expect("iogate runs");
    let report = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(0), "{report}");
    assert!(
        report.contains("is a deprecated template: not written")
            && report.contains("config-onokom-air-aux-1-mb-b.json is its current one"),
        "{report}"
    );
    let written = std::fs::read_to_string(out.join("onokom_air_aux_1_mb_b.yaml")).expect("profile");
    let fields = written.lines().filter(|l| l.starts_with("  - {")).count();
    assert_eq!(fields, 124, "the current template's fields:\n{written}");
    std::fs::remove_dir_all(&out).expect("cleanup");
}

#[test]
fn the_sources_options_are_checked_before_anything_is_asked() {
    for (args, says) in [
        (
            &["--from", "eip", "--path", "1,x", "127.0.0.1"][..],
            "is not an address",
        ),
        (&["--from", "eip", "a", "b"][..], "give one controller"),
        (&["--from", "eip", "--node", "x", "a"][..], "no --node"),
        (&["--path", "1,0", "x.json"][..], "--path is for --from eip"),
    ] {
        let output = Command::new(env!("CARGO_BIN_EXE_iogate"))
            .args(["profile", "import"])
            .args(args)
            .output()
            .expect("iogate runs");
        let report = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(64), "{args:?}: {report}");
        assert!(report.contains(says), "{args:?}: {report}");
    }
}

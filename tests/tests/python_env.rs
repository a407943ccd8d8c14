//! The tests' own Python: every peer at the version `tests/python/requirements.txt` pins,
//! in `tests/.venv`, whatever the user's own Python holds.

use iogate_tests::{python, repo_file};

#[test]
fn the_python_peers_are_the_pinned_ones_in_the_tests_own_environment() {
    let python = python();
    let venv = repo_file(".venv");
    assert!(
        python.starts_with(&venv),
        "{} is not in {}",
        python.display(),
        venv.display()
    );
    let out = std::process::Command::new(&python)
        .args(["-m", "pip", "freeze", "--disable-pip-version-check"])
        .output()
        .expect("pip freeze");
    assert!(out.status.success(), "pip freeze failed");
    let have: Vec<String> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| l.to_ascii_lowercase())
        .collect();
    let pinned = std::fs::read_to_string(repo_file("python/requirements.txt")).expect("read");
    for want in pinned
        .lines()
        .filter(|l| !l.starts_with('#') && !l.is_empty())
    {
        let want = want.to_ascii_lowercase();
        assert!(
            have.contains(&want),
            "{want} missing from tests/.venv: {have:?}"
        );
    }
    // The environment does not see the user's own packages.
    let isolated = std::process::Command::new(&python)
        .args(["-c", "import sys; print(sys.prefix != sys.base_prefix)"])
        .output()
        .expect("python");
    assert_eq!(String::from_utf8_lossy(&isolated.stdout).trim(), "True");
}

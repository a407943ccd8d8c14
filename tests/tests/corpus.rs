//! Every broken profile and config in `fixtures/` is rejected with exactly the problems its
//! `# expect: [FILE:]LINE: TEXT` comments name, each at its line (`\n` in TEXT is a line
//! break).

use std::path::{Path, PathBuf};

use iogate::app::Setup;
use iogate::yaml::Problems;
use iogate_tests::fixtures_dir;

struct Expectation {
    file: Option<String>,
    line: u64,
    text: String,
}

fn expectations(path: &Path) -> Vec<Expectation> {
    let text = std::fs::read_to_string(path).expect("fixture readable");
    text.lines()
        .filter_map(|l| l.strip_prefix("# expect: "))
        .map(|rest| {
            let (head, text) = rest.split_once(": ").expect("`# expect: LINE: TEXT`");
            let (file, line) = match head.rsplit_once(':') {
                Some((file, line)) => (Some(file.to_owned()), line),
                None => (None, head),
            };
            Expectation {
                file,
                line: line.parse().expect("line number"),
                text: text.replace("\\n", "\n"),
            }
        })
        .collect()
}

fn yaml_files(dir: &str) -> Vec<PathBuf> {
    let mut files: Vec<_> = std::fs::read_dir(fixtures_dir().join(dir))
        .expect("fixture dir")
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "yaml"))
        .collect();
    files.sort();
    assert!(!files.is_empty());
    files
}

fn check(path: &Path, problems: &Problems) {
    let expected = expectations(path);
    assert!(
        !expected.is_empty(),
        "{} has no expectations",
        path.display()
    );
    let own_name = path.file_name().and_then(|n| n.to_str()).expect("name");
    for e in &expected {
        let file = e.file.as_deref().unwrap_or(own_name);
        let found = problems
            .iter()
            .any(|p| p.file.ends_with(file) && p.line == e.line && p.to_string().contains(&e.text));
        assert!(
            found,
            "{}: expected a problem at {file}:{} containing {:?}; got:\n{problems}",
            path.display(),
            e.line,
            e.text
        );
    }
    if expected.iter().all(|e| e.file.is_none()) {
        assert_eq!(
            problems.len(),
            expected.len(),
            "{}: every problem must be expected; got:\n{problems}",
            path.display()
        );
    }
}

#[test]
fn every_broken_profile_names_its_problems_and_lines() {
    for path in yaml_files("bad_profiles") {
        let text = std::fs::read_to_string(&path).expect("readable");
        let name = path.display().to_string();
        iogate::drivers::register();
        match iogate::profile::load_str(&name, &text) {
            Ok(p) => panic!("{name} loaded as {}", p.name),
            Err(problems) => check(&path, &problems),
        }
    }
}

#[test]
fn every_broken_config_names_its_problems_and_lines() {
    for path in yaml_files("bad_configs") {
        match Setup::from_file(&path) {
            Ok(_) => panic!("{} was accepted", path.display()),
            Err(problems) => check(&path, &problems),
        }
    }
}

#[test]
fn a_directory_with_one_broken_profile_loads_nothing() {
    iogate::drivers::register();
    let problems = iogate::profile::load_dir(&fixtures_dir().join("bad_profiles"))
        .expect_err("broken profiles");
    let files: std::collections::BTreeSet<_> = problems.iter().map(|p| p.file.clone()).collect();
    assert_eq!(
        files.len(),
        yaml_files("bad_profiles").len(),
        "every file is reported"
    );
}

#[test]
fn every_shipped_profile_loads() {
    iogate::drivers::register();
    let profiles =
        iogate::profile::load_dir(&iogate_tests::profiles_dir()).expect("profiles/ is valid");
    let names: Vec<_> = profiles.iter().map(|p| p.name.as_str()).collect();
    for expected in [
        "WaveshareAnalogInput",
        "MyIoModule",
        "EastronSDM630",
        "GenericVfd",
        "SimIo",
        "SimPlant",
    ] {
        assert!(
            names.contains(&expected),
            "{expected} missing from {names:?}"
        );
    }
}

#[test]
fn the_example_configs_are_valid() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples");
    for entry in std::fs::read_dir(&dir).expect("examples/") {
        let path = entry.expect("entry").path();
        if path.extension().is_some_and(|e| e == "yaml")
            && let Err(problems) = Setup::from_file(&path)
        {
            panic!("{}:\n{problems}", path.display());
        }
    }
}

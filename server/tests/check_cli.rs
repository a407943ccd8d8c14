//! `iogate check` on a config outside the repository with three mistakes: each is named,
//! none hides another.

mod common;

#[test]
fn three_mistakes_are_three_problems_with_or_without_a_profiles_directory() {
    let dir = std::env::temp_dir().join(format!("iogate-check-three-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("dir");
    let body = "links:\n  - { name: bus, tcp: { host: 127.0.0.1, port: 1502 } }\ndevices:\n  - { name: io, profile: myiomodule, link: bus, slave_id: 1, refresh_rat: 100ms }\n  - { name: io2, profile: MyIoModule, link: nolink, slave_id: 2 }\n";
    let run = |text: &str| common::check_text(&dir, "iogate", text);
    // No profiles directory anywhere above it: said once, and the rest still checked.
    let (code, text) = run(body);
    assert_eq!(code, Some(64), "{text}");
    for line in [
        "profiles: no profiles directory found",
        "iogate.yaml:4: device io: unknown key `refresh_rat`",
        "iogate.yaml:5: device io2: unknown link `nolink` (known: bus)",
    ] {
        assert!(text.contains(line), "missing {line:?} in:\n{text}");
    }
    // With the profiles: the profile name in the wrong case is the third.
    let profiles = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../profiles");
    let (code, text) = run(&format!("profiles: {}\n{body}", profiles.display()));
    assert_eq!(code, Some(64), "{text}");
    for line in [
        "iogate.yaml:5: device io: unknown key `refresh_rat`",
        "iogate.yaml:5: device io: unknown profile `myiomodule`: profile names are case-sensitive, did you mean `MyIoModule`?",
        "iogate.yaml:6: device io2: unknown link `nolink` (known: bus)",
        "3 problems found",
    ] {
        assert!(text.contains(line), "missing {line:?} in:\n{text}");
    }
    std::fs::remove_dir_all(&dir).expect("cleanup");
}

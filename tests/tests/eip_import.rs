//! `iogate profile import --from eip` against a controller's tag directory
//! (`tests/eip/directory_plc.py`), with pylogix's GetTagList (another implementation) as
//! the check of what the directory holds: controller and program tags, listed a page at a
//! time; arrays made elements; structures (read from their templates) made their atomic
//! members, nested ones and arrays of them included; strings made STRING fields; hidden,
//! system and module tags, BOOL arrays and names `tag:` does not take reported; a
//! controller whose pages never end is an error, not a loop.

use std::path::{Path, PathBuf};

use iogate_tests::devices::temp_dir;
use iogate_tests::eip::LogixPlc;

/// Runs the import into `out`; its exit code.
async fn import(target: String, out: PathBuf) -> u8 {
    tokio::task::spawn_blocking(move || {
        iogate::drivers::eip::import::run(&target, None, Some(&out))
    })
    .await
    .unwrap_or(255)
}

/// The written profile's `(tag, type)` of each field.
fn fields(dir: &Path, port: u16) -> Vec<(String, String)> {
    let text = std::fs::read_to_string(dir.join(format!("Logix_127_0_0_1_{port}.yaml")))
        .unwrap_or_default();
    text.lines()
        .filter_map(|l| {
            let ty = l.split("type: ").nth(1)?.split(',').next()?;
            let tag = l.split("tag: \"").nth(1)?.split('"').next()?;
            Some((tag.to_owned(), ty.to_owned()))
        })
        .collect()
}

fn has(fields: &[(String, String)], tag: &str, ty: &str) -> bool {
    fields.iter().any(|(t, y)| t == tag && y == ty)
}

#[tokio::test]
async fn a_controllers_tags_become_a_profile_of_their_atomic_values() {
    let plc = LogixPlc::directory(&["--extra", "60"])
        .await
        .expect("controller");
    let listed = plc.tag_list().await.expect("pylogix");
    let dir = temp_dir("eip-import");
    let code = import(format!("127.0.0.1:{}", plc.port), dir.clone()).await;
    assert_eq!(code, 0);
    let made = fields(&dir, plc.port);
    // Every atomic tag pylogix lists is a field of the same type; arrays are elements.
    let tags = listed["tags"].as_array().cloned().unwrap_or_default();
    let mut atomic = 0;
    for t in &tags {
        let (name, ty) = (
            t["name"].as_str().unwrap_or(""),
            t["type"].as_str().unwrap_or(""),
        );
        if t["struct"] == true
            || name.contains("Program:Main") && !name.contains('.')
            || name == "Bad Name"
        {
            continue;
        }
        if ["REAL", "DINT", "INT", "BOOL", "LINT", "LREAL", "UINT"].contains(&ty) {
            atomic += 1;
            let tag = match t["size"].as_u64() {
                Some(n) if n > 0 => format!("{name}[0]"),
                _ => name.to_owned(),
            };
            let tag = if name == "Grid" {
                "Grid[0,0]".to_owned()
            } else {
                tag
            };
            assert!(has(&made, &tag, ty), "{tag} {ty}: {made:?}");
        }
    }
    assert!(atomic >= 66, "{listed}");
    // Every page was read: the last of the 60 extra tags.
    assert!(has(&made, "Extra59", "DINT"));
    assert!(has(&made, "Counts[4]", "DINT") && has(&made, "Grid[1,1]", "INT"));
    // Structures, by the members pylogix reads from the same templates.
    let motor = listed["udts"]["MOTOR"]
        .as_array()
        .cloned()
        .unwrap_or_default();
    assert!(
        motor.iter().any(|m| m[0] == "Speed" && m[1] == "REAL"),
        "{listed}"
    );
    for (tag, ty) in [
        ("M1.Speed", "REAL"),
        ("M1.Status.Running", "BOOL"),
        ("M1.Status.Code", "INT"),
        ("M1.Hist[2]", "INT"),
        ("M1.Label", "STRING"),
        ("M1.Enabled", "BOOL"),
        ("Name", "STRING"),
        ("Program:Main.Level", "UINT"),
        ("Program:Main.Motors[1].Status.Faulted", "BOOL"),
    ] {
        assert!(has(&made, tag, ty), "{tag} {ty}: {made:?}");
    }
    // A name `tag:` does not take is reported, not written (the profile still loads).
    assert!(!made.iter().any(|(t, _)| t.contains("Bad")), "{made:?}");
    // Hidden members, hidden and module tags, and BOOL arrays are not fields.
    assert!(
        !made.iter().any(|(t, _)| t.contains("ZZZZ")
            || t.contains("__")
            || t.starts_with("Map:")
            || t.starts_with("Bits")),
        "{made:?}"
    );
    plc.kill().await.expect("kill");
}

#[tokio::test]
async fn a_controller_whose_pages_never_end_one_without_a_directory_and_one_not_there_are_errors() {
    let plc = LogixPlc::directory(&["--stuck"]).await.expect("controller");
    let dir = temp_dir("eip-import-stuck");
    let code = tokio::time::timeout(
        std::time::Duration::from_secs(30),
        import(format!("127.0.0.1:{}", plc.port), dir.clone()),
    )
    .await
    .expect("the import ends");
    assert_eq!(code, 1);
    assert!(fields(&dir, plc.port).is_empty());
    let port = plc.port;
    plc.kill().await.expect("kill");
    // cpppo's simulator has no tag directory: an error, no profile.
    let cpppo = LogixPlc::start(None, &["Speed=REAL"]).await.expect("cpppo");
    assert_eq!(
        import(format!("127.0.0.1:{}", cpppo.port), dir.clone()).await,
        1
    );
    assert!(fields(&dir, cpppo.port).is_empty());
    cpppo.kill().await.expect("kill");
    // Nothing listens there now; a port that is not one is a bad argument.
    assert_eq!(import(format!("127.0.0.1:{port}"), dir.clone()).await, 1);
    assert_eq!(import("127.0.0.1:nope".to_owned(), dir).await, 64);
}

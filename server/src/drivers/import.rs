//! `iogate profile import`: files (wb-mqtt-serial templates, EdgeX profiles), or a live
//! device through the driver whose import `--from` names (an OPC UA server, a Logix
//! controller); each option checked against the import it is for.

use std::path::{Path, PathBuf};

use super::{Driver, ForDriver, IMPORTS, ImportOptions, for_import};

/// Runs the import; its exit code (64: a bad argument).
pub fn run(
    from: Option<&str>,
    options: &ImportOptions<'_>,
    out: Option<&Path>,
    files: &[PathBuf],
) -> u8 {
    let bad = |why: &str| {
        eprintln!("iogate profile import{why}");
        crate::EXIT_CONFIG as u8
    };
    let chosen = IMPORTS.iter().flatten().find(|i| Some(i.from) == from);
    for (flag, _) in options {
        match chosen {
            Some(i) if i.options.contains(flag) => {}
            Some(i) => {
                return bad(&format!(
                    " --from {}: give {} (no {flag})",
                    i.from, i.source
                ));
            }
            None => {
                let owner = IMPORTS.iter().flatten().find(|i| i.options.contains(flag));
                return bad(&match owner {
                    Some(i) => format!(": {flag} is for --from {}", i.from),
                    None => format!(": {flag} is for no import"),
                });
            }
        }
    }
    let Some(import) = chosen else {
        return crate::profile::import::run(files, from, out);
    };
    let [source] = files else {
        return bad(&format!(" --from {}: give {}", import.from, import.source));
    };
    struct Run<'a>(&'a str, &'a ImportOptions<'a>, Option<&'a Path>);
    impl ForDriver for Run<'_> {
        type Output = u8;
        fn with<D: Driver>(self) -> u8 {
            D::import(self.0, self.1, self.2)
        }
    }
    let source = source.to_string_lossy();
    for_import(import.from, Run(&source, options, out)).unwrap_or(crate::EXIT_CONFIG as u8)
}

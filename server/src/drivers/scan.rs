//! `iogate scan --from PROTOCOL`: finding the devices of a network of another protocol than
//! a serial line's (a BACnet Who-Is), through the driver whose scan `--from` names; each
//! option checked against the scan it is for.

use super::{Driver, ForDriver, ImportOptions, SCANS, for_scan};

/// Runs the scan; its exit code (64: a bad argument).
pub fn run(from: &str, options: &ImportOptions<'_>, json: bool) -> u8 {
    let bad = |why: String| {
        eprintln!("iogate scan{why}");
        crate::EXIT_CONFIG as u8
    };
    let Some(scan) = SCANS.iter().flatten().find(|s| s.from == from) else {
        let known: Vec<&str> = SCANS.iter().flatten().map(|s| s.from).collect();
        return bad(format!(
            " --from {from}: no such network to scan (one of: {})",
            known.join(", ")
        ));
    };
    if let Some((flag, _)) = options.iter().find(|(f, _)| !scan.options.contains(f)) {
        return bad(format!(" --from {from}: {flag} is not one of its options"));
    }
    struct Run<'a>(&'a ImportOptions<'a>, bool);
    impl ForDriver for Run<'_> {
        type Output = u8;
        fn with<D: Driver>(self) -> u8 {
            D::scan(self.0, self.1)
        }
    }
    for_scan(from, Run(options, json)).unwrap_or(crate::EXIT_CONFIG as u8)
}

//! `iogate profile import`: files (wb-mqtt-serial templates, EdgeX profiles), an OPC UA
//! server (`--from opcua URL [--node ROOT]`) or a Logix controller (`--from eip
//! HOST[:PORT] [--path ROUTE]`); each option checked against the source it is for.

use std::path::{Path, PathBuf};

/// Runs the import; its exit code (64: a bad argument).
pub fn run(
    from: Option<&str>,
    (node, path): (Option<&str>, Option<&str>),
    out: Option<&Path>,
    files: &[PathBuf],
) -> u8 {
    let bad = |why: &str| {
        eprintln!("iogate profile import{why}");
        crate::EXIT_CONFIG as u8
    };
    if path.is_some() && from != Some("eip") {
        return bad(": --path is for --from eip");
    }
    match from {
        Some("eip") => match (files, node) {
            ([host], None) => super::eip::import::run(&host.to_string_lossy(), path, out),
            _ => bad(" --from eip: give one controller, HOST or HOST:PORT (no --node)"),
        },
        Some("opcua") => match files {
            [url] => super::opcua::import::run(&url.to_string_lossy(), node, out),
            _ => bad(" --from opcua: give one endpoint URL"),
        },
        _ if node.is_some() => bad(": --node is for --from opcua"),
        _ => crate::profile::import::run(files, from, out),
    }
}

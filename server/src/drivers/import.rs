//! `iogate profile import`: files (wb-mqtt-serial templates, EdgeX profiles), or a live
//! device through the driver whose import `--from` names (an OPC UA server, a Logix
//! controller); each option checked against the import it is for.

use std::path::{Path, PathBuf};

use super::{Driver, ForDriver, IMPORTS, ImportOptions, for_import};

/// `iogate profile import`'s options, as given.
#[derive(Debug, clap::Args)]
pub struct Options {
    /// The source format; default: by the file name (.json wb, .yaml/.yml edgex); `opcua`
    /// takes a server's endpoint URL instead of files, `eip` a controller's HOST[:PORT],
    /// `bacnet` a device's HOST[:PORT] or its device instance.
    #[arg(long)]
    pub from: Option<String>,
    /// With `--from opcua`: the node to browse from (default: the Objects folder).
    #[arg(long)]
    pub node: Option<String>,
    /// With `--from eip`: the route to the controller (default: 1,0, the backplane's
    /// slot 0).
    #[arg(long)]
    pub path: Option<String>,
    /// With `--from bacnet`: the address the import's own BACnet/IP port is bound to
    /// (default 0.0.0.0:47808 for a device instance, a port of its own for an address).
    #[arg(long)]
    pub on: Option<String>,
    /// With `--from bacnet`: where the Who-Is goes (default 255.255.255.255).
    #[arg(long)]
    pub broadcast: Option<String>,
    /// With `--from bacnet`: a BBMD to register with as a foreign device.
    #[arg(long)]
    pub bbmd: Option<String>,
    /// Where to write the profiles (one file each); default: standard output.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// The files to convert.
    #[arg(required = true)]
    pub files: Vec<PathBuf>,
}

/// Runs the import the command line asks for; its exit code.
pub fn run_cli(o: &Options) -> u8 {
    let options: Vec<(&'static str, &str)> = [
        ("--node", &o.node),
        ("--path", &o.path),
        ("--on", &o.on),
        ("--broadcast", &o.broadcast),
        ("--bbmd", &o.bbmd),
    ]
    .into_iter()
    .filter_map(|(flag, v)| Some((flag, v.as_deref()?)))
    .collect();
    run(o.from.as_deref(), &options, o.out.as_deref(), &o.files)
}

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

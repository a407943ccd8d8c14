//! `iogate scan --port PORT`: a whole line scanned from the command line, progress on the
//! terminal (standard error), the result on standard output (text or `--json`).

use std::io::{IsTerminal, Write};
use std::path::Path;
use std::sync::Arc;

use tokio_util::sync::CancellationToken;

use super::port::PortProber;
use super::report::{Summary, device_line};
use super::{Plan, Progress};
use crate::profile::Profile;

/// The command line's options, as given.
#[derive(Debug, clap::Args)]
pub struct Options {
    /// The serial port (nothing else may have it open).
    #[arg(long, required_unless_present = "from")]
    pub port: Option<String>,
    /// A network of another protocol to scan instead of a serial line: `bacnet` (a Who-Is).
    #[arg(long, conflicts_with = "port")]
    pub from: Option<String>,
    /// With `--from bacnet`: the address the scan's own port is bound to (`HOST[:PORT]`,
    /// default 0.0.0.0:47808).
    #[arg(long)]
    pub on: Option<String>,
    /// With `--from bacnet`: where the Who-Is goes (default 255.255.255.255).
    #[arg(long)]
    pub broadcast: Option<String>,
    /// With `--from bacnet`: a BBMD to register with as a foreign device (`HOST[:PORT]`).
    #[arg(long)]
    pub bbmd: Option<String>,
    /// With `--from bacnet`: how long to listen for the devices' answers (default 3s).
    #[arg(long)]
    pub wait: Option<String>,
    /// Baud rates to try, in this order; default 115200,57600,38400,19200,9600.
    #[arg(long)]
    pub baud: Option<String>,
    /// Parities to try (N, E, O); default N,E.
    #[arg(long)]
    pub parity: Option<String>,
    /// Slave ids to try: ranges and single ids, `1-247`, `1,5,10-20`.
    #[arg(long, default_value = "1-247")]
    pub ids: String,
    /// One probe's time slot: the silence, the request and the answer.
    #[arg(long, default_value = "50ms")]
    pub timeout: String,
    /// The profiles to match devices against; default: ./profiles or a parent's.
    #[arg(long)]
    pub profiles: Option<std::path::PathBuf>,
    /// Print the result as JSON.
    #[arg(long)]
    pub json: bool,
}

/// The plan the options describe, or what is wrong with them.
pub fn plan(options: &Options) -> Result<Plan, String> {
    let bauds = match &options.baud {
        Some(text) => super::parse_bauds(text)?,
        None => super::DEFAULT_BAUDS.to_vec(),
    };
    let parities = match &options.parity {
        Some(text) => super::parse_parities(text)?,
        None => super::DEFAULT_PARITIES.to_vec(),
    };
    let timeout = crate::duration::parse(&options.timeout)
        .map_err(|e| format!("--timeout `{}`: {e}", options.timeout))?;
    let plan = Plan {
        settings: super::settings(&bauds, &parities),
        ids: super::parse_ids(&options.ids)?,
        timeout,
    };
    plan.check()?;
    Ok(plan)
}

/// The profiles to match: `--profiles DIR`, else `profiles/` here or in a parent; problems
/// are warnings (the profiles that load are used).
fn profiles(dir: Option<&Path>) -> Vec<Arc<Profile>> {
    let here = Path::new(".");
    let Some(dir) = crate::profile::find_dir(dir, here) else {
        eprintln!("no profiles directory found (--profiles DIR): devices are not matched");
        return Vec::new();
    };
    let (catalog, problems) = crate::profile::load_catalog_partial(&dir);
    for problem in problems.iter() {
        eprintln!("warning: {problem}");
    }
    catalog.iter().cloned().collect()
}

/// Runs the scan; the process's exit code: 0 done, 64 bad options, 1 the port failed.
pub fn run(options: &Options) -> u8 {
    if let Some(from) = &options.from {
        let given: Vec<(&'static str, &str)> = [
            ("--on", &options.on),
            ("--broadcast", &options.broadcast),
            ("--bbmd", &options.bbmd),
            ("--wait", &options.wait),
        ]
        .into_iter()
        .filter_map(|(flag, v)| Some((flag, v.as_deref()?)))
        .collect();
        return crate::drivers::scan::run(from, &given, options.json);
    }
    let Some(port) = options.port.as_deref() else {
        eprintln!("iogate scan: give --port (a serial line) or --from (another network)");
        return crate::EXIT_CONFIG as u8;
    };
    let plan = match plan(options) {
        Ok(plan) => plan,
        Err(e) => {
            eprintln!("iogate scan: {e}");
            return crate::EXIT_CONFIG as u8;
        }
    };
    let profiles = profiles(options.profiles.as_deref());
    let runtime = match tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("cannot start the runtime: {e}");
            return 1;
        }
    };
    eprintln!(
        "scanning {}: {} setting{} x {} ids ({}), a {} ms slot each: at most {:.1} s, plus a few probes for each device found",
        port,
        plan.settings.len(),
        if plan.settings.len() == 1 { "" } else { "s" },
        plan.ids.len(),
        super::report::ranges(&plan.ids),
        plan.timeout.as_millis(),
        plan.estimate().as_secs_f64()
    );
    let terminal = std::io::stderr().is_terminal();
    let started = std::time::Instant::now();
    let mut on_progress = |p: Progress| progress(p, terminal);
    let cancel = CancellationToken::new();
    let mut prober = PortProber::new(port, plan.timeout);
    let scanned = runtime.block_on(async {
        let cancel_on_ctrl_c = cancel.clone();
        let watch = tokio::spawn(async move {
            if tokio::signal::ctrl_c().await.is_ok() {
                cancel_on_ctrl_c.cancel();
            }
        });
        let result = super::run(&mut prober, &plan, &profiles, &mut on_progress, &cancel).await;
        watch.abort();
        result
    });
    if terminal {
        eprint!("\r\x1b[K");
    }
    let scanned = match scanned {
        Ok(scanned) => scanned,
        Err(e) => {
            eprintln!("iogate scan: {e}");
            return 1;
        }
    };
    let found = scanned.devices.len();
    eprintln!(
        "{found} device{} found in {:.1} s",
        if found == 1 { "" } else { "s" },
        started.elapsed().as_secs_f64()
    );
    let summary = Summary::new(&plan, scanned, Some(port), "line");
    print_summary(&summary, options.json)
}

/// A scan's progress on standard error: a line per setting and device found, the probes
/// counted on a terminal.
fn progress(p: Progress, terminal: bool) {
    match p {
        Progress::Setting { setting, index, of } => {
            if terminal {
                eprint!("\r\x1b[K");
            }
            eprintln!("{} ({} of {of})", setting.label(), index + 1);
        }
        Progress::Tried { done, total } if terminal => {
            eprint!("\r\x1b[K  {done} of {total} probed");
            let _ = std::io::stderr().flush();
        }
        Progress::Tried { .. } => {}
        Progress::Found(device) => {
            if terminal {
                eprint!("\r\x1b[K");
            }
            eprintln!("{}", device_line(&device));
        }
    }
}

/// What was found, on standard output: as JSON, or a line per device and the config
/// entries to paste; the exit code.
fn print_summary(summary: &Summary, json: bool) -> u8 {
    if json {
        match serde_json::to_string_pretty(summary) {
            Ok(text) => println!("{text}"),
            Err(e) => {
                eprintln!("{e}");
                return 1;
            }
        }
    } else if summary.devices.is_empty() && summary.strangers.is_empty() {
        println!("no device answered");
    } else {
        if summary.devices.is_empty() {
            println!("no device answered as the id asked");
        }
        for d in &summary.devices {
            println!("{}", device_line(d));
        }
        for s in &summary.strangers {
            println!("{}", super::report::stranger_line(s));
        }
        if !summary.devices.is_empty() {
            println!("\n# for iogate.yaml:\n{}", summary.config);
        }
    }
    0
}

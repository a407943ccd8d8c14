//! The `iogate` command: `serve` runs the gateway, `check` validates its configuration,
//! `plan` prints the poll plan of its links, `map` the Modbus TCP server's map.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// jemalloc, with its background thread returning freed pages to the system within seconds
/// (configured at build time in `.cargo/config.toml`):
/// the gateway's resident size comes back near its start after thousands of clients leave
/// (`cargo bench -p iogate --bench load`).
#[global_allocator]
static ALLOCATOR: tikv_jemallocator::Jemalloc = tikv_jemallocator::Jemalloc;
use iogate::app::{self, Setup};

#[derive(Parser)]
#[command(name = "iogate", version, about = "I/O gateway for industrial devices")]
struct Cli {
    /// Log lines as text (control characters escaped) or as JSON objects for log collectors.
    #[arg(
        long,
        global = true,
        env = "IOGATE_LOG_FORMAT",
        value_enum,
        default_value_t
    )]
    log_format: iogate::logging::LogFormat,
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Subcommand)]
enum Command {
    /// Run the gateway (the built-in demo when no config is given or found).
    Serve {
        /// The config file; default: ./iogate.yaml, else the built-in demo.
        #[arg(long, short)]
        config: Option<PathBuf>,
        #[command(flatten)]
        listen: ListenArgs,
    },
    /// Check the config and profiles; print every problem and exit 64 if there is any.
    /// With --diff, also print what a reload would change, applying nothing.
    Check {
        /// The config file; default: ./iogate.yaml, else the built-in demo.
        #[arg(long, short)]
        config: Option<PathBuf>,
        /// Print the report a reload of the config would give: the running gateway's dry
        /// run (at the config's listen.http, or --server), or a comparison with --against.
        #[arg(long)]
        diff: bool,
        /// Compare with this file (as if it were running) instead of asking the gateway.
        #[arg(long, requires = "diff")]
        against: Option<PathBuf>,
        /// The running gateway's URL; default: from the config's listen.http.
        #[arg(long, requires = "diff", conflicts_with = "against")]
        server: Option<String>,
        /// A bearer token with the admin role, for a gateway that asks for one.
        #[arg(long, env = "IOGATE_TOKEN", hide_env_values = true, requires = "diff")]
        token: Option<String>,
        /// Print the report as JSON (the reload call's `report`).
        #[arg(long, requires = "diff")]
        json: bool,
    },
    /// Print each link's poll plan: transactions per cycle, wire time, bus utilisation.
    Plan {
        /// The config file; default: ./iogate.yaml, else the built-in demo.
        #[arg(long, short)]
        config: Option<PathBuf>,
    },
    /// Print the Modbus TCP server's map: located address, table and address, field, type
    /// (`--iec104`: the IEC 104 outstation's, one line per point: IOA ASDU device.field).
    Map {
        /// The config file; default: ./iogate.yaml, else the built-in demo.
        #[arg(long, short)]
        config: Option<PathBuf>,
        /// Print a VAR_GLOBAL block of AT declarations for a remote runtime instead.
        #[arg(long, conflicts_with = "iec104")]
        st: bool,
        /// Print the IEC 104 outstation's information objects instead.
        #[arg(long)]
        iec104: bool,
    },
    /// Function blocks: `iogate fb st` prints the ST declarations of ModbusRead and
    /// ModbusWrite, the raw-transaction blocks of the client crate.
    Fb {
        #[command(subcommand)]
        command: FbCommand,
    },
    /// Find the devices on a serial line: every slave id at each baud rate and parity, what
    /// answers, its identification (FC 43), collisions, the profiles that fit, and ready
    /// `links:` and `devices:` entries. Progress on standard error.
    Scan(iogate::scan::cli::Options),
    /// Profiles: `iogate profile st NAME` prints a profile's ST function-block declaration.
    Profile {
        #[command(subcommand)]
        command: ProfileCommand,
    },
}

#[derive(Subcommand)]
enum FbCommand {
    /// Print the ST declarations of the ModbusRead and ModbusWrite blocks.
    St,
}

#[derive(Subcommand)]
enum ProfileCommand {
    /// Convert wb-mqtt-serial device templates (JSON) and EdgeX device profiles (YAML) into
    /// iogate profiles, browse an OPC UA server (`--from opcua opc.tcp://HOST:PORT`) or list
    /// a Logix controller's tags (`--from eip HOST[:PORT]`) for one; what cannot be mapped
    /// is reported with its source line, node or tag.
    Import(iogate::drivers::import::Options),
    /// Print the profile's function block as an IEC 61131-3 ST declaration.
    St {
        /// The profile name.
        name: String,
        /// The config file whose profiles to use; default: ./iogate.yaml, else the demo's.
        #[arg(long, short)]
        config: Option<PathBuf>,
    },
}

/// `iogate check --diff`'s options.
struct DiffOptions {
    against: Option<PathBuf>,
    server: Option<String>,
    token: Option<String>,
    json: bool,
}

enum Action {
    Serve(ListenArgs),
    Check,
    Diff(DiffOptions),
    Plan,
    Map { st: bool },
    MapIec104(Option<PathBuf>),
    St(String),
}

/// What is logged when `RUST_LOG` is unset: the gateway's information, and only warnings
/// and errors of the OPC UA library (its information is a start-up inventory).
/// The OPC UA library's own lines: warnings and errors, less those the client driver tells
/// itself (a failed connection, in the link's state and the log) or that are no fault (no
/// application certificate on a link without security).
const DEFAULT_LOG: &str = "info,opcua_server=warn,opcua_core=warn,opcua_crypto=warn,opcua_nodes=warn,opcua_types=warn,opcua_client=error,opcua_client::session::client=off,opcua_client::transport=off,opcua_crypto::certificate_store=off";

/// The log filter from `RUST_LOG` ([`DEFAULT_LOG`] when unset). A filter that does not
/// parse is a configuration error, not a silent fallback.
fn log_filter() -> Result<tracing_subscriber::EnvFilter, String> {
    use tracing_subscriber::EnvFilter;
    match std::env::var("RUST_LOG") {
        Ok(text) if !text.trim().is_empty() => EnvFilter::builder()
            .parse(&text)
            .map_err(|e| format!("RUST_LOG `{text}` is not a log filter: {e}")),
        Ok(_) | Err(std::env::VarError::NotPresent) => Ok(EnvFilter::new(DEFAULT_LOG)),
        Err(std::env::VarError::NotUnicode(_)) => Err("RUST_LOG is not valid UTF-8".to_owned()),
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    iogate::drivers::register();
    let filter = match log_filter() {
        Ok(filter) => filter,
        Err(message) => {
            eprintln!("iogate: {message}");
            return ExitCode::from(iogate::EXIT_CONFIG as u8);
        }
    };
    iogate::logging::init(cli.log_format, filter);
    if let Some(Command::Fb {
        command: FbCommand::St,
    }) = cli.command
    {
        print!("{}", iogate::transaction::st::declarations());
        return ExitCode::SUCCESS;
    }
    if let Some(Command::Scan(options)) = &cli.command {
        return ExitCode::from(iogate::scan::cli::run(options));
    }
    if let Some(Command::Profile {
        command: ProfileCommand::Import(options),
    }) = &cli.command
    {
        return ExitCode::from(iogate::drivers::import::run_cli(options));
    }
    let Some((config, action)) = action_of(cli.command) else {
        return ExitCode::SUCCESS;
    };
    let setup = match Setup::load(config.as_deref()) {
        Ok(setup) => setup,
        Err(problems) => {
            eprintln!("{problems}");
            eprintln!(
                "{} problem{} found; nothing was started",
                problems.len(),
                if problems.len() == 1 { "" } else { "s" }
            );
            return ExitCode::from(iogate::EXIT_CONFIG as u8);
        }
    };
    if matches!(action, Action::Check | Action::Serve(_) | Action::Diff(_)) {
        for warning in setup.warnings() {
            eprintln!("warning: {warning}");
        }
    }
    match action {
        Action::St(name) => st(&setup, &name),
        Action::Map { st } => map(&setup, st),
        Action::MapIec104(config) => map_iec104(&setup, config.as_deref()),
        Action::Diff(options) => diff(&setup, &options),
        Action::Plan => {
            print!("{}", iogate::plan::render(&setup.config, &setup.catalog));
            ExitCode::SUCCESS
        }
        Action::Check => check(&setup),
        Action::Serve(listen) => serve(setup, &listen),
    }
}

/// The config file named and what to do with the setup it makes; `None` for the commands
/// that need none (done already).
fn action_of(command: Option<Command>) -> Option<(Option<PathBuf>, Action)> {
    Some(match command {
        None => (None, Action::Serve(ListenArgs::default())),
        Some(Command::Serve { config, listen }) => (config, Action::Serve(listen)),
        Some(Command::Check {
            config,
            diff: true,
            against,
            server,
            token,
            json,
        }) => (
            config,
            Action::Diff(DiffOptions {
                against,
                server,
                token,
                json,
            }),
        ),
        Some(Command::Check { config, .. }) => (config, Action::Check),
        Some(Command::Plan { config }) => (config, Action::Plan),
        Some(Command::Map {
            config,
            iec104: true,
            ..
        }) => (config.clone(), Action::MapIec104(config)),
        Some(Command::Map { config, st, .. }) => (config, Action::Map { st }),
        Some(Command::Profile {
            command: ProfileCommand::St { name, config },
        }) => (config, Action::St(name)),
        Some(
            Command::Fb { .. }
            | Command::Scan(_)
            | Command::Profile {
                command: ProfileCommand::Import(_),
            },
        ) => return None,
    })
}

/// `profile st NAME`: the profile's ST declaration.
fn st(setup: &Setup, name: &str) -> ExitCode {
    match setup.catalog.get(name) {
        Some(profile) => {
            print!("{}", iogate::profile::st_declaration(profile));
            ExitCode::SUCCESS
        }
        None => {
            let known: Vec<_> = setup.catalog.iter().map(|p| p.name.as_str()).collect();
            eprintln!("unknown profile `{name}` (known: {})", known.join(", "));
            ExitCode::from(iogate::EXIT_CONFIG as u8)
        }
    }
}

/// `map [--st]`: the located addresses, as a table or as ST.
fn map(setup: &Setup, st: bool) -> ExitCode {
    match &setup.map {
        Some(plan) if st => {
            print!("{}", iogate::map::report::st(plan));
            ExitCode::SUCCESS
        }
        Some(plan) => {
            print!("{}", iogate::map::report::render(plan));
            ExitCode::SUCCESS
        }
        None => {
            eprintln!("no Modbus TCP server is configured (add `modbus_server:` to the config)");
            ExitCode::from(iogate::EXIT_CONFIG as u8)
        }
    }
}

/// `map --iec104`: the outstation's points, one line each; fields not served on stderr.
fn map_iec104(setup: &Setup, config: Option<&std::path::Path>) -> ExitCode {
    let base = config
        .and_then(|c| c.parent())
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(std::path::Path::new("."));
    match setup.iec104_map(base) {
        Some(Ok(list)) => {
            print!("{}", list.lines);
            for s in list.skipped {
                eprintln!("{s}");
            }
            ExitCode::SUCCESS
        }
        Some(Err(problems)) => {
            for p in problems {
                eprintln!("{p}");
            }
            ExitCode::from(iogate::EXIT_CONFIG as u8)
        }
        None => {
            eprintln!("no IEC 104 outstation is configured (add `iec104_server:` to the config)");
            ExitCode::from(iogate::EXIT_CONFIG as u8)
        }
    }
}

/// `check`: the plan's warnings and what was checked.
fn check(setup: &Setup) -> ExitCode {
    // `serve` says the same in its log, from each link's task.
    for warning in iogate::plan::warnings(&setup.config, &setup.catalog) {
        eprintln!("warning: {warning}");
    }
    let what = if setup.demo {
        "built-in demo".to_owned()
    } else {
        setup.config.source.clone()
    };
    let count = |n: usize, one: &str| match n {
        1 => format!("1 {one}"),
        n => format!("{n} {one}s"),
    };
    println!(
        "{what}: ok ({}, {}, {})",
        count(setup.catalog.len(), "profile"),
        count(setup.config.links.len(), "link"),
        count(setup.config.devices.len(), "device")
    );
    ExitCode::SUCCESS
}

/// `serve`: the gateway, on the listeners the command line moves, until a signal.
fn serve(mut setup: Setup, listen: &ListenArgs) -> ExitCode {
    if let Err(e) = setup.move_listeners(listen.listeners()) {
        eprintln!("iogate serve: {e}");
        return ExitCode::from(iogate::EXIT_CONFIG as u8);
    }
    let runtime = match tokio::runtime::Runtime::new() {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("cannot start the runtime: {e}");
            return ExitCode::FAILURE;
        }
    };
    match runtime.block_on(app::run(setup)) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // A log line, so a log collector reading JSON lines sees why.
            tracing::error!(error = %format!("{e:#}"), "the gateway could not start");
            ExitCode::FAILURE
        }
    }
}

/// `serve`'s listeners on the command line, over the config's (or the demo's): port 0 takes
/// any free one, and the address bound is printed.
#[derive(Debug, Clone, Copy, Default, clap::Args)]
struct ListenArgs {
    /// REST, the web page and /metrics (listen.http).
    #[arg(long, value_name = "ADDR")]
    http: Option<std::net::SocketAddr>,
    /// gRPC (listen.grpc).
    #[arg(long, value_name = "ADDR")]
    grpc: Option<std::net::SocketAddr>,
    /// The Modbus TCP server (modbus_server.listen).
    #[arg(long, value_name = "ADDR")]
    modbus: Option<std::net::SocketAddr>,
    /// The OPC UA server (opcua.listen).
    #[arg(long, value_name = "ADDR")]
    opcua: Option<std::net::SocketAddr>,
    /// The IEC 104 outstation (iec104_server.listen).
    #[arg(long, value_name = "ADDR")]
    iec104: Option<std::net::SocketAddr>,
}

impl ListenArgs {
    fn listeners(&self) -> iogate::app::Listeners {
        iogate::app::Listeners {
            http: self.http,
            grpc: self.grpc,
            modbus: self.modbus,
            sections: [("opcua", self.opcua), ("iec104_server", self.iec104)]
                .into_iter()
                .filter_map(|(s, a)| a.map(|a| (s, a)))
                .collect(),
        }
    }
}

/// `iogate check --diff`: prints the report a reload would give; exits 64 when the files
/// have problems, 1 when the gateway could not be asked.
fn diff(setup: &Setup, options: &DiffOptions) -> ExitCode {
    use iogate::reload::compare::{self, DiffError};
    if setup.demo {
        eprintln!(
            "check --diff compares a config file: none was given and ./iogate.yaml does not exist"
        );
        return ExitCode::from(iogate::EXIT_CONFIG as u8);
    }
    let config = PathBuf::from(&setup.config.source);
    let (answer, against) = match &options.against {
        Some(running) => (
            compare::against_file(running, &config),
            running.display().to_string(),
        ),
        None => {
            let url = options
                .server
                .clone()
                .unwrap_or_else(|| compare::gateway_url(setup));
            let Ok(runtime) = tokio::runtime::Builder::new_current_thread()
                .enable_all()
                .build()
                .inspect_err(|e| eprintln!("cannot start the runtime: {e}"))
            else {
                return ExitCode::FAILURE;
            };
            let answer = runtime.block_on(compare::against_gateway(
                setup,
                &config,
                &url,
                options.token.as_deref(),
            ));
            (answer, format!("the gateway at {url}"))
        }
    };
    match answer {
        Ok(report) if options.json => json_report(&report),
        Ok(report) => {
            let count = report.changes.len();
            if count == 0 {
                println!(
                    "{} against {against}: no changes; a reload would change nothing",
                    config.display()
                );
            } else {
                println!(
                    "{} against {against}: {count} change{}; nothing was applied",
                    config.display(),
                    if count == 1 { "" } else { "s" }
                );
                for line in report.lines() {
                    println!("  {line}");
                }
                if !report.reopened.is_empty() {
                    println!("  reopened: {}", report.reopened.join(", "));
                }
            }
            ExitCode::SUCCESS
        }
        Err(DiffError::Invalid(problems)) => {
            for problem in &problems {
                eprintln!("{problem}");
            }
            eprintln!(
                "{} problem{} found; a reload would change nothing",
                problems.len(),
                if problems.len() == 1 { "" } else { "s" }
            );
            ExitCode::from(iogate::EXIT_CONFIG as u8)
        }
        Err(e) => {
            eprintln!("{e}");
            ExitCode::FAILURE
        }
    }
}

/// A comparison's report as JSON.
fn json_report(report: &impl serde::Serialize) -> ExitCode {
    match serde_json::to_string_pretty(report) {
        Ok(text) => {
            println!("{text}");
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("{e}");
            ExitCode::FAILURE
        }
    }
}

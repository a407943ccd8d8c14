//! `iogate.yaml`: listeners, links and devices. The model is here; `read` reads it from
//! YAML, collecting every problem with file and line; `rules` holds the rules a link or
//! device obeys (shared with run-time declarations); `check` cross-checks links against each
//! other and devices against the loaded profiles.

mod check;
pub(crate) mod ha;
pub(crate) mod ha_arbiters;
mod line;
pub(crate) mod modbus_server;
mod parse;
pub(crate) mod rules;
mod sections;
pub mod security;
pub(crate) mod transactions;

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::time::Duration;

use crate::yaml::{self, Problems, Report};

pub(crate) use check::{Access, check_devices, check_security, safe_value};
pub(crate) use parse::{CORE_KEYS, duration_value};
pub use sections::Sections;
pub(crate) use sections::{Exposure, Section};

pub(crate) const DEFAULT_HTTP: &str = "127.0.0.1:8080";
pub(crate) const DEFAULT_GRPC: &str = "127.0.0.1:50051";
/// How long an HTTP client may take to send a request's headers, by default.
pub(crate) const DEFAULT_HEADER_TIMEOUT: Duration = Duration::from_secs(10);
/// How long a request body (at most 1 MiB) may take to arrive, by default.
pub(crate) const DEFAULT_BODY_TIMEOUT: Duration = Duration::from_secs(30);
/// The most change streams (SSE, gRPC Subscribe and Exchange) open at once, by default.
pub(crate) const DEFAULT_MAX_STREAMS: usize = 2048;
/// The most change streams one client address holds at once, by default.
pub(crate) const DEFAULT_MAX_STREAMS_PER_CLIENT: usize = 512;
/// The most connections each of the HTTP and gRPC listeners serves at once, by default.
pub(crate) const DEFAULT_MAX_CONNECTIONS: usize = 4096;
/// The most connections each listener serves from one client address, by default.
pub(crate) const DEFAULT_MAX_CONNECTIONS_PER_CLIENT: usize = 1024;
/// The most `listen.max_streams` and `listen.max_connections` may be.
pub(crate) const MAX_STREAMS_LIMIT: usize = 100_000;

#[derive(Debug, Clone, PartialEq)]
pub struct Config {
    pub http: SocketAddr,
    pub grpc: SocketAddr,
    /// How long an HTTP client may take to send a request's headers (`listen.header_timeout`).
    pub(crate) header_timeout: Duration,
    /// How long a request body may take to arrive (`listen.body_timeout`).
    pub(crate) body_timeout: Duration,
    /// The most change streams open at once (`listen.max_streams`).
    pub(crate) max_streams: usize,
    /// The most change streams open at once from one client address
    /// (`listen.max_streams_per_client`).
    pub(crate) max_streams_per_client: usize,
    /// The most connections each of the HTTP and gRPC listeners serves at once
    /// (`listen.max_connections`).
    pub(crate) max_connections: usize,
    /// The most connections each listener serves from one client address
    /// (`listen.max_connections_per_client`).
    pub(crate) max_connections_per_client: usize,
    /// The `profiles` directory as configured, relative to the config file's directory.
    pub profiles: Option<PathBuf>,
    pub links: Vec<LinkConfig>,
    pub devices: Vec<DeviceConfig>,
    /// The Modbus TCP server, when configured.
    pub modbus_server: Option<modbus_server::ModbusServerConfig>,
    /// The sections of the front-ends that read their own (`api::front_end`).
    pub sections: Sections,
    /// Standing raw transactions.
    pub(crate) transactions: Vec<transactions::StandingConfig>,
    pub security: security::SecurityConfig,
    /// `reload:`: whether changed files are applied by themselves.
    pub(crate) reload: ReloadConfig,
    /// `ha:`: this gateway as a node of an active/standby pair.
    pub(crate) ha: Option<ha::HaConfig>,
    /// The file the config came from.
    pub source: String,
    /// Where keys checked after reading are written, for their problems' lines.
    pub(crate) lines: KeyLines,
    /// What was written but could not be read (its problems are reported already), so the
    /// checks that follow do not report it again as missing.
    pub(crate) unreadable: Unreadable,
}

/// Reads the section `key` of `text` with `read`: what it made and every problem, as
/// `line: context: message` (the sections' unit tests).
#[cfg(test)]
pub(crate) fn read_section<T>(
    text: &str,
    key: &str,
    read: fn(&yaml::Node, &mut Report) -> Option<T>,
) -> (Option<T>, Vec<String>) {
    let mut report = Report::new("iogate.yaml");
    let node = yaml::parse(text, &mut report).expect("yaml");
    let mut map = node.map(&mut report, "config").expect("map");
    let section = map.get(key).and_then(|n| read(n, &mut report));
    let problems = report
        .into_problems()
        .iter()
        .map(|p| format!("{}: {}: {}", p.line, p.context, p.message))
        .collect();
    (section, problems)
}

/// The longest `reload.debounce`.
pub(crate) const MAX_DEBOUNCE: Duration = Duration::from_secs(60);

/// `reload: { watch, debounce }`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ReloadConfig {
    /// Watch the config file and the profiles directory, and reload when they change.
    pub(crate) watch: bool,
    /// How long the files must be quiet before a change is loaded.
    pub(crate) debounce: Duration,
}

impl Default for ReloadConfig {
    fn default() -> Self {
        ReloadConfig {
            watch: false,
            debounce: Duration::from_millis(500),
        }
    }
}

/// The lines of keys whose problems are found after reading (0: not written).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct KeyLines {
    pub(crate) http: u64,
    pub(crate) grpc: u64,
    pub(crate) profiles: u64,
}

/// Entries of the config file that had problems of their own.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Unreadable {
    /// Links written but not read.
    pub(crate) links: Vec<String>,
    /// Devices written but not read.
    pub(crate) devices: Vec<String>,
    /// Devices whose `slave_id` was written but refused.
    pub(crate) slave_ids: Vec<String>,
}

#[derive(Debug, Clone, PartialEq)]
pub struct LinkConfig {
    pub(crate) name: String,
    pub(crate) transport: Transport,
    /// Extra silence kept between frames, on top of the 3.5 characters.
    pub(crate) guard_time: Duration,
    pub(crate) line: u64,
}

#[derive(Debug, Clone, PartialEq)]
pub enum Transport {
    Serial(SerialSettings),
    Tcp {
        host: String,
        port: u16,
        framing: Framing,
    },
    /// A link of a protocol other than Modbus, read and checked by its driver.
    Driver(DriverLink),
}

/// A link of another field protocol: its settings as written, for its driver to read
/// (`crate::drivers`); the core knows only where it goes.
#[derive(Debug, Clone, PartialEq)]
pub struct DriverLink {
    /// The link's key for them, the protocol's (`opcua`).
    pub(crate) protocol: &'static str,
    /// Where it goes, as written (an OPC UA endpoint URL).
    pub(crate) endpoint: String,
    /// The settings' YAML tree.
    pub(crate) settings: crate::yaml::Node,
    /// The directory relative paths in the settings start from (the config file's).
    pub(crate) base: PathBuf,
}

impl SerialSettings {
    /// Whether a port is given (a declaration may leave it empty, for now).
    pub(crate) fn is_configured_port(&self) -> bool {
        !self.port.trim().is_empty()
    }
}

impl Transport {
    /// Whether there is something to open: a serial port can be declared empty at run time
    /// (`SerialLink` error 1 of source document 000, "no port configured") and given later.
    pub(crate) fn is_configured(&self) -> bool {
        match self {
            Transport::Serial(s) => !s.port.trim().is_empty(),
            Transport::Tcp { .. } | Transport::Driver(_) => true,
        }
    }

    /// Whether both reach the same port or TCP endpoint (whatever their other settings);
    /// unconfigured serial links are each their own.
    pub(crate) fn same_endpoint(&self, other: &Transport) -> bool {
        match (self, other) {
            (Transport::Serial(a), Transport::Serial(b)) => {
                a.port == b.port && self.is_configured()
            }
            (
                Transport::Tcp {
                    host: h1, port: p1, ..
                },
                Transport::Tcp {
                    host: h2, port: p2, ..
                },
            ) => h1 == h2 && p1 == p2,
            (Transport::Driver(a), Transport::Driver(b)) => {
                a.protocol == b.protocol && a.endpoint == b.endpoint
            }
            _ => false,
        }
    }
}

/// `serial PORT` or `tcp HOST:PORT (framing)`.
impl std::fmt::Display for Transport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Transport::Serial(s) if s.framing == Framing::Rtu => write!(f, "serial {}", s.port),
            Transport::Serial(s) => write!(f, "serial {} ({})", s.port, s.framing.name()),
            Transport::Tcp {
                host,
                port,
                framing,
            } => write!(f, "tcp {host}:{port} ({})", framing.name()),
            Transport::Driver(d) => write!(f, "{} {}", d.protocol, d.endpoint),
        }
    }
}

/// How Modbus frames travel: over a TCP link MBAP (the default), RTU or ASCII frames (to a
/// serial device server); over a serial line RTU (the default) or ASCII.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Framing {
    /// Modbus TCP (MBAP header).
    Mbap,
    /// RTU frames: binary, with a CRC, delimited by 3.5-character silences.
    #[default]
    Rtu,
    /// ASCII frames: `:`, hexadecimal characters with an LRC, CR LF.
    Ascii,
}

impl Framing {
    pub(crate) fn name(self) -> &'static str {
        match self {
            Framing::Mbap => "mbap",
            Framing::Rtu => "rtu",
            Framing::Ascii => "ascii",
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Parity {
    None,
    Even,
    Odd,
}

impl Parity {
    pub(crate) fn letter(self) -> char {
        match self {
            Parity::None => 'N',
            Parity::Even => 'E',
            Parity::Odd => 'O',
        }
    }
}

#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SerialSettings {
    pub port: String,
    pub baud: u32,
    pub parity: Parity,
    pub data_bits: u8,
    pub stop_bits: u8,
    /// RTU or ASCII (never MBAP on a line).
    pub framing: Framing,
}

#[derive(Debug, Clone, PartialEq)]
pub struct DeviceConfig {
    pub(crate) name: String,
    pub(crate) profile: String,
    pub(crate) link: Option<String>,
    pub(crate) slave_id: Option<u8>,
    pub(crate) refresh_rate: Duration,
    pub(crate) timeout: Duration,
    pub(crate) retries: u32,
    pub(crate) max_batch: u16,
    pub(crate) max_gap: u16,
    /// When outputs are written: on a new request, or also whenever the device holds another
    /// value than the one requested.
    pub(crate) write_mode: WriteMode,
    /// Whether the newest requested outputs are written again after a reconnect or the
    /// device's return; `None` is the protocol's default (`Protocol::rewrites_outputs`).
    pub(crate) rewrite_outputs: Option<RewriteOutputs>,
    /// What happens to outputs a scan-cycle client wrote when it is gone: `None` holds them.
    pub(crate) on_client_loss: Option<ClientLoss>,
    /// Where the device is on its link in its protocol's own keys (`Words::device_keys`:
    /// a BACnet device's `device_instance`), as written, for its driver to read.
    pub(crate) at: Vec<(&'static str, String)>,
    pub(crate) line: u64,
}

impl DeviceConfig {
    /// The text of one of the protocol's own keys the device carries, if it does.
    pub(crate) fn at(&self, key: &str) -> Option<&str> {
        self.at
            .iter()
            .find(|(k, _)| *k == key)
            .map(|(_, v)| v.as_str())
    }
}

/// `devices[].on_client_loss: { after, safe: { FIELD: value } }`: once the `Exchange` stream
/// that last wrote one of these outputs has been gone for `after` (and nobody wrote it
/// since), its safe value is written.
#[derive(Debug, Clone, PartialEq)]
pub struct ClientLoss {
    pub(crate) after: Duration,
    /// Field name and value text, checked against the profile.
    pub(crate) safe: Vec<(String, String)>,
}

/// `devices[].write_mode`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum WriteMode {
    /// Write when a client requests a value (default); a device that holds another value
    /// is shown as a mismatch.
    #[default]
    OnChange,
    /// Also write the requested value again whenever the device is read holding another
    /// (at most once per refresh period and 100 ms per field), as a PLC's cyclic output
    /// write does.
    Reconcile,
}

/// `devices[].rewrite_outputs`: what the gateway does with the outputs it wrote when the
/// link comes back (or the device answers again).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RewriteOutputs {
    /// Writes the newest requested value of each output again (an I/O module that loses
    /// its outputs at power-up), unless the device was read holding another value since
    /// it was written (someone else wrote it).
    OnReconnect,
    /// Writes nothing on its own (a controller whose program, HMIs and other masters
    /// write the same tags).
    Never,
}

impl RewriteOutputs {
    pub(crate) fn parse(text: &str) -> Option<RewriteOutputs> {
        match text {
            "on_reconnect" => Some(RewriteOutputs::OnReconnect),
            "never" => Some(RewriteOutputs::Never),
            _ => None,
        }
    }

    pub(crate) fn name(self) -> &'static str {
        match self {
            RewriteOutputs::OnReconnect => "on_reconnect",
            RewriteOutputs::Never => "never",
        }
    }
}

impl WriteMode {
    pub(crate) fn parse(text: &str) -> Option<WriteMode> {
        match text {
            "on_change" => Some(WriteMode::OnChange),
            "reconcile" => Some(WriteMode::Reconcile),
            _ => None,
        }
    }
}

impl Config {
    /// A config with default listeners and nothing else.
    pub(crate) fn empty(source: &str) -> Self {
        Config {
            http: DEFAULT_HTTP
                .parse()
                .unwrap_or(SocketAddr::from(([127, 0, 0, 1], 8080))),
            grpc: DEFAULT_GRPC
                .parse()
                .unwrap_or(SocketAddr::from(([127, 0, 0, 1], 50051))),
            header_timeout: DEFAULT_HEADER_TIMEOUT,
            body_timeout: DEFAULT_BODY_TIMEOUT,
            max_streams: DEFAULT_MAX_STREAMS,
            max_streams_per_client: DEFAULT_MAX_STREAMS_PER_CLIENT,
            max_connections: DEFAULT_MAX_CONNECTIONS,
            max_connections_per_client: DEFAULT_MAX_CONNECTIONS_PER_CLIENT,
            profiles: None,
            links: Vec::new(),
            devices: Vec::new(),
            modbus_server: None,
            sections: Sections::default(),
            transactions: Vec::new(),
            security: security::SecurityConfig::default(),
            reload: ReloadConfig::default(),
            ha: None,
            source: source.to_owned(),
            lines: KeyLines::default(),
            unreadable: Unreadable::default(),
        }
    }

    /// Reads a config file as far as it can be read: what could be read (nothing when the
    /// file or its YAML cannot be), and every problem found, so the checks that follow can
    /// still look at the rest.
    pub(crate) fn load_partial(path: &Path) -> (Option<Config>, Problems) {
        let file = path.display().to_string();
        let text = match crate::text::read_file(path) {
            Ok(text) => text,
            Err(e) => {
                let mut report = Report::new(&file);
                report.push(e.line().unwrap_or(0), "", e.to_string());
                return (None, report.into_problems());
            }
        };
        let (config, problems) = parse_partial(&file, &text);
        let Some(mut config) = config else {
            return (None, problems);
        };
        if let Some(dir) = &config.profiles
            && dir.is_relative()
        {
            let base = path.parent().unwrap_or(Path::new("."));
            config.profiles = Some(base.join(dir));
        }
        config
            .security
            .resolve(path.parent().unwrap_or(Path::new(".")));
        if let Some(file) = config
            .modbus_server
            .as_mut()
            .and_then(|m| m.memory_file.as_mut())
            .filter(|f| f.is_relative())
        {
            *file = path.parent().unwrap_or(Path::new(".")).join(&*file);
        }
        let mut problems = problems;
        if let Some(server) = &config.modbus_server
            && let Some(file) = &server.memory_file
        {
            // The file is made when the memory is first saved: its directory must be there.
            let dir = file
                .parent()
                .filter(|d| !d.as_os_str().is_empty())
                .unwrap_or(Path::new("."));
            if !dir.is_dir() {
                let mut report = Report::new(&config.source);
                report.push(
                    server.memory_file_line,
                    "modbus_server.memory_file",
                    format!(
                        "{}: the directory {} does not exist",
                        file.display(),
                        dir.display()
                    ),
                );
                problems.extend(report.into_problems());
            }
        }
        (Some(config), problems)
    }
}

/// Parses config text; `file` names it in problems.
pub fn parse(file: &str, text: &str) -> Result<Config, Problems> {
    match parse_partial(file, text) {
        (Some(c), problems) if problems.is_empty() => Ok(c),
        (_, problems) => Err(problems),
    }
}

/// Parses config text as far as it can be read, with every problem found.
pub(crate) fn parse_partial(file: &str, text: &str) -> (Option<Config>, Problems) {
    let mut report = Report::new(file);
    let config =
        yaml::parse(text, &mut report).and_then(|root| parse::read_config(&root, &mut report));
    (config, report.into_problems())
}

#[cfg(test)]
mod tests;

//! The `iec104_server:` section: where the outstation listens, its common address, which
//! fields it serves at which information object addresses (`map: auto`, or a file naming
//! them), the standard's windows and timers on its side (`k`, `w`, `t1`, `t2`, `t3`), how
//! many masters it serves at once, whether spontaneous data carries time tags, how long a
//! selected command waits for its execute, and how old a time-tagged command may be.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use crate::yaml::{Node, Report};

const KEYS: &[&str] = &[
    "listen",
    "common_address",
    "map",
    "k",
    "w",
    "t1",
    "t2",
    "t3",
    "max_connections",
    "max_connections_per_client",
    "time_tags",
    "select_timeout",
    "command_max_age",
];

pub(crate) const DEFAULT_LISTEN: &str = "127.0.0.1:2404";

/// Which fields are served, at which addresses.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum MapSource {
    /// Every field of every device, numbered from 1 in the devices' order.
    Auto,
    /// The entries of a YAML file (relative to the config's directory).
    File(PathBuf),
}

#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Iec104ServerConfig {
    pub(crate) listen: SocketAddr,
    pub(crate) common_address: u16,
    pub(crate) map: MapSource,
    pub(crate) k: u16,
    pub(crate) w: u16,
    pub(crate) t1: Duration,
    pub(crate) t2: Duration,
    pub(crate) t3: Duration,
    pub(crate) max_connections: usize,
    pub(crate) max_connections_per_client: usize,
    /// Spontaneous data as the time-tagged types (CP56Time2a), the time the value was read.
    pub(crate) time_tags: bool,
    pub(crate) select_timeout: Duration,
    /// A time-tagged command older (or newer) than this is refused; `None`: not checked.
    pub(crate) command_max_age: Option<Duration>,
    pub(crate) line: u64,
    /// The map file as resolved from the config's directory, and a digest of its contents
    /// when last read (a map file changed alone is a change of the section).
    pub(crate) map_file: Option<(std::path::PathBuf, u64)>,
}

impl crate::config::Section for Iec104ServerConfig {
    fn line(&self) -> u64 {
        self.line
    }

    fn listen_mut(&mut self) -> Option<&mut SocketAddr> {
        Some(&mut self.listen)
    }

    fn resolve(&mut self, base: &std::path::Path) {
        use std::hash::{Hash, Hasher};
        self.map_file = match &self.map {
            MapSource::Auto => None,
            MapSource::File(path) => {
                let path = base.join(path);
                let mut h = std::collections::hash_map::DefaultHasher::new();
                std::fs::read(&path).ok().hash(&mut h);
                Some((path, h.finish()))
            }
        };
    }

    fn files(&self) -> Vec<std::path::PathBuf> {
        self.map_file.iter().map(|(p, _)| p.clone()).collect()
    }
}

fn map_source(n: &Node, report: &mut Report) -> Option<MapSource> {
    let text = n.scalar_text(report, "iec104_server.map")?;
    match text.trim() {
        "auto" => Some(MapSource::Auto),
        "" => {
            report.push(
                n.line,
                "iec104_server.map",
                "write auto (every field an IOA) or the path of a map file",
            );
            None
        }
        path if path.contains('\0') => {
            report.push(n.line, "iec104_server.map", "is not a path");
            None
        }
        path => Some(MapSource::File(PathBuf::from(path))),
    }
}

/// The `listen` address, its default without one.
fn listen(node: Option<&Node>, report: &mut Report, ctx: &str) -> Option<SocketAddr> {
    let Some(n) = node else {
        return DEFAULT_LISTEN.parse().ok();
    };
    let text = n.scalar_text(report, ctx)?;
    text.parse::<SocketAddr>()
        .map_err(|_| {
            report.push(
                n.line,
                ctx,
                format!("`{text}` is not an address (host:port, e.g. 0.0.0.0:2404)"),
            )
        })
        .ok()
}

/// Reads the section; `None` after reporting its problems.
pub(super) fn read(node: &Node, report: &mut Report) -> Option<Iec104ServerConfig> {
    let ctx = "iec104_server";
    let at = |k: &str| format!("{ctx}.{k}");
    let mut map = node.map(report, ctx)?;
    let listen = listen(map.get("listen"), report, &at("listen"));
    let source = map
        .get("map")
        .map_or(Some(MapSource::Auto), |n| map_source(n, report));
    let mut int = |key: &str, default: i128, lo: i128, hi: i128, report: &mut Report| {
        map.get(key)
            .map_or(Some(default), |n| n.int_in(report, &at(key), lo, hi))
    };
    let common_address = int("common_address", 1, 1, 65534, report);
    let k = int("k", 12, 1, 32767, report);
    let w = int("w", 8, 1, 32767, report);
    let max = int("max_connections", 4, 1, 64, report);
    let per_client = int("max_connections_per_client", 2, 1, 64, report);
    let mut time = |key: &str, default: u64, most: u64, report: &mut Report| {
        map.get(key)
            .map_or(Some(Duration::from_secs(default)), |n| {
                crate::drivers::iec104::config::duration(
                    n,
                    report,
                    &at(key),
                    Duration::from_secs(most),
                )
            })
    };
    let t1 = time("t1", 15, 255, report);
    let t2 = time("t2", 10, 255, report);
    let t3 = time("t3", 20, 172_800, report);
    let select_timeout = time("select_timeout", 10, 600, report);
    let command_max_age = map
        .get("command_max_age")
        .map_or(Some(Some(Duration::from_secs(10))), |n| {
            crate::drivers::iec104::config::period(n, report, &at("command_max_age"))
        });
    let time_tags = map.get("time_tags").map_or(Some(true), |n| {
        crate::yaml::boolean(n, report, &at("time_tags"))
    });
    if let (Some(t1), Some(t2)) = (t1, t2)
        && t2 >= t1
    {
        report.push(node.line, at("t2"), format!("t2 ({t2:?}) must be shorter than t1 ({t1:?}): the master waits t1 for the outstation's acknowledgement"));
    }
    if let (Some(k), Some(w)) = (k, w)
        && w > k
    {
        let why =
            format!("w ({w}) must be at most k ({k}); the standard recommends two thirds of k");
        report.push(node.line, at("w"), why);
    }
    map.finish(report, ctx, KEYS);
    Some(Iec104ServerConfig {
        listen: listen?,
        common_address: u16::try_from(common_address?).ok()?,
        map: source?,
        k: u16::try_from(k?).ok()?,
        w: u16::try_from(w?).ok()?,
        t1: t1?,
        t2: t2?,
        t3: t3?,
        max_connections: max? as usize,
        max_connections_per_client: per_client? as usize,
        time_tags: time_tags?,
        select_timeout: select_timeout?,
        command_max_age: command_max_age?,
        line: node.line,
        map_file: None,
    })
}

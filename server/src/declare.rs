//! Declaring links and devices at run time, the way a remote runtime's `SerialLink` and device
//! function-block calls do. A declaration is idempotent: declaring what exists is fine; a
//! declaration that contradicts what exists is refused and the contradiction named. The
//! rules a link or device obeys are the config file's ([`crate::config::rules`]).

use std::fmt;
use std::sync::Arc;
use std::time::Duration;

use crate::cache::{AccessError, Cache, Device, Link, Registry};
use crate::config::rules::{self, Mismatch, RuleError};
use crate::config::{DeviceConfig, Framing, LinkConfig, Parity, Transport};
use crate::profile::Protocol;
use crate::runtime::Tasks;

/// A link's endpoint as a declaration gives it: numbers unchecked, zero or empty for "the
/// default" (8 data bits, 1 stop bit, no parity, port 502, MBAP framing).
#[derive(Debug, Clone, PartialEq)]
pub enum Endpoint {
    Serial {
        port: String,
        baud: u64,
        parity: String,
        data_bits: u64,
        stop_bits: u64,
    },
    Tcp {
        host: String,
        port: u64,
        framing: String,
    },
}

impl Endpoint {
    /// The transport, checked by the same rules as the config file's.
    pub fn transport(&self) -> Result<Transport, DeclareError> {
        let or = |n: u64, default: u8| if n == 0 { u64::from(default) } else { n };
        match self {
            Endpoint::Serial {
                port,
                baud,
                parity,
                data_bits,
                stop_bits,
            } => {
                let parity = match parity.as_str() {
                    "" => Ok(Parity::None),
                    text => rules::parse_parity(text),
                };
                let parity = parity.map_err(|e| DeclareError::Rules(vec![e]))?;
                rules::serial(
                    port.clone(),
                    *baud,
                    parity,
                    or(*data_bits, rules::DEFAULT_DATA_BITS),
                    or(*stop_bits, rules::DEFAULT_STOP_BITS),
                )
                .map(Transport::Serial)
                .map_err(DeclareError::Rules)
            }
            Endpoint::Tcp {
                host,
                port,
                framing,
            } => {
                let framing = match framing.as_str() {
                    "" => Ok(Framing::Mbap),
                    text => rules::parse_framing(text),
                }
                .map_err(|e| DeclareError::Rules(vec![e]))?;
                let port = if *port == 0 {
                    u64::from(rules::DEFAULT_TCP_PORT)
                } else {
                    *port
                };
                let port = rules::tcp_endpoint(host, port).map_err(DeclareError::Rules)?;
                Ok(Transport::Tcp {
                    host: host.clone(),
                    port,
                    framing,
                })
            }
        }
    }
}

#[derive(Debug, Clone, PartialEq)]
pub struct LinkDeclaration {
    /// Optional: by default the name is made from the port (`/dev/ttyUSB0` → `dev_ttyUSB0`)
    /// or the endpoint (`192.0.2.10_502`).
    pub name: Option<String>,
    pub endpoint: Endpoint,
    pub guard_time: Duration,
}

#[derive(Debug, Clone, PartialEq)]
pub struct DeviceDeclaration {
    pub name: String,
    pub profile: String,
    /// A link name, or a serial port path as a `SerialLink` instance's `port` gives it.
    pub link: String,
    pub slave_id: u32,
    pub refresh_rate: Duration,
    pub timeout: Option<Duration>,
}

/// Where a declaration contradicts what exists.
#[derive(Debug, Clone, PartialEq)]
pub enum Conflict {
    /// The serial port runs with other settings (the "configuration mismatch" of source
    /// document 004).
    Serial {
        port: String,
        mismatch: Mismatch,
    },
    Framing {
        have: Framing,
        want: Framing,
    },
    /// The endpoint is another link's.
    LinkName {
        is: String,
        declared: String,
    },
    Profile {
        have: String,
        want: String,
    },
    Link {
        have: Option<String>,
        want: Option<String>,
    },
    SlaveId {
        have: u8,
        want: u8,
    },
    RefreshRate {
        have: Duration,
        want: Duration,
    },
    Timeout {
        have: Duration,
        want: Duration,
    },
}

impl fmt::Display for Conflict {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let none = |n: &Option<String>| n.clone().unwrap_or_else(|| "none".to_owned());
        match self {
            Conflict::Serial { port, mismatch: m } => write!(
                f,
                "{} configuration mismatch on {port}: {} declared, {} in use",
                m.setting, m.want, m.have
            ),
            Conflict::Framing { have, want } => write!(
                f,
                "framing {} declared, {} in use",
                want.name(),
                have.name()
            ),
            Conflict::LinkName { is, declared } => {
                write!(f, "it is link `{is}`, not `{declared}`")
            }
            Conflict::Profile { have, want } => write!(f, "profile {have} (declared {want})"),
            Conflict::Link { have, want } => {
                write!(f, "link {} (declared {})", none(have), none(want))
            }
            Conflict::SlaveId { have, want } => write!(f, "slave_id {have} (declared {want})"),
            Conflict::RefreshRate { have, want } => write!(
                f,
                "refresh_rate {} ms (declared {} ms)",
                have.as_millis(),
                want.as_millis()
            ),
            Conflict::Timeout { have, want } => write!(
                f,
                "timeout {} ms (declared {} ms)",
                have.as_millis(),
                want.as_millis()
            ),
        }
    }
}

/// How a declaration was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refusal {
    /// The declaration itself is wrong.
    Invalid,
    /// It names a profile or link that does not exist.
    NotFound,
    /// It contradicts what exists.
    Conflict,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DeclareError {
    #[error("{}", rule_list(.0))]
    Rules(Vec<RuleError>),
    #[error("`{name}` cannot name a {what} (empty, or has a '/')")]
    BadName { what: &'static str, name: String },
    #[error(transparent)]
    UnknownProfile(AccessError),
    #[error("no link `{0}`; declare it with EnsureLink first")]
    UnknownLink(String),
    #[error("link {link} conflicts with its declaration: {}", join(.conflicts, "; "))]
    LinkConflict {
        link: String,
        conflicts: Vec<Conflict>,
    },
    #[error("link name `{name}` is already used by another endpoint ({endpoint})")]
    NameTaken { name: String, endpoint: String },
    #[error("device {device} exists with {}", join(.conflicts, ", "))]
    DeviceConflict {
        device: String,
        conflicts: Vec<Conflict>,
    },
}

impl DeclareError {
    pub fn refusal(&self) -> Refusal {
        match self {
            DeclareError::Rules(_) | DeclareError::BadName { .. } => Refusal::Invalid,
            DeclareError::UnknownProfile(_) | DeclareError::UnknownLink(_) => Refusal::NotFound,
            DeclareError::LinkConflict { .. }
            | DeclareError::NameTaken { .. }
            | DeclareError::DeviceConflict { .. } => Refusal::Conflict,
        }
    }
}

fn rule_list(errors: &[RuleError]) -> String {
    errors
        .iter()
        .map(|e| format!("{}: {e}", e.key()))
        .collect::<Vec<_>>()
        .join("; ")
}

fn join(conflicts: &[Conflict], separator: &str) -> String {
    conflicts
        .iter()
        .map(ToString::to_string)
        .collect::<Vec<_>>()
        .join(separator)
}

/// What a declaration resolved to, and whether it was created by it.
#[derive(Debug, Clone)]
pub struct Ensured<T> {
    pub value: Arc<T>,
    pub created: bool,
}

fn default_name(transport: &Transport) -> String {
    let raw = match transport {
        Transport::Serial(s) => s.port.trim_start_matches('/').to_owned(),
        Transport::Tcp { host, port, .. } => format!("{host}_{port}"),
    };
    raw.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '.' || c == '-' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

fn valid_name(what: &'static str, name: &str) -> Result<(), DeclareError> {
    if name.trim().is_empty() || name.contains('/') {
        return Err(DeclareError::BadName {
            what,
            name: name.to_owned(),
        });
    }
    Ok(())
}

/// Where `declared` differs from the link `existing` on the same endpoint.
fn link_conflicts(existing: &Link, declared: &Transport, name: Option<&String>) -> Vec<Conflict> {
    let mut conflicts = match (&existing.config.transport, declared) {
        (Transport::Serial(have), Transport::Serial(want)) => rules::serial_mismatches(have, want)
            .into_iter()
            .map(|mismatch| Conflict::Serial {
                port: have.port.clone(),
                mismatch,
            })
            .collect(),
        (Transport::Tcp { framing: have, .. }, Transport::Tcp { framing: want, .. })
            if have != want =>
        {
            vec![Conflict::Framing {
                have: *have,
                want: *want,
            }]
        }
        _ => Vec::new(),
    };
    if let Some(name) = name.filter(|n| *n != existing.name()) {
        conflicts.push(Conflict::LinkName {
            is: existing.name().to_owned(),
            declared: name.clone(),
        });
    }
    conflicts
}

/// Declares a link: returns the link with the same port (or endpoint) if its settings agree,
/// creates it (and starts its task) if there is none.
pub fn ensure_link(
    cache: &Cache,
    tasks: &Tasks,
    decl: LinkDeclaration,
) -> Result<Ensured<Link>, DeclareError> {
    let transport = decl.endpoint.transport()?;
    let guard_time =
        rules::guard_time(decl.guard_time).map_err(|e| DeclareError::Rules(vec![e]))?;
    let ensured = cache.change(|registry: &mut Registry| {
        if let Some(existing) = registry
            .links
            .iter()
            .find(|l| l.config.transport.same_endpoint(&transport))
        {
            let conflicts = link_conflicts(existing, &transport, decl.name.as_ref());
            if !conflicts.is_empty() {
                return Err(DeclareError::LinkConflict {
                    link: existing.name().to_owned(),
                    conflicts,
                });
            }
            return Ok(Ensured {
                value: existing.clone(),
                created: false,
            });
        }
        let name = decl
            .name
            .clone()
            .unwrap_or_else(|| default_name(&transport));
        valid_name("link", &name)?;
        if let Some(other) = registry.link(&name) {
            return Err(DeclareError::NameTaken {
                name,
                endpoint: other.config.transport.to_string(),
            });
        }
        let link = cache.insert_link(
            registry,
            LinkConfig {
                name,
                transport: transport.clone(),
                guard_time,
                line: 0,
            },
        );
        Ok(Ensured {
            value: link,
            created: true,
        })
    })?;
    if ensured.created {
        tracing::info!(link = %ensured.value.name(), "link declared");
        tasks.spawn_link(ensured.value.clone());
    }
    Ok(ensured)
}

/// Where `decl` differs from the device `existing` of the same name.
fn device_conflicts(
    existing: &DeviceConfig,
    decl: &DeviceDeclaration,
    profile: &str,
    link: &Option<String>,
    slave_id: Option<u8>,
) -> Vec<Conflict> {
    let mut conflicts = Vec::new();
    if existing.profile != profile {
        conflicts.push(Conflict::Profile {
            have: existing.profile.clone(),
            want: profile.to_owned(),
        });
    }
    if existing.link != *link {
        conflicts.push(Conflict::Link {
            have: existing.link.clone(),
            want: link.clone(),
        });
    }
    if existing.slave_id != slave_id {
        conflicts.push(Conflict::SlaveId {
            have: existing.slave_id.unwrap_or(0),
            want: slave_id.unwrap_or(0),
        });
    }
    if existing.refresh_rate != decl.refresh_rate {
        conflicts.push(Conflict::RefreshRate {
            have: existing.refresh_rate,
            want: decl.refresh_rate,
        });
    }
    if let Some(want) = decl.timeout.filter(|t| *t != existing.timeout) {
        conflicts.push(Conflict::Timeout {
            have: existing.timeout,
            want,
        });
    }
    conflicts
}

/// Declares a device: returns the device of that name if its settings agree, creates it
/// otherwise. Its link's task starts polling it at once; a simulated device gets its task.
pub fn ensure_device(
    cache: &Cache,
    tasks: &Tasks,
    decl: DeviceDeclaration,
) -> Result<Ensured<Device>, DeclareError> {
    valid_name("device", &decl.name)?;
    let profile = cache
        .profile(&decl.profile)
        .map_err(DeclareError::UnknownProfile)?
        .clone();
    let simulated = profile.protocol == Protocol::Simulated;
    let link = (!decl.link.trim().is_empty()).then_some(decl.link.as_str());
    let slave = (decl.slave_id != 0).then_some(u64::from(decl.slave_id));
    let mut broken = rules::binding(&profile, link, slave);
    broken.extend(rules::period("refresh_rate", decl.refresh_rate).err());
    if let Some(t) = decl.timeout {
        broken.extend(rules::period("timeout", t).err());
    }
    if !broken.is_empty() {
        return Err(DeclareError::Rules(broken));
    }
    let ensured = cache.change(|registry: &mut Registry| {
        let link = match link {
            None => None,
            Some(link) => {
                let found = registry.link(link).or_else(|| {
                    registry.links.iter().find(
                        |l| matches!(&l.config.transport, Transport::Serial(s) if s.port == link),
                    )
                });
                let found = found.ok_or_else(|| DeclareError::UnknownLink(link.to_owned()))?;
                Some(found.name().to_owned())
            }
        };
        let slave_id = slave.and_then(|id| rules::slave_id(id).ok());
        if let Some(existing) = registry.device(&decl.name) {
            let conflicts =
                device_conflicts(&existing.config, &decl, &profile.name, &link, slave_id);
            if !conflicts.is_empty() {
                return Err(DeclareError::DeviceConflict {
                    device: decl.name.clone(),
                    conflicts,
                });
            }
            return Ok(Ensured {
                value: existing.clone(),
                created: false,
            });
        }
        let config = DeviceConfig {
            name: decl.name.clone(),
            profile: profile.name.clone(),
            link,
            slave_id,
            refresh_rate: decl.refresh_rate,
            timeout: decl.timeout.unwrap_or(rules::DEFAULT_TIMEOUT),
            retries: rules::DEFAULT_RETRIES,
            max_batch: rules::MAX_READ_REGISTERS,
            max_gap: 0,
            line: 0,
        };
        let device = cache.insert_device(registry, config, profile.clone());
        Ok(Ensured {
            value: device,
            created: true,
        })
    })?;
    if ensured.created {
        tracing::info!(device = %ensured.value.name(), "device declared");
        if simulated {
            tasks.spawn_sim(ensured.value.clone());
        }
    }
    Ok(ensured)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics::Metrics;
    use tokio_util::sync::CancellationToken;
    use tokio_util::task::TaskTracker;

    fn serial(baud: u64, parity: &str) -> Endpoint {
        Endpoint::Serial {
            port: "/nonexistent/ttyIOGATE7".into(),
            baud,
            parity: parity.into(),
            data_bits: 0,
            stop_bits: 0,
        }
    }

    #[test]
    fn a_declared_endpoint_obeys_the_config_rules_and_defaults() {
        let Ok(Transport::Serial(s)) = serial(9600, "").transport() else {
            panic!("valid serial settings")
        };
        assert_eq!((s.data_bits, s.stop_bits, s.parity), (8, 1, Parity::None));
        let err = serial(5, "X").transport().expect_err("bad parity");
        assert_eq!(
            err.to_string(),
            "parity: Invalid parity configuration: `X` (expected N, E or O)"
        );
        let err = serial(5, "E").transport().expect_err("bad baud");
        assert_eq!(err.refusal(), Refusal::Invalid);
        assert!(
            err.to_string()
                .contains("Invalid baudrate configuration: 5")
        );
        let tcp = Endpoint::Tcp {
            host: "127.0.0.1".into(),
            port: 0,
            framing: String::new(),
        };
        assert_eq!(
            tcp.transport(),
            Ok(Transport::Tcp {
                host: "127.0.0.1".into(),
                port: rules::DEFAULT_TCP_PORT,
                framing: Framing::Mbap
            })
        );
    }

    #[tokio::test]
    async fn an_unbounded_guard_time_is_refused_before_anything_is_opened() {
        let setup = crate::app::Setup::demo().expect("demo");
        let cache = Cache::new(&setup.config, setup.catalog);
        let tasks = Tasks::new(
            TaskTracker::new(),
            CancellationToken::new(),
            Arc::new(Metrics::new()),
        );
        let err = ensure_link(
            &cache,
            &tasks,
            LinkDeclaration {
                name: None,
                endpoint: serial(9600, "N"),
                guard_time: Duration::from_millis(u64::from(u32::MAX)),
            },
        )
        .expect_err("refused");
        assert!(matches!(err, DeclareError::Rules(_)), "{err}");
        assert!(cache.links().is_empty(), "nothing was declared");
    }
}

//! Declaring links and devices at run time, the way a remote runtime's `SerialLink` and device
//! function-block calls do. A declaration is idempotent: declaring what exists is fine; a
//! declaration that contradicts what exists is refused and the contradiction named.

use std::sync::Arc;
use std::time::Duration;

use crate::cache::{Cache, Device, Link, Registry};
use crate::config::{
    DEFAULT_RETRIES, DEFAULT_TIMEOUT, DeviceConfig, Framing, LinkConfig, MAX_READ_REGISTERS,
    SerialSettings, Transport,
};
use crate::profile::Protocol;
use crate::runtime::Tasks;

#[derive(Debug, Clone, PartialEq)]
pub struct LinkDeclaration {
    /// Optional: by default the name is made from the port (`/dev/ttyUSB0` → `dev_ttyUSB0`)
    /// or the endpoint (`192.0.2.10_502`).
    pub name: Option<String>,
    pub transport: Transport,
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

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DeclareError {
    #[error("{0}")]
    Invalid(String),
    #[error("{0}")]
    NotFound(String),
    #[error("{0}")]
    Conflict(String),
}

/// What a declaration resolved to, and whether it was created by it.
#[derive(Debug, Clone)]
pub struct Ensured<T> {
    pub value: Arc<T>,
    pub created: bool,
}

fn invalid(msg: impl Into<String>) -> DeclareError {
    DeclareError::Invalid(msg.into())
}

fn check_transport(transport: &Transport) -> Result<(), DeclareError> {
    match transport {
        Transport::Serial(s) => {
            if s.port.trim().is_empty() {
                return Err(invalid(
                    "no port configured (SerialLink error 1): the port is empty",
                ));
            }
            if !(300..=4_000_000).contains(&s.baud) {
                return Err(invalid(format!(
                    "Invalid baudrate configuration: {}",
                    s.baud
                )));
            }
            if !matches!(s.data_bits, 7 | 8) {
                return Err(invalid(format!(
                    "data_bits must be 7 or 8, not {}",
                    s.data_bits
                )));
            }
            if !matches!(s.stop_bits, 1 | 2) {
                return Err(invalid(format!(
                    "Invalid stop bits configuration: {} (expected 1 or 2)",
                    s.stop_bits
                )));
            }
        }
        Transport::Tcp { host, port, .. } => {
            if host.trim().is_empty() {
                return Err(invalid("the TCP host is empty"));
            }
            if *port == 0 {
                return Err(invalid("the TCP port must be 1-65535"));
            }
        }
    }
    Ok(())
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

fn same_endpoint(a: &Transport, b: &Transport) -> bool {
    match (a, b) {
        (Transport::Serial(x), Transport::Serial(y)) => x.port == y.port,
        (
            Transport::Tcp {
                host: h1, port: p1, ..
            },
            Transport::Tcp {
                host: h2, port: p2, ..
            },
        ) => h1 == h2 && p1 == p2,
        _ => false,
    }
}

/// The settings of `declared` that differ from `existing`, in the seed's words.
fn serial_mismatches(existing: &SerialSettings, declared: &SerialSettings) -> Vec<String> {
    let mut out = Vec::new();
    let mut check = |what: &str, have: String, want: String| {
        if have != want {
            out.push(format!(
                "{what} configuration mismatch on {}: {want} declared, {have} in use",
                existing.port
            ));
        }
    };
    check(
        "Baudrate",
        existing.baud.to_string(),
        declared.baud.to_string(),
    );
    check(
        "Parity",
        existing.parity.letter().to_string(),
        declared.parity.letter().to_string(),
    );
    check(
        "Stop bits",
        existing.stop_bits.to_string(),
        declared.stop_bits.to_string(),
    );
    check(
        "Data bits",
        existing.data_bits.to_string(),
        declared.data_bits.to_string(),
    );
    out
}

/// Declares a link: returns the link with the same port (or endpoint) if its settings agree,
/// creates it (and starts its task) if there is none.
pub fn ensure_link(
    cache: &Cache,
    tasks: &Tasks,
    decl: LinkDeclaration,
) -> Result<Ensured<Link>, DeclareError> {
    check_transport(&decl.transport)?;
    let ensured = cache.change(|registry: &mut Registry| {
        if let Some(existing) = registry
            .links
            .iter()
            .find(|l| same_endpoint(&l.config.transport, &decl.transport))
        {
            let mut conflicts = match (&existing.config.transport, &decl.transport) {
                (Transport::Serial(have), Transport::Serial(want)) => serial_mismatches(have, want),
                (Transport::Tcp { framing: have, .. }, Transport::Tcp { framing: want, .. })
                    if have != want =>
                {
                    vec![format!(
                        "framing {} declared, {} in use",
                        want.name(),
                        have.name()
                    )]
                }
                _ => Vec::new(),
            };
            if let Some(name) = decl.name.as_ref().filter(|n| *n != existing.name()) {
                conflicts.push(format!("it is link `{}`, not `{name}`", existing.name()));
            }
            if !conflicts.is_empty() {
                return Err(DeclareError::Conflict(format!(
                    "link {} conflicts with its declaration: {}",
                    existing.name(),
                    conflicts.join("; ")
                )));
            }
            return Ok(Ensured {
                value: existing.clone(),
                created: false,
            });
        }
        let name = decl
            .name
            .clone()
            .unwrap_or_else(|| default_name(&decl.transport));
        if name.is_empty() || name.contains('/') {
            return Err(invalid(format!(
                "`{name}` cannot name a link (empty, or has a '/')"
            )));
        }
        if let Some(other) = registry.link(&name) {
            return Err(DeclareError::Conflict(format!(
                "link name `{name}` is already used by another endpoint ({})",
                describe(&other.config.transport)
            )));
        }
        let link = cache.insert_link(
            registry,
            LinkConfig {
                name,
                transport: decl.transport.clone(),
                guard_time: decl.guard_time,
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

fn describe(transport: &Transport) -> String {
    match transport {
        Transport::Serial(s) => format!("serial {}", s.port),
        Transport::Tcp {
            host,
            port,
            framing,
        } => format!("tcp {host}:{port} ({})", framing.name()),
    }
}

/// Declares a device: returns the device of that name if its settings agree, creates it
/// otherwise. Its link's task starts polling it at once; a simulated device gets its task.
pub fn ensure_device(
    cache: &Cache,
    tasks: &Tasks,
    decl: DeviceDeclaration,
) -> Result<Ensured<Device>, DeclareError> {
    if decl.name.trim().is_empty() || decl.name.contains('/') {
        return Err(invalid(format!(
            "`{}` cannot name a device (empty, or has a '/')",
            decl.name
        )));
    }
    let profile = cache
        .profile(&decl.profile)
        .map_err(|e| DeclareError::NotFound(e.to_string()))?
        .clone();
    if decl.refresh_rate < Duration::from_millis(1) {
        return Err(invalid("refresh_rate must be at least 1 ms"));
    }
    if decl.timeout.is_some_and(|t| t < Duration::from_millis(1)) {
        return Err(invalid("timeout must be at least 1 ms"));
    }
    let simulated = profile.protocol == Protocol::Simulated;
    if simulated && !decl.link.is_empty() {
        return Err(invalid(format!(
            "profile {} is simulated: the device has no link",
            profile.name
        )));
    }
    if !simulated {
        if decl.link.trim().is_empty() {
            return Err(invalid(
                "no link configured (device error 1): the link is empty",
            ));
        }
        if decl.slave_id == 0 {
            return Err(invalid(
                "no slave configured (device error 2): slave_id is 0",
            ));
        }
        if decl.slave_id > 247 {
            return Err(invalid(format!(
                "slave_id {} is outside 1-247",
                decl.slave_id
            )));
        }
    }
    let ensured = cache.change(|registry: &mut Registry| {
        let link = if simulated {
            None
        } else {
            let found = registry.link(&decl.link).or_else(|| {
                registry.links.iter().find(
                    |l| matches!(&l.config.transport, Transport::Serial(s) if s.port == decl.link),
                )
            });
            match found {
                Some(l) => Some(l.name().to_owned()),
                None => {
                    return Err(DeclareError::NotFound(format!(
                        "no link `{}`; declare it with EnsureLink first",
                        decl.link
                    )));
                }
            }
        };
        let slave_id = (!simulated).then_some(decl.slave_id as u8);
        if let Some(existing) = registry.device(&decl.name) {
            let c = &existing.config;
            let mut conflicts = Vec::new();
            if c.profile != profile.name {
                conflicts.push(format!("profile {} (declared {})", c.profile, profile.name));
            }
            if c.link != link {
                conflicts.push(format!(
                    "link {} (declared {})",
                    c.link.as_deref().unwrap_or("none"),
                    link.as_deref().unwrap_or("none")
                ));
            }
            if c.slave_id != slave_id {
                conflicts.push(format!(
                    "slave_id {} (declared {})",
                    c.slave_id.unwrap_or(0),
                    slave_id.unwrap_or(0)
                ));
            }
            if c.refresh_rate != decl.refresh_rate {
                conflicts.push(format!(
                    "refresh_rate {} ms (declared {} ms)",
                    c.refresh_rate.as_millis(),
                    decl.refresh_rate.as_millis()
                ));
            }
            if let Some(t) = decl.timeout.filter(|t| *t != c.timeout) {
                conflicts.push(format!(
                    "timeout {} ms (declared {} ms)",
                    c.timeout.as_millis(),
                    t.as_millis()
                ));
            }
            if !conflicts.is_empty() {
                return Err(DeclareError::Conflict(format!(
                    "device {} exists with {}",
                    decl.name,
                    conflicts.join(", ")
                )));
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
            timeout: decl.timeout.unwrap_or(DEFAULT_TIMEOUT),
            retries: DEFAULT_RETRIES,
            max_batch: MAX_READ_REGISTERS,
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

/// The framing names a declaration may use.
pub fn parse_framing(name: &str) -> Option<Framing> {
    match name {
        "" | "mbap" => Some(Framing::Mbap),
        "rtu" => Some(Framing::Rtu),
        _ => None,
    }
}

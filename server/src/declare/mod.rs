//! Declaring links and devices at run time, the way a remote runtime's `SerialLink` and device
//! function-block calls do. A declaration is idempotent: declaring what exists is fine; a
//! declaration that contradicts what exists is refused and the contradiction named. The
//! rules a link or device obeys are the config file's ([`crate::config::rules`]).

mod endpoint;
mod error;

use std::sync::Arc;
use std::time::Duration;

use crate::cache::{AccessError, Binding, Cache, Device, Link, Registry};
use crate::config::rules::{self, RuleError};
use crate::config::security::DeclarePolicy;
use crate::config::{DeviceConfig, LinkConfig, Transport};
use crate::profile::Protocol;
use crate::runtime::Tasks;
use crate::text::quote;

pub(crate) use endpoint::Endpoint;
pub(crate) use error::{Conflict, DeclareError};

#[derive(Debug, Clone, PartialEq)]
pub(crate) struct LinkDeclaration {
    /// Optional: by default the name is made from the port (`/dev/ttyUSB0` → `dev_ttyUSB0`)
    /// or the endpoint (`192.0.2.10_502`).
    pub(crate) name: Option<String>,
    pub(crate) endpoint: Endpoint,
    pub(crate) guard_time: Duration,
}

#[derive(Debug, Clone, PartialEq)]
pub(crate) struct DeviceDeclaration {
    pub(crate) name: String,
    pub(crate) profile: String,
    /// A link name, or a serial port path as a `SerialLink` instance's `port` gives it.
    pub(crate) link: String,
    pub(crate) slave_id: u32,
    pub(crate) refresh_rate: Duration,
    pub(crate) timeout: Option<Duration>,
}

/// What a declaration resolved to, and whether it was created by it.
#[derive(Debug, Clone)]
pub(crate) struct Ensured<T> {
    pub(crate) value: Arc<T>,
    pub(crate) created: bool,
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
    rules::name(name).map_err(|_| DeclareError::BadName {
        what,
        name: crate::text::quote(name),
    })
}

/// The most links and devices declarations may add to a gateway.
pub(crate) const MAX_DECLARED_LINKS: usize = 64;
pub(crate) const MAX_DECLARED_DEVICES: usize = 1024;
/// The timeouts a declared device may have.
pub(crate) const TIMEOUTS: std::ops::RangeInclusive<Duration> =
    Duration::from_millis(10)..=Duration::from_secs(10);
/// The refresh rates a declared device may have.
pub(crate) const REFRESH_RATES: std::ops::RangeInclusive<Duration> =
    Duration::from_millis(1)..=Duration::from_secs(3600);

/// Whether a declaration may reach `transport`: a serial port matching the allowed patterns
/// that, if it exists, is a character device; a TCP endpoint in the allowed list.
fn allowed(policy: &DeclarePolicy, transport: &Transport) -> Result<(), DeclareError> {
    match transport {
        Transport::Serial(s) if !s.is_configured_port() => Ok(()),
        Transport::Serial(s) => {
            // A `..` could lead a pattern such as /dev/serial/by-id/* anywhere in /dev.
            if s.port.split('/').any(|part| part == "..") {
                return Err(DeclareError::NotAllowed(format!(
                    "serial port `{}`: a path with `..` is not allowed",
                    crate::text::quote(&s.port)
                )));
            }
            if !policy.allows_serial(&s.port) {
                return Err(DeclareError::NotAllowed(format!(
                    "serial port `{}` does not match security.declare.serial_ports",
                    crate::text::quote(&s.port)
                )));
            }
            #[cfg(unix)]
            {
                use std::os::unix::fs::FileTypeExt;
                if let Ok(meta) = std::fs::metadata(&s.port)
                    && !meta.file_type().is_char_device()
                {
                    return Err(DeclareError::NotAllowed(format!(
                        "`{}` is not a character device",
                        crate::text::quote(&s.port)
                    )));
                }
            }
            Ok(())
        }
        Transport::Tcp { host, port, .. } => {
            if policy.allows_tcp(host, *port) {
                Ok(())
            } else {
                Err(DeclareError::NotAllowed(format!(
                    "TCP endpoint {}:{port} is not in security.declare.tcp_hosts",
                    crate::text::quote(host)
                )))
            }
        }
    }
}

/// Where `declared` differs from the link `existing` on the same endpoint.
fn link_conflicts(existing: &Link, declared: &Transport, name: Option<&String>) -> Vec<Conflict> {
    let mut conflicts = match (&existing.config().transport, declared) {
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
pub(crate) fn ensure_link(
    cache: &Cache,
    tasks: &Tasks,
    policy: &DeclarePolicy,
    decl: LinkDeclaration,
) -> Result<Ensured<Link>, DeclareError> {
    let transport = decl.endpoint.transport()?;
    allowed(policy, &transport)?;
    let guard_time =
        rules::guard_time(decl.guard_time).map_err(|e| DeclareError::Rules(vec![e]))?;
    let ensured = cache.change(|registry: &mut Registry| {
        if let Some(existing) = registry
            .links
            .iter()
            .find(|l| l.config().transport.same_endpoint(&transport))
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
        if decl.name.is_none() && !transport.is_configured() {
            // Nothing to name it by: without a name a port is required.
            return Err(DeclareError::Rules(vec![RuleError::NoPort]));
        }
        let name = decl
            .name
            .clone()
            .unwrap_or_else(|| default_name(&transport));
        valid_name("link", &name)?;
        if let Some(other) = registry.link(&name) {
            // A link declared without a port gets one when it is declared again with it,
            // the way a `SerialLink` instance whose port was empty is called again.
            if !other.is_configured() {
                if transport.is_configured() {
                    other.configure(transport.clone(), guard_time);
                    tracing::info!(link = %name, "link given its port");
                }
                return Ok(Ensured {
                    value: other.clone(),
                    created: false,
                });
            }
            return Err(DeclareError::NameTaken {
                name,
                endpoint: other.config().transport.to_string(),
            });
        }
        if registry
            .links
            .iter()
            .filter(|l| l.config().line == 0)
            .count()
            >= MAX_DECLARED_LINKS
        {
            return Err(DeclareError::TooMany("links", MAX_DECLARED_LINKS));
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

/// Removes a device declared at run time: it is no longer polled, its simulator stops, and
/// writes still waiting for it fail. A device from the config file stays.
pub(crate) fn remove_device(cache: &Cache, name: &str) -> Result<Arc<Device>, DeclareError> {
    let device = cache.change(|registry: &mut Registry| {
        let device = registry
            .device(name)
            .cloned()
            .ok_or_else(|| DeclareError::NotFound(AccessError::UnknownDevice(quote(name))))?;
        if device.config.line != 0 {
            return Err(DeclareError::FromConfig {
                what: "device",
                name: device.name().to_owned(),
            });
        }
        cache.remove_device(registry, &device, "the device was removed");
        Ok(device)
    })?;
    tracing::info!(device = %device.name(), "device removed");
    Ok(device)
}

/// Removes a link declared at run time once no device (and nothing in `users`, the standing
/// transactions on it) uses it; its task stops and closes the port or socket.
pub(crate) fn remove_link(
    cache: &Cache,
    name: &str,
    users: Vec<String>,
) -> Result<Arc<Link>, DeclareError> {
    let link = cache.change(|registry: &mut Registry| {
        let link = registry
            .link(name)
            .cloned()
            .ok_or_else(|| DeclareError::NotFound(AccessError::UnknownLink(quote(name))))?;
        if link.config().line != 0 {
            return Err(DeclareError::FromConfig {
                what: "link",
                name: link.name().to_owned(),
            });
        }
        let mut by: Vec<String> = registry
            .devices
            .iter()
            .filter(|d| d.binding().link.as_deref() == Some(link.name()))
            .map(|d| format!("device {}", d.name()))
            .collect();
        by.extend(users.into_iter().map(|t| format!("transaction {t}")));
        if !by.is_empty() {
            return Err(DeclareError::InUse {
                link: link.name().to_owned(),
                by,
            });
        }
        cache.remove_link(registry, &link);
        Ok(link)
    })?;
    tracing::info!(link = %link.name(), "link removed");
    Ok(link)
}

/// Where `decl` differs from the device `existing` of the same name. A link or slave id the
/// device does not have yet is no conflict: declaring it binds the device.
fn device_conflicts(
    existing: &Device,
    decl: &DeviceDeclaration,
    profile: &str,
    want: &Binding,
) -> Vec<Conflict> {
    let mut conflicts = Vec::new();
    let (config, have) = (&existing.config, existing.binding());
    if config.profile != profile {
        conflicts.push(Conflict::Profile {
            have: config.profile.clone(),
            want: profile.to_owned(),
        });
    }
    if have.link.is_some() && have.link != want.link {
        conflicts.push(Conflict::Link {
            have: have.link.clone(),
            want: want.link.clone(),
        });
    }
    if have.slave_id.is_some() && have.slave_id != want.slave_id {
        conflicts.push(Conflict::SlaveId {
            have: have.slave_id.unwrap_or(0),
            want: want.slave_id.unwrap_or(0),
        });
    }
    let config = &existing.config;
    if config.refresh_rate != decl.refresh_rate {
        conflicts.push(Conflict::RefreshRate {
            have: config.refresh_rate,
            want: decl.refresh_rate,
        });
    }
    if let Some(want) = decl.timeout.filter(|t| *t != config.timeout) {
        conflicts.push(Conflict::Timeout {
            have: config.timeout,
            want,
        });
    }
    conflicts
}

/// Declares a device: returns the device of that name if its settings agree, creates it
/// otherwise. Its link's task starts polling it at once; a simulated device gets its task.
///
/// A Modbus device declared with no link, or with slave id 0, is accepted and reports
/// error 1 (no link) or 2 (no slave) until it is declared again with them, as the device
/// function blocks of source document 000 do when called before their link is set. (A
/// config file refuses such devices: a file has no "later".)
pub(crate) fn ensure_device(
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
    let mut broken: Vec<RuleError> = rules::binding(&profile, link, slave)
        .into_iter()
        .filter(|e| !matches!(e, RuleError::NoLink { .. } | RuleError::NoSlave))
        .collect();
    broken.extend(rules::period("refresh_rate", decl.refresh_rate).err());
    if let Some(t) = decl.timeout {
        broken.extend(rules::period("timeout", t).err());
    }
    if !REFRESH_RATES.contains(&decl.refresh_rate) {
        return Err(DeclareError::OutOfBounds(format!(
            "refresh_rate {} ms is outside 1 ms - 1 h",
            decl.refresh_rate.as_millis()
        )));
    }
    if let Some(t) = decl.timeout.filter(|t| !TIMEOUTS.contains(t)) {
        return Err(DeclareError::OutOfBounds(format!(
            "timeout {} ms is outside 10 ms - 10 s (no device may hold its link longer)",
            t.as_millis()
        )));
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
                        |l| matches!(&l.config().transport, Transport::Serial(s) if s.port == link),
                    )
                });
                let found = found.ok_or_else(|| DeclareError::UnknownLink(crate::text::quote(link)))?;
                Some(found.name().to_owned())
            }
        };
        let slave_id = slave.and_then(|id| rules::slave_id(id).ok());
        let want = Binding {
            link: link.clone(),
            slave_id,
        };
        if let Some(other) = registry
            .devices
            .iter()
            .find(|d| d.name() != decl.name && d.name().eq_ignore_ascii_case(&decl.name))
        {
            return Err(DeclareError::NameClash {
                what: "device",
                name: decl.name.clone(),
                other: other.name().to_owned(),
            });
        }
        if let Some(existing) = registry.device(&decl.name) {
            let conflicts = device_conflicts(existing, &decl, &profile.name, &want);
            if !conflicts.is_empty() {
                return Err(DeclareError::DeviceConflict {
                    device: decl.name.clone(),
                    conflicts,
                });
            }
            let have = existing.binding();
            if !simulated && have != want && (have.link.is_none() || have.slave_id.is_none()) {
                let bound = Binding {
                    link: have.link.or(want.link),
                    slave_id: have.slave_id.or(want.slave_id),
                };
                tracing::info!(device = %decl.name, link = ?bound.link, slave = ?bound.slave_id, "device bound");
                cache.bind_device(registry, existing, bound);
            }
            return Ok(Ensured {
                value: existing.clone(),
                created: false,
            });
        }
        if registry.devices.iter().filter(|d| d.config.line == 0).count() >= MAX_DECLARED_DEVICES
        {
            return Err(DeclareError::TooMany("devices", MAX_DECLARED_DEVICES));
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
            write_mode: crate::config::WriteMode::default(),
            on_client_loss: None,
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
    use crate::cache::Refusal;
    use crate::config::{Framing, Parity};
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
            framing: String::new(),
        }
    }

    #[test]
    fn a_declared_endpoint_obeys_the_config_rules_and_defaults() {
        let Ok(Transport::Serial(s)) = serial(9600, "").transport() else {
            panic!("valid serial settings")
        };
        assert_eq!((s.data_bits, s.stop_bits, s.parity), (8, 1, Parity::None));
        let err = serial(5, "X").transport().expect_err("bad parity and baud");
        assert_eq!(
            err.to_string(),
            "parity: Invalid parity configuration.\n`X` is not N, E or O; baud: Invalid baudrate configuration.\n5 baud is outside 300-4000000",
            "every problem at once"
        );
        let err = serial(5, "E").transport().expect_err("bad baud");
        assert_eq!(err.refusal(), Refusal::Invalid);
        assert!(
            err.to_string()
                .contains("Invalid baudrate configuration.\n5 baud")
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
        let setup = crate::app::Setup::demo_simulated().expect("demo");
        let cache = Cache::new(&setup.config, setup.catalog);
        let tasks = Tasks::new(
            TaskTracker::new(),
            CancellationToken::new(),
            Arc::new(Metrics::new()),
        );
        let everything = DeclarePolicy {
            serial_ports: vec!["*".into()],
            ..DeclarePolicy::default()
        };
        let err = ensure_link(
            &cache,
            &tasks,
            &everything,
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

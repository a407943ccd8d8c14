//! Declaring a link: the endpoint the policy allows, the link of that endpoint if its
//! settings agree, a new one (and its task) if there is none.

use super::*;

fn default_name(transport: &Transport) -> String {
    let raw = match transport {
        Transport::Serial(s) => s.port.trim_start_matches('/').to_owned(),
        Transport::Tcp { host, port, .. } => format!("{host}_{port}"),
        Transport::Driver(d) => d.endpoint.clone(),
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

/// Whether a declaration may reach `transport`: a serial port matching the allowed patterns
/// that, if it exists, is a character device; a TCP endpoint in the allowed list.
fn allowed(policy: &DeclarePolicy, transport: &Transport) -> Result<(), DeclareError> {
    match transport {
        Transport::Driver(d) => Err(DeclareError::NotAllowed(format!(
            "{} links are configured in the config file, not declared",
            d.protocol
        ))),
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
            return given_port(other, name, &transport, guard_time);
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

/// The link `other` already named `name`: a link declared without a port gets one when it
/// is declared again with it, the way a `SerialLink` instance whose port was empty is
/// called again; a link with a port of its own keeps its name.
fn given_port(
    other: &Arc<Link>,
    name: String,
    transport: &Transport,
    guard_time: Duration,
) -> Result<Ensured<Link>, DeclareError> {
    if other.is_configured() {
        return Err(DeclareError::NameTaken {
            name,
            endpoint: other.config().transport.to_string(),
        });
    }
    if transport.is_configured() {
        other.configure(transport.clone(), guard_time);
        tracing::info!(link = %name, "link given its port");
    }
    Ok(Ensured {
        value: other.clone(),
        created: false,
    })
}

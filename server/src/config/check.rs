//! Cross-checks: links against each other (one serial port, one set of settings) and
//! devices against the loaded profiles and the configured links.

use std::collections::HashMap;

use super::rules;
use super::{Config, LinkConfig, SerialSettings, Transport};
use crate::profile::Catalog;
use crate::yaml::{Problems, Report};

/// One serial port is one link: two links on one port with different settings are the
/// "configuration mismatch" of source document 004.
pub(super) fn check_ports(links: &[LinkConfig], report: &mut Report) {
    let mut by_port: HashMap<&str, (&LinkConfig, &SerialSettings)> = HashMap::new();
    for link in links {
        let Transport::Serial(s) = &link.transport else {
            continue;
        };
        let Some((first, fs)) = by_port.get(s.port.as_str()) else {
            by_port.insert(&s.port, (link, s));
            continue;
        };
        let ctx = format!("link {}", link.name);
        let mismatches = rules::serial_mismatches(fs, s);
        for m in &mismatches {
            report.push(
                link.line,
                &ctx,
                format!(
                    "{} configuration mismatch.\n{}: {} here, {} in link {} (line {})",
                    m.setting, s.port, m.want, m.have, first.name, first.line
                ),
            );
        }
        if mismatches.is_empty() {
            report.push(
                link.line,
                &ctx,
                format!(
                    "port {} is already link {} (line {}); let the devices share that link",
                    s.port, first.name, first.line
                ),
            );
        }
    }
}

/// A port the Modbus server answers on as a slave is no link's: one owner a port.
pub(super) fn check_server_ports(config: &Config, report: &mut Report) {
    let Some(server) = &config.modbus_server else {
        return;
    };
    for (i, s) in server.serial.iter().enumerate() {
        let link = config
            .links
            .iter()
            .find(|l| matches!(&l.transport, Transport::Serial(line) if line.port == s.line.port));
        if let Some(link) = link {
            report.push(
                s.at,
                format!("modbus_server.serial[{i}].port"),
                format!(
                    "{} is link {}'s port (line {}): a port is either polled by iogate as a master or served as a slave, not both",
                    s.line.port, link.name, link.line
                ),
            );
        }
    }
}

/// Checks devices against the profiles and links: profile exists, simulated devices have no
/// link and slave id, Modbus devices have both.
pub(crate) fn check_devices(config: &Config, catalog: &Catalog) -> Result<(), Problems> {
    let mut report = Report::new(&config.source);
    for d in &config.devices {
        let ctx = format!("device {}", d.name);
        let Some(profile) = catalog.get(&d.profile) else {
            // A link named but not configured is wrong whatever the profile.
            unknown_link(config, d, &mut report);
            if catalog.is_unreadable(&d.profile) {
                continue; // the profile's own problems are reported
            }
            let known: Vec<_> = catalog.iter().map(|p| p.name.as_str()).collect();
            let message = match known.iter().find(|k| k.eq_ignore_ascii_case(&d.profile)) {
                Some(near) => format!(
                    "unknown profile `{}`: profile names are case-sensitive, did you mean `{near}`?",
                    d.profile
                ),
                None => format!(
                    "unknown profile `{}` (known: {})",
                    d.profile,
                    if known.is_empty() {
                        "none".to_owned()
                    } else {
                        known.join(", ")
                    }
                ),
            };
            report.push(d.line, &ctx, message);
            continue;
        };
        let link = d.link.as_deref();
        let slave_refused = config.unreadable.slave_ids.contains(&d.name);
        for e in rules::binding(profile, link, d.slave_id.map(u64::from)) {
            // A slave_id that was written but refused is reported where it is written.
            if slave_refused && matches!(e, rules::RuleError::NoSlave) {
                continue;
            }
            report.push(d.line, &ctx, e.to_string());
        }
        if profile.protocol != crate::profile::Protocol::Simulated {
            unknown_link(config, d, &mut report);
            wrong_link(config, d, profile, &mut report);
        }
        for (field, text) in d.on_client_loss.iter().flat_map(|l| &l.safe) {
            if let Err(why) = safe_value(profile, field, text) {
                report.push(d.line, format!("{ctx}: on_client_loss.safe.{field}"), why);
            }
        }
    }
    let problems = report.into_problems();
    if problems.is_empty() {
        Ok(())
    } else {
        Err(problems)
    }
}

/// A device's `link` of another protocol than its profile's: a Modbus device on an OPC UA
/// link, or the other way round.
fn wrong_link(
    config: &Config,
    d: &super::DeviceConfig,
    profile: &crate::profile::Profile,
    report: &mut Report,
) {
    let Some(link) = d
        .link
        .as_deref()
        .and_then(|l| config.links.iter().find(|c| c.name == l))
    else {
        return;
    };
    let speaks = match &link.transport {
        super::Transport::Driver(x) => Some(x.protocol),
        _ => None,
    };
    if speaks != profile.protocol.link_key() {
        let link_is = speaks.map_or("a Modbus link".to_owned(), |p| format!("an {p} link"));
        report.push(
            d.line,
            format!("device {}: link", d.name),
            format!(
                "profile {} is {}, but link {} is {link_is}",
                profile.name,
                profile.protocol.name(),
                link.name
            ),
        );
    }
}

/// A device's `link` that names no link of the file.
fn unknown_link(config: &Config, d: &super::DeviceConfig, report: &mut Report) {
    let Some(link) = d.link.as_deref() else {
        return;
    };
    if config.links.iter().any(|l| l.name == link)
        || config.unreadable.links.iter().any(|l| l == link)
    {
        return;
    }
    let known: Vec<_> = config.links.iter().map(|l| l.name.as_str()).collect();
    report.push(
        d.line,
        format!("device {}", d.name),
        format!(
            "unknown link `{link}` (known: {})",
            if known.is_empty() {
                "none".to_owned()
            } else {
                known.join(", ")
            }
        ),
    );
}

/// Why an `on_client_loss.safe` entry is refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub(crate) enum SafeValueError {
    #[error("profile {profile} has no field `{field}`")]
    NoField { profile: String, field: String },
    #[error("{field} is an input: only outputs have safe values")]
    Input { field: String },
    #[error("`{}` is not a {ty} value: {reason}", crate::text::quote(text))]
    Value {
        text: String,
        ty: crate::codec::IecType,
        reason: crate::codec::ValueError,
    },
    #[error("`{}` would be refused by a write: {reason}", crate::text::quote(text))]
    Register {
        text: String,
        reason: crate::codec::CodecError,
    },
}

/// The field index and value of one `on_client_loss.safe` entry: an output (or inout) of
/// the profile, and a value of its type.
pub(crate) fn safe_value(
    profile: &crate::profile::Profile,
    field: &str,
    text: &str,
) -> Result<(usize, crate::codec::Value), SafeValueError> {
    let idx = profile
        .field_index(field)
        .ok_or_else(|| SafeValueError::NoField {
            profile: profile.name.clone(),
            field: field.to_owned(),
        })?;
    let f = &profile.fields[idx];
    if f.direction == crate::profile::Direction::Input {
        return Err(SafeValueError::Input {
            field: field.to_owned(),
        });
    }
    let invalid = |reason| SafeValueError::Value {
        text: text.to_owned(),
        ty: f.ty,
        reason,
    };
    let value = crate::codec::Value::parse(f.ty, text).map_err(invalid)?;
    // The type's own range, as every write is checked (99999 is no INT, whatever the
    // device): parsing reads the number, this says whether the type holds it.
    let value = match (&value, value.as_i128()) {
        (crate::codec::Value::Int(_) | crate::codec::Value::UInt(_), Some(n)) => {
            crate::codec::Value::from_int(f.ty, n).map_err(invalid)?
        }
        (crate::codec::Value::Real(_) | crate::codec::Value::LReal(_), _) => {
            let x = value.as_f64().unwrap_or(f64::NAN);
            crate::codec::Value::from_real(f.ty, x).map_err(invalid)?
        }
        _ => value,
    };
    // The same check as a write's: the value must fit the register once scaled.
    let on_the_bus = profile.protocol != crate::profile::Protocol::Simulated
        && f.register.kind != crate::profile::RegisterKind::Virtual;
    if on_the_bus && let Err(reason) = f.encoding.encode(&value) {
        return Err(SafeValueError::Register {
            text: text.to_owned(),
            reason,
        });
    }
    Ok((idx, value))
}

/// What the security section gives the listeners.
#[derive(Debug, Default)]
pub(crate) struct Access {
    pub(crate) tokens: crate::auth::Tokens,
    pub(crate) tls: Option<crate::tls::Tls>,
}

/// The security rules of a config: its tokens and TLS files load, and without tokens the
/// HTTP and gRPC listeners stay on loopback unless `security.insecure: true` says otherwise.
pub(crate) fn check_security(config: &Config) -> Result<Access, Problems> {
    let mut report = Report::new(&config.source);
    let mut problems = Problems::default();
    let security = &config.security;
    let tokens = match crate::auth::Tokens::load(security.tokens_file.as_deref()) {
        Ok(tokens) => tokens,
        Err(bad) => {
            use crate::auth::TokensProblem;
            // A bad line (or byte) of the tokens file is reported in that file; a file that
            // cannot be read at the config's `tokens_file` key.
            let in_tokens_file = |line: u64, message: String| crate::yaml::Problem {
                file: security
                    .tokens_file
                    .as_ref()
                    .map_or_else(String::new, |f| f.display().to_string()),
                line,
                context: "security.tokens_file".to_owned(),
                message,
            };
            for problem in bad {
                match problem {
                    TokensProblem::Line { line, message }
                    | TokensProblem::File {
                        line: Some(line),
                        message,
                    } => problems.0.push(in_tokens_file(line, message)),
                    TokensProblem::File {
                        line: None,
                        message,
                    } => report.push(security.tokens_file_line, "security.tokens_file", message),
                    TokensProblem::Env { entry, message } => report.push(
                        security.tokens_file_line,
                        "IOGATE_TOKENS",
                        format!("entry {entry}: {message}"),
                    ),
                }
            }
            crate::auth::Tokens::default()
        }
    };
    let tls = security.tls.clone().and_then(|files| {
        crate::tls::Tls::load(files)
            .map_err(|e| report.push(security.tls_line, "security.tls", e.to_string()))
            .ok()
    });
    if tokens.is_empty() && !security.insecure {
        for (key, addr, line) in [
            ("listen.http", config.http, config.lines.http),
            ("listen.grpc", config.grpc, config.lines.grpc),
        ] {
            if !addr.ip().is_loopback() {
                report.push(
                    line,
                    key,
                    format!(
                        "{addr} is not a loopback address and no tokens are configured: set security.tokens_file (or IOGATE_TOKENS), or security.insecure: true to serve it unauthenticated"
                    ),
                );
            }
        }
    }
    let exposure = super::Exposure {
        no_tokens: tokens.is_empty(),
        insecure: security.insecure,
    };
    for section in config.sections.read() {
        section.check_exposure(&exposure, &mut report);
    }
    problems.extend(report.into_problems());
    if problems.is_empty() {
        Ok(Access { tokens, tls })
    } else {
        Err(problems)
    }
}

#[cfg(test)]
mod safe_value_tests {
    use super::*;

    #[test]
    fn a_safe_value_outside_its_type_is_refused_on_a_simulated_device_too() {
        let profile = crate::profile::load_str(
            "sim.yaml",
            "name: Sim\nprotocol: simulated\nfields:\n  - { name: AO_1, type: INT, direction: output, register: { address: 0, kind: virtual } }\n  - { name: R, type: REAL, direction: output, register: { address: 1, kind: virtual } }\n",
        )
        .expect("profile");
        let refused = safe_value(&profile, "AO_1", "99999").expect_err("no INT");
        assert!(
            refused.to_string().contains("`99999` is not a INT value"),
            "{refused}"
        );
        assert!(safe_value(&profile, "AO_1", "-32768").is_ok());
        assert!(safe_value(&profile, "R", "1e39").is_err(), "no REAL either");
        assert!(safe_value(&profile, "R", "2.5").is_ok());
    }
}

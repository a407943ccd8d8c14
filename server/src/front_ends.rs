//! The gateway's front-ends as one list ([`all`]), and what the composition root, the
//! setup and the reloader do with the whole list: read the front-ends' own sections, read
//! what they name as `check` does, prepare and start them, print their banner lines. The
//! contract each follows is `api::front_end`. Adding a front-end is its folder under
//! `api/` and its line in [`all`].

use std::path::Path;
use std::sync::Arc;

use crate::api;
use crate::api::front_end::{FrontEnd, Held, Prepare, Start, Starting};
use crate::config::{CORE_KEYS, Config};
use crate::service::Service;
use crate::tls::Tls;
use crate::yaml::{Problems, Report};

/// Every front-end, in the order they start.
pub(crate) fn all() -> Vec<Box<dyn FrontEnd>> {
    vec![
        Box::new(api::http::front_end::HttpFrontEnd),
        Box::new(api::grpc::front_end::GrpcFrontEnd),
        Box::new(api::modbus_server::front_end::ModbusTcpFrontEnd),
        Box::new(api::modbus_serial::front_end::ModbusSerialFrontEnd),
        Box::new(api::mqtt::MqttFrontEnd),
        Box::new(api::opcua::OpcUaFrontEnd),
        Box::new(api::iec104_server::Iec104FrontEnd),
    ]
}

/// Every front-end's banner lines, in the list's order, then their closing lines.
pub(crate) fn banners(service: &Service) -> Vec<String> {
    let front_ends = all();
    let lines = front_ends.iter().flat_map(|f| f.banner(service));
    let end = front_ends.iter().flat_map(|f| f.banner_end(service));
    lines.chain(end).collect()
}

/// What the front-ends add to the API's description, in the list's order.
pub(crate) fn described() -> crate::service::doors::Described {
    let front_ends = all();
    crate::service::doors::Described {
        section_keys: front_ends
            .iter()
            .filter(|f| f.has_section())
            .map(|f| f.name())
            .collect(),
        listeners: front_ends.iter().filter_map(|f| f.listener()).collect(),
        health: front_ends
            .iter()
            .filter_map(|f| f.health_schema())
            .collect(),
    }
}

/// Reads the sections the config reader kept (`Config::sections`), each by the front-end
/// of its key; a key no front-end reads is unknown, as the config reader would say. A
/// section read before (a reload's, a test's) is kept as it is.
pub(crate) fn read_sections(config: &mut Config) -> Problems {
    let mut report = Report::new(&config.source);
    let front_ends: Vec<_> = all().into_iter().filter(|f| f.has_section()).collect();
    let mut read = Vec::new();
    for (key, line, node) in config.sections.written() {
        if config.sections.section(key).is_some() {
            continue;
        }
        match front_ends.iter().find(|f| f.name() == key) {
            // A section written without a value is absent, as the config reader has it.
            Some(_) if node.kind == crate::yaml::Kind::Null => {}
            Some(front_end) => {
                if let Some(section) = front_end.read(node, &mut report) {
                    read.push((key.to_owned(), section));
                }
            }
            None => {
                let known = CORE_KEYS
                    .iter()
                    .copied()
                    .chain(front_ends.iter().map(|f| f.name()));
                report.push(
                    line,
                    "config",
                    format!(
                        "unknown key `{key}` (expected one of: {})",
                        known.collect::<Vec<_>>().join(", ")
                    ),
                );
            }
        }
    }
    for (key, section) in read {
        config.sections.set(&key, section);
    }
    report.into_problems()
}

/// What every front-end's section names outside the file, read as `check` does: one that
/// cannot be read (a password file, say) is a problem at its section's line.
pub(crate) fn check_files(
    config: &Config,
    catalog: &crate::profile::Catalog,
    base: &Path,
) -> Problems {
    let mut report = Report::new(&config.source);
    for front_end in all() {
        if let Err(problems) = front_end.check_files(config, catalog, base) {
            let line = config
                .sections
                .section(front_end.name())
                .map_or(0, |s| s.line());
            for e in problems {
                report.push(line, front_end.name(), e);
            }
        }
    }
    report.into_problems()
}

/// Prepares every front-end of the list for a start: every listener bound, every file
/// read, before anything else is done.
pub(crate) async fn prepare_all(
    config: &Config,
    base: &Path,
) -> Result<Vec<(&'static str, Box<dyn Starting>)>, String> {
    let prepare = Prepare {
        config,
        old: None,
        now: None,
        base,
    };
    let mut prepared = Vec::new();
    for front_end in all() {
        if let Some(starting) = front_end.prepare(&prepare).await? {
            prepared.push((front_end.name(), starting));
        }
    }
    Ok(prepared)
}

/// Starts the front-ends prepared, in order.
pub(crate) async fn start_all(
    service: &Arc<Service>,
    prepared: Vec<(&'static str, Box<dyn Starting>)>,
    tls: Option<Arc<Tls>>,
) -> Result<Vec<Held>, String> {
    let mut held = Vec::new();
    for (name, starting) in prepared {
        let start = Start {
            service: service.clone(),
            carried: None,
            tls: tls.clone(),
        };
        held.push(Held {
            name,
            running: starting.start(start).await?,
        });
    }
    Ok(held)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn problems(text: &str) -> (Config, String) {
        let mut config = crate::config::parse("iogate.yaml", text).expect("parses");
        let problems = read_sections(&mut config).to_string();
        (config, problems)
    }

    #[test]
    fn a_key_no_front_end_reads_is_named_with_or_without_a_value() {
        let (_, p) = problems("mqqt:\n");
        assert!(
            p.contains("iogate.yaml:1: config: unknown key `mqqt`"),
            "{p}"
        );
        let (_, p) = problems("mqqt: { url: mqtt://x }\n");
        assert!(p.contains("unknown key `mqqt`"), "{p}");
        // A front-end's section written without a value is absent.
        let (config, p) = problems("mqtt:\n");
        assert_eq!(p, "");
        assert!(config.sections.section("mqtt").is_none());
    }
}

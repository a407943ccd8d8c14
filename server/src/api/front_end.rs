//! The contract of a front-end started from a section of its own and started again by a
//! reload when that section changes (MQTT, OPC UA). The composition root starts them, and
//! the reloader compares, stops and starts them, as one list ([`all`]) knowing none by
//! name. Adding such a front-end is its folder and its line in [`all`].

use std::any::Any;
use std::path::Path;
use std::sync::Arc;

use futures_util::future::BoxFuture;

use crate::config::{CORE_KEYS, Config, Section};
use crate::service::{Action, Kind, Service};
use crate::yaml::{Node, Problems, Report};

/// What a stopped front-end hands to the one started after it (MQTT's next `bdSeq`).
pub(crate) type Carried = Option<Box<dyn Any + Send>>;

/// A kind of front-end.
pub(crate) trait FrontEnd: Send + Sync {
    /// Its section's key.
    fn name(&self) -> &'static str;

    /// The kind of a reload report's item about its section.
    fn kind(&self) -> Kind;

    /// Reads its section as written (`node`, never `null`), every problem with its line.
    fn read(&self, node: &Node, report: &mut Report) -> Option<Box<dyn Section>>;

    /// Its line of the banner `serve` prints, when it runs.
    fn banner(&self, _service: &Service) -> Option<String> {
        None
    }

    /// How its section changed from `old` to `new`, as a reload's report says it (the
    /// action and its details); `None` when it did not. A change restarts the front-end.
    fn changed(&self, old: &Config, new: &Config) -> Option<(Action, Vec<String>)>;

    /// Reads what its section names outside the file (passwords, certificates), before
    /// anything is started or a reload applies anything: a problem is named and stops the
    /// start (or refuses the reload). `None` when the section is absent.
    fn prepare(&self, config: &Config, base: &Path) -> Result<Option<Box<dyn Starting>>, String>;
}

/// A front-end prepared and ready to start.
pub(crate) trait Starting: Send {
    fn start(
        self: Box<Self>,
        service: Arc<Service>,
        carried: Carried,
    ) -> BoxFuture<'static, Result<Box<dyn Running>, String>>;
}

/// A front-end that runs.
pub(crate) trait Running: Send + Sync {
    /// Stops it (its sessions said goodbye to, its port released); what its successor
    /// carries on, or why it did not stop in time.
    fn stop(self: Box<Self>, service: Arc<Service>) -> BoxFuture<'static, Result<Carried, String>>;
}

/// Every front-end of this kind, in the order they start.
pub(crate) fn all() -> Vec<Box<dyn FrontEnd>> {
    vec![
        Box::new(super::mqtt::MqttFrontEnd),
        Box::new(super::opcua::OpcUaFrontEnd),
    ]
}

/// Reads the sections the config reader kept (`Config::sections`), each by the front-end
/// of its key; a key no front-end reads is unknown, as the config reader would say. A
/// section read before (a reload's, a test's) is kept as it is.
pub(crate) fn read_sections(config: &mut Config) -> Problems {
    let mut report = Report::new(&config.source);
    let front_ends = all();
    let mut read = Vec::new();
    for (key, line, node) in config.sections.written() {
        if config.sections.section(key).is_some() || node.kind == crate::yaml::Kind::Null {
            continue;
        }
        match front_ends.iter().find(|f| f.name() == key) {
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

/// Prepares every configured front-end without starting it, as `check` does: what its
/// section names outside the file (a password file, say) that cannot be read is a problem
/// at its section's line.
pub(crate) fn check_prepare(config: &Config, base: &Path) -> Problems {
    let mut report = Report::new(&config.source);
    for front_end in all() {
        if let Err(e) = front_end.prepare(config, base) {
            let line = config
                .sections
                .section(front_end.name())
                .map_or(0, |s| s.line());
            report.push(line, front_end.name(), e);
        }
    }
    report.into_problems()
}

/// Every front-end's banner line, in the list's order.
pub(crate) fn banners(service: &Service) -> Vec<String> {
    all().iter().filter_map(|f| f.banner(service)).collect()
}

/// A config from text with its front-ends' sections read (the sections' unit tests).
#[cfg(test)]
pub(crate) fn parse_config(text: &str) -> Config {
    let mut config = crate::config::parse("iogate.yaml", text).expect("parses");
    let problems = read_sections(&mut config);
    assert!(problems.is_empty(), "{problems}");
    config
}

/// A running front-end with its name, as the composition root and the reloader hold it.
pub(crate) struct Held {
    pub(crate) name: &'static str,
    pub(crate) running: Box<dyn Running>,
}

/// Prepares and starts every configured front-end of the list.
pub(crate) async fn start_all(
    service: &Arc<Service>,
    config: &Config,
    base: &Path,
) -> Result<Vec<Held>, String> {
    let mut held = Vec::new();
    for front_end in all() {
        if let Some(starting) = front_end.prepare(config, base)? {
            let running = starting.start(service.clone(), None).await?;
            held.push(Held {
                name: front_end.name(),
                running,
            });
        }
    }
    Ok(held)
}

//! What a reload may not do to what was declared at run time: take a declared name for a
//! config entry, or drop a link declared devices are on.

use crate::service::Service;
use crate::setup::Setup;
use crate::yaml::{Problems, Report as Problem};

/// A config entry whose name is taken by a link or device declared at run time: a reload
/// never removes what was declared, so the entry is a problem.
pub(super) fn clashes(service: &Service, old: &Setup, new: &Setup) -> Option<Problems> {
    let mut report = Problem::new(&new.config.source);
    for link in &new.config.links {
        let declared = service
            .cache
            .link(&link.name)
            .is_ok_and(|_| !old.config.links.iter().any(|l| l.name == link.name));
        if declared {
            report.push(
                link.line,
                format!("link {}", link.name),
                "a link of this name was declared at run time (EnsureLink or PUT); remove the declaration or rename the entry".to_owned(),
            );
        }
    }
    for device in &new.config.devices {
        let declared = service
            .cache
            .device(&device.name)
            .is_ok_and(|_| !old.config.devices.iter().any(|d| d.name == device.name));
        if declared {
            report.push(
                device.line,
                format!("device {}", device.name),
                "a device of this name was declared at run time (EnsureDevice or PUT); remove the declaration or rename the entry".to_owned(),
            );
        }
    }
    // A link the new file no longer has, still carrying devices declared at run time: the
    // reload would leave them on nothing (as DELETE of a link in use is refused, so is this).
    for link in &old.config.links {
        if new.config.links.iter().any(|l| l.name == link.name) {
            continue;
        }
        let declared: Vec<String> = service
            .devices()
            .iter()
            .filter(|d| d.binding().link.as_deref() == Some(link.name.as_str()))
            .filter(|d| {
                let name = d.name();
                !old.config.devices.iter().any(|o| o.name == name)
                    && !new.config.devices.iter().any(|n| n.name == name)
            })
            .map(|d| d.name().to_owned())
            .collect();
        if !declared.is_empty() {
            report.push(
                1,
                format!("link {}", link.name),
                format!(
                    "the file no longer has link {} (line {} before), but device(s) {} declared at run time are on it: remove them first (DELETE or RemoveDevice), or keep the link",
                    link.name,
                    link.line,
                    declared.join(", ")
                ),
            );
        }
    }
    pair_terms(old, new, &mut report);
    let problems = report.into_problems();
    (!problems.is_empty()).then_some(problems)
}

/// The pair's terms are fixed for the life of the process: a node that took a lease in one
/// group, or under one name, cannot change them under the other node's feet.
fn pair_terms(old: &Setup, new: &Setup, report: &mut Problem) {
    let terms = |c: &crate::config::Config| {
        c.ha.clone().map(|mut ha| {
            ha.line = 0;
            ha
        })
    };
    if terms(&old.config) != terms(&new.config) {
        let line = new.config.ha.as_ref().map_or(1, |ha| ha.line);
        report.push(
            line,
            "ha",
            "the `ha:` section changed: a node of a pair takes its terms (node, arbiter, lease, group) at start; restart the gateway to change them (the other node takes over meanwhile)",
        );
    }
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use super::*;

    fn setup(ha: &str) -> Setup {
        let text =
            format!("mqtt: {{ url: \"mqtt://127.0.0.1:1883\", json: {{ prefix: p }} }}\n{ha}");
        let config = crate::config::parse("iogate.yaml", &text).expect("config parses");
        Setup::from_config(config, Path::new(".")).expect("config checks")
    }

    #[test]
    fn a_reload_that_changes_the_pairs_terms_is_refused_and_one_that_keeps_them_is_not() {
        let a = setup("ha: { node: a, arbiter: mqtt, lease: 3s }\n");
        let moved = setup("\n\nha: { node: a, arbiter: mqtt, lease: 3s }\n");
        let mut report = Problem::new(&moved.config.source);
        pair_terms(&a, &moved, &mut report);
        assert!(report.into_problems().is_empty(), "only its line moved");
        let longer = setup("ha: { node: a, arbiter: mqtt, lease: 4s }\n");
        let mut report = Problem::new(&longer.config.source);
        pair_terms(&a, &longer, &mut report);
        let problems = report.into_problems().to_string();
        assert!(problems.contains("`ha:` section changed"), "{problems}");
    }
}

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
    let problems = report.into_problems();
    (!problems.is_empty()).then_some(problems)
}

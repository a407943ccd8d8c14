//! What the rest of the house asks of the drivers without naming one: a value checked
//! before it is sent, the links' and devices' settings checked (each alone, and against
//! each other: what a link takes of the host, what names a device on its link), the
//! warnings of the links' settings, and what `iogate plan` prints of a link.

use super::{Driver, Facts, ForDriver, Planned, for_protocol, with_driver};
use crate::cache::Device;
use crate::codec::Value;
use crate::config::{DeviceConfig, LinkConfig};

/// Whether the device's protocol can hold `value` where field `idx` is (a write refused
/// before it is sent is refused at once, with why, not accepted and then failed).
pub(crate) fn check_value(device: &Device, idx: usize, value: &Value) -> Result<(), String> {
    struct Check<'a>(&'a Device, usize, &'a Value);
    impl ForDriver for Check<'_> {
        type Output = Result<(), String>;
        fn with<D: Driver>(self) -> Result<(), String> {
            D::check_value(self.0, self.1, self.2)
        }
    }
    for_protocol(device.profile.protocol, Check(device, idx, value)).unwrap_or(Ok(()))
}

/// Whether field `idx` of a device can be relinquished, as its driver says (a simulated
/// device holds what is written: it has none).
pub(crate) fn check_relinquish(device: &Device, idx: usize) -> Result<(), String> {
    struct Check<'a>(&'a Device, usize);
    impl ForDriver for Check<'_> {
        type Output = Result<(), String>;
        fn with<D: Driver>(self) -> Result<(), String> {
            D::check_relinquish(self.0, self.1)
        }
    }
    let none = || Err("a simulated device has no relinquish; write a value".to_owned());
    if device.is_simulated() {
        return none();
    }
    for_protocol(device.profile.protocol, Check(device, idx)).unwrap_or_else(none)
}

/// What `check` finds wrong with the links' settings that their drivers read.
pub(crate) fn check_links(config: &crate::config::Config) -> crate::yaml::Problems {
    struct Check<'a>(&'a LinkConfig, &'a mut crate::yaml::Report);
    impl ForDriver for Check<'_> {
        type Output = ();
        fn with<D: Driver>(self) {
            D::check(self.0, self.1);
        }
    }
    struct CheckDevice<'a>(&'a DeviceConfig, &'a mut crate::yaml::Report);
    impl ForDriver for CheckDevice<'_> {
        type Output = ();
        fn with<D: Driver>(self) {
            D::check_device(self.0, self.1);
        }
    }
    let mut report = crate::yaml::Report::new(&config.source);
    for link in &config.links {
        with_driver(link, Check(link, &mut report));
    }
    for device in &config.devices {
        let link = config
            .links
            .iter()
            .find(|l| device.link.as_ref() == Some(&l.name));
        if let Some(link) = link {
            with_driver(link, CheckDevice(device, &mut report));
        }
    }
    check_unique(config, &mut report);
    report.into_problems()
}

/// Two links that take the same thing of the host, two devices of one link with the same
/// identity: each named once, at the second's line.
fn check_unique(config: &crate::config::Config, report: &mut crate::yaml::Report) {
    struct Claims<'a>(&'a LinkConfig);
    impl ForDriver for Claims<'_> {
        type Output = Option<(String, &'static str)>;
        fn with<D: Driver>(self) -> Self::Output {
            D::claims(self.0)
        }
    }
    struct Identity<'a>(&'a DeviceConfig);
    impl ForDriver for Identity<'_> {
        type Output = Option<String>;
        fn with<D: Driver>(self) -> Option<String> {
            D::device_identity(self.0)
        }
    }
    let mut claimed: std::collections::HashMap<String, &str> = Default::default();
    for link in &config.links {
        let Some((what, why)) = with_driver(link, Claims(link)).flatten() else {
            continue;
        };
        match claimed.get(&what) {
            Some(first) => report.push(
                link.line,
                format!("link {}", link.name),
                format!("link {first} takes {what} already ({why})"),
            ),
            None => {
                claimed.insert(what, &link.name);
            }
        }
    }
    let mut named: std::collections::HashMap<(&str, String), &str> = Default::default();
    for device in &config.devices {
        let Some(link) = config
            .links
            .iter()
            .find(|l| device.link.as_ref() == Some(&l.name))
        else {
            continue;
        };
        let Some(id) = with_driver(link, Identity(device)).flatten() else {
            continue;
        };
        match named.get(&(link.name.as_str(), id.clone())) {
            Some(first) => report.push(
                device.line,
                format!("device {}", device.name),
                format!(
                    "device {first} on link {} has {id} already: one device, one place",
                    link.name
                ),
            ),
            None => {
                named.insert((link.name.as_str(), id), &device.name);
            }
        }
    }
}

/// What `check` and `serve` warn of in the links' settings that their drivers read.
pub(crate) fn link_warnings(config: &crate::config::Config) -> Vec<crate::yaml::Problem> {
    struct Warn<'a>(&'a LinkConfig, &'a mut crate::yaml::Report);
    impl ForDriver for Warn<'_> {
        type Output = ();
        fn with<D: Driver>(self) {
            D::warn(self.0, self.1);
        }
    }
    let mut report = crate::yaml::Report::new(&config.source);
    for link in &config.links {
        with_driver(link, Warn(link, &mut report));
    }
    report.into_problems().0
}

/// What `iogate plan` prints under a link's line: how its driver reads its devices (with
/// what the peer told of itself, for a running link; nothing offline), and the warnings
/// `check` and `serve` print of its plan.
pub(crate) fn describe(
    link: &LinkConfig,
    devices: &Planned<'_>,
    peer: &Facts,
    out: &mut String,
) -> Vec<String> {
    struct Describe<'a, 'b>(&'a LinkConfig, &'a Planned<'b>, &'a Facts, &'a mut String);
    impl ForDriver for Describe<'_, '_> {
        type Output = Vec<String>;
        fn with<D: Driver>(self) -> Vec<String> {
            D::describe(self.0, self.1, self.2, self.3);
            D::plan_warnings(self.0, self.1)
        }
    }
    with_driver(link, Describe(link, devices, peer, out)).unwrap_or_default()
}

//! What `iogate plan` prints of a device whose driver names no requests of its own: one
//! subscription, a monitored item per field (the server samples each; the gateway asks
//! nothing per cycle). The default of `Driver::describe`.

use std::fmt::Write as _;

use crate::config::DeviceConfig;
use crate::profile::Profile;

/// A device of a protocol that names its points, each field with its point.
pub(crate) fn points(out: &mut String, d: &DeviceConfig, profile: &Profile) {
    let count = profile.fields.iter().filter(|f| f.point.is_some()).count();
    let how = format!(
        "a subscription publishing every {} ms, {count} monitored item(s); read every refresh where the server has no subscriptions",
        d.refresh_rate.as_millis()
    );
    let _ = writeln!(
        out,
        "  device {} (profile {}, {}): {how}",
        d.name,
        profile.name,
        profile.protocol.name(),
    );
    for f in &profile.fields {
        if let Some(p) = &f.point {
            let sampling = p.sampling.unwrap_or(d.refresh_rate).as_millis();
            let _ = writeln!(
                out,
                "    {} {} ({}, sampled every {sampling} ms)",
                f.name, p.address, f.ty
            );
        }
    }
}

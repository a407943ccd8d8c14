//! What `iogate plan` prints of a BACnet link's devices: each device's instance and where
//! it is found, its ReadPropertyMultiple requests per cycle, and each field's object and
//! property (with the priority its writes go at).

use std::fmt::Write as _;

use crate::drivers::Planned;

use super::point;
use super::read::PER_REQUEST;

/// The link's devices.
pub(super) fn link(devices: &Planned<'_>, out: &mut String) {
    for (d, profile) in devices {
        let at = match point::device(d.at(point::DEVICE_INSTANCE), d.at(point::ADDRESS)) {
            Ok((instance, Some(address))) => format!("instance {instance} at {address}"),
            Ok((instance, None)) => format!("instance {instance}, found by Who-Is"),
            Err(why) => why,
        };
        let n = profile.fields.iter().filter(|f| f.point.is_some()).count();
        let _ = writeln!(
            out,
            "  device {} (profile {}, bacnet {at}, every {} ms): {} ReadPropertyMultiple request(s) per cycle",
            d.name,
            profile.name,
            d.refresh_rate.as_millis(),
            n.div_ceil(PER_REQUEST),
        );
        for f in &profile.fields {
            let Some(p) = &f.point else { continue };
            let property = p.get(point::PROPERTY).unwrap_or("present-value");
            let priority = if f.direction.is_writable() {
                let at = p
                    .get(point::PRIORITY)
                    .map_or(point::DEFAULT_PRIORITY.to_string(), str::to_owned);
                format!(", written at priority {at}")
            } else {
                String::new()
            };
            let _ = writeln!(
                out,
                "    {} {} {property} ({}{priority})",
                f.name, p.address, f.ty
            );
        }
    }
}

//! What differs between two versions of a link, a device, a field, a profile or a
//! section, in the words a reload's report uses.

use super::*;

pub(super) use crate::service::{changed, changed_text, duration};

/// The Modbus server's TCP address, or that it has none.
pub(super) fn listened(s: &crate::config::modbus_server::ModbusServerConfig) -> String {
    s.listen
        .map_or_else(|| "no TCP listener".to_owned(), |l| l.to_string())
}

pub(super) fn option<T: ToString>(v: &Option<T>) -> String {
    v.as_ref()
        .map_or_else(|| "none".to_owned(), ToString::to_string)
}

/// A link's settings, line apart.
pub(super) fn link_details(old: &LinkConfig, new: &LinkConfig) -> Vec<String> {
    let mut details = Vec::new();
    match (&old.transport, &new.transport) {
        (Transport::Serial(a), Transport::Serial(b)) => details.extend(
            [
                changed_text("serial.port", &a.port, &b.port),
                changed_text("serial.baud", a.baud, b.baud),
                changed_text("serial.parity", a.parity.letter(), b.parity.letter()),
                changed_text("serial.data_bits", a.data_bits, b.data_bits),
                changed_text("serial.stop_bits", a.stop_bits, b.stop_bits),
            ]
            .into_iter()
            .flatten(),
        ),
        (a, b) if a != b => details.push(format!("transport: {a} -> {b}")),
        _ => {}
    }
    details.extend(changed_text(
        "guard_time",
        duration(old.guard_time),
        duration(new.guard_time),
    ));
    details
}

/// A device's settings, line apart (the profile's contents are compared apart).
pub(super) fn device_details(old: &DeviceConfig, new: &DeviceConfig) -> Vec<String> {
    [
        changed_text("profile", &old.profile, &new.profile),
        changed_text("link", option(&old.link), option(&new.link)),
        changed_text("slave_id", option(&old.slave_id), option(&new.slave_id)),
        changed_text(
            "refresh_rate",
            duration(old.refresh_rate),
            duration(new.refresh_rate),
        ),
        changed_text("timeout", duration(old.timeout), duration(new.timeout)),
        changed_text("retries", old.retries, new.retries),
        changed_text("max_batch", old.max_batch, new.max_batch),
        changed_text("max_gap", old.max_gap, new.max_gap),
        changed("write_mode", &old.write_mode, &new.write_mode),
        changed("on_client_loss", &old.on_client_loss, &new.on_client_loss),
    ]
    .into_iter()
    .flatten()
    .collect()
}

/// A field as compared: everything but the line it is written on.
pub(super) fn same_field(a: &Field, b: &Field) -> bool {
    let mut b = b.clone();
    b.line = a.line;
    *a == b
}

/// What differs between two versions of a field.
pub(super) fn field_details(a: &Field, b: &Field) -> Vec<String> {
    let (ra, rb) = (&a.register, &b.register);
    let mut details: Vec<String> = [
        changed_text("type", a.ty, b.ty),
        changed_text("direction", a.direction.name(), b.direction.name()),
        changed_text("register.kind", ra.kind.name(), rb.kind.name()),
        changed_text("register.address", ra.address, rb.address),
        changed_text("register.bit", option(&ra.bit), option(&rb.bit)),
        changed_text("register.scale", ra.scale, rb.scale),
        changed_text("register.offset", ra.offset, rb.offset),
        changed_text("register.unit", option(&ra.unit), option(&rb.unit)),
        changed("register.byte_order", &ra.byte_order, &rb.byte_order),
        changed_text("register.word_count", ra.word_count, rb.word_count),
        changed("register.raw_type", &ra.raw_type, &rb.raw_type),
        changed("register.on_value/off_value", &ra.switch, &rb.switch),
        changed("description", &a.description, &b.description),
        changed("deadband", &a.deadband, &b.deadband),
    ]
    .into_iter()
    .flatten()
    .collect();
    if details.is_empty() {
        details.push("its encoding".to_owned());
    }
    details
}

/// Two versions of a profile as compared: everything but lines and the file's name.
pub(crate) fn same_profile(a: &Profile, b: &Profile) -> bool {
    a.name == b.name
        && a.vendor == b.vendor
        && a.protocol == b.protocol
        && a.description == b.description
        && a.fields.len() == b.fields.len()
        && a.fields
            .iter()
            .zip(&b.fields)
            .all(|(x, y)| same_field(x, y))
}

/// The fields added, removed and changed from profile `a` to `b` (named `prefix.field`).
pub(super) fn field_items(prefix: &str, a: &Profile, b: &Profile) -> Vec<Item> {
    let mut items = Vec::new();
    let item = |name: &str, action, details| Item {
        kind: Kind::Field,
        name: format!("{prefix}.{name}"),
        action,
        details,
    };
    for f in &b.fields {
        match a.field_index(&f.name).map(|i| &a.fields[i]) {
            None => items.push(item(&f.name, Action::Added, Vec::new())),
            Some(old) if !same_field(old, f) => {
                let mut details = field_details(old, f);
                if old.ty != f.ty {
                    details.push("a new field: its old value and subscribers end".to_owned());
                }
                items.push(item(&f.name, Action::Changed, details));
            }
            Some(_) => {}
        }
    }
    for f in &a.fields {
        if b.field_index(&f.name).is_none() {
            items.push(item(&f.name, Action::Removed, Vec::new()));
        }
    }
    items
}

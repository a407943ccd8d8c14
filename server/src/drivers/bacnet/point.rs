//! Where a BACnet field is: its `object` as BACnet users write it (`analog-input:3`: every
//! standard object type by its name, then the instance), its `property` (`present-value`
//! unless it says; `status-flags`, `reliability`, `units` and the rest by their names), and
//! the `priority` its writes go at (1-16, 16 unless it says). Where a device is: its
//! `device_instance` and, optionally, the `address` (`HOST[:PORT]`) that binds it without a
//! Who-Is. Checked when the profile or the configuration is loaded, so a typo is a problem
//! with its line.

use std::net::SocketAddrV4;

use bacnet_types::enums::{ObjectType, PropertyIdentifier};
use bacnet_types::primitives::ObjectIdentifier;

use crate::codec::IecType;
use crate::profile::FieldKey;

/// The field key of the property read (default `present-value`).
pub(crate) const PROPERTY: &str = "property";
/// The field key of the priority its writes go at (default 16, the lowest).
pub(crate) const PRIORITY: &str = "priority";
/// The device keys: its instance number, and the address that binds it statically.
pub(crate) const DEVICE_INSTANCE: &str = "device_instance";
pub(crate) const ADDRESS: &str = "address";
/// The device key that turns its change-of-value subscriptions off (`cov: false`).
pub(crate) const COV: &str = "cov";

/// The priority a write goes at when the field does not say: the lowest, 16.
pub(crate) const DEFAULT_PRIORITY: u8 = 16;

/// A field's further keys.
pub(crate) const FIELD_KEYS: &[FieldKey] = &[
    FieldKey {
        key: PROPERTY,
        check: check_property,
    },
    FieldKey {
        key: PRIORITY,
        check: check_priority,
    },
];

/// An object as written: `TYPE:INSTANCE`.
pub(crate) fn object(text: &str) -> Result<ObjectIdentifier, String> {
    let (kind, instance) = text.rsplit_once(':').ok_or_else(|| {
        format!("`{text}` is not an object (write its type and instance: `analog-input:3`)")
    })?;
    let kind: ObjectType = kind
        .trim()
        .parse()
        .map_err(|_| format!("`{kind}` is not a BACnet object type (such as analog-input, binary-output, multi-state-value)"))?;
    let instance: u32 = instance
        .trim()
        .parse()
        .map_err(|_| format!("`{instance}` in `{text}` is not an instance number"))?;
    if instance >= ObjectIdentifier::MAX_INSTANCE {
        return Err(format!(
            "instance {instance} of `{text}` is past 4194302, the largest"
        ));
    }
    ObjectIdentifier::new(kind, instance).map_err(|e| format!("`{text}`: {e}"))
}

/// A property as written (`present-value`).
pub(crate) fn property(text: &str) -> Result<PropertyIdentifier, String> {
    text.trim()
        .parse()
        .map_err(|_| format!("`{text}` is not a BACnet property (such as present-value, status-flags, reliability, units)"))
}

/// A field's `object`, checked for the field's type.
pub(crate) fn check_object(
    _key: &str,
    text: &str,
    ty: Option<IecType>,
    _length: Option<u16>,
) -> Result<(), String> {
    let id = object(text)?;
    let kind = id.object_type();
    let binary = [
        ObjectType::BINARY_INPUT,
        ObjectType::BINARY_OUTPUT,
        ObjectType::BINARY_VALUE,
    ];
    match ty {
        Some(IecType::Real | IecType::Lreal) if binary.contains(&kind) => Err(format!(
            "a binary object's present value is a BOOL (or an integer), not {}",
            ty.map_or(String::new(), |t| t.to_string())
        )),
        _ => Ok(()),
    }
}

fn check_property(text: &str, _ty: Option<IecType>) -> Result<(), String> {
    property(text).map(drop)
}

fn check_priority(text: &str, _ty: Option<IecType>) -> Result<(), String> {
    priority(text).map(drop)
}

/// A write priority as written: 1 (manual life safety) to 16.
pub(crate) fn priority(text: &str) -> Result<u8, String> {
    text.trim()
        .parse::<u8>()
        .ok()
        .filter(|p| (1..=16).contains(p))
        .ok_or_else(|| format!("`{text}` is not a write priority (1-16; 16 is the lowest)"))
}

/// A device's instance number as written.
pub(crate) fn device_instance(text: &str) -> Result<u32, String> {
    text.trim()
        .parse::<u32>()
        .ok()
        .filter(|i| *i < ObjectIdentifier::MAX_INSTANCE)
        .ok_or_else(|| format!("`{text}` is not a device instance (0-4194302)"))
}

/// Whether a device is subscribed to (its `cov`, true unless it says).
pub(crate) fn cov(text: Option<&str>) -> Result<bool, String> {
    match text.map(str::trim) {
        None | Some("true") => Ok(true),
        Some("false") => Ok(false),
        Some(other) => Err(format!("`cov: {other}`: true or false")),
    }
}

/// A device's place as its configuration says: its instance, and the address binding it.
pub(crate) fn device(
    instance: Option<&str>,
    address: Option<&str>,
) -> Result<(u32, Option<SocketAddrV4>), String> {
    let instance = device_instance(instance.ok_or(
        "a BACnet device needs its `device_instance` (the instance of its device object)",
    )?)?;
    let address = address.map(super::config::address).transpose()?;
    if address.is_some_and(|a| a.port() == 0) {
        return Err("a device's `address` needs its port (not 0)".into());
    }
    if let Some(a) = address
        && (a.ip().is_unspecified() || a.ip().is_broadcast() || a.ip().is_multicast())
    {
        return Err(format!(
            "a device's `address` is one host's ({} is not: a device is asked by unicast)",
            a.ip()
        ));
    }
    Ok((instance, address))
}

/// An object type as a profile writes it (`analog-input`).
pub(crate) fn type_name(kind: ObjectType) -> String {
    kind.to_string().to_ascii_lowercase().replace('_', "-")
}

/// An object as a profile writes it (`analog-input:3`).
pub(crate) fn name(id: bacnet_types::primitives::ObjectIdentifier) -> String {
    format!("{}:{}", type_name(id.object_type()), id.instance_number())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn objects_are_named_by_type_and_instance() {
        let id = object("analog-input:3").expect("object");
        assert_eq!(id.object_type(), ObjectType::ANALOG_INPUT);
        assert_eq!(id.instance_number(), 3);
        assert!(object("multi-state-value:7").is_ok());
        assert!(
            object("analog-inputs:3")
                .expect_err("refused")
                .contains("not a BACnet object type")
        );
        assert!(
            object("analog-input")
                .expect_err("refused")
                .contains("instance")
        );
        assert!(
            object("analog-input:4194303")
                .expect_err("refused")
                .contains("largest")
        );
    }

    #[test]
    fn properties_priorities_and_instances_are_checked() {
        assert_eq!(
            property("status-flags"),
            Ok(PropertyIdentifier::STATUS_FLAGS)
        );
        assert!(property("presentvalue").is_ok());
        assert!(property("present-valu").is_err());
        assert_eq!(priority("8"), Ok(8));
        assert!(priority("0").is_err() && priority("17").is_err());
        assert!(device_instance("4194303").is_err());
        assert!(
            device(None, None)
                .expect_err("refused")
                .contains("device_instance")
        );
        assert_eq!(
            device(Some("1001"), Some("127.0.0.1:47809")).map(|d| d.0),
            Ok(1001)
        );
    }

    #[test]
    fn a_binary_object_is_not_a_real() {
        assert!(check_object("object", "binary-input:1", Some(IecType::Real), None).is_err());
        assert!(check_object("object", "binary-input:1", Some(IecType::Bool), None).is_ok());
    }
}

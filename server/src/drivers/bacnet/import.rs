//! `iogate profile import --from bacnet HOST[:PORT]`: a device's profile from its object
//! list. The device object is read by the wildcard instance (the device says its own), its
//! object list whole or, where the device cannot send it in one answer, element by element;
//! then each object's name (and an analog object's units) in ReadPropertyMultiple requests.
//! Inputs become input fields, outputs and values inout ones, each by its object; what is
//! not a value (the device, its network ports, files, schedules) is named and left out.

use std::collections::HashSet;
use std::fmt::Write as _;
use std::path::Path;

use bacnet_client::client::BACnetClient;
use bacnet_encoding::primitives::decode_application_value;
use bacnet_transport::bip::BipTransport;
use bacnet_types::constructed::{PropertyReference, ReadAccessSpecification};
use bacnet_types::enums::{EngineeringUnits, ObjectType, PropertyIdentifier};
use bacnet_types::primitives::{ObjectIdentifier, PropertyValue};

use crate::drivers::{ImportOptions, option};
use crate::profile::import::{identifier, quoted};

/// The most fields a profile made here holds.
const MAX_FIELDS: usize = 20_000;

/// One field made of an object.
struct Field {
    name: String,
    object: ObjectIdentifier,
    ty: &'static str,
    direction: &'static str,
    unit: Option<String>,
}

/// Runs the import; the exit code: 0 a profile written, 1 nothing could be imported, 64 a
/// bad argument.
pub fn run(target: &str, options: &ImportOptions<'_>, out: Option<&Path>) -> u8 {
    crate::drivers::register();
    crate::profile::import::emit::on_runtime(import(target, options, out))
}

/// The field type and direction an object's present value takes, or why it is left out.
fn kind_of(kind: ObjectType) -> Result<(&'static str, &'static str), String> {
    Ok(match kind {
        ObjectType::ANALOG_INPUT => ("REAL", "input"),
        ObjectType::ANALOG_OUTPUT | ObjectType::ANALOG_VALUE => ("REAL", "inout"),
        ObjectType::BINARY_INPUT => ("BOOL", "input"),
        ObjectType::BINARY_OUTPUT | ObjectType::BINARY_VALUE => ("BOOL", "inout"),
        ObjectType::MULTI_STATE_INPUT => ("UINT", "input"),
        ObjectType::MULTI_STATE_OUTPUT | ObjectType::MULTI_STATE_VALUE => ("UINT", "inout"),
        ObjectType::ACCUMULATOR => ("UDINT", "input"),
        other => {
            return Err(format!(
                "{}: not a value the gateway reads",
                super::point::type_name(other)
            ));
        }
    })
}

async fn read(
    client: &BACnetClient<BipTransport>,
    instance: u32,
    object: ObjectIdentifier,
    property: PropertyIdentifier,
    index: Option<u32>,
) -> Result<Vec<PropertyValue>, String> {
    let ack = client
        .read_property_from_device(instance, object, property, index)
        .await
        .map_err(|e| {
            format!(
                "reading {property} of {}: {e}",
                super::point::type_name(object.object_type())
            )
        })?;
    let mut values = Vec::new();
    let mut at = 0;
    while at < ack.property_value.len() {
        let (v, next) = decode_application_value(&ack.property_value, at)
            .map_err(|e| format!("{property} does not decode: {e}"))?;
        values.push(v);
        at = next;
    }
    Ok(values)
}

/// The device's object list: whole, or element by element where it does not fit an answer.
async fn object_list(
    client: &BACnetClient<BipTransport>,
    instance: u32,
    device: ObjectIdentifier,
) -> Result<Vec<ObjectIdentifier>, String> {
    let ids = |values: Vec<PropertyValue>| {
        values
            .into_iter()
            .filter_map(|v| match v {
                PropertyValue::ObjectIdentifier(id) => Some(id),
                _ => None,
            })
            .collect::<Vec<_>>()
    };
    if let Ok(whole) = read(
        client,
        instance,
        device,
        PropertyIdentifier::OBJECT_LIST,
        None,
    )
    .await
    {
        return Ok(ids(whole));
    }
    let count = match read(
        client,
        instance,
        device,
        PropertyIdentifier::OBJECT_LIST,
        Some(0),
    )
    .await?[..]
    {
        [PropertyValue::Unsigned(n)] => n,
        _ => return Err("the object list's length is not a number".into()),
    };
    let mut list = Vec::new();
    for k in 1..=count.min(MAX_FIELDS as u64 * 2) {
        let k = u32::try_from(k).unwrap_or(u32::MAX);
        list.extend(ids(read(
            client,
            instance,
            device,
            PropertyIdentifier::OBJECT_LIST,
            Some(k),
        )
        .await?));
    }
    Ok(list)
}

/// Each object's name and an analog object's units.
/// Each object's name and an analog object's units, one ReadProperty each.
async fn describe_one_by_one(
    client: &BACnetClient<BipTransport>,
    instance: u32,
    objects: &[ObjectIdentifier],
) -> Vec<(String, Option<String>)> {
    let mut out = Vec::new();
    for object in objects {
        let name = match read(
            client,
            instance,
            *object,
            PropertyIdentifier::OBJECT_NAME,
            None,
        )
        .await
        .as_deref()
        {
            Ok([PropertyValue::CharacterString(s)]) => s.clone(),
            _ => format!(
                "{}_{}",
                super::point::type_name(object.object_type()),
                object.instance_number()
            ),
        };
        let unit = match read(client, instance, *object, PropertyIdentifier::UNITS, None)
            .await
            .as_deref()
        {
            Ok([PropertyValue::Enumerated(u)]) => Some(
                EngineeringUnits::from_raw(*u)
                    .to_string()
                    .to_ascii_lowercase()
                    .replace('_', "-"),
            ),
            _ => None,
        };
        out.push((name, unit));
    }
    out
}

async fn describe(
    client: &BACnetClient<BipTransport>,
    instance: u32,
    objects: &[ObjectIdentifier],
) -> Result<Vec<(String, Option<String>)>, String> {
    let mut out = Vec::new();
    for chunk in objects.chunks(16) {
        let specs = chunk
            .iter()
            .map(|o| ReadAccessSpecification {
                object_identifier: *o,
                list_of_property_references: [
                    PropertyIdentifier::OBJECT_NAME,
                    PropertyIdentifier::UNITS,
                ]
                .into_iter()
                .map(|p| PropertyReference {
                    property_identifier: p,
                    property_array_index: None,
                })
                .collect(),
            })
            .collect();
        let ack = client
            .read_property_multiple_from_device(instance, specs)
            .await
            .map_err(|e| format!("reading the objects' names: {e}"))?;
        for (k, object) in chunk.iter().enumerate() {
            let result = ack
                .list_of_read_access_results
                .get(k)
                .filter(|r| r.object_identifier == *object);
            let value = |id: PropertyIdentifier| {
                let element = result?
                    .list_of_results
                    .iter()
                    .find(|e| e.property_identifier == id)?;
                decode_application_value(element.property_value.as_deref()?, 0)
                    .ok()
                    .map(|(v, _)| v)
            };
            let name = match value(PropertyIdentifier::OBJECT_NAME) {
                Some(PropertyValue::CharacterString(s)) => s,
                _ => format!(
                    "{}_{}",
                    super::point::type_name(object.object_type()),
                    object.instance_number()
                ),
            };
            let unit = match value(PropertyIdentifier::UNITS) {
                Some(PropertyValue::Enumerated(u)) => Some(
                    EngineeringUnits::from_raw(u)
                        .to_string()
                        .to_ascii_lowercase()
                        .replace('_', "-"),
                ),
                _ => None,
            };
            out.push((name, unit));
        }
    }
    Ok(out)
}

async fn import(target: &str, options: &ImportOptions<'_>, out: Option<&Path>) -> u8 {
    let parsed = match target.trim().parse::<u32>() {
        Ok(i) => super::point::device_instance(&i.to_string()).map(Target::Instance),
        Err(_) => super::config::address(target.trim()).map(Target::At),
    };
    let settings = parsed.and_then(|t| Ok((t, super::scan::settings(options)?.0)));
    let (target, mut settings) = match settings {
        Ok(s) => s,
        Err(e) => {
            eprintln!(
                "iogate profile import --from bacnet: {e} (give the device's HOST[:PORT] or its device instance)"
            );
            return crate::EXIT_CONFIG as u8;
        }
    };
    // A device at an address is asked from a port of the import's own, unless it says.
    if matches!(target, Target::At(_)) && option(options, "--on").is_none() {
        settings.bind = std::net::SocketAddrV4::new(std::net::Ipv4Addr::UNSPECIFIED, 0);
    }
    let source = match target {
        Target::At(a) => a.to_string(),
        Target::Instance(i) => format!("device {i}"),
    };
    let mut client = match super::client::start(&settings).await {
        Ok(c) => c,
        Err(e) => {
            eprintln!("iogate profile import: {source}: {e}");
            return 1;
        }
    };
    let made = walk(&client, target).await;
    let _ = client.stop().await;
    let (instance, device_name, fields, skipped) = match made {
        Ok(m) => m,
        Err(e) => {
            eprintln!("iogate profile import: {source}: {e}");
            return 1;
        }
    };
    for why in &skipped {
        eprintln!("not mapped: {why}");
    }
    let name = identifier(&format!("BACnet_{device_name}_{instance}"));
    let mut text = format!(
        "name: {name}\nprotocol: bacnet\ndescription: {}\nfields:\n",
        quoted(&format!(
            "Imported from BACnet device {instance} ({device_name}) at {source}"
        ))
    );
    for f in &fields {
        let _ = write!(
            text,
            "  - {{ name: {}, type: {}, direction: {}, object: {}",
            f.name,
            f.ty,
            f.direction,
            quoted(&format!(
                "{}:{}",
                super::point::type_name(f.object.object_type()),
                f.object.instance_number()
            ))
        );
        if let Some(u) = &f.unit {
            let _ = write!(text, ", unit: {}", quoted(u));
        }
        text.push_str(" }\n");
    }
    crate::profile::import::emit::emit(
        &crate::profile::import::emit::Made {
            source: &source,
            name: &name,
            text,
            fields: fields.len(),
            skipped: skipped.len(),
            things: "objects",
        },
        out,
    )
}

/// The device object of the device at `mac`, from its I-Am to a Who-Is sent to it alone.
async fn heard(
    client: &BACnetClient<BipTransport>,
    mac: &[u8],
) -> Result<ObjectIdentifier, String> {
    let mut events = client.device_events();
    client
        .who_is_directed(mac, None)
        .await
        .map_err(|e| format!("sending it a Who-Is: {e}"))?;
    let answer = async {
        loop {
            match events.recv().await {
                Ok(e) if e.device.is_local() && e.device.mac_address.as_slice() == mac => {
                    return Some(e.device.object_identifier);
                }
                Ok(_) | Err(tokio::sync::broadcast::error::RecvError::Lagged(_)) => {}
                Err(tokio::sync::broadcast::error::RecvError::Closed) => return None,
            }
        }
    };
    tokio::time::timeout(std::time::Duration::from_secs(3), answer)
        .await
        .ok()
        .flatten()
        .ok_or_else(|| {
            "neither its device object (by the wildcard instance) nor an I-Am to a Who-Is answered"
                .to_owned()
        })
}

/// Where the device to import is: at an address, or by its instance (a Who-Is finds it).
#[derive(Debug, Clone, Copy)]
pub(super) enum Target {
    At(std::net::SocketAddrV4),
    Instance(u32),
}

/// The device object of the device at an address: by the wildcard instance, else by its
/// I-Am to a Who-Is sent to it alone; the device put in the client's table.
async fn at(
    client: &BACnetClient<BipTransport>,
    at: std::net::SocketAddrV4,
) -> Result<ObjectIdentifier, String> {
    let mut mac = at.ip().octets().to_vec();
    mac.extend_from_slice(&at.port().to_be_bytes());
    let wildcard = ObjectIdentifier::new(ObjectType::DEVICE, ObjectIdentifier::MAX_INSTANCE)
        .map_err(|e| e.to_string())?;
    let asked = client
        .read_property(&mac, wildcard, PropertyIdentifier::OBJECT_IDENTIFIER, None)
        .await
        .ok()
        .and_then(|ack| decode_application_value(&ack.property_value, 0).ok());
    let device = match asked {
        Some((PropertyValue::ObjectIdentifier(id), _))
            if id.object_type() == ObjectType::DEVICE =>
        {
            id
        }
        // A device that does not take the wildcard instance says who it is in its I-Am.
        _ => heard(client, &mac).await?,
    };
    if client.get_device(device.instance_number()).await.is_none() {
        client
            .add_device(device.instance_number(), &mac)
            .await
            .map_err(|e| e.to_string())?;
    }
    Ok(device)
}

/// The device object of the device of an instance, from its I-Am to a Who-Is for it
/// (through a BBMD and routers too).
async fn by_instance(
    client: &BACnetClient<BipTransport>,
    instance: u32,
) -> Result<ObjectIdentifier, String> {
    let mut events = client.device_events();
    let range = bacnet_services::who_is::DeviceInstanceRange::new(instance, instance)
        .map_err(|e| e.to_string())?;
    client
        .who_is(Some(range))
        .await
        .map_err(|e| format!("sending a Who-Is: {e}"))?;
    let answer = async {
        loop {
            match events.recv().await {
                Ok(e) if e.device.object_identifier.instance_number() == instance => {
                    return Some(e.device.object_identifier);
                }
                Ok(_) | Err(tokio::sync::broadcast::error::RecvError::Lagged(_)) => {}
                Err(tokio::sync::broadcast::error::RecvError::Closed) => return None,
            }
        }
    };
    tokio::time::timeout(std::time::Duration::from_secs(3), answer)
        .await
        .ok()
        .flatten()
        .ok_or_else(|| format!("no device {instance} answered a Who-Is"))
}

/// The device's instance and name, its fields, and what was left out.
async fn walk(
    client: &BACnetClient<BipTransport>,
    target: Target,
) -> Result<(u32, String, Vec<Field>, Vec<String>), String> {
    let device = match target {
        Target::At(a) => at(client, a).await?,
        Target::Instance(i) => by_instance(client, i).await?,
    };
    let instance = device.instance_number();
    let device_name = match read(
        client,
        instance,
        device,
        PropertyIdentifier::OBJECT_NAME,
        None,
    )
    .await?[..]
    {
        [PropertyValue::CharacterString(ref s)] => s.clone(),
        _ => format!("device_{}", device.instance_number()),
    };
    let mut skipped = Vec::new();
    let mut objects = Vec::new();
    let mut listed = HashSet::new();
    for o in object_list(client, instance, device).await? {
        if !listed.insert(o) {
            skipped.push(format!("{}: listed twice", super::point::name(o)));
            continue;
        }
        match kind_of(o.object_type()) {
            Ok(_) if objects.len() < MAX_FIELDS => objects.push(o),
            Ok(_) => skipped.push(format!(
                "{}:{}: past {MAX_FIELDS} fields",
                super::point::type_name(o.object_type()),
                o.instance_number()
            )),
            Err(why) if o.object_type() != ObjectType::DEVICE => {
                skipped.push(format!("{why} ({})", o.instance_number()))
            }
            Err(_) => {}
        }
    }
    let described = match describe(client, instance, &objects).await {
        Ok(d) => d,
        // A device without ReadPropertyMultiple: each name on its own.
        Err(_) => describe_one_by_one(client, instance, &objects).await,
    };
    let mut names = HashSet::new();
    let mut fields = Vec::new();
    for (object, (text, unit)) in objects.into_iter().zip(described) {
        // Field names are one whatever their case.
        let mut name = identifier(&text);
        if !names.insert(name.to_ascii_lowercase()) {
            name = identifier(&format!(
                "{text}_{}_{}",
                super::point::type_name(object.object_type()),
                object.instance_number()
            ));
            names.insert(name.to_ascii_lowercase());
        }
        let (ty, direction) = kind_of(object.object_type())?;
        fields.push(Field {
            name,
            object,
            ty,
            direction,
            unit,
        });
    }
    Ok((device.instance_number(), device_name, fields, skipped))
}

//! A device's outputs: each a WriteProperty of its object's property at the field's
//! priority (the lowest, 16, unless the profile says), its outcome the device's answer. A
//! value the object cannot take is refused before it is sent; a write the device does not
//! answer leaves the rest unsent and says the device stopped answering.

use std::sync::Arc;

use bacnet_encoding::primitives::encode_property_value;
use bacnet_types::enums::PropertyIdentifier;
use bacnet_types::primitives::PropertyValue;
use bytes::BytesMut;

use super::value::writing;
use super::{Place, Plan, Port};
use crate::cache::{Device, FieldError, WriteError};
use crate::drivers::{WriteItem, finish};
use crate::link::LinkFault;

/// A field's value encoded as its property takes it (a present value as its object's
/// datatype), or why it cannot be.
pub(super) fn value(place: Place, value: &crate::codec::Value) -> Result<Vec<u8>, String> {
    let object = match place.property {
        PropertyIdentifier::PRESENT_VALUE => place.object.object_type(),
        // Another property: the value's own datatype.
        _ => bacnet_types::enums::ObjectType::from_raw(u32::MAX),
    };
    let mut bytes = BytesMut::new();
    encode_property_value(&mut bytes, &writing(object, value)?).map_err(|e| e.to_string())?;
    Ok(bytes.to_vec())
}

/// A relinquish: NULL written to a commandable object's present value at the field's
/// priority (the next priority, or the relinquish default, takes over), or why the field
/// has none.
pub(super) fn relinquishing(place: Place) -> Result<Vec<u8>, String> {
    use bacnet_types::enums::ObjectType as T;
    // The object types the standard gives a priority array (outputs always; values,
    // doors and lights where the device makes them commandable).
    let commandable = [
        T::ANALOG_OUTPUT,
        T::ANALOG_VALUE,
        T::BINARY_OUTPUT,
        T::BINARY_VALUE,
        T::MULTI_STATE_OUTPUT,
        T::MULTI_STATE_VALUE,
        T::ACCESS_DOOR,
        T::BITSTRING_VALUE,
        T::CHARACTERSTRING_VALUE,
        T::DATEPATTERN_VALUE,
        T::DATE_VALUE,
        T::DATETIMEPATTERN_VALUE,
        T::DATETIME_VALUE,
        T::INTEGER_VALUE,
        T::LARGE_ANALOG_VALUE,
        T::OCTETSTRING_VALUE,
        T::POSITIVE_INTEGER_VALUE,
        T::TIMEPATTERN_VALUE,
        T::TIME_VALUE,
        T::LIGHTING_OUTPUT,
        T::BINARY_LIGHTING_OUTPUT,
    ];
    if place.property != PropertyIdentifier::PRESENT_VALUE {
        return Err(format!(
            "only a present value is relinquished, not {}",
            place
                .property
                .to_string()
                .to_ascii_lowercase()
                .replace('_', "-")
        ));
    }
    if !commandable.contains(&place.object.object_type()) {
        return Err(format!(
            "{} is not commandable: it has no priorities to relinquish",
            super::point::name(place.object)
        ));
    }
    let mut bytes = BytesMut::new();
    encode_property_value(&mut bytes, &PropertyValue::Null).map_err(|e| e.to_string())?;
    Ok(bytes.to_vec())
}

/// Writes the items one request each, in order (a relinquish as NULL).
pub(super) async fn outputs(
    port: &Port,
    device: &Arc<Device>,
    plan: &mut Plan,
    items: Vec<WriteItem>,
) -> Result<Option<FieldError>, LinkFault> {
    let known = super::read::know(port, plan).await;
    let instance = match &plan.instance {
        Ok((i, _)) if matches!(known, Ok(true)) => *i,
        Ok(_) => {
            for item in &items {
                finish(device, item, Err(WriteError::DeviceDown), 0);
            }
            return Ok(None);
        }
        Err(why) => {
            for item in &items {
                finish(device, item, Err(WriteError::Refused(why.clone())), 0);
            }
            return Ok(None);
        }
    };
    let mut items = items.into_iter();
    while let Some(item) = items.next() {
        let place = match &plan.places[item.field] {
            Ok(p) => *p,
            Err(why) => {
                finish(device, &item, Err(WriteError::Refused(why.clone())), 0);
                continue;
            }
        };
        let bytes = match item
            .value
            .as_ref()
            .map_or_else(|| relinquishing(place), |v| value(place, v))
        {
            Ok(bytes) => bytes,
            Err(why) => {
                finish(device, &item, Err(WriteError::Refused(why)), 0);
                continue;
            }
        };
        port.started();
        let answer = port
            .client
            .write_property_to_device(
                instance,
                place.object,
                place.property,
                None,
                bytes,
                Some(place.priority),
            )
            .await;
        port.progress.ended();
        match answer {
            // Taken at its priority: the present value is what the device says at its next
            // read (a higher priority may hold it), never the value sent.
            Ok(()) => finish(device, &item, Ok(()), 1),
            Err(e) => match super::client::failure(e)? {
                (why, true) => {
                    let silent = WriteError::NoResponse(crate::link::TxError::Timeout);
                    finish(device, &item, Err(silent), 1);
                    for rest in items {
                        finish(device, &rest, Err(WriteError::DeviceDown), 0);
                    }
                    return Ok(Some(why));
                }
                (why, false) => finish(device, &item, Err(WriteError::Refused(why.to_string())), 1),
            },
        }
    }
    Ok(None)
}

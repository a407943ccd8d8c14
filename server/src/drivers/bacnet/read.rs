//! The port's start and a device's read: the device put in the client's table (by its
//! address, or by a Who-Is for its instance until its I-Am is heard), then its fields read
//! in ReadPropertyMultiple requests of at most [`PER_REQUEST`] objects, each present value
//! with the object's status flags. Every answer is checked against its request: an object
//! or a property that is not the one asked makes that field's error, never a value.

use std::sync::Arc;
use std::time::Duration;

use bacnet_client::discovery::RoutedDeviceConfig;
use bacnet_encoding::primitives::decode_application_value;
use bacnet_services::rpm::ReadAccessResult;
use bacnet_services::who_is::DeviceInstanceRange;
use bacnet_types::constructed::{PropertyReference, ReadAccessSpecification};
use bacnet_types::enums::PropertyIdentifier;
use bacnet_types::primitives::PropertyValue;
use tokio::time::Instant;

use super::value::{not_good, reading};
use super::{Place, Plan, Port};
use crate::cache::{Device, FieldError};
use crate::drivers::Read;
use crate::link::LinkFault;

/// The most objects one ReadPropertyMultiple asks for (each with at most two properties:
/// an answer stays within a device's smallest usual APDU of 480 bytes for numbers).
pub(super) const PER_REQUEST: usize = 16;

/// Puts the device in the client's table: by its address, or by asking for it (a Who-Is
/// for its instance); `false` while it is not known yet. Asked before every read and
/// write: the client forgets a device it has not heard an I-Am from for ten minutes,
/// however well it answers, and a forgotten device is put back as it was last known.
pub(super) async fn know(port: &Port, plan: &mut Plan) -> Result<bool, String> {
    let (instance, address) = plan.instance.clone()?;
    if let Some(row) = port.client.get_device(instance).await {
        plan.row = Some(row);
        return Ok(true);
    }
    let fail = |e: bacnet_types::error::Error| e.to_string();
    if let Some(at) = address {
        let mut mac = at.ip().octets().to_vec();
        mac.extend_from_slice(&at.port().to_be_bytes());
        port.client.add_device(instance, &mac).await.map_err(fail)?;
        return Ok(true);
    }
    let Some(row) = &plan.row else {
        let range = DeviceInstanceRange::new(instance, instance).map_err(|e| e.to_string())?;
        port.client.who_is(Some(range)).await.map_err(fail)?;
        return Ok(false);
    };
    match (row.source_network, &row.source_address) {
        (Some(network), Some(sadr)) => port
            .client
            .add_routed_device(RoutedDeviceConfig {
                instance,
                router_mac: row.mac_address.to_vec(),
                remote_network: network,
                remote_mac: sadr.to_vec(),
                max_apdu_length: row.max_apdu_length,
                segmentation_supported: row.segmentation_supported,
                max_segments_accepted: row.max_segments_accepted,
            })
            .await
            .map_err(fail)?,
        _ => port
            .client
            .add_device(instance, &row.mac_address)
            .await
            .map_err(fail)?,
    }
    Ok(true)
}

/// The request for some fields: each object with its property, and its status flags when
/// the property is the present value.
fn specs(places: &[(usize, Place)]) -> Vec<ReadAccessSpecification> {
    places
        .iter()
        .map(|(_, p)| {
            let mut refs = vec![PropertyReference {
                property_identifier: p.property,
                property_array_index: None,
            }];
            if p.property == PropertyIdentifier::PRESENT_VALUE {
                refs.push(PropertyReference {
                    property_identifier: PropertyIdentifier::STATUS_FLAGS,
                    property_array_index: None,
                });
            }
            ReadAccessSpecification {
                object_identifier: p.object,
                list_of_property_references: refs,
            }
        })
        .collect()
}

/// One property of an object's result, decoded, or why not.
fn property(result: &ReadAccessResult, id: PropertyIdentifier) -> Result<PropertyValue, String> {
    let mut found = result
        .list_of_results
        .iter()
        .filter(|r| r.property_identifier == id && r.property_array_index.is_none());
    let element = found.next().ok_or_else(|| {
        format!(
            "the answer has no {id} of {}",
            super::point::name(result.object_identifier)
        )
    })?;
    if found.next().is_some() {
        return Err(format!(
            "the answer holds {id} of {} twice",
            super::point::name(result.object_identifier)
        ));
    }
    if let Some((class, code)) = &element.error {
        return Err(format!("the device refused {id}: {class}, {code}"));
    }
    let bytes = element.property_value.as_deref().unwrap_or_default();
    let (value, used) =
        decode_application_value(bytes, 0).map_err(|e| format!("{id} does not decode: {e}"))?;
    if used != bytes.len() {
        return Err(format!(
            "{id} holds more than one value (a list or an array)"
        ));
    }
    Ok(value)
}

/// Each field's value from its object's result, checked against what was asked.
fn publish(device: &Device, asked: &[(usize, Place)], results: &[ReadAccessResult]) {
    for (k, (idx, place)) in asked.iter().enumerate() {
        let field = device.field(*idx);
        let outcome = match results.get(k) {
            None => Err(FieldError::Missing("the object's result")),
            Some(r) if r.object_identifier != place.object => Err(FieldError::Device(format!(
                "the answer is for {}, not the {} asked",
                super::point::name(r.object_identifier),
                super::point::name(place.object)
            ))),
            Some(r) => {
                let flags = (place.property == PropertyIdentifier::PRESENT_VALUE)
                    .then(|| property(r, PropertyIdentifier::STATUS_FLAGS));
                match (property(r, place.property), flags) {
                    (Err(why), _) | (_, Some(Err(why))) => Err(FieldError::Device(why)),
                    (Ok(_), Some(Ok(f))) if not_good(&f).is_some() => Err(FieldError::Device(
                        not_good(&f).unwrap_or_default().to_owned(),
                    )),
                    (Ok(v), _) => reading(field.ty, &v).map_err(FieldError::Device),
                }
            }
        };
        device.publish(*idx, outcome);
    }
}

/// The results for some fields: one ReadPropertyMultiple, or, for a device that does not
/// have that service (it rejects it as unrecognized), a ReadProperty for each property
/// from then on.
async fn read_chunk(
    port: &Port,
    plan: &mut Plan,
    instance: u32,
    chunk: &[(usize, Place)],
) -> Result<Vec<ReadAccessResult>, bacnet_types::error::Error> {
    use bacnet_types::enums::RejectReason;
    use bacnet_types::error::{Error, RemoteError};
    if !plan.one_by_one {
        port.started();
        let answer = port
            .client
            .read_property_multiple_from_device(instance, specs(chunk))
            .await;
        port.progress.ended();
        match answer {
            Ok(ack) => return Ok(ack.list_of_read_access_results),
            Err(Error::Remote(RemoteError::Reject { reason }))
                if reason == RejectReason::UNRECOGNIZED_SERVICE =>
            {
                tracing::info!(
                    instance,
                    "the device has no ReadPropertyMultiple: its properties are read one by one"
                );
                plan.one_by_one = true;
            }
            Err(e) => return Err(e),
        }
    }
    let mut results = Vec::with_capacity(chunk.len());
    for spec in specs(chunk) {
        let mut list = Vec::new();
        for r in spec.list_of_property_references {
            port.started();
            let answer = port
                .client
                .read_property_from_device(
                    instance,
                    spec.object_identifier,
                    r.property_identifier,
                    None,
                )
                .await;
            port.progress.ended();
            let (property_value, error) = match answer {
                Ok(ack)
                    if ack.object_identifier != spec.object_identifier
                        || ack.property_identifier != r.property_identifier =>
                {
                    return Err(Error::Encoding(format!(
                        "the answer is for {} of {}, not the {} of {} asked",
                        ack.property_identifier,
                        super::point::name(ack.object_identifier),
                        r.property_identifier,
                        super::point::name(spec.object_identifier)
                    )));
                }
                Ok(ack) => (Some(ack.property_value), None),
                Err(Error::Remote(RemoteError::Error { class, code })) => {
                    (None, Some((class, code)))
                }
                Err(e) => return Err(e),
            };
            list.push(bacnet_services::rpm::ReadResultElement {
                property_identifier: r.property_identifier,
                property_array_index: None,
                property_value,
                error,
            });
        }
        results.push(ReadAccessResult {
            object_identifier: spec.object_identifier,
            list_of_results: list,
        });
    }
    Ok(results)
}

/// Reads the device's fields (one cycle) and publishes each.
pub(super) async fn cycle(
    port: &Port,
    device: &Arc<Device>,
    plan: &mut Plan,
) -> Result<Read, LinkFault> {
    let started = Instant::now();
    let known = know(port, plan).await;
    if !matches!(known, Ok(true)) {
        plan.cov
            .answering
            .store(false, std::sync::atomic::Ordering::Relaxed);
    }
    let instance = match known {
        Ok(true) => plan.instance.as_ref().map_or(0, |(i, _)| *i),
        Ok(false) => {
            return Ok(Read::Silent(FieldError::Device(
                "not found yet: no I-Am answered the Who-Is for its instance".to_owned(),
            )));
        }
        Err(why) => return Ok(Read::Silent(FieldError::Device(why))),
    };
    let mut fields = Vec::new();
    for (idx, place) in plan.places.iter().enumerate() {
        match place {
            Ok(p) => fields.push((idx, *p)),
            Err(why) => device.publish(idx, Err(FieldError::Device(why.clone()))),
        }
    }
    let mut answered = false;
    for chunk in fields.chunks(PER_REQUEST) {
        let answer = read_chunk(port, plan, instance, chunk).await;
        match answer {
            Ok(results) => {
                answered = true;
                publish(device, chunk, &results);
            }
            Err(e) => match super::client::failure(e)? {
                (why, true) if !answered => {
                    plan.cov
                        .answering
                        .store(false, std::sync::atomic::Ordering::Relaxed);
                    return Ok(Read::Silent(why));
                }
                (why, _) => {
                    for (idx, _) in chunk {
                        device.publish(*idx, Err(why.clone()));
                    }
                }
            },
        }
    }
    plan.cov
        .answering
        .store(answered, std::sync::atomic::Ordering::Relaxed);
    if answered {
        // Subscribed once the device answers its reads: a silent device costs no more.
        super::cov::renew(port, device, plan, instance).await;
    }
    Ok(Read::Answered(
        started.elapsed().max(Duration::from_micros(1)),
    ))
}

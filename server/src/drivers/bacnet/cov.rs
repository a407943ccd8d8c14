//! Change of value: each object whose present value a device's fields read is subscribed
//! (SubscribeCOV, unconfirmed notifications, a lifetime of [`LIFETIME`], renewed when half
//! of it is gone), and a notification's present value and status flags are published at
//! once, between the device's reads. A device that refuses the subscription (it has no COV
//! for the object, or no COV at all) is read by polling alone. The reads go on at the
//! device's refresh rate either way: they are what tells a device that stopped answering
//! (a notification that does not come says nothing).
//!
//! The notifications come on the client's channel; one task per port (`listen`) gives each
//! to the device whose subscription it answers, checked: the subscriber process it names,
//! the device that sent it and the object must all be the ones subscribed.

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, Weak};
use std::time::Duration;

use bacnet_client::client::{COVNotificationDelivery, ReceivedCOVNotification};
use bacnet_encoding::primitives::decode_application_value;
use bacnet_types::MacAddr;
use bacnet_types::enums::PropertyIdentifier;
use bacnet_types::primitives::ObjectIdentifier;
use tokio::sync::broadcast;
use tokio::time::Instant;

use super::value::{not_good, reading};
use super::{Place, Plan, Port};
use crate::cache::{Device, FieldError};

/// How long a subscription lasts before it is renewed (at half of it).
pub(super) const LIFETIME: Duration = Duration::from_secs(300);

/// What a device's subscriptions stand at.
#[derive(Debug, Default)]
pub(super) struct Subscriptions {
    /// Whether the device is subscribed to at all (its `cov`).
    pub(super) wanted: bool,
    /// Whether the device answered its last read: a notification is taken only then.
    pub(super) answering: Arc<AtomicBool>,
    /// The subscriber process identifier of the device's subscriptions (0: none yet).
    pub(super) process: u32,
    /// Each subscribed object and when it was last subscribed; `None` where the device
    /// refused (read by polling alone).
    pub(super) objects: HashMap<ObjectIdentifier, Option<Instant>>,
}

/// Who a subscriber process is: the device (instance, where it is, its cache entry) and
/// which field reads which object.
struct Subscriber {
    instance: u32,
    /// The device's MAC and, behind a router, its network and MAC there: a notification
    /// must come from there.
    from: (MacAddr, Option<u16>, Option<MacAddr>),
    device: Weak<Device>,
    answering: Arc<AtomicBool>,
    fields: Vec<(usize, ObjectIdentifier)>,
}

/// The subscriber processes of a port.
#[derive(Default)]
pub(super) struct Table(Mutex<HashMap<u32, Subscriber>>);

impl Table {
    fn lock(&self) -> std::sync::MutexGuard<'_, HashMap<u32, Subscriber>> {
        // A panic while it was held leaves a map of plain values: still usable.
        self.0
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }
}

/// The subscriber process identifiers of this gateway, one for each device name, kept
/// while the gateway runs: a device re-planned by a reload subscribes under the same one, so
/// its new subscriptions replace the old ones on the device (a subscription is its
/// subscriber, process and object) instead of piling up in the device's few slots. At most
/// [`KEPT`] names are kept; past them a device gets a new one each time.
fn process_of(device: &str) -> u32 {
    static PROCESSES: Mutex<std::collections::BTreeMap<String, u32>> =
        Mutex::new(std::collections::BTreeMap::new());
    static BEYOND: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(KEPT + 1);
    let mut known = PROCESSES
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    if let Some(process) = known.get(device) {
        return *process;
    }
    if known.len() >= KEPT as usize {
        return BEYOND.fetch_add(1, Ordering::Relaxed);
    }
    let process = u32::try_from(known.len() + 1).unwrap_or(u32::MAX);
    known.insert(device.to_owned(), process);
    process
}

/// How many device names keep their subscriber process identifier.
const KEPT: u32 = 100_000;

/// The fields that read an object's present value.
fn watched(plan: &Plan) -> Vec<(usize, ObjectIdentifier)> {
    plan.places
        .iter()
        .enumerate()
        .filter_map(|(idx, p)| match p {
            Ok(Place {
                object, property, ..
            }) if *property == PropertyIdentifier::PRESENT_VALUE => Some((idx, *object)),
            _ => None,
        })
        .collect()
}

/// Subscribes (or renews) every object of the device due; a refusal leaves the object to
/// polling.
pub(super) async fn renew(port: &Port, device: &Arc<Device>, plan: &mut Plan, instance: u32) {
    let fields = watched(plan);
    if fields.is_empty() || !plan.cov.wanted {
        return;
    }
    if plan.cov.process == 0 {
        plan.cov.process = process_of(device.name());
    }
    let Some(at) = port.client.get_device(instance).await else {
        return;
    };
    port.cov.lock().insert(
        plan.cov.process,
        Subscriber {
            instance,
            from: (at.mac_address, at.source_network, at.source_address),
            device: Arc::downgrade(device),
            answering: plan.cov.answering.clone(),
            fields: fields.clone(),
        },
    );
    let now = Instant::now();
    // Each object once, however many fields read it (wherever they stand in the profile).
    let mut seen = std::collections::HashSet::new();
    let objects: Vec<ObjectIdentifier> = fields
        .iter()
        .map(|(_, o)| *o)
        .filter(|o| seen.insert(*o))
        .collect();
    for object in objects {
        let due = match plan.cov.objects.get(&object) {
            Some(None) => false,
            Some(Some(at)) => now.saturating_duration_since(*at) >= LIFETIME / 2,
            None => true,
        };
        if !due {
            continue;
        }
        port.started();
        let lifetime = u32::try_from(LIFETIME.as_secs()).unwrap_or(u32::MAX);
        let answer = port
            .client
            .subscribe_cov_to_device(instance, plan.cov.process, object, false, Some(lifetime))
            .await;
        port.progress.ended();
        let state = match answer {
            Ok(()) => Some(now),
            Err(e) => {
                let why = e.to_string();
                // Silence says nothing of the device's COV, but costs the link a timeout:
                // none of its objects is asked again before half a lifetime.
                if super::client::failure(e).is_ok_and(|(_, silent)| silent) {
                    tracing::info!(device = %device.name(), "the device did not answer a change-of-value subscription; asked again in {} s", (LIFETIME / 2).as_secs());
                    for (_, o) in &fields {
                        let state = plan.cov.objects.entry(*o).or_insert(Some(now));
                        if state.is_some() {
                            *state = Some(now);
                        }
                    }
                    return;
                }
                tracing::info!(device = %device.name(), object = ?object, error = %why, "no change-of-value subscription; the object is polled");
                None
            }
        };
        plan.cov.objects.insert(object, state);
    }
}

/// Cancels the device's subscriptions (a SubscribeCOV without lifetime or kind), as the
/// session ends.
pub(super) async fn cancel(port: &Port) {
    let subscribers: Vec<(u32, u32, Vec<ObjectIdentifier>)> = port
        .cov
        .lock()
        .iter()
        .map(|(pid, s)| (*pid, s.instance, s.fields.iter().map(|(_, o)| *o).collect()))
        .collect();
    for (pid, instance, objects) in subscribers {
        let mut seen = std::collections::HashSet::new();
        for object in objects.into_iter().filter(|o| seen.insert(*o)) {
            let _ = port
                .client
                .unsubscribe_cov_to_device(instance, pid, object)
                .await;
        }
    }
}

/// A notification's property, decoded.
fn property(
    n: &ReceivedCOVNotification,
    id: PropertyIdentifier,
) -> Option<Result<bacnet_types::primitives::PropertyValue, String>> {
    let v = n
        .notification
        .list_of_values
        .iter()
        .find(|v| v.property_identifier == id && v.property_array_index.is_none())?;
    Some(
        decode_application_value(&v.value, 0)
            .map(|(value, _)| value)
            .map_err(|e| format!("{id} of a notification does not decode: {e}")),
    )
}

/// Publishes a notification to the fields of the subscription it answers.
fn deliver(table: &Table, n: &ReceivedCOVNotification) {
    let note = &n.notification;
    // Subscribed for unconfirmed notifications: a confirmed one is not this subscription's.
    if n.delivery != COVNotificationDelivery::Unconfirmed {
        return;
    }
    let (device, fields) = {
        let subscribers = table.lock();
        let Some(s) = subscribers.get(&note.subscriber_process_identifier) else {
            tracing::debug!(
                process = note.subscriber_process_identifier,
                "a change-of-value notification for no subscription of this port: dropped"
            );
            return;
        };
        let from = (
            n.source_mac.clone(),
            n.source_network,
            n.source_address.clone(),
        );
        if note.initiating_device_identifier.instance_number() != s.instance || from != s.from {
            tracing::debug!(from = ?from, subscribed = ?s.from, "a change-of-value notification not from its subscription's device: dropped");
            return;
        }
        let Some(device) = s.device.upgrade() else {
            return;
        };
        // A device that does not answer its reads is not vouched for by a notification.
        if !s.answering.load(Ordering::Relaxed) {
            tracing::debug!(device = %device.name(), "a change-of-value notification for a device not answering: dropped");
            return;
        }
        let fields: Vec<usize> = s
            .fields
            .iter()
            .filter(|(_, o)| *o == note.monitored_object_identifier)
            .map(|(idx, _)| *idx)
            .collect();
        (device, fields)
    };
    let Some(value) = property(n, PropertyIdentifier::PRESENT_VALUE) else {
        return;
    };
    // The standard's notifications carry the status flags beside the present value
    // (Table 13-1): one without them cannot say the value is good, and is left to the reads.
    let Some(flags) = property(n, PropertyIdentifier::STATUS_FLAGS) else {
        tracing::debug!(device = %device.name(), "a change-of-value notification without status-flags: dropped");
        return;
    };
    for idx in fields {
        let outcome = match (&value, &flags) {
            (Err(why), _) | (_, Err(why)) => Err(FieldError::Device(why.clone())),
            (Ok(_), Ok(f)) if not_good(f).is_some() => Err(FieldError::Device(
                not_good(f).unwrap_or_default().to_owned(),
            )),
            (Ok(v), _) => reading(device.field(idx).ty, v).map_err(FieldError::Device),
        };
        device.publish(idx, outcome);
    }
}

/// Gives each notification of the port to its subscription's device, until the client
/// stops.
pub(super) async fn listen(
    table: Arc<Table>,
    mut notifications: broadcast::Receiver<ReceivedCOVNotification>,
) {
    let (mut lagged, mut told) = (0u64, None);
    loop {
        match notifications.recv().await {
            Ok(n) => deliver(&table, &n),
            Err(broadcast::error::RecvError::Lagged(missed)) => {
                // The next reads bring what was missed; told at most every 10 s.
                lagged += missed;
                if told.is_none_or(|t: Instant| t.elapsed() >= Duration::from_secs(10)) {
                    tracing::warn!(
                        missed = lagged,
                        "change-of-value notifications came faster than they were taken"
                    );
                    (lagged, told) = (0, Some(Instant::now()));
                }
            }
            Err(broadcast::error::RecvError::Closed) => return,
        }
    }
}

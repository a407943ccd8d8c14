//! A device as a subscription: its refresh rate the publishing interval, one monitored item
//! per resolved field (the field's sampling interval, else the refresh rate; its deadband as
//! a data change filter), each change published with its status and source timestamp. Any
//! publish response of the subscription, data or keep-alive, shows it alive; one that stays
//! silent past its keep-alive period and a publishing interval, or that the server says it
//! dropped or has not (a publish answered `BadNoSubscription`), has its values stale and is
//! made again.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use opcua::client::{MonitoredItemMap, OnSubscriptionNotificationCore};
use opcua::types::{
    DataChangeFilter, DataChangeNotification, DataChangeTrigger, DataValue, ExtensionObject,
    MonitoredItemCreateRequest, MonitoringMode, MonitoringParameters, NotificationMessage,
    ReadValueId, StatusChangeNotification, StatusCode, TimestampsToReturn, VariantScalarTypeId,
    match_extension_object_owned,
};
use tokio::time::Instant;

use super::{Connection, Plan, refuse};
use crate::cache::Device;
use crate::link::LinkFault;
use crate::opcua_variant::reading;
use crate::profile::deadband::Deadband;

/// The most notifications one publish response is asked to carry: more changes come in
/// more responses (a server that sends more anyway is taken up to the link's
/// `max_array_length`).
const PER_PUBLISH: u32 = 1000;

/// About how often a quiet subscription says it is alive.
const KEEP_ALIVE: Duration = Duration::from_secs(2);

/// A device's subscription in a session.
pub(crate) struct Watched {
    id: u32,
    /// When the server last answered a publish request for it.
    heard: Arc<Mutex<Instant>>,
    /// The server told it was dropped.
    gone: Arc<AtomicBool>,
    keep_alive: Duration,
    /// The publishing interval.
    interval: Duration,
    /// The session's count of "no subscription" publish answers when it was made.
    since: u64,
}

/// How late a keep-alive may be (the network, the server's timer) before it is missed.
const LATE: Duration = Duration::from_millis(500);

/// Why a subscription is not vouching for its values any more.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Unwell {
    /// The server answered a publish request saying it has no subscription of the session.
    Deleted,
    /// Neither a notification nor a keep-alive came within the keep-alive period and a
    /// publishing interval.
    Silent,
    /// The server told it dropped it (a status change notification).
    Dropped,
}

impl Unwell {
    pub(crate) fn says(self) -> &'static str {
        match self {
            Unwell::Deleted => "the server deleted the device's subscription; made again",
            Unwell::Silent => {
                "the device's subscription sent neither a change nor a keep-alive in time; made again"
            }
            Unwell::Dropped => "the server dropped the device's subscription; made again",
        }
    }
}

impl Watched {
    /// Whether the subscription still reports: not deleted or dropped, and heard within the
    /// keep-alive period and a publishing interval (at least [`LATE`]). `dropped` is the
    /// session's count of "no subscription" publish answers now.
    pub(crate) fn health(&self, dropped: u64) -> Result<(), Unwell> {
        let heard = *self
            .heard
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if dropped != self.since {
            return Err(Unwell::Deleted);
        }
        if self.gone.load(Ordering::Relaxed) {
            return Err(Unwell::Dropped);
        }
        if heard.elapsed() > self.keep_alive + self.interval.max(LATE) {
            return Err(Unwell::Silent);
        }
        Ok(())
    }
}

/// Publishes a data value of field `idx` into the cache, remembering its variant type in
/// `types` (the device's, locked by the caller once for many values).
pub(super) fn publish(
    device: &Device,
    types: &mut [Option<VariantScalarTypeId>],
    idx: usize,
    dv: &DataValue,
    now: crate::cache::Stamp,
) {
    let Some(field) = device.profile.fields.get(idx) else {
        return;
    };
    let max_len = usize::from(field.register.word_count) * 2;
    let r = reading(field.ty, max_len, dv);
    if let Some(t) = dv.value.as_ref().and_then(|v| v.scalar_type_id())
        && let Some(slot) = types.get_mut(idx)
    {
        *slot = Some(t);
    }
    device.publish_from(idx, r.value, r.doubt, r.at, now);
}

/// The device's variant types, locked.
pub(super) fn lock(
    types: &Mutex<Vec<Option<VariantScalarTypeId>>>,
) -> std::sync::MutexGuard<'_, Vec<Option<VariantScalarTypeId>>> {
    types
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// What a subscription's publish responses do.
struct Notifications {
    device: Arc<Device>,
    types: Arc<Mutex<Vec<Option<VariantScalarTypeId>>>>,
    heard: Arc<Mutex<Instant>>,
    gone: Arc<AtomicBool>,
}

impl OnSubscriptionNotificationCore for Notifications {
    fn on_subscription_notification(&mut self, n: NotificationMessage, _: MonitoredItemMap<'_>) {
        let now = crate::cache::Stamp::now();
        *self
            .heard
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner) = now.instant;
        for obj in n.notification_data.into_iter().flatten() {
            match_extension_object_owned!(obj,
                v: DataChangeNotification => {
                    let mut types = lock(&self.types);
                    for item in v.monitored_items.into_iter().flatten() {
                        let idx = item.client_handle.wrapping_sub(1) as usize;
                        publish(&self.device, &mut types, idx, &item.value, now);
                    }
                },
                v: StatusChangeNotification => {
                    if v.status.is_bad() {
                        tracing::warn!(device = %self.device.name(), status = %v.status, "the server dropped the device's subscription");
                        self.gone.store(true, Ordering::Relaxed);
                    }
                },
            )
        }
    }
}

/// The filter of a field's deadband.
fn filter(deadband: Option<Deadband>) -> ExtensionObject {
    let (kind, value) = match deadband {
        Some(Deadband::Absolute(x)) => (1, x),
        Some(Deadband::Percent(p)) => (2, p),
        _ => return ExtensionObject::null(),
    };
    ExtensionObject::from_message(DataChangeFilter {
        trigger: DataChangeTrigger::StatusValue,
        deadband_type: kind,
        deadband_value: value,
    })
}

/// Statuses that say the server has no subscriptions for us: the device is read instead.
fn unsupported(code: StatusCode) -> bool {
    [
        StatusCode::BadServiceUnsupported,
        StatusCode::BadNotSupported,
        StatusCode::BadNotImplemented,
        StatusCode::BadTooManySubscriptions,
    ]
    .iter()
    .any(|c| c.sub_code() == code.sub_code())
}

/// Creates the device's subscription and its monitored items (dropping an older one).
pub(super) async fn watch(
    conn: &Connection,
    device: &Arc<Device>,
    plan: &mut Plan,
) -> Result<(), LinkFault> {
    if let Some(old) = plan.watched.take() {
        conn.started();
        let _ = conn.session.delete_subscription(old.id).await;
        conn.ended();
    }
    let refresh = device
        .config
        .refresh_rate
        .max(crate::config::rules::MIN_PERIOD);
    let keep_alive_count =
        (KEEP_ALIVE.as_millis() / refresh.as_millis().max(1)).clamp(1, 1000) as u32;
    let heard = Arc::new(Mutex::new(Instant::now()));
    let gone = Arc::new(AtomicBool::new(false));
    let since = conn.dropped.load(Ordering::Relaxed);
    let callback = Notifications {
        device: device.clone(),
        types: plan.types.clone(),
        heard: heard.clone(),
        gone: gone.clone(),
    };
    conn.started();
    let created = conn
        .session
        .create_subscription(
            refresh,
            keep_alive_count * 3,
            keep_alive_count,
            PER_PUBLISH,
            0,
            true,
            callback,
        )
        .await;
    conn.ended();
    let id = match created {
        Ok(id) => id,
        Err(e) => {
            if let Some(fault) = conn.fault(&e) {
                return Err(fault);
            }
            if unsupported(e.status()) {
                let full = e.status().sub_code() == StatusCode::BadTooManySubscriptions.sub_code();
                let why = match full {
                    true => {
                        "the server takes no more subscriptions (its limit is reached, by this gateway's devices or other clients)"
                    }
                    false => "the server has no subscriptions",
                };
                tracing::info!(device = %device.name(), status = %e.status(), "{why}; reading the device every refresh");
                plan.subscribe = false;
                return Ok(());
            }
            return Err(LinkFault::lost(super::UaError::Subscription(e.to_string())));
        }
    };
    plan.watched = Some(Watched {
        id,
        heard,
        gone,
        keep_alive: refresh * keep_alive_count,
        interval: refresh,
        since,
    });
    items(conn, device, plan, id).await
}

/// The monitored items of every resolved field; one the server refuses is that field's error.
async fn items(conn: &Connection, device: &Device, plan: &Plan, id: u32) -> Result<(), LinkFault> {
    let refresh = device
        .config
        .refresh_rate
        .max(crate::config::rules::MIN_PERIOD);
    let (handles, requests): (Vec<usize>, Vec<MonitoredItemCreateRequest>) = plan
        .nodes
        .iter()
        .enumerate()
        .filter_map(|(idx, node)| {
            let node = node.as_ref().ok()?;
            let field = device.field(idx);
            let sampling = field
                .point
                .as_ref()
                .and_then(|p| p.sampling)
                .unwrap_or(refresh);
            Some((
                idx,
                MonitoredItemCreateRequest {
                    item_to_monitor: ReadValueId::from(node.clone()),
                    monitoring_mode: MonitoringMode::Reporting,
                    requested_parameters: MonitoringParameters {
                        client_handle: idx as u32 + 1,
                        sampling_interval: sampling.as_secs_f64() * 1000.0,
                        filter: filter(field.deadband),
                        queue_size: 1,
                        discard_oldest: true,
                    },
                },
            ))
        })
        .unzip();
    let session = &conn.session;
    let answered = super::limits::in_requests(conn, super::Service::Monitor, &requests, |r| {
        session.create_monitored_items(id, TimestampsToReturn::Source, r.to_vec())
    })
    .await;
    for (range, created) in answered {
        let handles = &handles[range];
        let results = match created {
            Ok(r) => r,
            Err(e) => {
                if let Some(fault) = conn.fault(&e) {
                    return Err(fault);
                }
                for &idx in handles {
                    refuse(device, idx, e.status().to_string());
                }
                continue;
            }
        };
        for (idx, r) in handles.iter().zip(results.iter()) {
            if r.result.status_code.is_bad() {
                tracing::warn!(device = %device.name(), field = %device.field(*idx).name, status = %r.result.status_code, "the server refused to monitor the field");
                refuse(device, *idx, r.result.status_code.to_string());
            }
        }
    }
    Ok(())
}

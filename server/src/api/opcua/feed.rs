//! The address space follows the gateway: devices and links added, removed or re-planned
//! (declarations, reloads, links declared at run time) appear and disappear. Values are not
//! kept in it (`live.rs` reads them when asked): a change from the service's change stream
//! goes to the monitored items of its variable only, rendered only when an item watches it
//! (their sampling, queue and deadband filter are the OPC UA library's), and while no
//! monitored item exists at all the stream is not even read (it keeps the newest value of
//! each field for when one is made). Writes to output variables go to the service, as
//! REST's do.

use std::borrow::{Borrow, Cow};
use std::cell::Cell;
use std::collections::HashMap;
use std::sync::Arc;
use std::time::Duration;

use futures_util::{FutureExt, StreamExt};
use opcua::core_namespace::events::BaseModelChangeEventType;
use opcua::server::SubscriptionCache;
use opcua::types::{
    AttributeId, DataValue, DateTime, ModelChangeStructureDataType, NodeId, ObjectTypeId,
};
use tokio_util::sync::CancellationToken;

use super::space::{self, Ids};
use crate::cache::{Device, Link};
use crate::service::{Change, Changes, Service};

use super::nodes::Manager;

/// How often the links' diagnostics are looked at (links have no change stream).
const LINKS_EVERY: Duration = Duration::from_millis(500);
/// Changes set on the address space under one lock, at most.
const BATCH: usize = 1024;

/// What is in the address space.
struct Shown {
    devices: HashMap<String, ShownDevice>,
    links: HashMap<String, Arc<Link>>,
    /// Filled once: later changes are model changes.
    synced: bool,
}

/// What renders a variable's value: the change's place in its batch, and the diagnostic it
/// is of (none: the field's value).
type Rendered = (usize, Option<&'static str>);

/// A device in the address space: its fields' names and their variables' ids, in the
/// profile's order (a change names its field by index).
struct ShownDevice {
    device: Arc<Device>,
    fields: Vec<String>,
    ids: Vec<NodeId>,
}

impl Shown {
    /// The id of field `idx` of `device` as shown, if it is (a device replaced since the
    /// last sync is not yet).
    fn field_id(&self, device: &Arc<Device>, idx: usize) -> Option<&NodeId> {
        self.devices
            .get(device.name())
            .filter(|d| Arc::ptr_eq(&d.device, device))
            .and_then(|d| d.ids.get(idx))
    }
}

pub(crate) struct Feed {
    pub(crate) service: Arc<Service>,
    pub(crate) manager: Arc<Manager>,
    pub(crate) subscriptions: Arc<SubscriptionCache>,
    pub(crate) ids: Ids,
    pub(crate) counts: Arc<super::OpcUaState>,
}

impl Feed {
    pub(crate) async fn run(self, token: CancellationToken) {
        let mut shown = Shown {
            devices: HashMap::new(),
            links: HashMap::new(),
            synced: false,
        };
        let mut devices_changed = self.service.watch_devices();
        // Followed before the address space is brought up to date: a change made meanwhile
        // is in the stream (a subscription begins with the current values).
        let mut changes = self.subscribe();
        self.sync(&mut shown);
        let mut links = tokio::time::interval(LINKS_EVERY);
        links.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            let watching = self.counts.watching();
            tokio::select! {
                _ = token.cancelled() => return,
                _ = devices_changed.changed() => {
                    changes = self.subscribe();
                    self.sync(&mut shown);
                }
                // Woken when the first item is made: the loop then reads the stream.
                _ = self.counts.watched(), if !watching => {}
                change = next(&mut changes), if watching => match change {
                    Some(change) => {
                        let mut batch = vec![change];
                        while batch.len() < BATCH {
                            match changes.as_mut().and_then(|c| c.next().now_or_never()) {
                                Some(Some(change)) => batch.push(change),
                                _ => break,
                            }
                        }
                        self.apply(&shown, &batch);
                    }
                    None => changes = None,
                },
                _ = links.tick() => {
                    if self.links_changed(&shown) {
                        self.sync(&mut shown);
                    }
                    if watching {
                        self.diagnostics(&shown);
                    }
                }
            }
        }
    }

    fn subscribe(&self) -> Option<Changes> {
        match self.service.subscribe_devices(&self.service.devices()) {
            Ok(changes) => Some(changes),
            Err(e) => {
                tracing::warn!(error = %e, "OPC UA: cannot follow the devices' changes");
                None
            }
        }
    }

    /// Brings the address space's devices and links to the service's; when anything came
    /// or went, a `GeneralModelChangeEvent` from the Server object names the nodes added
    /// and removed, so that clients browse again.
    fn sync(&self, shown: &mut Shown) {
        let changes = self.sync_nodes(shown);
        if !changes.is_empty() && shown.synced {
            self.model_changed(changes);
        }
        shown.synced = true;
    }

    fn model_changed(&self, changes: Vec<ModelChangeStructureDataType>) {
        use opcua::nodes::BaseEventType;
        use opcua::types::{ByteString, ObjectId};
        let id: [u8; 16] = {
            let nanos = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_nanos());
            nanos.to_le_bytes()
        };
        let event = GeneralModelChangeEvent {
            base: BaseModelChangeEventType {
                base: BaseEventType::new_now(
                    ObjectTypeId::GeneralModelChangeEventType,
                    ByteString::from(id.to_vec()),
                    "devices or links were added or removed: browse Objects/iogate again",
                )
                .set_source_node(self.ids.folder(space::ROOT))
                .set_source_name("iogate".into())
                .set_severity(100),
            },
            changes,
        };
        let server: NodeId = ObjectId::Server.into();
        self.subscriptions
            .notify_events([(&event as &dyn opcua::nodes::Event, &server)].into_iter());
    }

    /// The nodes added and removed: each device or link object, and its folder's reference.
    fn sync_nodes(&self, shown: &mut Shown) -> Vec<ModelChangeStructureDataType> {
        let now = DateTime::now();
        let devices = self.service.devices();
        let links = self.service.links();
        self.tell_gone(shown, &devices, &links, now);
        let mut model = Vec::new();
        let mut space = self.manager.address_space().write();
        let ids = self.ids;
        shown.devices.retain(|name, old| {
            let kept = devices.iter().any(|d| Arc::ptr_eq(d, &old.device));
            if !kept {
                space::remove_device(&mut space, ids, name, &old.fields);
                model.extend(node_changes(ids, ids.device(name), space::DEVICES, false));
            }
            kept
        });
        let mut added = Vec::new();
        for device in &devices {
            if shown.devices.contains_key(device.name()) {
                continue;
            }
            space::add_device(&mut space, &self.service, ids, device, now);
            model.extend(node_changes(
                ids,
                ids.device(device.name()),
                space::DEVICES,
                true,
            ));
            added.push(device.clone());
            let fields: Vec<String> = device
                .profile
                .fields
                .iter()
                .map(|f| f.name.clone())
                .collect();
            let field_ids = fields.iter().map(|f| ids.field(device.name(), f)).collect();
            shown.devices.insert(
                device.name().to_owned(),
                ShownDevice {
                    device: device.clone(),
                    fields,
                    ids: field_ids,
                },
            );
        }
        shown.links.retain(|name, old| {
            let kept = links.iter().any(|l| Arc::ptr_eq(l, old));
            if !kept {
                space::remove_link(&mut space, ids, name);
                model.extend(node_changes(ids, ids.link(name), space::LINKS, false));
            }
            kept
        });
        for link in &links {
            if !shown.links.contains_key(link.name()) {
                space::add_link(&mut space, ids, link, now);
                shown.links.insert(link.name().to_owned(), link.clone());
                model.extend(node_changes(ids, ids.link(link.name()), space::LINKS, true));
            }
        }
        drop(space);
        self.show_values(&added, now);
        model
    }

    /// Items monitoring a variable that goes (a field, or a device's or link's diagnostic)
    /// are told so (Bad_NodeIdUnknown) before its node is deleted; a re-planned device's
    /// kept fields and its diagnostics are not.
    fn tell_gone(
        &self,
        shown: &Shown,
        devices: &[Arc<Device>],
        links: &[Arc<Link>],
        now: DateTime,
    ) {
        let mut gone = Vec::new();
        for (name, old) in &shown.devices {
            if devices.iter().any(|d| Arc::ptr_eq(d, &old.device)) {
                continue;
            }
            let next = devices.iter().find(|d| d.name() == name.as_str());
            for field in &old.fields {
                if next.is_none_or(|d| d.field_index(field).is_err()) {
                    gone.push(self.ids.field(name, field));
                }
            }
            if next.is_none() {
                let ids = space::DEVICE_DIAGNOSTICS.map(|v| self.ids.device_diagnostic(name, v));
                gone.extend(ids);
            }
        }
        for name in shown.links.keys() {
            if !links.iter().any(|l| l.name() == name.as_str()) {
                gone.extend(space::LINK_DIAGNOSTICS.map(|v| self.ids.link_diagnostic(name, v)));
            }
        }
        let unknown = DataValue {
            value: Some(opcua::types::Variant::Empty),
            status: Some(opcua::types::StatusCode::BadNodeIdUnknown),
            server_timestamp: Some(now),
            ..DataValue::default()
        };
        self.set(gone.into_iter().map(|id| (id, unknown.clone())).collect());
    }

    /// Items that monitored a re-planned device's fields see its values now.
    fn show_values(&self, added: &[Arc<Device>], now: DateTime) {
        let values = added
            .iter()
            .flat_map(|d| {
                d.profile.fields.iter().enumerate().map(|(idx, f)| {
                    (
                        self.ids.field(d.name(), &f.name),
                        space::data_value(&self.service.field_view_now(d, idx), now),
                    )
                })
            })
            .collect();
        self.set(values);
    }

    /// A batch of changes to the items that monitor their variables; a value is rendered
    /// only for a variable that has one.
    fn apply(&self, shown: &Shown, batch: &[Change]) {
        let now = DateTime::now();
        let instant = tokio::time::Instant::now();
        let mut items: Vec<(Cow<'_, NodeId>, Rendered)> = Vec::with_capacity(batch.len());
        for (n, change) in batch.iter().enumerate() {
            match change {
                Change::Value { device, idx, .. } => {
                    let id = match shown.field_id(device, *idx) {
                        Some(id) => Cow::Borrowed(id),
                        None => Cow::Owned(self.ids.field(device.name(), &device.field(*idx).name)),
                    };
                    items.push((id, (n, None)));
                }
                Change::Diagnostics { device, .. } => {
                    for name in space::DEVICE_DIAGNOSTICS {
                        let id = self.ids.device_diagnostic(device.name(), name);
                        items.push((Cow::Owned(id), (n, Some(name))));
                    }
                }
                Change::Removed { .. } => {}
            }
        }
        self.notify(&items, |_, &(n, diagnostic)| {
            match (&batch[n], diagnostic) {
                (
                    Change::Value {
                        device,
                        idx,
                        sample,
                        ..
                    },
                    _,
                ) => Some(space::sample_value(device, *idx, sample, instant, now)),
                (Change::Diagnostics { diagnostics, .. }, Some(name)) => {
                    space::device_diagnostics(diagnostics, now)
                        .into_iter()
                        .find(|(n, _)| *n == name)
                        .map(|(_, v)| v)
                }
                _ => None,
            }
        });
    }

    /// Whether links came or went since the address space was last brought up to date
    /// (declared or removed at run time, with no device changing).
    fn links_changed(&self, shown: &Shown) -> bool {
        let links = self.service.links();
        links.len() != shown.links.len()
            || links
                .iter()
                .any(|l| shown.links.get(l.name()).is_none_or(|s| !Arc::ptr_eq(s, l)))
    }

    /// The diagnostics that count on without a change of state (a device's `io_cycles` and
    /// `last_response_ms`, a link's state) to the items that monitor them.
    fn diagnostics(&self, shown: &Shown) {
        let mut ids: Vec<(NodeId, super::space::Live)> = Vec::new();
        for name in shown.links.keys() {
            for var in space::LINK_DIAGNOSTICS {
                let id = self.ids.link_diagnostic(name, var);
                ids.push((
                    id.clone(),
                    super::space::Live::LinkDiagnostic(name.clone(), var.into()),
                ));
            }
        }
        for name in shown.devices.keys() {
            for var in space::DEVICE_DIAGNOSTICS {
                let id = self.ids.device_diagnostic(name, var);
                ids.push((
                    id.clone(),
                    super::space::Live::DeviceDiagnostic(name.clone(), var.into()),
                ));
            }
        }
        let now = DateTime::now();
        self.notify(&ids, |id, _| {
            super::live::value(&self.service, self.ids, id, now)
        });
    }

    /// Notifies the monitored items of the variables `items` name (each with what renders
    /// its value), rendering a value only for a variable that has one. The library asks
    /// for a variable's value while at that variable, before it takes the next: the item
    /// last taken is the one asked for (looked up only if it ever were not).
    fn notify<K: Borrow<NodeId>, T>(
        &self,
        items: &[(K, T)],
        render: impl Fn(&NodeId, &T) -> Option<DataValue>,
    ) {
        if items.is_empty() {
            return;
        }
        let at = Cell::new(0usize);
        let rendered = Cell::new(0usize);
        self.subscriptions.maybe_notify(
            items.iter().enumerate().map(|(n, (id, _))| {
                at.set(n);
                (id.borrow(), AttributeId::Value)
            }),
            |id, _, _, _| {
                let item = Some(&items[at.get()])
                    .filter(|(i, _)| i.borrow() == id)
                    .or_else(|| items.iter().find(|(i, _)| i.borrow() == id))?;
                let value = render(id, &item.1);
                rendered.set(rendered.get() + usize::from(value.is_some()));
                value
            },
        );
        self.counts.values_set(rendered.get());
    }

    /// Tells the items of variables that go (or come back) their value, whatever it is.
    fn set(&self, values: Vec<(NodeId, DataValue)>) {
        if values.is_empty() {
            return;
        }
        self.counts.values_set(values.len());
        self.subscriptions.notify_data_change(
            values
                .iter()
                .map(|(id, v)| (v.clone(), id, AttributeId::Value)),
        );
    }
}

/// A `GeneralModelChangeEventType` whose `Changes` is the array the type declares (the
/// library's generated struct has room for one change only).
#[derive(Debug, opcua::Event)]
#[opcua(identifier = "i=2133")]
struct GeneralModelChangeEvent {
    base: BaseModelChangeEventType,
    changes: Vec<ModelChangeStructureDataType>,
}

/// A device's or link's object added or removed, and the reference to it from its folder.
fn node_changes(
    ids: Ids,
    node: NodeId,
    folder: &str,
    added: bool,
) -> [ModelChangeStructureDataType; 2] {
    // Part 5, 6.4.32: NodeAdded 1, NodeDeleted 2, ReferenceAdded 4, ReferenceDeleted 8.
    let (node_verb, reference_verb) = if added { (1, 4) } else { (2, 8) };
    [
        ModelChangeStructureDataType {
            affected: node,
            affected_type: ObjectTypeId::BaseObjectType.into(),
            verb: node_verb,
        },
        ModelChangeStructureDataType {
            affected: ids.folder(folder),
            affected_type: ObjectTypeId::FolderType.into(),
            verb: reference_verb,
        },
    ]
}

async fn next(changes: &mut Option<Changes>) -> Option<Change> {
    match changes {
        Some(c) => c.next().await,
        None => std::future::pending().await,
    }
}

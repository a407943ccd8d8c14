//! Values that live in the gateway, not in the address space: a field's sample, a device's
//! or link's diagnostics. They are rendered when a client reads them (or creates a monitored
//! item on them) and when a change reaches an item that monitors them; a change that no one
//! monitors costs the OPC UA server nothing.

use opcua::server::address_space::{AddressSpace, NodeType};
use opcua::sync::RwLock;
use opcua::types::{DataValue, DateTime, NodeId};

use super::space::{self, Ids, Live};
use crate::service::Service;

/// The data value of `id` now, when it is a live variable of a device or link that exists.
pub(crate) fn value(service: &Service, ids: Ids, id: &NodeId, now: DateTime) -> Option<DataValue> {
    match ids.live_of(id)? {
        Live::Field(device, field) => {
            let device = service.device(&device).ok()?;
            let idx = device.field_index(&field).ok()?;
            // A name that matched another case is another node.
            (device.field(idx).name == field)
                .then(|| space::data_value(&service.field_view_now(&device, idx), now))
        }
        Live::DeviceDiagnostic(device, name) => {
            let device = service.device(&device).ok()?;
            space::device_diagnostics(&device.diagnostics(), now)
                .into_iter()
                .find(|(n, _)| *n == name)
                .map(|(_, v)| v)
        }
        Live::LinkDiagnostic(link, name) => {
            let link = service.links().into_iter().find(|l| l.name() == link)?;
            space::link_diagnostics(&link.diagnostics(), now)
                .into_iter()
                .find(|(n, _)| *n == name)
                .map(|(_, v)| v)
        }
    }
}

/// Sets the live variables among `ids` to their values now, so that the address space
/// answers a read (with its index ranges, encodings and timestamps) as it is.
pub(crate) fn refresh<'a>(
    service: &Service,
    ids: Ids,
    address_space: &RwLock<AddressSpace>,
    nodes: impl Iterator<Item = &'a NodeId>,
) {
    let now = DateTime::now();
    let values: Vec<(&NodeId, DataValue)> = nodes
        .filter_map(|id| Some((id, value(service, ids, id, now)?)))
        .collect();
    if values.is_empty() {
        return;
    }
    let mut space = address_space.write();
    for (id, value) in values {
        if let Some(NodeType::Variable(v)) = space.find_mut(id) {
            v.set_data_value(value);
        }
    }
}

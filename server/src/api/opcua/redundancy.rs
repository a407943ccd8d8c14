//! The OPC UA server of a node of an active/standby pair, as OPC UA Part 4 (6.6.2,
//! non-transparent redundancy) has clients find the server to use: `ServerRedundancy`
//! says Warm (the backup runs, but is not connected to the field: a standby touches
//! nothing in it) with the pair's application URIs in `ServerUriArray`, and `ServiceLevel`
//! is 255 on the active and 1 (no data) on the standby, so that a client that follows the
//! highest ServiceLevel (UaExpert's and Ignition's redundancy settings) switches by itself.
//! A gateway alone says None and 255.

use std::sync::Arc;

use opcua::server::ServerHandle;
use opcua::server::address_space::NodeType;
use opcua::server::node_manager::memory::CoreNodeManager;
use opcua::types::{DateTime, NodeId, ReferenceTypeId, StatusCode, Variant};
use tokio_util::sync::CancellationToken;

use crate::role::Role;

/// `RedundancySupport` (Part 5, 12.5): None, and Warm.
const NONE: i32 = 0;
const WARM: i32 = 2;
/// `ServiceLevel` (Part 4, 6.6.2.4.2): healthy, and no data.
pub(crate) const ACTIVE_LEVEL: u8 = 255;
pub(crate) const STANDBY_LEVEL: u8 = 1;

const SERVER_REDUNDANCY: u32 = 2296;
const REDUNDANCY_SUPPORT: u32 = 3709;
const SERVER_URI_ARRAY: u32 = 11314;
const SERVER_REDUNDANCY_TYPE: u32 = 2034;
const NON_TRANSPARENT_REDUNDANCY_TYPE: u32 = 2039;

/// The application URI of node `node` of a pair whose config names `base`: each server of
/// a redundant set has its own.
pub(crate) fn application_uri(base: &str, node: Option<&str>) -> String {
    match node {
        Some(node) => format!("{base}:{node}"),
        None => base.to_owned(),
    }
}

/// The ServiceLevel of a gateway in `role` now.
fn level(role: &Role) -> u8 {
    if role.owns_field() {
        ACTIVE_LEVEL
    } else {
        STANDBY_LEVEL
    }
}

/// Says the server's redundancy, and follows the role with its ServiceLevel until `token`
/// is cancelled.
pub(crate) async fn follow(
    handle: ServerHandle,
    role: Arc<Role>,
    base_uri: String,
    token: CancellationToken,
) {
    let mut lease = role.watch();
    loop {
        let uris = match role.node() {
            None => Vec::new(),
            Some(me) => {
                let mut uris = vec![application_uri(&base_uri, Some(me))];
                let other = lease.borrow().active.as_ref().map(|p| p.node.clone());
                if let Some(other) = other.filter(|o| o != me) {
                    uris.push(application_uri(&base_uri, Some(&other)));
                }
                uris
            }
        };
        describe(&handle, &uris);
        handle.set_service_level(level(&role));
        tokio::select! {
            _ = token.cancelled() => return,
            changed = lease.changed() => if changed.is_err() { return },
        }
    }
}

/// `ServerRedundancy`: its support and, for a pair, its type and `ServerUriArray`.
fn describe(handle: &ServerHandle, uris: &[String]) {
    let Some(core) = handle.node_managers().get_of_type::<CoreNodeManager>() else {
        return;
    };
    let mut space = core.address_space().write();
    let now = DateTime::now();
    let mut set = |id: u32, value: Variant| {
        if let Some(NodeType::Variable(v)) = space.find_mut(&NodeId::new(0, id)) {
            let _ = v.set_value_direct(value, StatusCode::Good, &now, &now);
        }
    };
    let paired = !uris.is_empty();
    set(
        REDUNDANCY_SUPPORT,
        Variant::Int32(if paired { WARM } else { NONE }),
    );
    if !paired {
        return;
    }
    set(SERVER_URI_ARRAY, Variant::from(uris.to_vec()));
    let redundancy = NodeId::new(0, SERVER_REDUNDANCY);
    let uri_array = NodeId::new(0, SERVER_URI_ARRAY);
    space.delete_reference(
        &redundancy,
        &NodeId::new(0, SERVER_REDUNDANCY_TYPE),
        ReferenceTypeId::HasTypeDefinition,
    );
    let non_transparent = NodeId::new(0, NON_TRANSPARENT_REDUNDANCY_TYPE);
    space.delete_reference(
        &redundancy,
        &non_transparent,
        ReferenceTypeId::HasTypeDefinition,
    );
    space.delete_reference(&redundancy, &uri_array, ReferenceTypeId::HasProperty);
    space.insert_reference(
        &redundancy,
        &non_transparent,
        ReferenceTypeId::HasTypeDefinition,
    );
    space.insert_reference(&redundancy, &uri_array, ReferenceTypeId::HasProperty);
}

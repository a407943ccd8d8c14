//! The gateway's node manager: the address space kept in memory by `feed.rs`, read as it
//! is, and written through the service. A write is refused in OPC UA's words: an input is
//! `Bad_NotWritable`, a session whose role may not write `Bad_UserAccessDenied`, a value
//! of the wrong kind `Bad_TypeMismatch`, one outside the field's range `Bad_OutOfRange`;
//! an accepted write answers Good (its outcome follows in the REST API and the variable).

use std::sync::{Arc, Weak};

use opcua::server::CreateMonitoredItem;
use opcua::server::address_space::{AccessLevel, AddressSpace, NodeType, read_node_value};
use opcua::server::diagnostics::NamespaceMetadata;
use opcua::server::node_manager::memory::{
    InMemoryNodeManagerBuilder, InMemoryNodeManagerImpl, InMemoryNodeManagerImplBuilder,
};
use opcua::server::node_manager::{
    MonitoredItemRef, NodeManagerBuilder, ParsedReadValueId, RequestContext, ServerContext,
    WriteNode,
};
use opcua::sync::RwLock;
use opcua::types::{AttributeId, DataValue, NumericRange, StatusCode, TimestampsToReturn};

use super::OpcUaState;
use super::space::{self, Ids};
use crate::cache::Refusal;
use crate::service::{Service, ServiceError};

/// Builds the node manager of namespace `namespace`.
pub(crate) fn builder(
    namespace: &str,
    service: Weak<Service>,
    counts: Arc<OpcUaState>,
) -> impl NodeManagerBuilder {
    InMemoryNodeManagerBuilder::new(Builder {
        namespace: NamespaceMetadata {
            namespace_uri: namespace.to_owned(),
            ..Default::default()
        },
        service,
        counts,
    })
}

struct Builder {
    namespace: NamespaceMetadata,
    service: Weak<Service>,
    counts: Arc<OpcUaState>,
}

impl InMemoryNodeManagerImplBuilder for Builder {
    type Impl = GatewayNodes;

    fn build(mut self, context: ServerContext, address_space: &mut AddressSpace) -> GatewayNodes {
        self.namespace.namespace_index = context
            .type_tree
            .write()
            .namespaces_mut()
            .add_namespace(&self.namespace.namespace_uri);
        address_space.add_namespace(
            &self.namespace.namespace_uri,
            self.namespace.namespace_index,
        );
        GatewayNodes {
            ids: Ids {
                ns: self.namespace.namespace_index,
            },
            namespace: self.namespace,
            service: self.service,
            counts: self.counts,
        }
    }
}

pub(crate) struct GatewayNodes {
    namespace: NamespaceMetadata,
    ids: Ids,
    service: Weak<Service>,
    counts: Arc<OpcUaState>,
}

#[async_trait::async_trait]
impl InMemoryNodeManagerImpl for GatewayNodes {
    async fn init(&self, _address_space: &mut AddressSpace, _context: ServerContext) {}

    fn name(&self) -> &str {
        "iogate"
    }

    fn namespaces(&self) -> Vec<NamespaceMetadata> {
        vec![self.namespace.clone()]
    }

    async fn read_values(
        &self,
        context: &RequestContext,
        address_space: &RwLock<AddressSpace>,
        nodes: &[&ParsedReadValueId],
        max_age: f64,
        timestamps_to_return: TimestampsToReturn,
    ) -> Vec<DataValue> {
        if let Some(service) = self.service.upgrade() {
            super::live::refresh(
                &service,
                self.ids,
                address_space,
                nodes.iter().map(|n| &n.node_id),
            );
        }
        let space = address_space.read();
        nodes
            .iter()
            .map(|n| match space.find(&n.node_id) {
                Some(node) => read_node_value(node, context, n, max_age, timestamps_to_return),
                None => DataValue {
                    status: Some(StatusCode::BadNodeIdUnknown),
                    ..Default::default()
                },
            })
            .collect()
    }

    async fn create_value_monitored_items(
        &self,
        context: &RequestContext,
        address_space: &RwLock<AddressSpace>,
        items: &mut [&mut &mut CreateMonitoredItem],
    ) {
        // Every session's items together are bounded: past the bound, an item is refused.
        let taken = self.counts.reserve_items(items.len());
        let (items, refused) = items.split_at_mut(taken);
        for item in refused {
            item.set_status(StatusCode::BadTooManyMonitoredItems);
        }
        let to_read: Vec<_> = items.iter().map(|r| r.item_to_monitor()).collect();
        let values = self
            .read_values(
                context,
                address_space,
                &to_read,
                0.0,
                TimestampsToReturn::Both,
            )
            .await;
        // A node without a value (an object, a folder) has no Value item, as a Read of it
        // answers; its place is given back.
        let mut invalid = 0;
        for (value, item) in values.into_iter().zip(items.iter_mut()) {
            if value.status() == StatusCode::BadAttributeIdInvalid {
                item.set_status(StatusCode::BadAttributeIdInvalid);
                invalid += 1;
            } else {
                item.set_initial_value(value);
                item.set_status(StatusCode::Good);
            }
        }
        self.counts.items_deleted(invalid);
    }

    async fn delete_monitored_items(&self, _context: &RequestContext, items: &[&MonitoredItemRef]) {
        self.counts.items_deleted(items.len());
    }

    async fn write(
        &self,
        context: &RequestContext,
        address_space: &RwLock<AddressSpace>,
        nodes_to_write: &mut [&mut WriteNode],
    ) -> Result<(), StatusCode> {
        for write in nodes_to_write {
            let status = self.write_one(context, address_space, write);
            self.counts.write(status.is_good());
            write.set_status(status);
        }
        Ok(())
    }
}

impl GatewayNodes {
    fn write_one(
        &self,
        context: &RequestContext,
        address_space: &RwLock<AddressSpace>,
        write: &WriteNode,
    ) -> StatusCode {
        let w = write.value();
        let (device, field) = {
            let space = address_space.read();
            let Some(node) = space.find(&w.node_id) else {
                return StatusCode::BadNodeIdUnknown;
            };
            let NodeType::Variable(variable) = node else {
                return StatusCode::BadNotWritable;
            };
            if w.attribute_id != AttributeId::Value {
                return StatusCode::BadNotWritable;
            }
            if !variable.access_level().contains(AccessLevel::CURRENT_WRITE) {
                return StatusCode::BadNotWritable;
            }
            let user = context.authenticator.effective_user_access_level(
                &context.token,
                variable.user_access_level(),
                &w.node_id,
            );
            if !user.contains(AccessLevel::CURRENT_WRITE) {
                return StatusCode::BadUserAccessDenied;
            }
            match self.ids.field_of(&w.node_id) {
                Some(named) => named,
                None => return StatusCode::BadNotWritable,
            }
        };
        if !matches!(w.index_range, NumericRange::None) {
            return StatusCode::BadIndexRangeInvalid;
        }
        // Only the value is taken (OPC UA Part 4, 5.10.4: a status or timestamps the server
        // does not write are refused).
        if w.value.status.is_some_and(|s| !s.is_good())
            || w.value.source_timestamp.is_some()
            || w.value.server_timestamp.is_some()
        {
            return StatusCode::BadWriteNotSupported;
        }
        let Some(variant) = &w.value.value else {
            return StatusCode::BadTypeMismatch;
        };
        let Some(service) = self.service.upgrade() else {
            return StatusCode::BadShutdown;
        };
        let prepared = service.prepare_named(&device, &field, |ty| space::value_of(ty, variant));
        match prepared.and_then(|p| service.write(p)) {
            Ok(_) => StatusCode::Good,
            Err(e) => refused(&e),
        }
    }
}

/// The node manager as the server holds it.
pub(crate) type Manager = opcua::server::node_manager::memory::InMemoryNodeManager<GatewayNodes>;

/// The status code of a refused write: the OPC UA column of the refusal kinds (the one
/// table; REST's is `api/error.rs`, gRPC's `api::grpc::status`).
pub(crate) fn refused(e: &ServiceError) -> StatusCode {
    match e.refusal().0 {
        Refusal::Invalid if e.out_of_range() => StatusCode::BadOutOfRange,
        Refusal::Invalid => StatusCode::BadTypeMismatch,
        Refusal::NotFound => StatusCode::BadNodeIdUnknown,
        Refusal::Conflict => StatusCode::BadNotWritable,
        Refusal::Forbidden => StatusCode::BadUserAccessDenied,
        Refusal::Gone => StatusCode::BadNotFound,
        Refusal::Unavailable => StatusCode::BadShutdown,
        Refusal::TooMany | Refusal::Busy => StatusCode::BadTooManyOperations,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cache::AccessError;

    #[test]
    fn every_refusal_kind_has_its_status_code() {
        let input = AccessError::NotWritable {
            device: "d".into(),
            field: "f".into(),
        };
        assert_eq!(
            refused(&ServiceError::Access(input)),
            StatusCode::BadNotWritable
        );
        let unknown = AccessError::UnknownField {
            device: "d".into(),
            field: "f".into(),
        };
        assert_eq!(
            refused(&ServiceError::Access(unknown)),
            StatusCode::BadNodeIdUnknown
        );
        assert_eq!(
            refused(&ServiceError::ReadOnly),
            StatusCode::BadUserAccessDenied
        );
        assert_eq!(
            refused(&ServiceError::Busy("rs485".into())),
            StatusCode::BadTooManyOperations
        );
        assert_eq!(
            refused(&ServiceError::ShuttingDown),
            StatusCode::BadShutdown
        );
    }
}

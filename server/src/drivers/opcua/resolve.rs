//! A device's fields as the nodes of the session's server: the namespace of each written
//! index taken by its URI (learned the first time, then looked up in each new session's
//! namespace array), browse paths translated from the Objects folder. A field that does
//! not resolve is a field error naming why; the others are read.

use std::str::FromStr;
use std::sync::Arc;

use opcua::types::{
    BrowsePath, ByteString, Guid, NodeId, ObjectId, QualifiedName, ReferenceTypeId, RelativePath,
    RelativePathElement,
};

use super::node::{Identifier, Namespace, NodeAddress, Step, parse_browse_path, parse_node};
use super::{Connection, Plan, refuse};
use crate::cache::Device;
use crate::link::LinkFault;

impl Connection {
    /// The session's index of a namespace URI.
    fn index_of(&self, uri: &str) -> Option<u16> {
        self.namespaces
            .iter()
            .position(|u| u == uri)
            .and_then(|i| u16::try_from(i).ok())
    }
}

/// The session's index of a namespace the profile wrote: by the URI learned for a written
/// index (learning it from this session the first time), or by its URI.
fn namespace(conn: &Connection, plan: &mut Plan, ns: &Namespace) -> Result<u16, String> {
    match ns {
        Namespace::Index(0) => Ok(0),
        Namespace::Index(i) => {
            let uri = match plan.uris.get(i) {
                Some(uri) => uri.clone(),
                None => {
                    let uri = conn
                        .namespaces
                        .get(usize::from(*i))
                        .cloned()
                        .ok_or_else(|| {
                            format!(
                                "namespace {i} is not on the server ({} namespaces)",
                                conn.namespaces.len()
                            )
                        })?;
                    plan.uris.insert(*i, uri.clone());
                    uri
                }
            };
            conn.index_of(&uri).ok_or_else(|| {
                format!("namespace {uri} (index {i} before) is no longer on the server")
            })
        }
        Namespace::Uri(uri) => conn
            .index_of(uri)
            .ok_or_else(|| format!("namespace {uri} is not on the server")),
    }
}

fn node_id(ns: u16, id: &Identifier) -> Result<NodeId, String> {
    Ok(match id {
        Identifier::Numeric(n) => NodeId::new(ns, *n),
        Identifier::String(s) => NodeId::new(ns, s.clone()),
        Identifier::Guid(g) => NodeId::new(
            ns,
            Guid::from_str(g).map_err(|_| format!("`{g}` is not a GUID"))?,
        ),
        Identifier::Opaque(b) => NodeId::new(
            ns,
            ByteString::from_base64(b).ok_or_else(|| format!("`{b}` is not base64"))?,
        ),
    })
}

fn path(conn: &Connection, plan: &mut Plan, steps: &[Step]) -> Result<BrowsePath, String> {
    let elements = steps
        .iter()
        .map(|s| {
            let ns = namespace(conn, plan, &Namespace::Index(s.namespace))?;
            Ok(RelativePathElement {
                reference_type_id: ReferenceTypeId::HierarchicalReferences.into(),
                is_inverse: false,
                include_subtypes: true,
                target_name: QualifiedName::new(ns, s.name.as_str()),
            })
        })
        .collect::<Result<Vec<_>, String>>()?;
    Ok(BrowsePath {
        starting_node: ObjectId::ObjectsFolder.into(),
        relative_path: RelativePath {
            elements: Some(elements),
        },
    })
}

/// Resolves every field of the device in this session; the fields that do not resolve
/// are published with why.
pub(super) async fn nodes(
    conn: &Connection,
    device: &Arc<Device>,
    plan: &mut Plan,
) -> Result<(), LinkFault> {
    let mut nodes = Vec::with_capacity(device.profile.fields.len());
    let mut paths = Vec::new();
    for (idx, field) in device.profile.fields.iter().enumerate() {
        let Some(point) = &field.point else {
            nodes.push(Err("the field names no node".to_owned()));
            continue;
        };
        let resolved = if point.browse_path {
            parse_browse_path(&point.address)
                .and_then(|steps| path(conn, plan, &steps))
                .map(|p| {
                    paths.push((idx, p));
                    NodeId::null()
                })
        } else {
            parse_node(&point.address).and_then(
                |NodeAddress {
                     namespace: ns,
                     identifier,
                 }| { node_id(namespace(conn, plan, &ns)?, &identifier) },
            )
        };
        nodes.push(resolved);
    }
    translate(conn, &mut nodes, paths).await?;
    for (idx, n) in nodes.iter().enumerate() {
        if let Err(why) = n {
            if device.field(idx).point.is_some() {
                tracing::warn!(device = %device.name(), field = %device.field(idx).name, error = %why, "field not on the server");
            }
            refuse(device, idx, why.clone());
        }
    }
    plan.nodes = nodes;
    plan.generation = conn.generation;
    Ok(())
}

/// Browse paths to node ids, in requests within the server's limit.
async fn translate(
    conn: &Connection,
    nodes: &mut [Result<NodeId, String>],
    paths: Vec<(usize, BrowsePath)>,
) -> Result<(), LinkFault> {
    let asked: Vec<BrowsePath> = paths.iter().map(|(_, p)| p.clone()).collect();
    let session = &conn.session;
    let answered = super::limits::in_requests(conn, super::Service::Translate, &asked, |p| {
        session.translate_browse_paths_to_node_ids(p)
    })
    .await;
    for (range, got) in answered {
        let paths = &paths[range];
        let results = match got {
            Ok(r) => r,
            Err(e) => {
                if let Some(fault) = conn.fault(&e) {
                    return Err(fault);
                }
                for (idx, _) in paths {
                    nodes[*idx] = Err(format!("browse path not translated: {}", e.status()));
                }
                continue;
            }
        };
        found(nodes, paths, &results);
    }
    Ok(())
}

/// Each path's node, from the server's answer.
fn found(
    nodes: &mut [Result<NodeId, String>],
    paths: &[(usize, BrowsePath)],
    results: &[opcua::types::BrowsePathResult],
) {
    for ((idx, _), result) in paths.iter().zip(results.iter()) {
        let target = result
            .targets
            .as_ref()
            .and_then(|t| t.iter().find(|t| t.remaining_path_index == u32::MAX));
        nodes[*idx] = match target {
            Some(t) if result.status_code.is_good() => Ok(t.target_id.node_id.clone()),
            _ => Err(format!("browse path not found: {}", result.status_code)),
        };
    }
    for (idx, _) in paths.iter().skip(results.len()) {
        nodes[*idx] = Err("browse path not answered".to_owned());
    }
}

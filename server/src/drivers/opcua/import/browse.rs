//! The browse of an import: every variable below the root, level by level, each level's
//! nodes browsed together in requests within the server's limit. A variable reached by two
//! paths is one variable (the other path noted).

use std::collections::{HashMap, HashSet};

use opcua::types::{
    BrowseDescription, BrowseDirection, BrowseResult, NodeClass, NodeId, ObjectId,
    ReferenceDescription, ReferenceTypeId, StatusCode,
};

use super::super::Connection;
use super::super::limits::{self, Service};

/// How deep the browse goes below the root, how many variables it takes and how many nodes
/// it visits at most (a server with more is reported as cut short).
const MAX_DEPTH: usize = 12;
const MAX_VARIABLES: usize = 20_000;
const MAX_NODES: usize = 100_000;
/// The references asked of each node per answer (more come by continuation): with the
/// nodes of one request, an answer stays within the message size.
const REFERENCES_PER_NODE: u32 = 100;

/// A variable found, with the browse names that lead to it.
pub(super) struct Found {
    pub(super) node: NodeId,
    pub(super) path: Vec<String>,
}

/// What the browse found: the variables, and notes on what it did not take twice or at all.
#[derive(Default)]
pub(super) struct Browsed {
    pub(super) found: Vec<Found>,
    pub(super) notes: Vec<String>,
}

/// Every variable below `root` (objects and variables followed, properties not).
pub(super) async fn browse(conn: &Connection, root: &NodeId) -> Result<Browsed, String> {
    let mut browsed = Browsed::default();
    let mut known: HashMap<NodeId, usize> = HashMap::new();
    let mut seen = HashSet::from([root.clone()]);
    let mut level = vec![(root.clone(), Vec::<String>::new())];
    let mut depth = 0;
    while !level.is_empty() {
        if depth > MAX_DEPTH {
            browsed.notes.push(format!(
                "browse stopped {MAX_DEPTH} levels below the root: give --node a deeper root"
            ));
            break;
        }
        let results = references(conn, &level).await?;
        if depth == 0 {
            root_exists(root, &results)?;
        }
        let mut next = Vec::new();
        for ((_, path), refs) in level.iter().zip(results) {
            let refs = match refs {
                Ok(refs) => refs,
                Err(why) => {
                    browsed
                        .notes
                        .push(format!("{}: not browsed: {why}", path.join("/")));
                    continue;
                }
            };
            for r in refs {
                let mut child = path.clone();
                child.push(r.browse_name.name.as_ref().to_owned());
                let id = r.node_id.node_id;
                if r.node_class == NodeClass::Variable {
                    match known.get(&id) {
                        Some(&i) => browsed.notes.push(format!(
                            "{} is {} again: one field",
                            child.join("/"),
                            browsed.found[i].path.join("/")
                        )),
                        None if browsed.found.len() < MAX_VARIABLES => {
                            known.insert(id.clone(), browsed.found.len());
                            browsed.found.push(Found {
                                node: id.clone(),
                                path: child.clone(),
                            });
                        }
                        None => {}
                    }
                }
                if seen.len() < MAX_NODES && seen.insert(id.clone()) {
                    next.push((id, child));
                }
            }
        }
        if browsed.found.len() >= MAX_VARIABLES || seen.len() >= MAX_NODES {
            browsed.notes.push(format!(
                "browse cut short after {} nodes and {} variables: give --node a narrower root",
                seen.len(),
                browsed.found.len()
            ));
            break;
        }
        level = next;
        depth += 1;
    }
    Ok(browsed)
}

/// A root the server does not have is named as such.
fn root_exists(
    root: &NodeId,
    results: &[Result<Vec<ReferenceDescription>, String>],
) -> Result<(), String> {
    match results.first() {
        Some(Err(why)) => Err(format!("{root}: {why}")),
        _ => Ok(()),
    }
}

/// The hierarchical references (to objects and variables, properties and the server's own
/// object left out) of each node of a level, or why a node's could not be browsed.
async fn references(
    conn: &Connection,
    level: &[(NodeId, Vec<String>)],
) -> Result<Vec<Result<Vec<ReferenceDescription>, String>>, String> {
    let descriptions: Vec<BrowseDescription> = level
        .iter()
        .map(|(node, _)| BrowseDescription {
            node_id: node.clone(),
            browse_direction: BrowseDirection::Forward,
            reference_type_id: ReferenceTypeId::HierarchicalReferences.into(),
            include_subtypes: true,
            node_class_mask: (NodeClass::Object as u32) | (NodeClass::Variable as u32),
            result_mask: 0x3f,
        })
        .collect();
    let session = &conn.session;
    let results = limits::all(conn, Service::Browse, &descriptions, |d| {
        session.browse(d, REFERENCES_PER_NODE, None)
    })
    .await
    .map_err(|e| e.to_string())?;
    let mut out = Vec::with_capacity(results.len());
    for result in results {
        out.push(match result.status_code {
            s if s.is_bad() => Err(said(s)),
            _ => Ok(all_of(conn, result).await?),
        });
    }
    Ok(out)
}

/// A node's references, its continuation points followed to the end.
async fn all_of(
    conn: &Connection,
    first: BrowseResult,
) -> Result<Vec<ReferenceDescription>, String> {
    let server: NodeId = ObjectId::Server.into();
    let mut refs = Vec::new();
    let mut result = first;
    let mut pages = 0;
    loop {
        let got = result.references.as_ref().map_or(0, Vec::len);
        refs.extend(result.references.into_iter().flatten().filter(|r| {
            r.reference_type_id != ReferenceTypeId::HasProperty && r.node_id.node_id != server
        }));
        if result.continuation_point.is_null() {
            return Ok(refs);
        }
        // A server whose pages do not go forward is an error, not a loop.
        pages += 1;
        if got == 0 || refs.len() > MAX_NODES {
            let _ = conn
                .session
                .browse_next(true, std::slice::from_ref(&result.continuation_point))
                .await;
            return Err(format!(
                "the server's browse did not go forward (page {pages} of a node: {got} references, {} in all)",
                refs.len()
            ));
        }
        conn.started();
        let next = conn
            .session
            .browse_next(false, std::slice::from_ref(&result.continuation_point))
            .await;
        conn.ended();
        result = next
            .map_err(|e| e.to_string())?
            .into_iter()
            .next()
            .ok_or("the server answered a browse continuation with nothing")?;
        if result.status_code.is_bad() {
            return Err(said(result.status_code));
        }
    }
}

/// A browse result's status as a user reads it.
fn said(status: StatusCode) -> String {
    if status.sub_code() == StatusCode::BadNodeIdUnknown.sub_code() {
        "no such node on the server (BadNodeIdUnknown)".to_owned()
    } else {
        status.to_string()
    }
}

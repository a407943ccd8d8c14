//! `iogate profile import --from opcua opc.tcp://HOST:PORT [--node ROOT]`: browses a server
//! from ROOT (the Objects folder by default) and writes a profile of its variables: each
//! scalar of a built-in type an IEC type has becomes a field with its node (by namespace
//! URI), its unit from EngineeringUnits, its direction from its access level; what cannot
//! be mapped is reported with why. The profile is loaded back before it is written.

use std::collections::{HashSet, VecDeque};
use std::fmt::Write as _;
use std::path::Path;
use std::sync::Arc;

use opcua::types::{
    AttributeId, BrowseDescription, BrowseDirection, BrowsePath, ExtensionObject, Identifier,
    NodeClass, NodeId, ObjectId, QualifiedName, ReadValueId, ReferenceTypeId, RelativePath,
    RelativePathElement, TimestampsToReturn, Variant,
};

use super::Connection;
use super::config::{DEFAULT_PKI_DIR, Settings, User};
use crate::codec::IecType;
use crate::profile::import::{identifier, quoted};

/// How deep the browse goes below the root, how many variables it takes and how many nodes
/// it visits at most (a server with more is reported as cut short).
const MAX_DEPTH: usize = 12;
const MAX_VARIABLES: usize = 20_000;
const MAX_NODES: usize = 100_000;

/// A variable found, with the browse names that lead to it.
struct Found {
    node: NodeId,
    path: Vec<String>,
}

/// A variable made a field, or why not.
struct Field {
    name: String,
    ty: IecType,
    direction: &'static str,
    node: String,
    unit: Option<String>,
}

/// Runs the import; the exit code: 0 a profile written, 1 nothing could be imported, 64 a
/// bad argument.
pub fn run(url: &str, root: Option<&str>, out: Option<&Path>) -> u8 {
    crate::profile::import::emit::on_runtime(import(url, root, out))
}

async fn import(url: &str, root: Option<&str>, out: Option<&Path>) -> u8 {
    if !url.starts_with("opc.tcp://") {
        eprintln!(
            "iogate profile import: `{url}` is not an OPC UA endpoint (write opc.tcp://HOST:PORT)"
        );
        return crate::EXIT_CONFIG as u8;
    }
    let settings = Settings {
        url: url.to_owned(),
        policy: "None",
        mode: "None",
        certificate: None,
        private_key: None,
        pki_dir: std::env::temp_dir()
            .join("iogate-import")
            .join(DEFAULT_PKI_DIR),
        trusted: Vec::new(),
        user: User::Anonymous,
        subscribe: false,
        limits: Default::default(),
    };
    let connecting = super::session::connect(settings, Arc::default());
    let conn = match tokio::time::timeout(std::time::Duration::from_secs(10), connecting).await {
        Ok(Ok(conn)) => conn,
        Ok(Err(e)) => {
            eprintln!("iogate profile import: {e}");
            return 1;
        }
        Err(_) => {
            eprintln!("iogate profile import: no session with {url} within 10 s");
            return 1;
        }
    };
    let root_id = match root.map(|r| root_node(&conn, r)).transpose() {
        Ok(r) => r.unwrap_or_else(|| ObjectId::ObjectsFolder.into()),
        Err(e) => {
            eprintln!("iogate profile import: --node {e}");
            return crate::EXIT_CONFIG as u8;
        }
    };
    let found = match browse(&conn, &root_id).await {
        Ok(f) => f,
        Err(e) => {
            eprintln!("iogate profile import: browsing {root_id}: {e}");
            return 1;
        }
    };
    let (fields, skipped) = match describe(&conn, &found).await {
        Ok(r) => r,
        Err(e) => {
            eprintln!("iogate profile import: reading attributes: {e}");
            return 1;
        }
    };
    for why in &skipped {
        eprintln!("not mapped: {why}");
    }
    let name = profile_name(url, root);
    write(&name, url, root, &fields, out, skipped.len())
}

/// The root given as a node id, in the server's namespaces.
fn root_node(conn: &Connection, text: &str) -> Result<NodeId, String> {
    let parsed = crate::profile::point::parse_node(text)?;
    let ns = match &parsed.namespace {
        crate::profile::point::Namespace::Index(i) => *i,
        crate::profile::point::Namespace::Uri(u) => conn
            .namespaces
            .iter()
            .position(|x| x == u)
            .and_then(|i| u16::try_from(i).ok())
            .ok_or_else(|| format!("namespace {u} is not on the server"))?,
    };
    use crate::profile::point::Identifier as I;
    Ok(match parsed.identifier {
        I::Numeric(n) => NodeId::new(ns, n),
        I::String(s) => NodeId::new(ns, s),
        I::Guid(g) => NodeId::new(
            ns,
            g.parse::<opcua::types::Guid>()
                .map_err(|_| format!("`{g}` is not a GUID"))?,
        ),
        I::Opaque(b) => NodeId::new(
            ns,
            opcua::types::ByteString::from_base64(&b).ok_or("not base64")?,
        ),
    })
}

/// Every variable below `root` (objects and variables followed, properties not).
async fn browse(conn: &Connection, root: &NodeId) -> Result<Vec<Found>, String> {
    let mut found = Vec::new();
    let mut seen = HashSet::new();
    let mut queue = VecDeque::from([(root.clone(), Vec::<String>::new())]);
    while let Some((node, path)) = queue.pop_front() {
        if found.len() >= MAX_VARIABLES || seen.len() >= MAX_NODES {
            eprintln!(
                "browse cut short after {} nodes and {} variables: give --node a narrower root",
                seen.len(),
                found.len()
            );
            break;
        }
        if path.len() > MAX_DEPTH || !seen.insert(node.clone()) {
            continue;
        }
        let description = BrowseDescription {
            node_id: node.clone(),
            browse_direction: BrowseDirection::Forward,
            reference_type_id: ReferenceTypeId::HierarchicalReferences.into(),
            include_subtypes: true,
            node_class_mask: (NodeClass::Object as u32) | (NodeClass::Variable as u32),
            result_mask: 0x3f,
        };
        let mut results = conn
            .session
            .browse(&[description], 1000, None)
            .await
            .map_err(|e| e.to_string())?;
        while let Some(result) = results.pop() {
            for r in result.references.iter().flatten() {
                // Properties are no fields; the server's own object is not the device.
                let server: NodeId = ObjectId::Server.into();
                if r.reference_type_id == ReferenceTypeId::HasProperty
                    || r.node_id.node_id == server
                {
                    continue;
                }
                let mut child = path.clone();
                child.push(r.browse_name.name.as_ref().to_owned());
                let id = r.node_id.node_id.clone();
                if r.node_class == NodeClass::Variable {
                    found.push(Found {
                        node: id.clone(),
                        path: child.clone(),
                    });
                }
                if queue.len() < MAX_NODES {
                    queue.push_back((id, child));
                }
            }
            if result.continuation_point.is_null() {
                break;
            }
            results = conn
                .session
                .browse_next(false, std::slice::from_ref(&result.continuation_point))
                .await
                .map_err(|e| e.to_string())?;
        }
    }
    Ok(found)
}

/// The IEC type of a built-in data type.
fn iec_type(data_type: &NodeId) -> Option<IecType> {
    if data_type.namespace != 0 {
        return None;
    }
    let Identifier::Numeric(n) = data_type.identifier else {
        return None;
    };
    Some(match n {
        1 => IecType::Bool,
        2 => IecType::Sint,
        3 => IecType::Usint,
        4 => IecType::Int,
        5 => IecType::Uint,
        6 => IecType::Dint,
        7 => IecType::Udint,
        8 => IecType::Lint,
        9 => IecType::Ulint,
        10 => IecType::Real,
        11 => IecType::Lreal,
        12 => IecType::String,
        _ => return None,
    })
}

/// A node id as a profile writes it: by namespace URI outside namespace 0.
fn node_text(conn: &Connection, node: &NodeId) -> String {
    let id = match &node.identifier {
        Identifier::Numeric(n) => format!("i={n}"),
        Identifier::String(s) => format!("s={}", s.as_ref()),
        Identifier::Guid(g) => format!("g={g}"),
        Identifier::ByteString(b) => format!("b={}", b.as_base64()),
    };
    match conn.namespaces.get(usize::from(node.namespace)) {
        Some(uri) if node.namespace != 0 => format!("nsu={uri};{id}"),
        _ if node.namespace != 0 => format!("ns={};{id}", node.namespace),
        _ => id,
    }
}

/// Each variable's data type, value rank, access level and engineering unit, read in
/// batches; the fields and why the others are not.
async fn describe(conn: &Connection, found: &[Found]) -> Result<(Vec<Field>, Vec<String>), String> {
    let mut fields = Vec::new();
    let mut skipped = Vec::new();
    let mut names = HashSet::new();
    for chunk in found.chunks(500) {
        let mut asked = Vec::new();
        for f in chunk {
            for a in [
                AttributeId::DataType,
                AttributeId::ValueRank,
                AttributeId::AccessLevel,
            ] {
                asked.push(ReadValueId {
                    node_id: f.node.clone(),
                    attribute_id: a as u32,
                    ..Default::default()
                });
            }
        }
        let values = conn
            .session
            .read(&asked, TimestampsToReturn::Neither, 0.0)
            .await
            .map_err(|e| e.to_string())?;
        let units = units(conn, chunk).await;
        for (i, f) in chunk.iter().enumerate() {
            let at = |k: usize| values.get(i * 3 + k).and_then(|v| v.value.clone());
            let where_ = format!("{} ({})", f.path.join("/"), node_text(conn, &f.node));
            let data_type = match at(0) {
                Some(Variant::NodeId(id)) => *id,
                _ => {
                    skipped.push(format!("{where_}: its data type could not be read"));
                    continue;
                }
            };
            let Some(ty) = iec_type(&data_type) else {
                skipped.push(format!(
                    "{where_}: data type {data_type} is not a boolean, number or string"
                ));
                continue;
            };
            if !matches!(at(1), Some(Variant::Int32(-1))) {
                skipped.push(format!("{where_}: not a scalar (arrays are not fields)"));
                continue;
            }
            let access = match at(2) {
                Some(Variant::Byte(a)) => a,
                _ => 1,
            };
            let direction = match (access & 1 != 0, access & 2 != 0) {
                (true, true) => "inout",
                (true, false) => "input",
                (false, true) => "output",
                (false, false) => {
                    skipped.push(format!("{where_}: neither readable nor writable"));
                    continue;
                }
            };
            let base = identifier(&f.path.join("_"));
            let mut name = base.clone();
            let mut n = 2;
            while !names.insert(name.to_ascii_lowercase()) {
                name = format!("{base}_{n}");
                n += 1;
            }
            fields.push(Field {
                name,
                ty,
                direction,
                node: node_text(conn, &f.node),
                unit: units.get(i).cloned().flatten(),
            });
        }
    }
    Ok((fields, skipped))
}

/// Each variable's EngineeringUnits display name, where it has one.
async fn units(conn: &Connection, chunk: &[Found]) -> Vec<Option<String>> {
    let paths: Vec<BrowsePath> = chunk
        .iter()
        .map(|f| BrowsePath {
            starting_node: f.node.clone(),
            relative_path: RelativePath {
                elements: Some(vec![RelativePathElement {
                    reference_type_id: ReferenceTypeId::HasProperty.into(),
                    is_inverse: false,
                    include_subtypes: true,
                    target_name: QualifiedName::new(0, "EngineeringUnits"),
                }]),
            },
        })
        .collect();
    let Ok(targets) = conn
        .session
        .translate_browse_paths_to_node_ids(&paths)
        .await
    else {
        return vec![None; chunk.len()];
    };
    let ids: Vec<Option<NodeId>> = targets
        .iter()
        .map(|t| {
            t.targets
                .as_ref()
                .and_then(|t| t.first())
                .map(|t| t.target_id.node_id.clone())
        })
        .collect();
    let asked: Vec<ReadValueId> = ids
        .iter()
        .flatten()
        .map(|id| ReadValueId::from(id.clone()))
        .collect();
    let values = if asked.is_empty() {
        Vec::new()
    } else {
        conn.session
            .read(&asked, TimestampsToReturn::Neither, 0.0)
            .await
            .unwrap_or_default()
    };
    let mut values = values.into_iter();
    ids.iter()
        .map(|id| {
            id.as_ref()?;
            let v = values.next()?.value?;
            let Variant::ExtensionObject(obj) = v else {
                return None;
            };
            eu_name(obj)
        })
        .collect()
}

fn eu_name(obj: ExtensionObject) -> Option<String> {
    let eu = obj.into_inner_as::<opcua::types::EUInformation>()?;
    let text = eu.display_name.text.as_ref().trim().to_owned();
    (!text.is_empty()).then_some(text)
}

/// The profile's name: the root's last id part or the server's host and port.
fn profile_name(url: &str, root: Option<&str>) -> String {
    let source = match root {
        Some(r) => r
            .rsplit(['=', ';', '.', '/'])
            .next()
            .unwrap_or(r)
            .to_owned(),
        None => format!("OpcUa_{}", url.trim_start_matches("opc.tcp://")),
    };
    identifier(&source)
}

fn write(
    name: &str,
    url: &str,
    root: Option<&str>,
    fields: &[Field],
    out: Option<&Path>,
    skipped: usize,
) -> u8 {
    let mut text = format!(
        "name: {name}\nprotocol: opcua\ndescription: {}\nfields:\n",
        quoted(&format!(
            "Imported from {url}{}",
            root.map(|r| format!(" ({r})")).unwrap_or_default()
        ))
    );
    for f in fields {
        let _ = write!(
            text,
            "  - {{ name: {}, type: {}, direction: {}, node: {}",
            f.name,
            f.ty,
            f.direction,
            quoted(&f.node)
        );
        if let Some(u) = &f.unit {
            let _ = write!(text, ", unit: {}", quoted(u));
        }
        text.push_str(" }\n");
    }
    crate::profile::import::emit::emit(
        &crate::profile::import::emit::Made {
            source: url,
            name,
            text,
            fields: fields.len(),
            skipped,
            things: "variables",
        },
        out,
    )
}

//! What an import makes of each variable found: its data type, value rank, access level
//! and engineering unit, read in requests within the server's limits; a field, or why not.

use std::collections::HashSet;

use opcua::types::{
    AttributeId, BrowsePath, ExtensionObject, Identifier, NodeId, QualifiedName, ReadValueId,
    ReferenceTypeId, RelativePath, RelativePathElement, TimestampsToReturn, Variant,
};

use super::super::Connection;
use super::super::limits::{self, Service};
use super::browse::Found;
use crate::codec::IecType;
use crate::profile::import::identifier;

/// A variable made a field, or why not.
pub(super) struct Field {
    pub(super) name: String,
    pub(super) ty: IecType,
    pub(super) direction: &'static str,
    pub(super) node: String,
    pub(super) unit: Option<String>,
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
pub(super) fn node_text(conn: &Connection, node: &NodeId) -> String {
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
pub(super) async fn describe(
    conn: &Connection,
    found: &[Found],
) -> Result<(Vec<Field>, Vec<String>), String> {
    let mut fields = Vec::new();
    let mut skipped = Vec::new();
    let mut names = HashSet::new();
    let mut asked = Vec::with_capacity(found.len() * 3);
    for f in found {
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
    let session = &conn.session;
    let values = limits::all(conn, Service::Read, &asked, |a| {
        session.read(a, TimestampsToReturn::Neither, 0.0)
    })
    .await
    .map_err(|e| e.to_string())?;
    let units = units(conn, found).await;
    for (i, f) in found.iter().enumerate() {
        let at = |k: usize| values.get(i * 3 + k).and_then(|v| v.value.clone());
        match field(conn, f, [at(0), at(1), at(2)], &mut names) {
            Ok(field) => fields.push(Field {
                unit: units.get(i).cloned().flatten(),
                ..field
            }),
            Err(why) => skipped.push(format!(
                "{} ({}): {why}",
                f.path.join("/"),
                node_text(conn, &f.node)
            )),
        }
    }
    Ok((fields, skipped))
}

/// A variable's field from its data type, value rank and access level, named after its
/// path (made unique among `names`); or why it is none.
fn field(
    conn: &Connection,
    f: &Found,
    [data_type, rank, access]: [Option<Variant>; 3],
    names: &mut HashSet<String>,
) -> Result<Field, String> {
    let data_type = match data_type {
        Some(Variant::NodeId(id)) => *id,
        _ => return Err("its data type could not be read".to_owned()),
    };
    let ty = iec_type(&data_type)
        .ok_or_else(|| format!("data type {data_type} is not a boolean, number or string"))?;
    if !matches!(rank, Some(Variant::Int32(-1))) {
        return Err("not a scalar (arrays are not fields)".to_owned());
    }
    let access = match access {
        Some(Variant::Byte(a)) => a,
        _ => 1,
    };
    let direction = match (access & 1 != 0, access & 2 != 0) {
        (true, true) => "inout",
        (true, false) => "input",
        (false, true) => "output",
        (false, false) => return Err("neither readable nor writable".to_owned()),
    };
    let base = identifier(&f.path.join("_"));
    let mut name = base.clone();
    let mut n = 2;
    while !names.insert(name.to_ascii_lowercase()) {
        name = format!("{base}_{n}");
        n += 1;
    }
    Ok(Field {
        name,
        ty,
        direction,
        node: node_text(conn, &f.node),
        unit: None,
    })
}

/// Each variable's EngineeringUnits display name, where it has one.
async fn units(conn: &Connection, found: &[Found]) -> Vec<Option<String>> {
    let paths: Vec<BrowsePath> = found
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
    let session = &conn.session;
    let Ok(targets) = limits::all(conn, Service::Translate, &paths, |p| {
        session.translate_browse_paths_to_node_ids(p)
    })
    .await
    else {
        return vec![None; found.len()];
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
    let values = limits::all(conn, Service::Read, &asked, |a| {
        session.read(a, TimestampsToReturn::Neither, 0.0)
    })
    .await
    .unwrap_or_default();
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

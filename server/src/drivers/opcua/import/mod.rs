//! `iogate profile import --from opcua opc.tcp://HOST:PORT [--node ROOT]`: browses a server
//! from ROOT (the Objects folder by default) and writes a profile of its variables: each
//! scalar of a built-in type an IEC type has becomes a field with its node (by namespace
//! URI), its unit from EngineeringUnits, its direction from its access level; what cannot
//! be mapped is reported with why. The profile is loaded back before it is written.

mod browse;
mod describe;

use std::fmt::Write as _;
use std::path::Path;
use std::sync::Arc;

use opcua::types::{NodeId, ObjectId};

use super::Connection;
use super::config::{DEFAULT_PKI_DIR, Settings, User};
use crate::profile::import::{identifier, quoted};
use describe::Field;

/// Runs the import; the exit code: 0 a profile written, 1 nothing could be imported, 64 a
/// bad argument.
pub fn run(url: &str, root: Option<&str>, out: Option<&Path>) -> u8 {
    // What is made is loaded back before it is written, as configuration reads it.
    crate::drivers::register();
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
        accept_host_mismatch: false,
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
    let made = fields(&conn, root).await;
    // The session is closed on the server, not left to its timeout.
    let _ =
        tokio::time::timeout(std::time::Duration::from_secs(2), conn.session.disconnect()).await;
    let (fields, skipped) = match made {
        Ok(made) => made,
        Err((code, why)) => {
            eprintln!("iogate profile import: {why}");
            return code;
        }
    };
    let name = profile_name(url, root);
    write(&name, url, root, &fields, out, skipped)
}

/// The fields of the variables below the root, and how many were not mapped (each told on
/// the standard error, with the notes of the browse); or the exit code and why none.
async fn fields(
    conn: &Connection,
    root: Option<&str>,
) -> Result<(Vec<Field>, usize), (u8, String)> {
    let root_id = match root.map(|r| root_node(conn, r)).transpose() {
        Ok(r) => r.unwrap_or_else(|| ObjectId::ObjectsFolder.into()),
        Err(e) => return Err((crate::EXIT_CONFIG as u8, format!("--node {e}"))),
    };
    exists(conn, &root_id)
        .await
        .map_err(|why| (1, format!("--node {root_id}: {why}")))?;
    let browsed = browse::browse(conn, &root_id)
        .await
        .map_err(|e| (1, format!("browsing {e}")))?;
    for note in &browsed.notes {
        eprintln!("note: {note}");
    }
    let (fields, skipped) = describe::describe(conn, &browsed.found)
        .await
        .map_err(|e| (1, format!("reading attributes: {e}")))?;
    for why in &skipped {
        eprintln!("not mapped: {why}");
    }
    Ok((fields, skipped.len()))
}

/// Whether the server has the node (its NodeClass read): a root it does not have is named
/// as such rather than imported as nothing.
async fn exists(conn: &Connection, node: &NodeId) -> Result<(), String> {
    use opcua::types::{AttributeId, ReadValueId, StatusCode, TimestampsToReturn};
    let asked = [ReadValueId {
        node_id: node.clone(),
        attribute_id: AttributeId::NodeClass as u32,
        ..Default::default()
    }];
    let read = conn
        .session
        .read(&asked, TimestampsToReturn::Neither, 0.0)
        .await
        .map_err(|e| e.to_string())?;
    match read.first().and_then(|v| v.status) {
        Some(s) if s.sub_code() == StatusCode::BadNodeIdUnknown.sub_code() => {
            Err("no such node on the server (BadNodeIdUnknown)".to_owned())
        }
        Some(s) if s.is_bad() => Err(s.to_string()),
        _ => Ok(()),
    }
}

/// The root given as a node id, in the server's namespaces.
fn root_node(conn: &Connection, text: &str) -> Result<NodeId, String> {
    let parsed = crate::drivers::opcua::node::parse_node(text)?;
    let ns = match &parsed.namespace {
        crate::drivers::opcua::node::Namespace::Index(i) => *i,
        crate::drivers::opcua::node::Namespace::Uri(u) => conn
            .namespaces
            .iter()
            .position(|x| x == u)
            .and_then(|i| u16::try_from(i).ok())
            .ok_or_else(|| format!("namespace {u} is not on the server"))?,
    };
    use crate::drivers::opcua::node::Identifier as I;
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

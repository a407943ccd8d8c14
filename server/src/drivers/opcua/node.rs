//! The addresses of points on devices that name them: OPC UA node ids as people write them
//! (`ns=3;s=Line1.Speed`, `i=2258`, `nsu=urn:plant:line;s=Speed`, `ns=2;g=<guid>`,
//! `ns=2;b=<base64>`) and browse paths from the Objects folder (`2:Line1/2:Speed`, each
//! step `[namespace:]BrowseName`). Only the syntax here; the driver resolves them.

use crate::codec::IecType;

/// A namespace as written: its index on the server, or its URI (stable across restarts).
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub(crate) enum Namespace {
    Index(u16),
    Uri(String),
}

/// A node id's identifier as written.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub(crate) enum Identifier {
    Numeric(u32),
    String(String),
    /// A GUID in its text form.
    Guid(String),
    /// Opaque bytes in base64.
    Opaque(String),
}

/// A node id as written.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub(crate) struct NodeAddress {
    pub(crate) namespace: Namespace,
    pub(crate) identifier: Identifier,
}

/// The longest node id or browse path accepted.
const MAX_LEN: usize = 4096;

/// Parses a node id (`ns=N;` or `nsu=URI;` then `i=`, `s=`, `g=` or `b=`).
pub(crate) fn parse_node(text: &str) -> Result<NodeAddress, String> {
    let t = text.trim();
    if t.is_empty() || t.len() > MAX_LEN {
        return Err(format!(
            "`{}` is not a node id (write e.g. `ns=3;s=Line1.Speed` or `i=2258`)",
            crate::text::quote(text)
        ));
    }
    let (namespace, rest) = if let Some(rest) = t.strip_prefix("nsu=") {
        let (uri, id) = rest.split_once(';').ok_or_else(|| {
            format!("`{t}`: a namespace URI is followed by `;` and the identifier")
        })?;
        if uri.is_empty() {
            return Err(format!("`{t}`: the namespace URI is empty"));
        }
        (Namespace::Uri(uri.to_owned()), id)
    } else if let Some(rest) = t.strip_prefix("ns=") {
        let (ns, id) = rest.split_once(';').ok_or_else(|| {
            format!("`{t}`: a namespace index is followed by `;` and the identifier")
        })?;
        let ns = ns
            .parse::<u16>()
            .map_err(|_| format!("`{t}`: the namespace index `{ns}` is not a number 0-65535"))?;
        (Namespace::Index(ns), id)
    } else {
        (Namespace::Index(0), t)
    };
    let identifier = identifier(rest).map_err(|why| format!("`{t}`: {why}"))?;
    Ok(NodeAddress {
        namespace,
        identifier,
    })
}

fn identifier(text: &str) -> Result<Identifier, String> {
    let (kind, value) = text
        .split_once('=')
        .ok_or("the identifier is `i=`, `s=`, `g=` or `b=` and its value")?;
    if value.is_empty() {
        return Err("the identifier is empty".to_owned());
    }
    match kind {
        "i" => value
            .parse::<u32>()
            .map(Identifier::Numeric)
            .map_err(|_| format!("`i={value}` is not a number 0-4294967295")),
        "s" => Ok(Identifier::String(value.to_owned())),
        "g" => {
            let hex: String = value.chars().filter(|c| *c != '-').collect();
            if hex.len() == 32 && hex.chars().all(|c| c.is_ascii_hexdigit()) {
                Ok(Identifier::Guid(value.to_owned()))
            } else {
                Err(format!("`g={value}` is not a GUID"))
            }
        }
        "b" => {
            let ok = value
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || matches!(c, '+' | '/' | '='));
            if ok {
                Ok(Identifier::Opaque(value.to_owned()))
            } else {
                Err(format!("`b={value}` is not base64"))
            }
        }
        other => Err(format!(
            "unknown identifier kind `{other}=` (expected i=, s=, g= or b=)"
        )),
    }
}

/// An OPC UA field's `node` (a node id) or `browse_path`, checked.
pub(crate) fn check(
    key: &str,
    text: &str,
    _ty: Option<IecType>,
    _length: Option<u16>,
) -> Result<(), String> {
    if key == "browse_path" {
        parse_browse_path(text).map(drop)
    } else {
        parse_node(text).map(drop)
    }
}

/// One step of a browse path: a browse name and its namespace index.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub(crate) struct Step {
    pub(crate) namespace: u16,
    pub(crate) name: String,
}

/// Parses a browse path from the Objects folder: steps separated by `/`, each
/// `[namespace:]BrowseName` (a leading `/` or `Objects/` is allowed).
pub(crate) fn parse_browse_path(text: &str) -> Result<Vec<Step>, String> {
    let t = text.trim();
    let t = t.strip_prefix('/').unwrap_or(t);
    let t = t
        .strip_prefix("Objects/")
        .or_else(|| t.strip_prefix("0:Objects/"))
        .unwrap_or(t);
    if t.is_empty() || text.len() > MAX_LEN {
        return Err(format!(
            "`{}` is not a browse path (write e.g. `2:Line1/2:Speed`, from the Objects folder)",
            crate::text::quote(text)
        ));
    }
    t.split('/')
        .map(|step| {
            let (ns, name) = match step.split_once(':') {
                Some((ns, name)) if ns.chars().all(|c| c.is_ascii_digit()) && !ns.is_empty() => {
                    let ns = ns
                        .parse::<u16>()
                        .map_err(|_| format!("`{step}`: namespace `{ns}` is not 0-65535"))?;
                    (ns, name)
                }
                _ => (0, step),
            };
            if name.is_empty() {
                return Err(format!("`{text}`: an empty step"));
            }
            Ok(Step {
                namespace: ns,
                name: name.to_owned(),
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn node_ids_in_every_written_form_parse() {
        let n = parse_node("ns=3;s=Line1.Speed").expect("string id");
        assert_eq!(n.namespace, Namespace::Index(3));
        assert_eq!(n.identifier, Identifier::String("Line1.Speed".into()));
        let n = parse_node("i=2258").expect("numeric in ns 0");
        assert_eq!(n.namespace, Namespace::Index(0));
        assert_eq!(n.identifier, Identifier::Numeric(2258));
        let n = parse_node("nsu=urn:plant:line;s=A;B").expect("uri, ; in the string");
        assert_eq!(n.namespace, Namespace::Uri("urn:plant:line".into()));
        assert_eq!(n.identifier, Identifier::String("A;B".into()));
        assert!(parse_node("ns=2;g=09087e75-8e5e-499b-954f-f2a9603db28a").is_ok());
        assert!(parse_node("ns=2;b=M/RbKBsRVkePCePcx24oRA==").is_ok());
    }

    #[test]
    fn malformed_node_ids_say_what_is_wrong() {
        for (text, says) in [
            ("", "not a node id"),
            ("ns=70000;i=1", "not a number 0-65535"),
            ("ns=2", "followed by `;`"),
            ("ns=2;x=1", "unknown identifier kind"),
            ("ns=2;i=-1", "not a number"),
            ("ns=2;s=", "empty"),
            ("ns=2;g=zz", "not a GUID"),
            ("nsu=;s=a", "URI is empty"),
        ] {
            let e = parse_node(text).expect_err(text);
            assert!(e.contains(says), "{text}: {e}");
        }
    }

    #[test]
    fn browse_paths_start_at_the_objects_folder() {
        let p = parse_browse_path("/Objects/2:Line1/2:Speed").expect("path");
        assert_eq!(
            p,
            vec![
                Step {
                    namespace: 2,
                    name: "Line1".into()
                },
                Step {
                    namespace: 2,
                    name: "Speed".into()
                }
            ]
        );
        assert_eq!(parse_browse_path("Server").expect("ns 0")[0].namespace, 0);
        assert!(parse_browse_path("2:A//2:B").is_err());
        assert!(parse_browse_path("").is_err());
    }
}

//! Profile YAML to [`Profile`], reporting every problem with file, line and field.

use std::collections::{BTreeMap, HashMap};
use std::path::Path;

mod field;
mod point;
mod register;

use super::words::Words;
use super::{Field, ProbeRead, Profile, Protocol, RegisterKind};
use crate::codec::IecType;
use crate::yaml::{self, Node, Problems, Report};
use field::read_field;

const PROFILE_KEYS: &[&str] = &[
    "name",
    "vendor",
    "protocol",
    "description",
    "identification",
    "probe",
    "fields",
];
const PROBE_KEYS: &[&str] = &["kind", "address", "count", "values"];
const FIELD_KEYS: &[&str] = &[
    "name",
    "type",
    "direction",
    "register",
    "description",
    "deadband",
];
const REGISTER_KEYS: &[&str] = &[
    "address",
    "kind",
    "bit",
    "scale",
    "offset",
    "unit",
    "byte_order",
    "word_count",
    "raw_type",
    "on_value",
    "off_value",
];

/// Names a profile field may not take: the generated function block already has them.
pub(crate) const RESERVED_NAMES: &[&str] = &[
    "link",
    "slave_id",
    "refresh_rate",
    "connected",
    "error_code",
    "io_cycles",
    "last_response_ms",
];

/// The longest STRING field: what one read transaction can carry.
const MAX_STRING_WORDS: u16 = 125;

/// Loads every `*.yaml`/`*.yml` file of `dir`. Nothing is returned if any file has a problem.
pub fn load_dir(dir: &Path) -> Result<Vec<Profile>, Problems> {
    match load_dir_partial(dir) {
        (profiles, _, problems) if problems.is_empty() => Ok(profiles),
        (_, _, problems) => Err(problems),
    }
}

/// Loads every `*.yaml`/`*.yml` file of `dir` that has no problem; the names of the profiles
/// in files that have one (as far as a `name:` line shows them); every problem.
pub(crate) fn load_dir_partial(dir: &Path) -> (Vec<Profile>, Vec<String>, Problems) {
    let shown = dir.display().to_string();
    let entries = match std::fs::read_dir(dir) {
        Ok(entries) => entries,
        Err(e) => {
            let mut report = Report::new(shown);
            report.push(0, "", format!("cannot read the profiles directory: {e}"));
            return (Vec::new(), Vec::new(), report.into_problems());
        }
    };
    let mut paths: Vec<_> = entries
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| {
            p.is_file()
                && p.extension()
                    .is_some_and(|ext| ext == "yaml" || ext == "yml")
        })
        .collect();
    paths.sort();
    let mut profiles: Vec<Profile> = Vec::new();
    let mut unreadable = Vec::new();
    let mut problems = Problems::default();
    let mut seen: HashMap<String, (String, u64)> = HashMap::new();
    for path in paths {
        let name = path.display().to_string();
        let text = match crate::text::read_file(&path) {
            Ok(text) => text,
            Err(e) => {
                let mut report = Report::new(name);
                report.push(e.line().unwrap_or(0), "", e.to_string());
                problems.extend(report.into_problems());
                continue;
            }
        };
        match load_unique(&name, &text, &mut seen) {
            Ok(profile) => profiles.push(profile),
            Err(more) => {
                problems.extend(more);
                unreadable.extend(text.lines().find_map(|l| {
                    l.strip_prefix("name:")
                        .map(|n| n.trim().trim_matches(['"', '\'']).to_owned())
                }));
            }
        }
    }
    (profiles, unreadable, problems)
}

/// One profile whose name no profile of `seen` has (ignoring case).
fn load_unique(
    file: &str,
    text: &str,
    seen: &mut HashMap<String, (String, u64)>,
) -> Result<Profile, Problems> {
    let profile = load_str(file, text)?;
    let key = profile.name.to_ascii_lowercase();
    if let Some((other, line)) = seen.get(&key) {
        let mut report = Report::new(file);
        report.push(
            1,
            format!("profile {}", profile.name),
            format!("profile name already used in {other}:{line}"),
        );
        return Err(report.into_problems());
    }
    seen.insert(key, (file.to_owned(), 1));
    Ok(profile)
}

/// Loads profiles from `(file name, text)` pairs; profile names must be unique across them.
pub fn load_files<'a>(
    files: impl IntoIterator<Item = (&'a str, &'a str)>,
) -> Result<Vec<Profile>, Problems> {
    let mut problems = Problems::default();
    let mut profiles: Vec<Profile> = Vec::new();
    let mut seen: HashMap<String, (String, u64)> = HashMap::new();
    for (file, text) in files {
        match load_unique(file, text, &mut seen) {
            Ok(profile) => profiles.push(profile),
            Err(more) => problems.extend(more),
        }
    }
    if problems.is_empty() {
        Ok(profiles)
    } else {
        Err(problems)
    }
}

/// Loads one profile from YAML text; `file` names it in problems.
pub fn load_str(file: &str, text: &str) -> Result<Profile, Problems> {
    let mut report = Report::new(file);
    let profile = yaml::parse(text, &mut report).and_then(|root| read_profile(&root, &mut report));
    match profile {
        Some(p) if !report.has_problems() => Ok(p),
        _ => Err(report.into_problems()),
    }
}

fn read_profile(root: &Node, report: &mut Report) -> Option<Profile> {
    let mut map = root.map(report, "profile")?;
    let name = map
        .require("name", report, "profile")
        .and_then(|n| identifier(n, report, "profile: name"));
    let ctx = match &name {
        Some(n) => format!("profile {n}"),
        None => "profile".to_owned(),
    };
    let vendor = map
        .get("vendor")
        .and_then(|n| n.scalar_text(report, &format!("{ctx}: vendor")));
    let description = map
        .get("description")
        .and_then(|n| n.scalar_text(report, &format!("{ctx}: description")));
    let protocol = match map.get("protocol") {
        None => Some(Protocol::ModbusRtu),
        Some(n) => one_of(
            n,
            report,
            &format!("{ctx}: protocol"),
            &Protocol::all(),
            |p| p.name(),
        ),
    };
    let field_nodes = map
        .require("fields", report, &ctx)
        .and_then(|n| n.seq(report, &format!("{ctx}: fields")));
    let identification = map
        .get("identification")
        .map(|n| read_identification(n, report, &ctx))
        .unwrap_or_default();
    let probe = map
        .get("probe")
        .map(|n| read_probe(n, report, &ctx))
        .unwrap_or_default();
    map.finish(report, &ctx, PROFILE_KEYS);

    let mut fields = Vec::new();
    if let Some(nodes) = field_nodes {
        if nodes.is_empty() {
            report.push(root.line, &ctx, "a profile needs at least one field");
        }
        for (i, node) in nodes.iter().enumerate() {
            if let Some(field) = read_field(node, i, protocol, report) {
                fields.push(field);
            }
        }
    }
    check_names(&fields, report);
    check_overlaps(&fields, protocol.and_then(|p| p.words()), report);
    Some(Profile {
        name: name?,
        vendor,
        protocol: protocol?,
        description,
        fields,
        identification,
        probe,
        source: report.file().to_owned(),
    })
}

/// `identification: { vendor: ..., product_code: ... }`: FC 43 objects by key.
fn read_identification(node: &Node, report: &mut Report, ctx: &str) -> BTreeMap<String, String> {
    let ctx = format!("{ctx}: identification");
    let mut out = BTreeMap::new();
    let Some(mut map) = node.map(report, &ctx) else {
        return out;
    };
    for key in super::IDENTIFICATION_KEYS {
        if let Some(text) = map
            .get(key)
            .and_then(|n| n.scalar_text(report, &format!("{ctx}.{key}")))
        {
            out.insert((*key).to_owned(), text);
        }
    }
    map.finish(report, &ctx, super::IDENTIFICATION_KEYS);
    if out.is_empty() {
        report.push(
            node.line,
            &ctx,
            "states nothing (keys: vendor, product_code, product_name, model_name, revision)",
        );
    }
    out
}

/// `probe: [{ kind, address, count, values }]`: reads a scan tells the device by.
fn read_probe(node: &Node, report: &mut Report, ctx: &str) -> Vec<ProbeRead> {
    let ctx = format!("{ctx}: probe");
    let Some(nodes) = node.seq(report, &ctx) else {
        return Vec::new();
    };
    let mut reads = Vec::new();
    for (i, n) in nodes.iter().enumerate() {
        let at = format!("{ctx}[{i}]");
        let Some(mut map) = n.map(report, &at) else {
            continue;
        };
        let kind = map.require("kind", report, &at).and_then(|k| {
            one_of(
                k,
                report,
                &format!("{at}.kind"),
                &RegisterKind::ALL[..4],
                |k| k.name(),
            )
        });
        let address = map
            .require("address", report, &at)
            .and_then(|a| a.int_in(report, &format!("{at}.address"), 0, 65535));
        let count = match map.get("count") {
            None => Some(1),
            Some(c) => c.int_in(report, &format!("{at}.count"), 1, 125),
        };
        let values = map.get("values").and_then(|v| {
            let items = v.seq(report, &format!("{at}.values"))?;
            items
                .iter()
                .map(|x| {
                    x.int_in(report, &format!("{at}.values"), 0, 65535)
                        .map(|x| x as u16)
                })
                .collect::<Option<Vec<u16>>>()
        });
        map.finish(report, &at, PROBE_KEYS);
        let (Some(kind), Some(address), Some(count)) = (kind, address, count) else {
            continue;
        };
        if address + count > 65536 {
            report.push(
                n.line,
                &at,
                format!("address {address} + {count} runs past 65535"),
            );
            continue;
        }
        if let Some(v) = &values {
            if kind.is_bit() {
                report.push(
                    n.line,
                    &at,
                    "`values` are for register reads, not coils or discrete inputs",
                );
            } else if v.len() as i128 != count {
                report.push(
                    n.line,
                    &at,
                    format!("{} values for a read of {count} registers", v.len()),
                );
            }
        }
        reads.push(ProbeRead {
            kind,
            address: address as u16,
            count: count as u16,
            values,
        });
    }
    reads
}

/// Duplicate names (IEC identifiers ignore case) and names the FB layout already uses.
fn check_names(fields: &[Field], report: &mut Report) {
    let mut seen: HashMap<String, &Field> = HashMap::new();
    for f in fields {
        let key = f.name.to_ascii_lowercase();
        if RESERVED_NAMES.contains(&key.as_str()) {
            report.push(
                f.line,
                format!("field {}", f.name),
                "name is taken by the device's own parameters and diagnostics",
            );
        }
        if let Some(first) = seen.get(&key) {
            report.push(
                f.line,
                format!("field {}", f.name),
                format!(
                    "duplicate field name (first defined as {} on line {})",
                    first.name, first.line
                ),
            );
        } else {
            seen.insert(key, f);
        }
    }
}

/// Two fields may not name one point (however each writes it), and two fields of one
/// register kind may not share a register, except BOOL fields on different bits of one
/// register.
fn check_overlaps(fields: &[Field], words: Option<&Words>, report: &mut Report) {
    let plain = |p: &crate::profile::Point| p.address.clone();
    let identity = words.map_or(plain as fn(&crate::profile::Point) -> String, |w| {
        w.point_identity
    });
    let mut points: HashMap<(bool, String), &Field> = HashMap::new();
    for a in fields {
        let Some(x) = &a.point else { continue };
        match points.entry((x.browse_path, identity(x))) {
            std::collections::hash_map::Entry::Occupied(b) => report.push(
                a.line,
                format!("field {}", a.name),
                format!(
                    "names the same point as field {} (line {})",
                    b.get().name,
                    b.get().line
                ),
            ),
            std::collections::hash_map::Entry::Vacant(slot) => {
                slot.insert(a);
            }
        }
    }
    for (i, a) in fields.iter().enumerate() {
        if a.point.is_some() {
            continue;
        }
        for b in &fields[..i] {
            if a.register.kind != b.register.kind || b.point.is_some() {
                continue;
            }
            let (a0, b0) = (u32::from(a.register.address), u32::from(b.register.address));
            let (a1, b1) = (a0 + a.span() - 1, b0 + b.span() - 1);
            if a1 < b0 || b1 < a0 {
                continue;
            }
            if let (Some(x), Some(y)) = (a.register.bit, b.register.bit)
                && x != y
            {
                continue;
            }
            let what = match (a.register.bit, b.register.bit) {
                (Some(bit), Some(_)) => format!("bit {bit} of {} {a0}", a.register.kind.name()),
                _ => format!("{} {}-{}", a.register.kind.name(), a0.max(b0), a1.min(b1)),
            };
            report.push(
                a.line,
                format!("field {}", a.name),
                format!("overlaps field {} (line {}) at {what}", b.name, b.line),
            );
            break;
        }
    }
}

fn identifier(node: &Node, report: &mut Report, ctx: &str) -> Option<String> {
    let text = node.str(report, ctx)?;
    let mut chars = text.chars();
    let valid = chars
        .next()
        .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
        && chars.all(|c| c.is_ascii_alphanumeric() || c == '_')
        && !text.contains("__");
    if valid && crate::profile::keywords::is_keyword(text) {
        report.push(
            node.line,
            ctx,
            format!(
                "`{text}` is an IEC 61131-3 keyword: the generated function block would not parse (choose another name; docs/profiles.md lists the keywords)"
            ),
        );
        None
    } else if valid {
        Some(text.to_owned())
    } else {
        report.push(
            node.line,
            ctx,
            format!(
                "`{text}` is not an IEC identifier (letters, digits and single underscores, not starting with a digit)"
            ),
        );
        None
    }
}

fn iec_type(node: &Node, report: &mut Report, ctx: &str) -> Option<IecType> {
    let text = node.str(report, ctx)?;
    let ty = IecType::parse(text);
    if ty.is_none() {
        let names: Vec<_> = IecType::ALL.iter().map(|t| t.name()).collect();
        report.push(
            node.line,
            ctx,
            format!(
                "unknown type `{text}` (expected one of: {})",
                names.join(", ")
            ),
        );
    }
    ty
}

/// One of a fixed set of names.
fn one_of<T: Copy>(
    node: &Node,
    report: &mut Report,
    ctx: &str,
    all: &[T],
    name: impl Fn(T) -> &'static str,
) -> Option<T> {
    let text = node.str(report, ctx)?;
    let found = all.iter().copied().find(|v| name(*v) == text);
    if found.is_none() {
        let names: Vec<_> = all.iter().map(|v| name(*v)).collect();
        report.push(
            node.line,
            ctx,
            format!(
                "unknown value `{text}` (expected one of: {})",
                names.join(", ")
            ),
        );
    }
    found
}

#[cfg(test)]
mod tests;

//! `iogate profile import --from eip HOST[:PORT] [--path 1,0]`: lists a Logix controller's
//! tags (controller and program scope, Get Instance Attribute List) and the structures'
//! templates, and writes a profile (`protocol: ab-eip`) of every atomic value: atomic tags,
//! array elements, structure members down to their atomic parts, and strings; what cannot
//! be mapped is reported with why. The profile is loaded back before it is written.

use std::collections::{HashMap, HashSet};
use std::fmt::Write as _;
use std::path::Path;
use std::time::Duration;

use super::cip;
use super::conn::Connection;
use super::directory::{self as dir, Symbol, Template};
use crate::codec::IecType;
use crate::profile::import::{identifier, quoted};

/// Bounds on what a controller can make the import hold: symbols listed, programs,
/// templates, a template's definition, fields written and elements taken of one array.
const MAX_SYMBOLS: usize = 100_000;
const MAX_PROGRAMS: usize = 1_000;
const MAX_TEMPLATES: usize = 2_000;
const MAX_TEMPLATE_BYTES: usize = 64 * 1024;
const MAX_FIELDS: usize = 20_000;
const MAX_ELEMENTS: usize = 1_000;
/// How deep structures nest before the import stops following them.
const MAX_DEPTH: usize = 8;
/// How long the controller may take to answer one request.
const TIMEOUT: Duration = Duration::from_secs(5);

/// A field made.
struct Field {
    name: String,
    ty: IecType,
    tag: String,
}

/// What the walk found: the fields, what was not mapped and why, the templates read.
#[derive(Default)]
struct Walk {
    fields: Vec<Field>,
    names: HashSet<String>,
    skipped: Vec<String>,
    templates: HashMap<u16, Result<Template, String>>,
    /// Set when the profile reached [`MAX_FIELDS`].
    full: bool,
}

/// Runs the import; the exit code: 0 a profile written, 1 nothing could be imported, 64 a
/// bad argument.
pub fn run(target: &str, path: Option<&str>, out: Option<&Path>) -> u8 {
    // What is made is loaded back before it is written, as configuration reads it.
    crate::drivers::register();
    crate::profile::import::emit::on_runtime(import(target, path, out))
}

/// `HOST` or `HOST:PORT` (44818 by default).
fn endpoint(target: &str) -> Result<(String, u16), String> {
    let target = target.trim();
    match target.rsplit_once(':') {
        Some((host, port)) if !host.is_empty() && !host.contains(':') => port
            .parse()
            .ok()
            .filter(|&p| p != 0)
            .map(|p| (host.to_owned(), p))
            .ok_or_else(|| format!("`{port}` is not a port")),
        _ if target.is_empty() => Err("give the controller's HOST or HOST:PORT".into()),
        _ => Ok((target.to_owned(), 44818)),
    }
}

async fn import(target: &str, path: Option<&str>, out: Option<&Path>) -> u8 {
    let (host, port, route) = match endpoint(target)
        .and_then(|(h, p)| Ok((h, p, super::config::route(path.unwrap_or("1,0"))?)))
    {
        Ok(t) => t,
        Err(e) => {
            eprintln!("iogate profile import --from eip: {e}");
            return crate::EXIT_CONFIG as u8;
        }
    };
    let source = format!("{host}:{port}");
    let mut conn = match Connection::open((host.as_str(), port), route, TIMEOUT).await {
        Ok(c) => c,
        Err(e) => {
            eprintln!("iogate profile import: {source}: {e}");
            return 1;
        }
    };
    let identity = match conn.forward_open(0x7E01).await {
        Ok(()) => conn.identity().await.ok().flatten(),
        Err(e) => {
            eprintln!("iogate profile import: {source}: {e}");
            return 1;
        }
    };
    let mut walk = Walk::default();
    let walked = walk.run(&mut conn).await;
    conn.close().await;
    if let Err(e) = walked {
        eprintln!("iogate profile import: {source}: {e}");
        return 1;
    }
    for why in &walk.skipped {
        eprintln!("not mapped: {why}");
    }
    let name = identifier(&format!("Logix_{host}_{port}"));
    let product =
        identity.map(|(_, _, revision, _, product)| format!(" ({product}, revision {revision})"));
    let text = walk.profile(&name, &format!("{source}{}", product.unwrap_or_default()));
    crate::profile::import::emit::emit(
        &crate::profile::import::emit::Made {
            source: &source,
            name: &name,
            text,
            fields: walk.fields.len(),
            skipped: walk.skipped.len(),
            things: "tags",
        },
        out,
    )
}

/// Why a symbol holds no value the gateway reads, if it does not: hidden (`__`), a
/// system object, or a name with `:` other than a program's (module I/O, maps, tasks,
/// routines, which `tag:` does not take).
fn not_a_value(name: &str, ty: u16) -> Option<&'static str> {
    if name.starts_with("__") {
        Some("a hidden tag")
    } else if name.contains(':') {
        Some(
            "a module's I/O, map, task or routine (names with `:` other than `Program:` are not taken by `tag:`)",
        )
    } else if dir::is_system(ty) && !dir::is_structure(ty) {
        Some("a system object, not a value")
    } else {
        None
    }
}

/// One request's reply to `service`, good or partial (`true` when more is to come).
async fn ask(
    conn: &mut Connection,
    message: &[u8],
    service: u8,
) -> Result<(Vec<u8>, bool), String> {
    let answer = conn.request(message).await.map_err(|e| e.to_string())?;
    let r = cip::reply(&answer).map_err(|e| e.to_string())?;
    r.answers(service).map_err(|e| e.to_string())?;
    match r.status {
        0 => Ok((r.data.to_vec(), false)),
        0x06 => Ok((r.data.to_vec(), true)),
        s => Err(cip::cip_status(s, r.ext)),
    }
}

/// Every symbol of the controller or of `program`, a page at a time.
async fn list(conn: &mut Connection, program: Option<&str>) -> Result<Vec<Symbol>, String> {
    let mut out = Vec::new();
    let mut from = 0u32;
    loop {
        let request = dir::list_request(program, from);
        let (data, more) = ask(conn, &request, dir::GET_INSTANCE_ATTRIBUTE_LIST).await?;
        let page = dir::symbols(&data).map_err(|e| e.to_string())?;
        let next = page.last().map(|s| s.instance.saturating_add(1));
        out.extend(page);
        if out.len() > MAX_SYMBOLS {
            return Err(format!("more than {MAX_SYMBOLS} symbols"));
        }
        match next {
            Some(n) if more && n > from => from = n,
            None if more => return Err("a partial answer without a symbol".into()),
            _ if more => return Err("a page that does not go forward".into()),
            _ => return Ok(out),
        }
    }
}

/// Template `id`'s definition: its attributes, then Read Template a part at a time.
async fn read_template(conn: &mut Connection, id: u16) -> Result<Template, String> {
    let request = dir::template_attributes_request(id);
    let (data, _) = ask(conn, &request, dir::GET_ATTRIBUTE_LIST).await?;
    let info = dir::template_attributes(&data).map_err(|e| e.to_string())?;
    let total = info.bytes();
    if total > MAX_TEMPLATE_BYTES {
        return Err(format!("a definition of {total} bytes"));
    }
    let mut bytes = Vec::with_capacity(total);
    while bytes.len() < total {
        let left = u16::try_from(total - bytes.len()).unwrap_or(u16::MAX);
        let request = dir::read_template_request(id, bytes.len() as u32, left);
        let (data, more) = ask(conn, &request, dir::READ_TEMPLATE).await?;
        bytes.extend_from_slice(&data);
        if !more || data.is_empty() {
            break;
        }
    }
    dir::template(&bytes, info.members).map_err(|e| e.to_string())
}

impl Walk {
    /// Lists the controller's and its programs' symbols, reads the templates they use and
    /// makes the fields.
    async fn run(&mut self, conn: &mut Connection) -> Result<(), String> {
        let controller = list(conn, None).await.map_err(|e| {
            format!("the controller did not list its tags (Get Instance Attribute List of the Symbol class): {e}")
        })?;
        let mut scopes = vec![(None, controller.clone())];
        for program in controller.iter().filter(|s| s.name.starts_with("Program:")) {
            if program.name.len() > usize::from(u8::MAX) {
                self.skipped
                    .push(format!("a program's name of {} bytes", program.name.len()));
                continue;
            }
            if scopes.len() > MAX_PROGRAMS {
                self.skipped.push(format!(
                    "`{}`: more than {MAX_PROGRAMS} programs",
                    program.name
                ));
                continue;
            }
            match list(conn, Some(&program.name)).await {
                Ok(symbols) => scopes.push((Some(program.name.clone()), symbols)),
                Err(e) => self.skipped.push(format!("`{}`: {e}", program.name)),
            }
        }
        for (program, symbols) in &scopes {
            for s in symbols {
                let tag = match program {
                    Some(p) => format!("{p}.{}", s.name),
                    None => s.name.clone(),
                };
                if s.name.starts_with("Program:") {
                    continue;
                }
                if let Some(why) = not_a_value(&s.name, s.ty) {
                    self.skipped.push(format!("`{tag}`: {why}"));
                    continue;
                }
                self.templates_of(conn, s.ty).await;
                let n = dir::dimensions(s.ty);
                self.array(&tag, s.ty, &s.dims[..n], 0);
            }
        }
        Ok(())
    }

    /// Reads the templates a type word needs (its structure's, and its members'), once each.
    async fn templates_of(&mut self, conn: &mut Connection, ty: u16) {
        let mut wanted = vec![ty];
        while let Some(ty) = wanted.pop() {
            if !dir::is_structure(ty) || dir::is_system(ty) {
                continue;
            }
            let id = dir::template_id(ty);
            if self.templates.contains_key(&id) {
                continue;
            }
            let read = if self.templates.len() >= MAX_TEMPLATES {
                Err(format!("more than {MAX_TEMPLATES} structure types"))
            } else {
                read_template(conn, id).await
            };
            if let Ok(t) = &read {
                wanted.extend(t.members.iter().map(|m| m.ty));
            }
            self.templates.insert(id, read);
        }
    }

    /// `tag` of type `ty`, an array of `dims` (none: one value): each element's fields.
    fn array(&mut self, tag: &str, ty: u16, dims: &[u32], depth: usize) {
        if dims.is_empty() {
            return self.value(tag, ty, depth);
        }
        if dir::atomic_code(ty) == 0xD3 && !dir::is_structure(ty) {
            self.skipped
                .push(format!("`{tag}`: a BOOL array (bits packed in DWORDs) is not mapped; name its elements' bits by hand"));
            return;
        }
        let total = dims
            .iter()
            .fold(1u64, |all, &d| all.saturating_mul(u64::from(d)));
        let taken = usize::try_from(total)
            .unwrap_or(usize::MAX)
            .min(MAX_ELEMENTS);
        if total > taken as u64 {
            self.skipped.push(format!(
                "`{tag}`: {} of its {total} elements (the first {taken} are mapped)",
                total - taken as u64
            ));
        }
        for k in 0..taken {
            let mut rest = k as u64;
            let mut index = vec![0u64; dims.len()];
            for (slot, &d) in index.iter_mut().zip(dims).rev() {
                *slot = rest % u64::from(d.max(1));
                rest /= u64::from(d.max(1));
            }
            let joined: Vec<String> = index.iter().map(u64::to_string).collect();
            self.value(&format!("{tag}[{}]", joined.join(",")), ty, depth);
        }
    }

    /// One value of type `ty` at `tag`: a field, a string, or a structure's members.
    fn value(&mut self, tag: &str, ty: u16, depth: usize) {
        if self.fields.len() >= MAX_FIELDS {
            if !self.full {
                self.full = true;
                self.skipped.push(format!(
                    "`{tag}` and every tag after it: the profile has {MAX_FIELDS} fields, the most an import writes"
                ));
            }
            return;
        }
        if !dir::is_structure(ty) {
            let code = dir::atomic_code(ty);
            match IecType::ALL
                .into_iter()
                .find(|t| super::tag::type_code(*t) == Some(code))
            {
                Some(iec) => self.field(tag, iec),
                None => self
                    .skipped
                    .push(format!("`{tag}`: the type {code:#04x} has no IEC type")),
            }
            return;
        }
        let id = dir::template_id(ty);
        let template = match self.templates.get(&id) {
            Some(Ok(t)) => t.clone(),
            Some(Err(e)) => {
                return self
                    .skipped
                    .push(format!("`{tag}`: its structure {id:#x}: {e}"));
            }
            None => {
                return self
                    .skipped
                    .push(format!("`{tag}`: its structure {id:#x} was not read"));
            }
        };
        if template.is_string() {
            return self.field(tag, IecType::String);
        }
        if depth >= MAX_DEPTH {
            return self.skipped.push(format!(
                "`{tag}`: structures nested deeper than {MAX_DEPTH}"
            ));
        }
        for m in template.visible() {
            let member = format!("{tag}.{}", m.name);
            if dir::dimensions(m.ty) > 0 {
                self.array(&member, m.ty & !0x6000, &[u32::from(m.info)], depth + 1);
            } else {
                self.value(&member, m.ty, depth + 1);
            }
        }
    }

    /// A field for `tag`, named after it (unique in the profile); a tag `tag:` does not
    /// take (a controller's name of other characters, too long) is reported instead.
    fn field(&mut self, tag: &str, ty: IecType) {
        if let Err(why) = super::tag::parse(tag) {
            self.skipped.push(why);
            return;
        }
        let base = identifier(tag.strip_prefix("Program:").unwrap_or(tag));
        let mut name = base.clone();
        let mut k = 2;
        while !self.names.insert(name.to_ascii_lowercase()) {
            name = format!("{base}_{k}");
            k += 1;
        }
        self.fields.push(Field {
            name,
            ty,
            tag: tag.to_owned(),
        });
    }

    /// The profile's YAML.
    fn profile(&self, name: &str, source: &str) -> String {
        let mut text = format!(
            "name: {name}\nprotocol: ab-eip\ndescription: {}\nfields:\n",
            quoted(&format!("Imported from the Logix controller at {source}"))
        );
        for f in &self.fields {
            let _ = writeln!(
                text,
                "  - {{ name: {}, type: {}, direction: inout, tag: {} }}",
                f.name,
                f.ty,
                quoted(&f.tag)
            );
        }
        text
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn arrays_of_any_claimed_size_give_at_most_their_first_elements() {
        let mut walk = super::Walk::default();
        // Three dimensions of 2^32 - 1 each: their product is past any integer.
        walk.array("Big", 0x60C4, &[u32::MAX; 3], 0);
        assert_eq!(walk.fields.len(), super::MAX_ELEMENTS);
        assert_eq!(walk.fields[1].tag, "Big[0,0,1]");
        assert!(
            walk.skipped[0].contains("the first 1000 are mapped"),
            "{:?}",
            walk.skipped
        );
        // A structure whose template was not read, a type without an IEC one: reported.
        walk.value("S", 0x8123, 0);
        walk.value("P", 0x00A0, 0);
        assert_eq!(walk.skipped.len(), 3, "{:?}", walk.skipped);
    }

    #[test]
    fn endpoints_take_a_host_and_an_optional_port() {
        assert_eq!(super::endpoint("10.0.0.5"), Ok(("10.0.0.5".into(), 44818)));
        assert_eq!(super::endpoint("plc:2222"), Ok(("plc".into(), 2222)));
        assert!(super::endpoint("plc:x").is_err());
        assert!(super::endpoint("plc:0").is_err());
        assert!(super::endpoint(" ").is_err());
    }
}

//! A Logix controller's tag directory, as the Logix 5000 Data Access manual (1756-PM020)
//! describes it: the Symbol class's instances (Get Instance Attribute List, a page at a
//! time, controller or program scope) and the Template class's structure definitions
//! (Get Attribute List, then Read Template a part at a time). Every length in an answer is
//! checked; a short or inconsistent one is a `Malformed` naming what was wrong.

use super::cip::{Malformed, request};

const SYMBOL_CLASS: u8 = 0x6B;
const TEMPLATE_CLASS: u8 = 0x6C;
pub(super) const GET_INSTANCE_ATTRIBUTE_LIST: u8 = 0x55;
pub(super) const GET_ATTRIBUTE_LIST: u8 = 0x03;
pub(super) const READ_TEMPLATE: u8 = 0x4C;

/// A symbol's type word: a structure (its template's id in the low 12 bits), its array
/// dimensions, a system symbol; else an atomic type's code in the low byte.
const STRUCTURE: u16 = 0x8000;
const SYSTEM: u16 = 0x1000;

/// A symbol (a tag) of the directory.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(super) struct Symbol {
    pub(super) instance: u32,
    pub(super) name: String,
    pub(super) ty: u16,
    pub(super) dims: [u32; 3],
}

/// A type word's parts.
pub(super) fn is_structure(ty: u16) -> bool {
    ty & STRUCTURE != 0
}
pub(super) fn template_id(ty: u16) -> u16 {
    ty & 0x0FFF
}
pub(super) fn atomic_code(ty: u16) -> u16 {
    ty & 0x00FF
}
pub(super) fn dimensions(ty: u16) -> usize {
    usize::from((ty >> 13) & 3)
}
pub(super) fn is_system(ty: u16) -> bool {
    ty & SYSTEM != 0
}

/// The path to `class`'s `instance`, in the smallest instance segment that holds it.
fn class_instance(class: u8, instance: u32, path: &mut Vec<u8>) {
    path.extend_from_slice(&[0x20, class]);
    super::tag::logical(0x24, instance, path);
}

/// Get Instance Attribute List of the symbols from instance `from` on, of the controller
/// or of `program` (`Program:Main`): each one's name (1), type (2) and dimensions (8).
pub(super) fn list_request(program: Option<&str>, from: u32) -> Vec<u8> {
    let mut path = Vec::new();
    if let Some(p) = program {
        path.push(0x91);
        path.push(p.len() as u8);
        path.extend_from_slice(p.as_bytes());
        if p.len() % 2 == 1 {
            path.push(0);
        }
    }
    class_instance(SYMBOL_CLASS, from, &mut path);
    let mut data = Vec::with_capacity(8);
    for word in [3u16, 1, 2, 8] {
        data.extend_from_slice(&word.to_le_bytes());
    }
    request(GET_INSTANCE_ATTRIBUTE_LIST, &path, &data)
}

fn u16_at(b: &[u8], at: usize, what: &'static str) -> Result<u16, Malformed> {
    b.get(at..at + 2)
        .map(|s| u16::from_le_bytes([s[0], s[1]]))
        .ok_or(Malformed::Short(what))
}
fn u32_at(b: &[u8], at: usize, what: &'static str) -> Result<u32, Malformed> {
    b.get(at..at + 4)
        .map(|s| u32::from_le_bytes([s[0], s[1], s[2], s[3]]))
        .ok_or(Malformed::Short(what))
}

/// The symbols of a Get Instance Attribute List answer (asked as [`list_request`] does).
pub(super) fn symbols(data: &[u8]) -> Result<Vec<Symbol>, Malformed> {
    let mut out = Vec::new();
    let mut at = 0;
    while at < data.len() {
        let instance = u32_at(data, at, "symbol's instance")?;
        let len = usize::from(u16_at(data, at + 4, "symbol's name length")?);
        let name = data
            .get(at + 6..at + 6 + len)
            .ok_or(Malformed::Short("symbol's name"))?;
        let rest = at + 6 + len;
        let ty = u16_at(data, rest, "symbol's type")?;
        let mut dims = [0u32; 3];
        for (k, d) in dims.iter_mut().enumerate() {
            *d = u32_at(data, rest + 2 + 4 * k, "symbol's dimensions")?;
        }
        out.push(Symbol {
            instance,
            name: String::from_utf8_lossy(name).into_owned(),
            ty,
            dims,
        });
        at = rest + 14;
    }
    Ok(out)
}

/// A template's attributes: its definition's size (32-bit words), the structure's size
/// (bytes) and member count.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct TemplateInfo {
    pub(super) definition_words: u32,
    pub(super) structure_size: u32,
    pub(super) members: u16,
}

impl TemplateInfo {
    /// The bytes Read Template gives: the definition less its 23 bytes of header, in
    /// whole words.
    pub(super) fn bytes(&self) -> usize {
        (self.definition_words as usize * 4)
            .saturating_sub(23)
            .next_multiple_of(4)
    }
}

/// Get Attribute List of template `id`: definition size (4), structure size (5), member
/// count (2), handle (1).
pub(super) fn template_attributes_request(id: u16) -> Vec<u8> {
    let mut path = Vec::new();
    class_instance(TEMPLATE_CLASS, u32::from(id), &mut path);
    let mut data = Vec::with_capacity(10);
    for word in [4u16, 4, 5, 2, 1] {
        data.extend_from_slice(&word.to_le_bytes());
    }
    request(GET_ATTRIBUTE_LIST, &path, &data)
}

/// The attributes of a Get Attribute List answer (each: id, status, value when good).
pub(super) fn template_attributes(data: &[u8]) -> Result<TemplateInfo, Malformed> {
    let count = u16_at(data, 0, "attribute count")?;
    let mut at = 2;
    let (mut words, mut size, mut members) = (None, None, None);
    for _ in 0..count {
        let id = u16_at(data, at, "attribute id")?;
        let status = u16_at(data, at + 2, "attribute status")?;
        at += 4;
        if status != 0 {
            continue;
        }
        match id {
            4 => words = Some(u32_at(data, at, "definition size")?),
            5 => size = Some(u32_at(data, at, "structure size")?),
            2 => members = Some(u16_at(data, at, "member count")?),
            1 => {}
            other => {
                return Err(Malformed::Refused(format!(
                    "template attribute {other}, which was not asked for"
                )));
            }
        }
        at += if id == 4 || id == 5 { 4 } else { 2 };
    }
    match (words, size, members) {
        (Some(definition_words), Some(structure_size), Some(members)) => Ok(TemplateInfo {
            definition_words,
            structure_size,
            members,
        }),
        _ => Err(Malformed::Refused(
            "a template without its size or member count".into(),
        )),
    }
}

/// Read Template of `len` bytes of template `id`'s definition from `offset`.
pub(super) fn read_template_request(id: u16, offset: u32, len: u16) -> Vec<u8> {
    let mut path = Vec::new();
    class_instance(TEMPLATE_CLASS, u32::from(id), &mut path);
    let mut data = offset.to_le_bytes().to_vec();
    data.extend_from_slice(&len.to_le_bytes());
    request(READ_TEMPLATE, &path, &data)
}

/// A structure's member: its name, the array length or bit number (`info`), its type
/// word (as a symbol's) and offset.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(super) struct Member {
    pub(super) name: String,
    pub(super) info: u16,
    pub(super) ty: u16,
}

/// A structure's definition.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(super) struct Template {
    pub(super) name: String,
    pub(super) members: Vec<Member>,
}

impl Template {
    /// The members a user sees (not the hidden hosts of BOOLs, nor `__` ones).
    pub(super) fn visible(&self) -> impl Iterator<Item = &Member> {
        self.members
            .iter()
            .filter(|m| !m.name.starts_with("ZZZZZZZZZZ") && !m.name.starts_with("__"))
    }

    /// Whether this is a string type: `LEN` (DINT) and `DATA` (SINT array) only.
    pub(super) fn is_string(&self) -> bool {
        let v: Vec<&Member> = self.visible().collect();
        matches!(v.as_slice(), [len, data]
            if len.name == "LEN" && len.ty == 0xC4
                && data.name == "DATA" && atomic_code(data.ty) == 0xC2 && dimensions(data.ty) > 0)
    }
}

/// A template's definition (`members` of 8 bytes each, then its name and the members'
/// names, each ended by a NUL; the name may carry `;` and more).
pub(super) fn template(bytes: &[u8], members: u16) -> Result<Template, Malformed> {
    let n = usize::from(members);
    let table = bytes
        .get(..n * 8)
        .ok_or(Malformed::Short("template's member table"))?;
    let mut names = bytes[n * 8..]
        .split(|&b| b == 0)
        .map(String::from_utf8_lossy);
    let name = names.next().unwrap_or_default();
    let name = name.split(';').next().unwrap_or_default().to_owned();
    let mut out = Vec::with_capacity(n);
    for entry in table.chunks_exact(8) {
        let member = names
            .next()
            .filter(|m| !m.is_empty())
            .ok_or(Malformed::Short("template's member names"))?;
        out.push(Member {
            name: member.into_owned(),
            info: u16::from_le_bytes([entry[0], entry[1]]),
            ty: u16::from_le_bytes([entry[2], entry[3]]),
        });
    }
    Ok(Template { name, members: out })
}

#[cfg(test)]
#[path = "directory_tests.rs"]
mod tests;

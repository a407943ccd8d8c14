//! The outstation's points: every served field at an information object address with the
//! ASDU type its IEC type calls for (`map: auto`: every field, numbered from 1 in the
//! devices' order, an output's command at the address after its value), or the entries
//! of a map file. A BOOL is a single point and its command `C_SC_NA_1`; SINT, INT and
//! USINT are scaled values (`C_SE_NB_1`); BYTE, WORD and DWORD bitstrings (`C_BO_NA_1`);
//! every other number a short float (`C_SE_NC_1`). STRING and LWORD are not served.

use std::collections::HashMap;
use std::path::Path;

use crate::codec::IecType;
use crate::drivers::iec104::asdu::MAX_IOA;
use crate::drivers::iec104::types::{Kind, Tag, TypeId, id};
use crate::profile::deadband::Deadband;
use crate::profile::{Direction, Profile};
use crate::yaml::{Node, Report};

/// One point: a field's value (a monitor type) or its command.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Point {
    pub(crate) ioa: u32,
    pub(crate) device: String,
    pub(crate) field: String,
    pub(crate) idx: usize,
    pub(crate) ty: IecType,
    /// Untagged: a monitor type (its time-tagged form is sent where `time_tags` says), or
    /// a command type.
    pub(crate) asdu: TypeId,
    pub(crate) deadband: Deadband,
}

impl Point {
    pub(crate) fn kind(&self) -> Kind {
        self.asdu.kind().unwrap_or(Kind::Float)
    }

    pub(crate) fn is_command(&self) -> bool {
        is_command(self.kind())
    }
}

/// A map file's entry: `{ ioa: 100, field: pump.speed, asdu: M_ME_NC_1 }`.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Entry {
    pub(crate) ioa: u32,
    pub(crate) device: String,
    pub(crate) field: String,
    pub(crate) asdu: Option<TypeId>,
    pub(crate) line: u64,
}

/// The points, by address and by field.
#[derive(Debug, Default)]
pub(crate) struct Table {
    pub(crate) points: Vec<Point>,
    by_ioa: HashMap<u32, usize>,
    /// The monitor points of each (device, field index).
    by_field: HashMap<(String, usize), Vec<usize>>,
    /// The fields not served, and why.
    pub(crate) skipped: Vec<String>,
}

fn is_command(kind: Kind) -> bool {
    matches!(
        kind,
        Kind::SingleCommand
            | Kind::DoubleCommand
            | Kind::SetNormalized
            | Kind::SetScaled
            | Kind::SetFloat
            | Kind::BitsCommand
    )
}

/// The monitor and command types a field of `ty` is served with, when it is.
pub(crate) fn types_for(ty: IecType) -> Option<(u8, u8)> {
    use IecType::*;
    Some(match ty {
        Bool => (id::M_SP_NA_1, id::C_SC_NA_1),
        Sint | Int | Usint => (id::M_ME_NB_1, id::C_SE_NB_1),
        Byte | Word | Dword => (id::M_BO_NA_1, id::C_BO_NA_1),
        Dint | Lint | Uint | Udint | Ulint | Real | Lreal | Time => (id::M_ME_NC_1, id::C_SE_NC_1),
        String | Lword => return None,
    })
}

/// Whether a field of `ty` can be served as `asdu`, else why not.
fn fits(ty: IecType, asdu: TypeId) -> Result<(), String> {
    let Some(kind) = asdu.kind() else {
        return Err(format!("{} is not a type", asdu.0));
    };
    if asdu.tag() != Tag::None {
        return Err(format!(
            "{} carries a time tag: name the type without one (time_tags: decides)",
            asdu.name()
        ));
    }
    let ok = match kind {
        Kind::Single | Kind::Double | Kind::SingleCommand | Kind::DoubleCommand => {
            ty == IecType::Bool
        }
        Kind::Bits | Kind::BitsCommand | Kind::Counter => {
            ty.int_bits().is_some_and(|(bits, _)| bits <= 32) && ty != IecType::Time
        }
        Kind::Normalized | Kind::Scaled | Kind::Float => {
            !matches!(ty, IecType::Bool | IecType::String)
        }
        Kind::SetNormalized | Kind::SetScaled | Kind::SetFloat => {
            !matches!(ty, IecType::Bool | IecType::String)
        }
        _ => return Err(format!("{} is not served by the outstation", asdu.name())),
    };
    match ok {
        true => Ok(()),
        false => Err(format!(
            "a {} field cannot be served as {}",
            ty.name(),
            asdu.name()
        )),
    }
}

impl Table {
    fn push(&mut self, point: Point) {
        let at = self.points.len();
        self.by_ioa.insert(point.ioa, at);
        if !point.is_command() {
            let key = (point.device.clone(), point.idx);
            self.by_field.entry(key).or_default().push(at);
        }
        self.points.push(point);
    }

    /// The point at `ioa`.
    pub(crate) fn get(&self, ioa: u32) -> Option<&Point> {
        self.by_ioa.get(&ioa).map(|&i| &self.points[i])
    }

    /// The monitor points showing field `idx` of `device`.
    pub(crate) fn monitors(&self, device: &str, idx: usize) -> &[usize] {
        self.by_field
            .get(&(device.to_owned(), idx))
            .map_or(&[], Vec::as_slice)
    }

    /// Every field of `devices`, numbered from 1; `kept` gives the addresses a previous
    /// table gave (a device added at run time is numbered after them, nothing moves).
    pub(crate) fn auto<'a>(
        devices: impl IntoIterator<Item = (&'a str, &'a Profile)>,
        kept: Option<&Table>,
    ) -> Table {
        let mut table = Table::default();
        let old: HashMap<(String, String, bool), u32> = kept
            .map(|t| {
                let key = |p: &Point| ((p.device.clone(), p.field.clone(), p.is_command()), p.ioa);
                t.points.iter().map(key).collect()
            })
            .unwrap_or_default();
        let mut next = old.values().max().map_or(1, |m| m + 1);
        let take = |key: (&str, &str, bool), next: &mut u32| match old.get(&(
            key.0.to_owned(),
            key.1.to_owned(),
            key.2,
        )) {
            Some(&ioa) => ioa,
            None => {
                *next += 1;
                *next - 1
            }
        };
        for (device, profile) in devices {
            for (idx, f) in profile.fields.iter().enumerate() {
                let Some((monitor, command)) = types_for(f.ty) else {
                    let why = format!(
                        "{device}.{} ({}) is not served: 104 has no type for it",
                        f.name,
                        f.ty.name()
                    );
                    table.skipped.push(why);
                    continue;
                };
                let point = |ioa, asdu| Point {
                    ioa,
                    device: device.to_owned(),
                    field: f.name.clone(),
                    idx,
                    ty: f.ty,
                    asdu: TypeId(asdu),
                    deadband: f.deadband.unwrap_or_default(),
                };
                let ioa = take((device, &f.name, false), &mut next);
                table.push(point(ioa, monitor));
                if f.direction != Direction::Input {
                    let ioa = take((device, &f.name, true), &mut next);
                    table.push(point(ioa, command));
                }
            }
        }
        table
    }

    /// The points a map file names, every problem with its line.
    pub(crate) fn of_entries<'a>(
        entries: &[Entry],
        devices: impl IntoIterator<Item = (&'a str, &'a Profile)>,
    ) -> Result<Table, Vec<String>> {
        let (table, problems) = Table::of_some_entries(entries, devices);
        match problems.is_empty() {
            true => Ok(table),
            false => Err(problems),
        }
    }

    /// The points of the entries that can be served, and the problems of the others.
    pub(crate) fn of_some_entries<'a>(
        entries: &[Entry],
        devices: impl IntoIterator<Item = (&'a str, &'a Profile)>,
    ) -> (Table, Vec<String>) {
        let devices: HashMap<&str, &Profile> = devices.into_iter().collect();
        let mut table = Table::default();
        let mut problems = Vec::new();
        for e in entries {
            match entry_point(e, &devices) {
                Ok(point) => table.push(point),
                Err(why) => {
                    problems.push(format!("line {}: {}.{}: {why}", e.line, e.device, e.field))
                }
            }
        }
        (table, problems)
    }

    /// The index of the point at `ioa`.
    pub(crate) fn index(&self, ioa: u32) -> Option<usize> {
        self.by_ioa.get(&ioa).copied()
    }

    /// One line per point: `IOA ASDU device.field`.
    pub(crate) fn render(&self) -> String {
        let mut points: Vec<&Point> = self.points.iter().collect();
        points.sort_by_key(|p| p.ioa);
        points
            .iter()
            .map(|p| format!("{} {} {}.{}\n", p.ioa, p.asdu.name(), p.device, p.field))
            .collect()
    }
}

fn entry_point(e: &Entry, devices: &HashMap<&str, &Profile>) -> Result<Point, String> {
    let profile = devices.get(e.device.as_str()).ok_or("no such device")?;
    let idx = profile.field_index(&e.field).ok_or("no such field")?;
    let f = &profile.fields[idx];
    let asdu = match e.asdu {
        Some(asdu) => asdu,
        None => types_for(f.ty)
            .map(|(m, _)| TypeId(m))
            .ok_or_else(|| format!("104 has no type for a {}", f.ty.name()))?,
    };
    fits(f.ty, asdu)?;
    if is_command(asdu.kind().unwrap_or(Kind::Float)) && f.direction == Direction::Input {
        return Err(format!("an input is not commanded ({})", asdu.name()));
    }
    Ok(Point {
        ioa: e.ioa,
        device: e.device.clone(),
        field: f.name.clone(),
        idx,
        ty: f.ty,
        asdu,
        deadband: f.deadband.unwrap_or_default(),
    })
}

/// Reads a map file: a list of `{ ioa, field: device.field, asdu }`, each address once.
pub(crate) fn read_file(path: &Path) -> Result<Vec<Entry>, Vec<String>> {
    let (entries, problems) = read_some(path);
    if problems.is_empty() {
        Ok(entries)
    } else {
        Err(problems)
    }
}

/// A map file's entries that are well written, and the problems of the others (as `check`
/// reads it, to name every problem at once).
pub(crate) fn read_some(path: &Path) -> (Vec<Entry>, Vec<String>) {
    match std::fs::read_to_string(path) {
        Ok(text) => parse_some_entries(&text, &path.display().to_string()),
        Err(e) => (
            Vec::new(),
            vec![format!("cannot read the map file {}: {e}", path.display())],
        ),
    }
}

/// A map file's text: its entries that are well written, and every problem, each on its own
/// and named with `source`.
pub(crate) fn parse_some_entries(text: &str, source: &str) -> (Vec<Entry>, Vec<String>) {
    let mut report = Report::new(source.to_owned());
    let entries = crate::yaml::parse(text, &mut report).and_then(|n| entries(&n, &mut report));
    let problems = report.into_problems();
    (
        entries.unwrap_or_default(),
        problems.iter().map(ToString::to_string).collect(),
    )
}

fn entries(node: &Node, report: &mut Report) -> Option<Vec<Entry>> {
    let mut seen: HashMap<u32, u64> = HashMap::new();
    let mut out = Vec::new();
    for n in node.seq(report, "map")? {
        let Some(mut map) = n.map(report, "map entry") else {
            continue;
        };
        let ioa = map
            .require("ioa", report, "map entry")
            .and_then(|v| v.int_in(report, "ioa", 1, i128::from(MAX_IOA)));
        let field = map
            .require("field", report, "map entry")
            .and_then(|v| v.scalar_text(report, "field"));
        let asdu = map.get("asdu").map(|v| {
            let text = v.scalar_text(report, "asdu")?;
            let known = || {
                crate::drivers::iec104::types::TypeId::names()
                    .collect::<Vec<_>>()
                    .join(", ")
            };
            TypeId::named(text.trim()).or_else(|| {
                report.push(
                    v.line,
                    "asdu",
                    format!("`{text}` is not a type (one of {})", known()),
                );
                None
            })
        });
        map.finish(report, "map entry", &["ioa", "field", "asdu"]);
        let (Some(ioa), Some(field)) = (ioa, field) else {
            continue;
        };
        let Some((device, field)) = field.split_once('.') else {
            report.push(n.line, "field", format!("`{field}` is not device.field"));
            continue;
        };
        let ioa = ioa as u32;
        if let Some(first) = seen.insert(ioa, n.line) {
            report.push(
                n.line,
                "ioa",
                format!("IOA {ioa} is given twice (first at line {first})"),
            );
            continue;
        }
        let asdu = match asdu {
            Some(None) => continue,
            Some(Some(a)) => Some(a),
            None => None,
        };
        out.push(Entry {
            ioa,
            device: device.to_owned(),
            field: field.to_owned(),
            asdu,
            line: n.line,
        });
    }
    Some(out)
}

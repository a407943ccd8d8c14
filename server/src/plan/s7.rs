//! An S7 device's reads: each field an area range (its address, its form's size), ranges of one
//! block merged where they touch, packed into jobs within the negotiated PDU (items per
//! request, answer bytes). Timers and counters count cells of two bytes.

use crate::profile::Profile;
use crate::profile::s7_address::{Address, Area, parse};
use crate::profile::s7_form::{Form, form};

/// One item of a Read Var or Write Var: bytes (or one bit) of an area, or timers and
/// counters by number.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Item {
    pub(crate) area: Area,
    pub(crate) db: u16,
    /// The first byte (a timer's or counter's number).
    pub(crate) byte: u32,
    /// `Some(bit)` for a single bit (length 1).
    pub(crate) bit: Option<u8>,
    /// Bytes (1 for a bit; timers and counters: how many).
    pub(crate) length: u16,
}

impl Item {
    /// Whether it counts timers or counters (two bytes each) rather than bytes.
    pub(crate) fn cells(&self) -> bool {
        matches!(self.area, Area::Timers | Area::Counters)
    }
}

/// A field's place: its address, how its value is stored and the bytes it takes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Place {
    pub(crate) address: Address,
    pub(crate) form: Form,
    /// The type the PLC stores (the field's, or its `raw_type`).
    pub(crate) stored: crate::codec::IecType,
    pub(crate) bytes: u16,
}

impl Place {
    /// The field's first byte in its area (a timer's or counter's number counts cells of
    /// two bytes).
    fn start(&self) -> u32 {
        match self.address.area {
            Area::Timers | Area::Counters => self.address.byte * 2,
            _ => self.address.byte,
        }
    }
}

/// Each field's place, or why it has none.
pub(crate) fn places(profile: &Profile) -> Vec<Result<Place, String>> {
    profile
        .fields
        .iter()
        .map(|f| {
            let point = f.point.as_ref().ok_or("the field has no address")?;
            let address = parse(&point.address)?;
            let stored = f.register.raw_type.unwrap_or(f.ty);
            let form = form(&address, stored, point.length)?;
            Ok(Place {
                address,
                form,
                stored,
                bytes: form.bytes(stored),
            })
        })
        .collect()
}

/// A range of one block: its area, block, first and past-last byte, and the fields in it
/// with their offsets.
type Range = (Area, u16, u32, u32, Vec<(usize, u32)>);

/// One read job: its items and, per item, the fields it carries with their offsets.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Batch {
    pub(crate) items: Vec<Item>,
    pub(crate) fields: Vec<Vec<(usize, u32)>>,
}

/// The most items of one request: what S7-300/400 CPUs and Snap7 take (more are cut off).
pub(crate) const MAX_ITEMS: usize = 20;

/// The most bytes one item's answer carries in a PDU of `pdu` bytes (a field larger is not
/// read: its error says so).
pub(crate) fn max_item(pdu: u16) -> u32 {
    u32::from(pdu.saturating_sub(18 + 4)).max(1)
}

/// The fields' ranges merged where they touch and packed into jobs: at most
/// `(pdu - 19) / 12` items a request, answers within `pdu - 14` bytes.
pub(crate) fn batches(
    places: &[Result<Place, String>],
    pdu: u16,
    alone: &std::collections::BTreeSet<usize>,
) -> Vec<Batch> {
    let mut ranges: Vec<Range> = Vec::new();
    let max_item = max_item(pdu);
    let mut order: Vec<(usize, Place)> = places
        .iter()
        .enumerate()
        .filter_map(|(i, p)| p.as_ref().ok().map(|p| (i, *p)))
        .filter(|(_, p)| u32::from(p.bytes) <= max_item)
        .collect();
    order.sort_by_key(|(_, p)| (p.address.area, p.address.db, p.start()));
    for (i, p) in order {
        let (a, first) = (p.address, p.start());
        let end = first + u32::from(p.bytes);
        match ranges.last_mut() {
            Some((area, db, start, stop, fields))
                if *area == a.area
                    && *db == a.db
                    && first <= *stop
                    && end - *start <= max_item
                    && !alone.contains(&i)
                    && !fields.iter().any(|(f, _)| alone.contains(f)) =>
            {
                *stop = (*stop).max(end);
                fields.push((i, first - *start));
            }
            _ => ranges.push((a.area, a.db, first, end, vec![(i, 0)])),
        }
    }
    let per_request = usize::from(pdu.saturating_sub(19) / 12).clamp(1, MAX_ITEMS);
    let answer_room = u32::from(pdu.saturating_sub(14));
    let mut out: Vec<Batch> = Vec::new();
    let mut used = u32::MAX;
    for (area, db, start, stop, fields) in ranges {
        let len = stop - start;
        let cost = 4 + len + len % 2;
        let full =
            out.last().is_none_or(|b| b.items.len() >= per_request) || used + cost > answer_room;
        if full {
            out.push(Batch {
                items: Vec::new(),
                fields: Vec::new(),
            });
            used = 0;
        }
        used += cost;
        let cells = matches!(area, Area::Timers | Area::Counters);
        let (byte, length) = if cells {
            (start / 2, len / 2)
        } else {
            (start, len)
        };
        if let Some(b) = out.last_mut() {
            b.items.push(Item {
                area,
                db,
                byte,
                bit: None,
                length: length as u16,
            });
            b.fields.push(fields);
        }
    }
    out
}

/// The PDU size a link's settings ask for (960 unless they say).
pub(crate) fn asked_pdu(settings: &crate::yaml::Node) -> u16 {
    let mut quiet = crate::yaml::Report::new("plan");
    settings
        .map(&mut quiet, "s7")
        .and_then(|mut m| m.get("pdu_size").cloned())
        .and_then(|n| n.int_in(&mut quiet, "pdu_size", 240, 960))
        .map_or(960, |v| v as u16)
}

/// An item as S7 users read it: its area, block and bytes (timers and counters by number).
pub(crate) fn describe(item: &Item) -> String {
    let (first, last) = (item.byte, item.byte + u32::from(item.length.max(1)) - 1);
    let bytes = |area: &str| match first == last {
        true => format!("{area} byte {first}"),
        false => format!("{area} bytes {first}-{last}"),
    };
    let cells = |letter: &str| match first == last {
        true => format!("{letter}{first}"),
        false => format!("{letter}{first}-{letter}{last}"),
    };
    match item.area {
        Area::DataBlock => bytes(&format!("DB{}", item.db)),
        Area::Merkers => bytes("M"),
        Area::Inputs => bytes("I"),
        Area::Outputs => bytes("Q"),
        Area::Timers => cells("T"),
        Area::Counters => cells("C"),
    }
}

//! An S7 device's reads: each field an area range (its address, its form's size), ranges of one
//! block merged where they touch or lie at most the link's `max_gap` bytes apart, packed into
//! jobs within the negotiated PDU (items per request, answer bytes). Timers and counters
//! count cells of two bytes.

use super::address::{Address, Area, parse};
use super::form::{Form, form};
use crate::profile::Profile;

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

/// A range of one block, read as one item or (larger than an item's answer) several: the
/// fields in it with their offsets, and where its pieces are (job, item), in order.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Span {
    pub(crate) fields: Vec<(usize, u32)>,
    pub(crate) pieces: Vec<(usize, usize)>,
}

/// A device's reads: its jobs (each its items) and the spans they carry.
#[derive(Debug, Clone, PartialEq, Default)]
pub(crate) struct ReadPlan {
    pub(crate) jobs: Vec<Vec<Item>>,
    pub(crate) spans: Vec<Span>,
}

/// The most items of one request: what S7-300/400 CPUs and Snap7 take (more are cut off).
pub(crate) const MAX_ITEMS: usize = 20;

/// The most bytes one item's answer carries in a PDU of `pdu` bytes (even, so that a piece
/// of timers or counters holds whole ones).
pub(crate) fn max_item(pdu: u16) -> u32 {
    (u32::from(pdu.saturating_sub(18 + 4)) & !1).max(2)
}

/// The bytes between two fields of one block read with them (not asked for) rather than
/// in an item of their own, unless the link says (`max_gap`): an item costs 16 bytes of
/// request and answer and a request holds 20, so up to about 40 bytes apart, fields of a
/// few bytes are read in fewer requests merged (500 INTs 8 bytes apart: 5 requests, not
/// 25; `docs/benchmarks.md`).
pub(crate) const DEFAULT_GAP: u32 = 32;

/// The fields' ranges, merged where they touch or are at most `gap` bytes apart, up to one
/// item's answer (a field never merged with `alone` ones), in area, block and address
/// order.
fn ranges(
    places: &[Result<Place, String>],
    max_item: u32,
    alone: &std::collections::BTreeSet<usize>,
    gap: u32,
) -> Vec<Range> {
    let mut ranges: Vec<Range> = Vec::new();
    let mut order: Vec<(usize, Place)> = places
        .iter()
        .enumerate()
        .filter_map(|(i, p)| p.as_ref().ok().map(|p| (i, *p)))
        .collect();
    order.sort_by_key(|(_, p)| (p.address.area, p.address.db, p.start()));
    for (i, p) in order {
        let (a, first) = (p.address, p.start());
        let end = first + u32::from(p.bytes);
        match ranges.last_mut() {
            Some((area, db, start, stop, fields))
                if *area == a.area
                    && *db == a.db
                    && first <= *stop + gap
                    && end.max(*stop) - *start <= max_item
                    && !alone.contains(&i)
                    && !fields.iter().any(|(f, _)| alone.contains(f)) =>
            {
                *stop = (*stop).max(end);
                fields.push((i, first - *start));
            }
            _ => ranges.push((a.area, a.db, first, end, vec![(i, 0)])),
        }
    }
    ranges
}

/// The fields' ranges packed into jobs: at most `(pdu - 19) / 12` (and 20) items a
/// request, answers within `pdu - 14` bytes, a range larger than one item's answer split
/// into pieces.
pub(crate) fn read_plan(
    places: &[Result<Place, String>],
    pdu: u16,
    alone: &std::collections::BTreeSet<usize>,
    gap: u32,
) -> ReadPlan {
    let max_item = max_item(pdu);
    let per_request = usize::from(pdu.saturating_sub(19) / 12).clamp(1, MAX_ITEMS);
    let answer_room = u32::from(pdu.saturating_sub(14));
    let mut plan = ReadPlan::default();
    let mut used = u32::MAX;
    for (area, db, start, stop, fields) in ranges(places, max_item, alone, gap) {
        let mut span = Span {
            fields,
            pieces: Vec::new(),
        };
        let mut at = start;
        while at < stop {
            let len = (stop - at).min(max_item);
            let cost = 4 + len + len % 2;
            let full = plan.jobs.last().is_none_or(|j| j.len() >= per_request)
                || used + cost > answer_room;
            if full {
                plan.jobs.push(Vec::new());
                used = 0;
            }
            used += cost;
            let cells = matches!(area, Area::Timers | Area::Counters);
            let (byte, length) = if cells { (at / 2, len / 2) } else { (at, len) };
            let job = plan.jobs.len() - 1;
            if let Some(items) = plan.jobs.last_mut() {
                span.pieces.push((job, items.len()));
                items.push(Item {
                    area,
                    db,
                    byte,
                    bit: None,
                    length: length as u16,
                });
            }
            at += len;
        }
        plan.spans.push(span);
    }
    plan
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

/// The gap a link's settings allow between fields read together ([`DEFAULT_GAP`] unless
/// they say).
pub(crate) fn asked_gap(settings: &crate::yaml::Node) -> u32 {
    let mut quiet = crate::yaml::Report::new("plan");
    settings
        .map(&mut quiet, "s7")
        .and_then(|mut m| m.get("max_gap").cloned())
        .and_then(|n| n.int_in(&mut quiet, "max_gap", 0, i128::from(MAX_GAP)))
        .map_or(DEFAULT_GAP, |v| v as u32)
}

/// The largest `max_gap` a link may set.
pub(crate) const MAX_GAP: u32 = 512;

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

#[cfg(test)]
mod tests {
    use super::*;

    fn place(text: &str, bytes: u16) -> Result<Place, String> {
        let address = parse(text)?;
        Ok(Place {
            address,
            form: Form::Number,
            stored: crate::codec::IecType::Byte,
            bytes,
        })
    }

    #[test]
    fn touching_fields_merge_and_a_large_one_is_read_in_pieces() {
        let places = [
            place("DB1.DBW0", 2),
            place("DB1.DBW2", 2),
            place("DB1.DBB10", 256),
            place("MW0", 2),
            place("DB2.DBW0", 2),
        ];
        let plan = read_plan(&places, 240, &Default::default(), 0);
        // M, DB1 0-3, DB1 10-265 (218 + 38 bytes), DB2 0-1.
        let spans: Vec<usize> = plan.spans.iter().map(|s| s.pieces.len()).collect();
        assert_eq!(spans, [1, 1, 2, 1]);
        let pieces: Vec<(u32, u16)> = plan
            .jobs
            .iter()
            .flatten()
            .map(|i| (i.byte, i.length))
            .collect();
        assert!(
            pieces.contains(&(10, 218)) && pieces.contains(&(228, 38)),
            "{pieces:?}"
        );
        for job in &plan.jobs {
            let answer: u32 = job
                .iter()
                .map(|i| 4 + u32::from(i.length) + u32::from(i.length) % 2)
                .sum();
            assert!(answer <= 240 - 14 && job.len() <= 18, "{job:?}");
        }
        // At 960 everything is one job of four items.
        let plan = read_plan(&places, 960, &Default::default(), 0);
        assert_eq!((plan.jobs.len(), plan.jobs[0].len()), (1, 4));
        // A field read alone is not merged.
        let plan = read_plan(&places, 960, &[1].into_iter().collect(), 0);
        assert_eq!(plan.spans.len(), 5);
    }

    #[test]
    fn scattered_fields_within_the_gap_are_read_together() {
        // 500 INTs 8 bytes apart in DB1 (0-3993).
        let places: Vec<_> = (0..500)
            .map(|k| place(&format!("DB1.DBW{}", 8 * k), 2))
            .collect();
        let apart = read_plan(&places, 960, &Default::default(), 0);
        assert_eq!(apart.jobs.len(), 25, "20 items a job");
        let merged = read_plan(&places, 960, &Default::default(), DEFAULT_GAP);
        assert_eq!(merged.jobs.len(), 5, "{:?}", merged.jobs);
        let read: u32 = merged
            .jobs
            .iter()
            .flatten()
            .map(|i| u32::from(i.length))
            .sum();
        // Every byte from the first field to the last, once, but for the 6 bytes between
        // two items (an item holds at most 938 bytes).
        let gaps = 6 * (merged.spans.len() as u32 - 1);
        assert_eq!((merged.spans.len(), read), (5, 3994 - gaps));
        // Fields further apart than the gap stay apart; fields at the gap merge.
        let two = [place("DB1.DBW0", 2), place("DB1.DBW34", 2)];
        assert_eq!(read_plan(&two, 960, &Default::default(), 32).spans.len(), 1);
        assert_eq!(read_plan(&two, 960, &Default::default(), 31).spans.len(), 2);
        // Another block is never merged, whatever the gap.
        let blocks = [place("DB1.DBW0", 2), place("DB2.DBW0", 2)];
        assert_eq!(
            read_plan(&blocks, 960, &Default::default(), 512)
                .spans
                .len(),
            2
        );
    }
}

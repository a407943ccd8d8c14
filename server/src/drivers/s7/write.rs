//! A device's writes: each output's bytes as its form stores them (a BOOL as a bit item,
//! a STRING's length byte and characters, a timer or counter by number), packed into jobs
//! that fit the PDU the PLC granted; a value larger than one item is written in pieces, the
//! one with a string's length last. Each item's return code is its write's outcome.

use std::sync::Arc;

use super::form::Form;
use super::pdu::{self, Item};
use super::plan::MAX_ITEMS;
use super::{Plan, Plc, fault, value};
use crate::cache::{Device, FieldError, WriteError};
use crate::drivers::WriteItem;
use crate::drivers::{finish, written};
use crate::link::LinkFault;

/// One piece of an output to write: which write it belongs to, where, and its bytes.
type Piece = (usize, Item, Vec<u8>);

/// The bytes an item takes in a Write Var request: its spec, its data header and data
/// (padded to even).
fn cost(bytes: usize) -> usize {
    12 + 4 + bytes + bytes % 2
}

/// The most data bytes one item of a request of `pdu` bytes carries (even).
fn max_piece(pdu: u16) -> usize {
    (usize::from(pdu).saturating_sub(12 + 16) & !1).max(2)
}

/// The items an output is written to, in the order to write them.
fn pieces(plan: &Plan, item: &WriteItem, device: &Device) -> Result<Vec<(Item, Vec<u8>)>, String> {
    let place = match plan.places.get(item.field) {
        Some(Ok(p)) => *p,
        Some(Err(why)) => return Err(why.clone()),
        None => return Err("no such field".to_owned()),
    };
    let raw = device.field(item.field).to_raw(item.value()?)?;
    let (skip, bytes) = value::encode(place.form, place.stored, &raw)?;
    let a = place.address;
    let at = |byte: u32, bit: Option<u8>, length: u16| Item {
        area: a.area,
        db: a.db,
        byte,
        bit,
        length,
    };
    Ok(match place.form {
        Form::Bit(b) => vec![(at(a.byte, Some(b), 1), bytes)],
        Form::Timer | Form::Counter => vec![(at(a.byte, None, 1), bytes)],
        _ => {
            let start = a.byte + u32::from(skip);
            let mut out: Vec<(Item, Vec<u8>)> = bytes
                .chunks(max_piece(plan.pdu))
                .scan(start, |next, chunk| {
                    let item = at(*next, None, chunk.len() as u16);
                    *next += chunk.len() as u32;
                    Some((item, chunk.to_vec()))
                })
                .collect();
            // The first piece holds a string's length: written last, after its characters.
            out.reverse();
            out
        }
    })
}

/// The pieces of one request each: as many as the PDU holds.
fn requests(pieces: Vec<Piece>, pdu: u16) -> Vec<Vec<Piece>> {
    let room = usize::from(pdu).saturating_sub(12);
    let per_request = usize::from(pdu.saturating_sub(19) / 12).clamp(1, MAX_ITEMS);
    let mut out: Vec<Vec<Piece>> = Vec::new();
    let mut used = room;
    for piece in pieces {
        let c = cost(piece.2.len());
        let full = out.last().is_none_or(|r| r.len() >= per_request) || used + c > room;
        if full {
            out.push(Vec::new());
            used = 0;
        }
        used += c;
        if let Some(r) = out.last_mut() {
            r.push(piece);
        }
    }
    out
}

pub(super) async fn write(
    plc: &mut Plc,
    device: &Arc<Device>,
    plan: &mut Plan,
    items: Vec<WriteItem>,
) -> Result<Option<FieldError>, LinkFault> {
    if (plan.pdu, plan.gap) != (plc.conn.pdu, plc.gap) {
        super::read::replan(device, plan, (plc.conn.pdu, plc.gap));
    }
    // Each write's pieces still to be written, and its first failure.
    let mut left = vec![0usize; items.len()];
    let mut failed: Vec<Option<String>> = vec![None; items.len()];
    let mut all = Vec::new();
    for (n, item) in items.iter().enumerate() {
        match pieces(plan, item, device) {
            Ok(p) => {
                left[n] = p.len();
                all.extend(p.into_iter().map(|(to, bytes)| (n, to, bytes)));
            }
            Err(why) => failed[n] = Some(why),
        }
    }
    for request in requests(all, plan.pdu) {
        let asked: Vec<(Item, Vec<u8>)> = request.iter().map(|(_, t, b)| (*t, b.clone())).collect();
        plc.started();
        let answered = plc.conn.write(&asked).await;
        plc.progress.ended();
        let results: Vec<Result<(), String>> = match answered.map_err(fault) {
            Ok(o) => o
                .into_iter()
                .map(|r| r.map_err(|code| pdu::item_error(code).to_owned()))
                .collect(),
            Err(Ok(why)) => {
                plc.tell_refused(&why);
                vec![Err(why); request.len()]
            }
            Err(Err(lost)) => {
                // Writes with pieces not answered are replayed after the reconnect.
                for (n, item) in items.iter().enumerate() {
                    match (&failed[n], left[n]) {
                        (Some(why), _) => finish_one(device, item, Err(why.clone())),
                        (None, 0) => finish_one(device, item, Ok(())),
                        (None, _) => {
                            finish(device, item, Err(WriteError::LinkDown(lost.clone())), 1)
                        }
                    }
                }
                return Err(lost);
            }
        };
        for ((n, _, _), result) in request.iter().zip(results) {
            left[*n] = left[*n].saturating_sub(1);
            if let (Err(why), None) = (result, &failed[*n]) {
                failed[*n] = Some(why);
            }
        }
    }
    for (n, item) in items.iter().enumerate() {
        finish_one(device, item, failed[n].clone().map_or(Ok(()), Err));
    }
    Ok(None)
}

/// Finishes a write with its outcome.
fn finish_one(device: &Device, item: &WriteItem, outcome: Result<(), String>) {
    match outcome {
        Ok(()) => written(device, item, 1),
        Err(why) => finish(device, item, Err(WriteError::Refused(why)), 1),
    }
}

/// Whether `value` can be written to field `idx` at all (its place in the PLC takes it):
/// checked before the write is accepted, so a value no S7 PLC could hold there is refused at
/// once, never sent.
pub(crate) fn check_value(
    device: &Device,
    idx: usize,
    value: &crate::codec::Value,
) -> Result<(), String> {
    let field = device.field(idx);
    let Some(point) = &field.point else {
        return Ok(());
    };
    let address = super::address::parse(&point.address)?;
    let stored = field.register.raw_type.unwrap_or(field.ty);
    let form = super::form::form(&address, stored, point.length)?;
    let raw = field.to_raw(value)?;
    value::encode(form, stored, &raw).map(|_| ())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::drivers::s7::address::Area;

    #[test]
    fn writes_are_packed_within_the_pdu() {
        let item = Item {
            area: Area::DataBlock,
            db: 1,
            byte: 0,
            bit: None,
            length: 100,
        };
        let piece = |n| (n, item, vec![0u8; 100]);
        // 116 bytes an item in a request's 12 + its items: one fits 240, eight fit 960.
        let sizes = |pdu, n| -> Vec<usize> {
            requests((0..n).map(piece).collect(), pdu)
                .iter()
                .map(Vec::len)
                .collect()
        };
        assert_eq!(sizes(240, 3), [1, 1, 1]);
        assert_eq!(sizes(960, 10), [8, 2]);
        // Small items: as many as the PDU and 20 a request allow (18 at 240).
        let bits = requests(
            (0..40)
                .map(|n| {
                    let (_, mut i, _) = piece(n);
                    i.bit = Some(0);
                    (n, i, vec![1u8])
                })
                .collect(),
            240,
        );
        assert!(
            bits.iter()
                .all(|r| r.len() <= 18 && 12 + r.len() * 18 <= 240),
            "{:?}",
            bits.iter().map(Vec::len).collect::<Vec<_>>()
        );
        assert_eq!(bits.iter().map(Vec::len).sum::<usize>(), 40);
        assert_eq!(max_piece(240), 212);
    }
}

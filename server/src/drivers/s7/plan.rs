//! A device's reads: each field an area range (its address, its type's size), ranges of one
//! block merged where they touch, packed into jobs within the negotiated PDU (items per
//! request, answer bytes); values decoded big-endian as the PLC stores them.

use crate::codec::{IecType, Value};
use crate::profile::Profile;
use crate::profile::s7_address::{Address, Area, Width, parse};

use super::pdu::Item;

/// A field's place: its address and the bytes it takes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Place {
    pub(crate) address: Address,
    pub(crate) bytes: u16,
}

/// The bytes a value of `ty` takes (a STRING of `chars`: its two length bytes and them).
pub(crate) fn size_of(ty: IecType, chars: u16) -> u16 {
    match ty {
        IecType::Bool | IecType::Sint | IecType::Usint | IecType::Byte => 1,
        IecType::Int | IecType::Uint | IecType::Word => 2,
        IecType::Dint | IecType::Udint | IecType::Dword | IecType::Real | IecType::Time => 4,
        IecType::Lint | IecType::Ulint | IecType::Lword | IecType::Lreal => 8,
        IecType::String => chars + 2,
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
            let chars = f.register.word_count * 2;
            let bytes = size_of(f.ty, chars);
            match (address.width, f.ty) {
                (Width::Bit(_), IecType::Bool) => Ok(Place { address, bytes: 1 }),
                (Width::Bit(_), t) => Err(format!("{} is a bit; a {t} is not", point.address)),
                (_, IecType::Bool) => Err(format!(
                    "a BOOL is a bit: write {}.x (bit x of the byte)",
                    point.address
                )),
                (w, t) => match w.bytes() {
                    Some(b) if b != bytes => Err(format!(
                        "{} is {b} byte(s); a {t} is {bytes}",
                        point.address
                    )),
                    _ => Ok(Place { address, bytes }),
                },
            }
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

/// The most bytes one item's answer carries in a PDU of `pdu` bytes (a field larger is not
/// read: its error says so).
pub(crate) fn max_item(pdu: u16) -> u32 {
    u32::from(pdu.saturating_sub(18 + 4)).max(1)
}

/// The fields' ranges merged where they touch and packed into jobs: at most
/// `(pdu - 19) / 12` items a request, answers within `pdu - 14` bytes.
pub(crate) fn batches(places: &[Result<Place, String>], pdu: u16) -> Vec<Batch> {
    let mut ranges: Vec<Range> = Vec::new();
    let max_item = max_item(pdu);
    let mut order: Vec<(usize, Place)> = places
        .iter()
        .enumerate()
        .filter_map(|(i, p)| p.as_ref().ok().map(|p| (i, *p)))
        .filter(|(_, p)| u32::from(p.bytes) <= max_item)
        .collect();
    order.sort_by_key(|(_, p)| (p.address.area, p.address.db, p.address.byte));
    for (i, p) in order {
        let a = p.address;
        let end = a.byte + u32::from(p.bytes);
        match ranges.last_mut() {
            Some((area, db, start, stop, fields))
                if *area == a.area
                    && *db == a.db
                    && a.byte <= *stop
                    && end - *start <= max_item =>
            {
                *stop = (*stop).max(end);
                fields.push((i, a.byte - *start));
            }
            _ => ranges.push((a.area, a.db, a.byte, end, vec![(i, 0)])),
        }
    }
    let per_request = usize::from(pdu.saturating_sub(19) / 12).max(1);
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
        if let Some(b) = out.last_mut() {
            b.items.push(Item {
                area,
                db,
                byte: start,
                bit: None,
                length: len as u16,
            });
            b.fields.push(fields);
        }
    }
    out
}

/// A field's value from its bytes (big-endian; a STRING with its two length bytes).
pub(crate) fn decode(ty: IecType, address: &Address, bytes: &[u8]) -> Result<Value, String> {
    let short = || format!("{} bytes answered for a {ty}", bytes.len());
    let be = |n: usize| -> Result<u64, String> {
        let b = bytes.get(..n).ok_or_else(short)?;
        Ok(b.iter().fold(0u64, |acc, &x| acc << 8 | u64::from(x)))
    };
    let signed = |n: usize| -> Result<i128, String> {
        let v = be(n)?;
        let shift = 64 - 8 * n as u32;
        Ok(i128::from(((v << shift) as i64) >> shift))
    };
    let fits = |r: Result<Value, iogate_types::ValueError>| r.map_err(|e| e.to_string());
    match ty {
        IecType::Bool => match address.width {
            Width::Bit(b) => Ok(Value::Bool(be(1)? >> b & 1 == 1)),
            _ => Err("a BOOL is a bit".to_owned()),
        },
        IecType::Sint | IecType::Int | IecType::Dint | IecType::Lint => {
            fits(Value::from_int(ty, signed(usize::from(size_of(ty, 0)))?))
        }
        IecType::Time => Ok(Value::Time(signed(4)? as i64)),
        IecType::Real => Ok(Value::Real(f32::from_bits(be(4)? as u32))),
        IecType::Lreal => Ok(Value::LReal(f64::from_bits(be(8)?))),
        IecType::String => {
            let (max, len) = (
                bytes.first().ok_or_else(short)?,
                bytes.get(1).ok_or_else(short)?,
            );
            let len = usize::from(*len.min(max));
            let chars = bytes.get(2..2 + len).ok_or_else(short)?;
            Ok(Value::String(
                chars.iter().map(|&c| char::from(c)).collect(),
            ))
        }
        _ => fits(Value::from_int(
            ty,
            i128::from(be(usize::from(size_of(ty, 0)))?),
        )),
    }
}

/// A value's bytes as the PLC stores them (a STRING: its length byte and characters, the
/// maximum left as it is).
pub(crate) fn encode(ty: IecType, value: &Value) -> Result<Vec<u8>, String> {
    let n = usize::from(size_of(ty, 0));
    let int = |v: i128| -> Vec<u8> { v.to_be_bytes()[16 - n..].to_vec() };
    Ok(match (ty, value) {
        (IecType::Bool, Value::Bool(b)) => vec![u8::from(*b)],
        (_, Value::Int(v)) => int(i128::from(*v)),
        (_, Value::UInt(v)) => int(i128::from(*v)),
        (_, Value::Time(ms)) => int(i128::from(*ms)),
        (IecType::Real, Value::Real(x)) => x.to_be_bytes().to_vec(),
        (IecType::Lreal, Value::LReal(x)) => x.to_be_bytes().to_vec(),
        (IecType::String, Value::String(s)) => {
            if !s.is_ascii() {
                return Err("an S7 STRING holds ASCII characters".to_owned());
            }
            let mut out = vec![u8::try_from(s.len()).map_err(|_| "the string is too long")?];
            out.extend_from_slice(s.as_bytes());
            out
        }
        (t, v) => return Err(format!("a {t} does not take {v}")),
    })
}

//! A device's writes: each output's bytes as its form stores them (a BOOL as a bit item,
//! a STRING's length byte and characters, a timer or counter by number), packed into jobs
//! that fit the PDU the PLC granted; each item's return code is its write's outcome.

use std::sync::Arc;

use super::pdu::{self, Item};
use super::{Plan, Plc, fault, value};
use crate::cache::{Device, FieldError, WriteError};
use crate::drivers::{finish, written};
use crate::link::LinkFault;
use crate::plan::WriteItem;
use crate::profile::s7_form::Form;

/// One output to write: what was asked, where, and its bytes.
type Job = (WriteItem, Item, Vec<u8>);

/// The bytes an item takes in a Write Var request: its spec, its data header and data
/// (padded to even).
fn cost(bytes: usize) -> usize {
    12 + 4 + bytes + bytes % 2
}

/// The item an output is written to.
fn target(plan: &Plan, item: &WriteItem, device: &Device) -> Result<(Item, Vec<u8>), String> {
    let place = match plan.places.get(item.field) {
        Some(Ok(p)) => *p,
        Some(Err(why)) => return Err(why.clone()),
        None => return Err("no such field".to_owned()),
    };
    let raw = value::unscaled(device.field(item.field), &item.value)?;
    let (skip, bytes) = value::encode(place.form, place.stored, &raw)?;
    let a = place.address;
    let (bit, length) = match place.form {
        Form::Bit(b) => (Some(b), 1),
        Form::Timer | Form::Counter => (None, 1),
        _ => (None, bytes.len() as u16),
    };
    let room = usize::from(plan.pdu).saturating_sub(12);
    if cost(bytes.len()) > room {
        return Err(format!(
            "{} bytes do not fit one write of the PLC's PDU ({} bytes)",
            bytes.len(),
            plan.pdu
        ));
    }
    let item = Item {
        area: a.area,
        db: a.db,
        byte: a.byte + u32::from(skip),
        bit,
        length,
    };
    Ok((item, bytes))
}

/// The jobs of one request each: as many outputs as the PDU holds.
fn requests(jobs: Vec<Job>, pdu: u16) -> Vec<Vec<Job>> {
    let room = usize::from(pdu).saturating_sub(12);
    let per_request = usize::from(pdu.saturating_sub(19) / 12).max(1);
    let mut out: Vec<Vec<Job>> = Vec::new();
    let mut used = room;
    for job in jobs {
        let c = cost(job.2.len());
        let full = out.last().is_none_or(|r| r.len() >= per_request) || used + c > room;
        if full {
            out.push(Vec::new());
            used = 0;
        }
        used += c;
        if let Some(r) = out.last_mut() {
            r.push(job);
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
    if plan.pdu != plc.conn.pdu {
        super::replan(device, plan, plc.conn.pdu);
    }
    let mut jobs = Vec::new();
    for item in items {
        match target(plan, &item, device) {
            Ok((to, bytes)) => jobs.push((item, to, bytes)),
            Err(why) => finish(device, &item, Err(WriteError::Refused(why)), 0),
        }
    }
    let mut requests = requests(jobs, plan.pdu).into_iter();
    while let Some(request) = requests.next() {
        let asked: Vec<(Item, Vec<u8>)> = request.iter().map(|(_, t, b)| (*t, b.clone())).collect();
        plc.started();
        let answered = plc.conn.write(&asked).await;
        plc.progress.ended();
        let outcomes = match answered.map_err(fault) {
            Ok(o) => o,
            Err(Ok(why)) => {
                plc.tell_refused(&why);
                for (item, _, _) in &request {
                    finish(device, item, Err(WriteError::Refused(why.clone())), 1);
                }
                continue;
            }
            Err(Err(lost)) => {
                let rest: Vec<Job> = requests.flatten().collect();
                for (item, _, _) in request.iter().chain(&rest) {
                    finish(device, item, Err(WriteError::LinkDown(lost.clone())), 1);
                }
                return Err(lost);
            }
        };
        for ((item, _, _), outcome) in request.iter().zip(outcomes) {
            match outcome {
                Ok(()) => written(device, item, 1),
                Err(code) => finish(
                    device,
                    item,
                    Err(WriteError::Refused(pdu::item_error(code).to_owned())),
                    1,
                ),
            }
        }
    }
    Ok(None)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::profile::s7_address::Area;

    #[test]
    fn writes_are_packed_within_the_pdu() {
        let item = Item {
            area: Area::DataBlock,
            db: 1,
            byte: 0,
            bit: None,
            length: 100,
        };
        let job = |field| {
            let w = WriteItem {
                field,
                value: crate::codec::Value::Int(0),
                generation: None,
                registers: None,
            };
            (w, item, vec![0u8; 100])
        };
        // 116 bytes an item in a request's 12 + its items: one fits 240, eight fit 960.
        let sizes = |pdu, n| -> Vec<usize> {
            requests((0..n).map(job).collect(), pdu)
                .iter()
                .map(Vec::len)
                .collect()
        };
        assert_eq!(sizes(240, 3), [1, 1, 1]);
        assert_eq!(sizes(960, 10), [8, 2]);
        // Small items: as many as an answer's item count allows ((240 - 19) / 12 = 18).
        let bits = requests(
            (0..40)
                .map(|f| {
                    let (w, mut i, _) = job(f);
                    i.bit = Some(0);
                    (w, i, vec![1u8])
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
    }
}

//! Writing a device's outputs: each item's request (Write Tag in the field's type, a
//! STRING in the layout the controller answered, a bit of an integer with
//! Read-Modify-Write Tag, never the whole integer), packed in Multiple Service Packets
//! within the connection's size, as reads are; each reply's status is its write's outcome.
//! The writes of a packet sent when the link was lost are finished as sent, the later ones
//! as not sent; the latest values are written again after the reconnect.

use iogate_types::Value;

use super::{Controller, Plan, cip, finish, lost, value, written};
use crate::cache::{Device, WriteError};
use crate::link::LinkFault;
use crate::plan::WriteItem;

/// A write's reply at most: service, reserved, status, extended status of one word.
const REPLY: usize = 6;

/// An item's request and the service it asks, or why it cannot be written.
fn message(plan: &Plan, device: &Device, item: &WriteItem) -> Result<(u8, Vec<u8>), String> {
    let tag = plan.tags[item.field].as_ref().map_err(Clone::clone)?;
    if let Some(bit) = tag.bit {
        let code = plan.codes[item.field]
            .ok_or("the integer holding the bit was not read yet: its size is unknown")?;
        let on = matches!(item.value, Value::Bool(true));
        let masks = value::bit_masks(code, bit, on)?;
        return Ok((
            cip::READ_MODIFY_WRITE,
            cip::request(cip::READ_MODIFY_WRITE, &tag.path, &masks),
        ));
    }
    let request = match (&item.value, plan.codes[item.field]) {
        (Value::String(text), Some(code)) => {
            let data = value::encode_string(text, code, plan.layouts[item.field])?;
            cip::request(cip::WRITE_TAG, &tag.path, &data)
        }
        _ => {
            let (code, bytes) = value::encode(&item.value, device.profile.fields[item.field].ty)?;
            cip::write_tag(&tag.path, code, &bytes)
        }
    };
    Ok((cip::WRITE_TAG, request))
}

/// A request ready to go: the item it writes, its service and bytes.
struct Ready {
    item: usize,
    service: u8,
    request: Vec<u8>,
}

impl Controller {
    /// Writes `items`, finishing each with its outcome.
    pub(super) async fn write_items(
        &mut self,
        device: &Device,
        plan: &Plan,
        items: &[WriteItem],
    ) -> Result<(), LinkFault> {
        let mut ready = Vec::with_capacity(items.len());
        for (n, item) in items.iter().enumerate() {
            match message(plan, device, item) {
                Ok((service, request)) => ready.push(Ready {
                    item: n,
                    service,
                    request,
                }),
                Err(why) => finish(device, item, Err(WriteError::Refused(why)), 0),
            }
        }
        let sizes: Vec<(usize, usize, usize)> = ready
            .iter()
            .enumerate()
            .map(|(k, r)| (k, r.request.len(), REPLY))
            .collect();
        let packets = match self.single {
            true => (0..ready.len()).map(|k| vec![k]).collect(),
            false => crate::plan::eip::packets(&sizes, self.conn.message_limit()),
        };
        for (p, packet) in packets.iter().enumerate() {
            let group: Vec<&Ready> = packet.iter().map(|&k| &ready[k]).collect();
            let mut sent = self.write_packet(device, items, &group).await;
            if matches!(sent, Ok(false)) {
                // No Multiple Service Packets: each write alone.
                for r in &group {
                    sent = self.write_packet(device, items, &[r]).await;
                    if sent.is_err() {
                        break;
                    }
                }
            }
            if let Err(fault) = sent {
                for r in &group {
                    let why = Err(WriteError::LinkDown(fault.clone()));
                    finish(device, &items[r.item], why, 1);
                }
                for r in packets[p + 1..].iter().flatten().map(|&k| &ready[k]) {
                    let why = Err(WriteError::LinkDown(fault.clone()));
                    finish(device, &items[r.item], why, 0);
                }
                return Err(fault);
            }
        }
        Ok(())
    }

    /// Sends one packet's writes (one alone, several in a Multiple Service Packet) and
    /// finishes each with its reply's status; `false` when the controller has no Multiple
    /// Service Packets (none of them finished: to be sent alone).
    async fn write_packet(
        &mut self,
        device: &Device,
        items: &[WriteItem],
        group: &[&Ready],
    ) -> Result<bool, LinkFault> {
        let message = match group {
            [one] => one.request.clone(),
            _ => {
                let requests: Vec<Vec<u8>> = group.iter().map(|r| r.request.clone()).collect();
                cip::multiple(&requests)
            }
        };
        let answer = match self.request(&message).await? {
            Ok(a) => a,
            Err(why) => {
                refuse_all(device, items, group, &why);
                return Ok(true);
            }
        };
        let replies: Vec<&[u8]> = match group {
            [_] => vec![answer.as_slice()],
            _ => {
                let outer = cip::reply(&answer).map_err(|e| lost(e.into()))?;
                outer.answers(cip::MULTIPLE).map_err(|e| lost(e.into()))?;
                if outer.status == super::read::SERVICE_NOT_SUPPORTED {
                    self.no_multiple();
                    return Ok(false);
                }
                if outer.status != 0 && outer.status != 0x1E {
                    let why = cip::cip_status(outer.status, outer.ext);
                    refuse_all(device, items, group, &why);
                    return Ok(true);
                }
                cip::multiple_replies(outer.data, group.len()).map_err(|e| lost(e.into()))?
            }
        };
        // Every reply taken apart before any write is finished: an answer out of step
        // is a lost link, and then the packet's writes are finished as sent, once.
        let mut outcomes = Vec::with_capacity(group.len());
        for (r, bytes) in group.iter().zip(replies) {
            let reply = cip::reply(bytes).map_err(|e| lost(e.into()))?;
            reply.answers(r.service).map_err(|e| lost(e.into()))?;
            outcomes.push(match reply.status {
                0 => None,
                s => Some(cip::cip_status(s, reply.ext)),
            });
        }
        for (r, outcome) in group.iter().zip(outcomes) {
            match outcome {
                None => written(device, &items[r.item], 1),
                Some(why) => finish(device, &items[r.item], Err(WriteError::Refused(why)), 1),
            }
        }
        Ok(true)
    }
}

/// A packet refused whole: every write in it, with why.
fn refuse_all(device: &Device, items: &[WriteItem], group: &[&Ready], why: &str) {
    for r in group {
        let refused = Err(WriteError::Refused(why.to_owned()));
        finish(device, &items[r.item], refused, 1);
    }
}

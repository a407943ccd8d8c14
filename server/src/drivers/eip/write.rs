//! Writing a device's outputs: each item's request (Write Tag in the field's type, a
//! STRING in the layout the controller answered, a bit of an integer with
//! Read-Modify-Write Tag, never the whole integer), packed in Multiple Service Packets
//! within the connection's size, as reads are; each reply's status is its write's outcome.
//! The writes of a packet sent when the link was lost are finished as sent, the later ones
//! as not sent; the latest values are written again after the reconnect.

use iogate_types::Value;

use super::{Controller, Plan, cip, finish, lost, value, written};
use crate::cache::{Device, WriteError};
use crate::drivers::WriteItem;
use crate::link::LinkFault;

/// A write's reply at most: service, reserved, status, extended status of one word.
const REPLY: usize = 6;

/// An item's request and the service it asks, or why it cannot be written.
fn message(plan: &Plan, device: &Device, item: &WriteItem) -> Result<(u8, Vec<u8>), String> {
    let tag = plan.tags[item.field].as_ref().map_err(Clone::clone)?;
    let value = item.value()?;
    if let Some(bit) = tag.bit {
        if let Some(why) = &plan.no_bit_writes {
            return Err(why.clone());
        }
        let code = plan.codes[item.field]
            .ok_or("the integer holding the bit was not read yet: its size is unknown")?;
        let on = matches!(value, Value::Bool(true));
        let masks = value::bit_masks(code, bit, on)?;
        return Ok((
            cip::READ_MODIFY_WRITE,
            cip::request(cip::READ_MODIFY_WRITE, &tag.path, &masks),
        ));
    }
    let request = match (value, plan.codes[item.field]) {
        (Value::String(text), Some(code)) => {
            let data = value::encode_string(text, code, plan.layouts[item.field])?;
            cip::request(cip::WRITE_TAG, &tag.path, &data)
        }
        _ => {
            let (code, bytes) = value::encode(value, device.profile.fields[item.field].ty)?;
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
        plan: &mut Plan,
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
        // A bit's Read-Modify-Write goes alone: a controller without the service may
        // close the connection, and then it is known which write did it.
        let (bits, words): (Vec<_>, Vec<_>) = sizes
            .into_iter()
            .partition(|(k, _, _)| ready[*k].service == cip::READ_MODIFY_WRITE);
        let mut packets: Vec<Vec<usize>> = match self.single {
            true => words.iter().map(|(k, _, _)| vec![*k]).collect(),
            false => super::plan::packets(&words, self.conn.message_limit()),
        };
        packets.extend(bits.iter().map(|(k, _, _)| vec![*k]));
        for (p, packet) in packets.iter().enumerate() {
            let group: Vec<&Ready> = packet.iter().map(|&k| &ready[k]).collect();
            let mut sent = self.write_packet(device, items, &group).await;
            if matches!(sent, Ok(Sent::NoMultiple)) {
                // No Multiple Service Packets: each write alone.
                for r in &group {
                    sent = self.write_packet(device, items, &[r]).await;
                    if sent.is_err() {
                        break;
                    }
                }
            }
            if let Ok(Sent::NoBitWrites) = sent {
                plan.no_bit_writes = Some(NO_RMW_REFUSED.to_owned());
            }
            if let Err(fault) = sent {
                if let [r] = group.as_slice()
                    && r.service == cip::READ_MODIFY_WRITE
                {
                    // The controller closed the connection when asked to change a bit:
                    // it has no Read-Modify-Write Tag, and asking again would do it again.
                    plan.no_bit_writes = Some(NO_RMW_CLOSED.to_owned());
                    finish(
                        device,
                        &items[r.item],
                        Err(WriteError::Refused(NO_RMW_CLOSED.to_owned())),
                        1,
                    );
                    tracing::warn!(link = %self.link.name(), "{NO_RMW_CLOSED}");
                    return Err(fault);
                }
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
    /// finishes each with its reply's status.
    async fn write_packet(
        &mut self,
        device: &Device,
        items: &[WriteItem],
        group: &[&Ready],
    ) -> Result<Sent, LinkFault> {
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
                if let [r] = group
                    && r.service == cip::READ_MODIFY_WRITE
                {
                    // Refused whole (cpppo): the service is missing.
                    let why = format!("{NO_RMW_REFUSED} ({why})");
                    finish(device, &items[r.item], Err(WriteError::Refused(why)), 1);
                    return Ok(Sent::NoBitWrites);
                }
                refuse_all(device, items, group, &why);
                return Ok(Sent::Done);
            }
        };
        let replies: Vec<&[u8]> = match group {
            [_] => vec![answer.as_slice()],
            _ => {
                let outer = cip::reply(&answer).map_err(|e| lost(e.into()))?;
                outer.answers(cip::MULTIPLE).map_err(|e| lost(e.into()))?;
                if outer.status == super::read::SERVICE_NOT_SUPPORTED {
                    self.no_multiple();
                    return Ok(Sent::NoMultiple);
                }
                if outer.status != 0 && outer.status != 0x1E {
                    let why = cip::cip_status(outer.status, outer.ext);
                    refuse_all(device, items, group, &why);
                    return Ok(Sent::Done);
                }
                cip::multiple_replies(outer.data, group.len()).map_err(|e| lost(e.into()))?
            }
        };
        // Every reply taken apart before any write is finished: an answer out of step
        // is a lost link, and then the packet's writes are finished as sent, once.
        let mut outcomes = Vec::with_capacity(group.len());
        let mut sent = Sent::Done;
        for (r, bytes) in group.iter().zip(replies) {
            let reply = cip::reply(bytes).map_err(|e| lost(e.into()))?;
            reply.answers(r.service).map_err(|e| lost(e.into()))?;
            outcomes.push(match reply.status {
                0 => None,
                super::read::SERVICE_NOT_SUPPORTED if r.service == cip::READ_MODIFY_WRITE => {
                    sent = Sent::NoBitWrites;
                    Some(NO_RMW_REFUSED.to_owned())
                }
                s => Some(cip::cip_status(s, reply.ext)),
            });
        }
        for (r, outcome) in group.iter().zip(outcomes) {
            match outcome {
                None => written(device, &items[r.item], 1),
                Some(why) => finish(device, &items[r.item], Err(WriteError::Refused(why)), 1),
            }
        }
        Ok(sent)
    }
}

/// What sending a packet of writes found.
enum Sent {
    /// Each write finished with its reply.
    Done,
    /// The controller has no Multiple Service Packets: none finished, each to be sent alone.
    NoMultiple,
    /// The controller has no Read-Modify-Write Tag: the bit's write refused so.
    NoBitWrites,
}

/// Why a bit of an integer is not written, when the controller refused Read-Modify-Write
/// Tag or closed the connection when asked for it.
const NO_RMW_REFUSED: &str = "the controller does not support Read-Modify-Write Tag: a bit of an integer is not written (writing the whole integer from a value read earlier would undo the controller's own changes to its other bits); write a BOOL tag, or the whole integer as a field of its own";
const NO_RMW_CLOSED: &str = "the controller closed the connection when asked for Read-Modify-Write Tag (it does not support it): a bit of an integer is not written (writing the whole integer from a value read earlier would undo the controller's own changes to its other bits); write a BOOL tag, or the whole integer as a field of its own";

/// A packet refused whole: every write in it, with why.
fn refuse_all(device: &Device, items: &[WriteItem], group: &[&Ready], why: &str) {
    for r in group {
        let refused = Err(WriteError::Refused(why.to_owned()));
        finish(device, &items[r.item], refused, 1);
    }
}

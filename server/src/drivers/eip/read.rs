//! Reading a device: its reads (one tag, or consecutive elements of one array read
//! together) packed in Multiple Service Packets within the connection's size (a controller
//! without them, CIP status 0x08, gets one Read Tag a request, remembered for the link); a read too
//! large for a packet sent alone with Read Tag Fragmented, a part at a time. Each reply's
//! status is its fields' error; elements read together whose read failed (one of them past
//! the array's end, say) are read one by one from then on, and at once.

use super::plan::{fragmented, packet_sizes, packets, runs};
use super::{Controller, Plan, cip, lost, value};
use crate::cache::{Device, FieldError, Stamp};
use crate::link::LinkFault;

/// A device's reads packed for a connection of `limit` bytes, each packet with its
/// request built: kept from cycle to cycle, made again when what it depends on changes (a
/// type learned, an element set apart, a read found to need fragments: `Plan::repack`).
pub(super) struct Packed {
    limit: usize,
    /// One read a request, without Multiple Service Packets.
    single: bool,
    reads: Vec<Vec<usize>>,
    /// Each packet's reads and its request (none for a read sent fragmented).
    packets: Vec<(Vec<usize>, Option<Vec<u8>>)>,
}

impl Packed {
    fn new(
        plan: &Plan,
        device: &Device,
        reads: Vec<Vec<usize>>,
        limit: usize,
        single: bool,
    ) -> Packed {
        let sizes: Vec<(usize, usize, usize)> = reads
            .iter()
            .enumerate()
            .map(|(r, fields)| {
                let first = fields[0];
                let (ask, answer) = plan.tags[first].as_ref().map_or((0, 0), |t| {
                    let ty = device.profile.fields[first].ty;
                    packet_sizes(t, ty, plan.codes[first], fields.len())
                });
                // A read the controller answered in part goes alone, fragmented.
                let answer = if plan.fragment[first] && fields.len() > 1 {
                    answer.max(limit)
                } else {
                    answer
                };
                (r, ask, answer)
            })
            .collect();
        let packed = match single {
            true => (0..reads.len()).map(|r| vec![r]).collect(),
            false => packets(&sizes, limit),
        };
        let packets = packed
            .into_iter()
            .map(|packet| {
                let request = match packet.as_slice() {
                    [one] if fragmented(sizes[*one].2, limit) => None,
                    [one] if single => plan.tags[reads[*one][0]]
                        .as_ref()
                        .ok()
                        .map(|tag| cip::read_tag(&tag.path, reads[*one].len() as u16)),
                    _ => {
                        let requests: Vec<Vec<u8>> = packet
                            .iter()
                            .filter_map(|&r| {
                                let tag = plan.tags[reads[r][0]].as_ref().ok()?;
                                Some(cip::read_tag(&tag.path, reads[r].len() as u16))
                            })
                            .collect();
                        Some(cip::multiple(&requests))
                    }
                };
                (packet, request)
            })
            .collect();
        Packed {
            limit,
            single,
            reads,
            packets,
        }
    }
}

impl Controller {
    /// Reads every readable field of the device and publishes each.
    pub(super) async fn read_device(
        &mut self,
        device: &Device,
        plan: &mut Plan,
    ) -> Result<(), LinkFault> {
        let limit = self.conn.message_limit();
        let single = self.single;
        let packed = match plan.packed.take() {
            Some(p) if p.limit == limit && p.single == single => p,
            _ => {
                let reads = runs(&plan.tags, &device.profile, &plan.alone);
                Packed::new(plan, device, reads, limit, single)
            }
        };
        plan.repack = false;
        let read = self.read_all(device, plan, &packed).await;
        if !plan.repack {
            plan.packed = Some(packed);
        }
        let mut failed = read?;
        if self.single && !single {
            // The controller has no Multiple Service Packets: every read again, alone.
            let reads = runs(&plan.tags, &device.profile, &plan.alone);
            let packed = Packed::new(plan, device, reads, limit, true);
            failed = self.read_all(device, plan, &packed).await?;
            plan.packed = Some(packed);
        }
        if !failed.is_empty() {
            for &i in &failed {
                plan.alone[i] = true;
            }
            plan.packed = None;
            let singles = failed.iter().map(|&i| vec![i]).collect();
            let singles = Packed::new(plan, device, singles, limit, self.single);
            self.read_all(device, plan, &singles).await?;
        }
        Ok(())
    }

    /// Reads the packed reads; the fields of the reads of several elements that failed.
    async fn read_all(
        &mut self,
        device: &Device,
        plan: &mut Plan,
        packed: &Packed,
    ) -> Result<Vec<usize>, LinkFault> {
        let mut failed = Vec::new();
        let mut partial = Vec::new();
        for (packet, request) in &packed.packets {
            let group: Vec<&[usize]> = packet.iter().map(|&r| packed.reads[r].as_slice()).collect();
            match (group.as_slice(), request) {
                ([one], None) => {
                    self.read_fragmented(device, plan, one, &mut failed).await?;
                }
                (_, Some(request)) => {
                    let retry = (&mut failed, &mut partial);
                    let bare = packed.single;
                    self.read_packet(device, plan, (&group, request, bare), retry)
                        .await?;
                }
                _ => {}
            }
        }
        // Reads the controller answered in part (more than it puts in one reply): read
        // fragmented now and from now on.
        for run in partial {
            plan.fragment[run[0]] = true;
            plan.repack = true;
            self.read_fragmented(device, plan, &run, &mut failed)
                .await?;
        }
        Ok(failed)
    }

    /// Reads one packet's reads (`bare`: one Read Tag, not in a Multiple Service Packet)
    /// and publishes their fields.
    async fn read_packet(
        &mut self,
        device: &Device,
        plan: &mut Plan,
        (group, request, bare): (&[&[usize]], &[u8], bool),
        (failed, partial): (&mut Vec<usize>, &mut Vec<Vec<usize>>),
    ) -> Result<(), LinkFault> {
        let answer = self.request(request).await?;
        let now = Stamp::now();
        let every = |why: String| {
            for &i in group.iter().flat_map(|r| r.iter()) {
                device.publish_at(i, Err(FieldError::Device(why.clone())), now);
            }
        };
        let answer = match answer {
            Ok(a) => a,
            Err(why) => {
                every(why);
                return Ok(());
            }
        };
        let replies = if bare {
            vec![answer.as_slice()]
        } else {
            let outer = cip::reply(&answer).map_err(|e| lost(e.into()))?;
            outer.answers(cip::MULTIPLE).map_err(|e| lost(e.into()))?;
            if outer.status == SERVICE_NOT_SUPPORTED && !self.single {
                // Read again, one Read Tag a request, by the caller.
                self.no_multiple();
                return Ok(());
            }
            if outer.status != 0 && outer.status != 0x1E {
                every(cip::cip_status(outer.status, outer.ext));
                return Ok(());
            }
            cip::multiple_replies(outer.data, group.len()).map_err(|e| lost(e.into()))?
        };
        for (&run, bytes) in group.iter().zip(replies) {
            match cip::reply(bytes).and_then(|r| r.answers(cip::READ_TAG).map(|()| r)) {
                Ok(r) if r.status == 0 => publish(device, plan, run, r.data, now),
                Ok(r) if r.status == 0x06 && run.len() > 1 => partial.push(run.to_vec()),
                Ok(r) if run.len() > 1 => {
                    apart(device, run, &cip::cip_status(r.status, r.ext));
                    failed.extend_from_slice(run);
                }
                Ok(r) => publish_error(device, run, &cip::cip_status(r.status, r.ext), now),
                Err(e) => publish_error(device, run, &e.to_string(), now),
            }
        }
        Ok(())
    }

    /// Reads one read too large for a packet with Read Tag Fragmented, a part at a time.
    async fn read_fragmented(
        &mut self,
        device: &Device,
        plan: &mut Plan,
        run: &[usize],
        failed: &mut Vec<usize>,
    ) -> Result<(), LinkFault> {
        let Ok(tag) = plan.tags[run[0]].as_ref().map(|t| t.path.clone()) else {
            return Ok(());
        };
        // The most a reply may hold: the largest atomic type of each element.
        let most = 8 * run.len();
        let mut code: Option<[u8; 2]> = None;
        let mut data = Vec::new();
        loop {
            let message = cip::read_fragmented(&tag, run.len() as u16, data.len() as u32);
            let answer = match self.request(&message).await? {
                Ok(a) => a,
                Err(why) => {
                    publish_error(device, run, &why, Stamp::now());
                    return Ok(());
                }
            };
            let r = cip::reply(&answer).map_err(|e| lost(e.into()))?;
            r.answers(cip::READ_FRAGMENTED)
                .map_err(|e| lost(e.into()))?;
            if r.status != 0 && r.status != 0x06 {
                if run.len() > 1 {
                    apart(device, run, &cip::cip_status(r.status, r.ext));
                    failed.extend_from_slice(run);
                } else {
                    publish_error(device, run, &cip::cip_status(r.status, r.ext), Stamp::now());
                }
                return Ok(());
            }
            let (head, part) = r.data.split_at_checked(2).unwrap_or((&[], &[]));
            let why = match code {
                _ if head.len() < 2 => Some("a part without its type"),
                Some(c) if c != head => Some("parts of different types"),
                _ if part.is_empty() && r.status == 0x06 => Some("a part without data"),
                _ if data.len() + part.len() > most => Some("more data than the elements hold"),
                _ => None,
            };
            if let Some(why) = why {
                let why = format!("a fragmented read answered with {why}");
                publish_error(device, run, &why, Stamp::now());
                return Ok(());
            }
            code = Some([head[0], head[1]]);
            data.extend_from_slice(part);
            if r.status == 0 {
                break;
            }
        }
        let mut whole = code.map_or_else(Vec::new, |c| c.to_vec());
        whole.extend_from_slice(&data);
        publish(device, plan, run, &whole, Stamp::now());
        Ok(())
    }
}

/// CIP's general status "service not supported".
pub(super) const SERVICE_NOT_SUPPORTED: u8 = 0x08;

/// Tells that a read of elements together failed and they are read one by one.
fn apart(device: &Device, run: &[usize], why: &str) {
    let first = &device.profile.fields[run[0]].name;
    tracing::info!(device = %device.name(), first = %first, elements = run.len(), why, "a read of elements together failed: reading them one by one");
}

fn publish_error(device: &Device, run: &[usize], why: &str, now: Stamp) {
    for &i in run {
        device.publish_at(i, Err(FieldError::Device(why.to_owned())), now);
    }
}

/// A good reply's data (the type, then the values) published as the read's fields.
fn publish(device: &Device, plan: &mut Plan, run: &[usize], data: &[u8], now: Stamp) {
    if let [idx] = run {
        let idx = *idx;
        let bit = plan.tags[idx].as_ref().ok().and_then(|t| t.bit);
        plan.layouts[idx] = value::layout(data);
        match value::decode(data, device.profile.fields[idx].ty, bit) {
            Ok((code, v)) => {
                plan.set_code(idx, code);
                device.publish_at(idx, Ok(v), now);
            }
            Err(why) => device.publish_at(idx, Err(FieldError::Device(why)), now),
        }
        return;
    }
    let Some(head) = data.get(..2) else {
        return publish_error(device, run, "a reply without its type", now);
    };
    let code = u16::from_le_bytes([head[0], head[1]]);
    if code == 0x02A0 {
        let why = value::decode(data, device.profile.fields[run[0]].ty, None).err();
        return publish_error(device, run, &why.unwrap_or_default(), now);
    }
    let size = cip::value_len(code);
    let values = &data[2..];
    if values.len() != size * run.len() {
        let why = format!(
            "a reply of {} bytes for {} elements of {size} bytes",
            values.len(),
            run.len()
        );
        return publish_error(device, run, &why, now);
    }
    let mut one = head.to_vec();
    for (&idx, chunk) in run.iter().zip(values.chunks_exact(size)) {
        one.truncate(2);
        one.extend_from_slice(chunk);
        match value::decode(&one, device.profile.fields[idx].ty, None) {
            Ok((code, v)) => {
                plan.set_code(idx, code);
                device.publish_at(idx, Ok(v), now);
            }
            Err(why) => device.publish_at(idx, Err(FieldError::Device(why)), now),
        }
    }
}

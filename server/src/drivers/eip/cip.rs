//! EtherNet/IP's bytes: the encapsulation header, the common packet format of SendRRData,
//! CIP requests routed through the Connection Manager's Unconnected Send, the Logix tag
//! services (Read Tag, Write Tag) and Multiple Service Packets. Every length in an answer
//! is checked before it is used: a short or inconsistent answer is a `Malformed` naming
//! what was wrong.

/// Encapsulation commands.
pub(super) const REGISTER_SESSION: u16 = 0x65;
pub(super) const UNREGISTER_SESSION: u16 = 0x66;
pub(super) const SEND_RR_DATA: u16 = 0x6F;
pub(super) const LIST_IDENTITY: u16 = 0x63;
pub(super) const SEND_UNIT_DATA: u16 = 0x70;

/// CIP services.
pub(super) const READ_TAG: u8 = 0x4C;
pub(super) const READ_FRAGMENTED: u8 = 0x52;
pub(super) const WRITE_TAG: u8 = 0x4D;
pub(super) const MULTIPLE: u8 = 0x0A;
pub(super) const READ_MODIFY_WRITE: u8 = 0x4E;
const UNCONNECTED_SEND: u8 = 0x52;

/// The encapsulation header's length.
pub(super) const HEADER: usize = 24;

/// What is wrong with an answer.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub(crate) enum Malformed {
    #[error("an answer shorter than its {0}")]
    Short(&'static str),
    #[error("the encapsulation status {code:#010x} ({why})", code = .0, why = encapsulation_status(*.0))]
    Encapsulation(u32),
    #[error("an answer to command {got:#06x}, not to {asked:#06x}")]
    Command { asked: u16, got: u16 },
    #[error("no unconnected data item in the answer")]
    NoData,
    #[error("an answer to service {got:#04x}, not to {asked:#04x}")]
    Service { asked: u8, got: u8 },
    #[error("{0}")]
    Refused(String),
    /// The Unconnected Send's own error reply: the request did not reach the controller
    /// (a module on the route missing or not answering). The link stays in step.
    #[error("the route to the controller failed: {why}{hint}", why = cip_status(*status, *ext), hint = route_hint(*status))]
    Route { status: u8, ext: Option<u16> },
}

fn encapsulation_status(status: u32) -> &'static str {
    match status {
        0x01 => "invalid or unsupported command",
        0x02 => "no memory for the command",
        0x03 => "incorrect data",
        0x64 => "invalid session handle",
        0x65 => "invalid length",
        0x69 => "unsupported protocol version",
        _ => "not one the specification names",
    }
}

/// What to do about a route refused as unknown (no Connection Manager routes it).
fn route_hint(status: u8) -> &'static str {
    match status {
        0x08 => "; a controller that answers itself (a Micro800, a simulator) takes `path: \"\"`",
        _ => "",
    }
}

/// The general status of a CIP reply, as Rockwell's manuals name it.
pub(crate) fn cip_status(status: u8, ext: Option<u16>) -> String {
    let what = match status {
        0x01 => "connection failure",
        0x02 => "resource unavailable",
        0x04 => "path segment error (the tag does not exist, or its name is wrong)",
        0x05 => "path destination unknown (no such tag or element)",
        0x06 => "partial transfer (more data than fits the answer)",
        0x08 => "service not supported",
        0x0A => "attribute list error",
        0x0C => "object state conflict",
        0x10 => "device state conflict (the controller is in a mode that refuses it)",
        0x13 => "not enough data",
        0x15 => "too much data",
        0x1E => "embedded service error",
        0x20 => "invalid parameter",
        0x26 => "path size invalid",
        0xFF => match ext {
            Some(0x2105) => "general error: access beyond the end of the object",
            Some(0x2107) => "general error: the tag's type differs from the data's",
            Some(0x2104) => "general error: offset beyond the end of the tag",
            _ => "general error",
        },
        _ => "error",
    };
    match ext {
        Some(e) => format!("CIP status {status:#04x} ({what}), extended {e:#06x}"),
        None => format!("CIP status {status:#04x} ({what})"),
    }
}

/// An encapsulation packet: `command` with `data`, in `session`.
pub(super) fn encapsulate(command: u16, session: u32, context: u64, data: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(HEADER + data.len());
    out.extend_from_slice(&command.to_le_bytes());
    out.extend_from_slice(&(data.len() as u16).to_le_bytes());
    out.extend_from_slice(&session.to_le_bytes());
    out.extend_from_slice(&0u32.to_le_bytes());
    out.extend_from_slice(&context.to_le_bytes());
    out.extend_from_slice(&0u32.to_le_bytes());
    out.extend_from_slice(data);
    out
}

/// A header's command, length, session, status and sender context.
pub(super) struct Header {
    pub(super) command: u16,
    pub(super) length: usize,
    pub(super) session: u32,
    pub(super) status: u32,
    pub(super) context: u64,
}

pub(super) fn header(b: &[u8]) -> Result<Header, Malformed> {
    let b = b.get(..HEADER).ok_or(Malformed::Short("header"))?;
    let u16_at = |i: usize| u16::from_le_bytes([b[i], b[i + 1]]);
    let u32_at = |i: usize| u32::from_le_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]);
    let mut context = [0u8; 8];
    context.copy_from_slice(&b[12..20]);
    Ok(Header {
        command: u16_at(0),
        length: usize::from(u16_at(2)),
        session: u32_at(4),
        status: u32_at(8),
        context: u64::from_le_bytes(context),
    })
}

/// RegisterSession's data: protocol version 1, no options.
pub(super) fn register_session() -> Vec<u8> {
    vec![1, 0, 0, 0]
}

/// SendRRData's data around an unconnected message `mr`.
pub(super) fn send_rr_data(mr: &[u8], timeout_s: u16) -> Vec<u8> {
    let mut d = Vec::with_capacity(16 + mr.len());
    d.extend_from_slice(&0u32.to_le_bytes()); // interface handle: CIP
    d.extend_from_slice(&timeout_s.to_le_bytes());
    d.extend_from_slice(&2u16.to_le_bytes()); // two items
    d.extend_from_slice(&[0, 0, 0, 0]); // null address item
    d.extend_from_slice(&0x00B2u16.to_le_bytes()); // unconnected data item
    d.extend_from_slice(&(mr.len() as u16).to_le_bytes());
    d.extend_from_slice(mr);
    d
}

/// The body of the first item of `kind` in a common packet format answer (SendRRData's or
/// SendUnitData's data: interface handle, timeout, then the items).
fn cpf_item(data: &[u8], kind: u16) -> Result<&[u8], Malformed> {
    let count = u16_le(data, 6, "item count")?;
    let mut at = 8;
    for _ in 0..count {
        let this = u16_le(data, at, "item")?;
        let len = usize::from(u16_le(data, at + 2, "item")?);
        let body = data
            .get(at + 4..at + 4 + len)
            .ok_or(Malformed::Short("item"))?;
        if this == kind {
            return Ok(body);
        }
        at += 4 + len;
    }
    Err(Malformed::NoData)
}

/// The unconnected data item's message of a SendRRData answer.
pub(super) fn rr_data_reply(data: &[u8]) -> Result<&[u8], Malformed> {
    cpf_item(data, 0x00B2)
}

fn u16_le(b: &[u8], at: usize, what: &'static str) -> Result<u16, Malformed> {
    b.get(at..at + 2)
        .map(|s| u16::from_le_bytes([s[0], s[1]]))
        .ok_or(Malformed::Short(what))
}

/// A CIP request: `service` to the object at `path` (an even number of bytes), with `data`.
pub(super) fn request(service: u8, path: &[u8], data: &[u8]) -> Vec<u8> {
    let mut r = Vec::with_capacity(2 + path.len() + data.len());
    r.push(service);
    r.push((path.len() / 2) as u8);
    r.extend_from_slice(path);
    r.extend_from_slice(data);
    r
}

/// `message` routed by the Connection Manager to the module at `route` (port segments,
/// `1,0`: the backplane, slot 0); sent as it is where there is no route.
pub(super) fn routed(message: &[u8], route: &[u8]) -> Vec<u8> {
    if route.is_empty() {
        return message.to_vec();
    }
    // Ticks of 1,024 ms, 5 of them: the module gives up on the message after about 5 s.
    let mut data = vec![0x0A, 0x05];
    data.extend_from_slice(&(message.len() as u16).to_le_bytes());
    data.extend_from_slice(message);
    if message.len() % 2 == 1 {
        data.push(0);
    }
    data.push((route.len().div_ceil(2)) as u8);
    data.push(0);
    data.extend_from_slice(route);
    if route.len() % 2 == 1 {
        data.push(0);
    }
    request(UNCONNECTED_SEND, &[0x20, 0x06, 0x24, 0x01], &data)
}

/// Whether `answer`, to `message` routed by an Unconnected Send, is the Unconnected Send's
/// own error reply (Vol. 1, 3-5.5.2: its service with the reply bit, a status not 0). For
/// a message of Read Tag Fragmented, whose service shares the number, only "connection
/// failure" (0x01: timed out, no such port or address on the route), which a tag never
/// answers, is the route's; its other statuses are the read's own.
pub(super) fn route_failed(message: &[u8], answer: &[u8]) -> Result<(), Malformed> {
    let fragmented = message.first() == Some(&READ_FRAGMENTED);
    match reply(answer) {
        Ok(r)
            if r.service == UNCONNECTED_SEND | 0x80
                && r.status != 0
                && (!fragmented || r.status == 0x01) =>
        {
            Err(Malformed::Route {
                status: r.status,
                ext: r.ext,
            })
        }
        _ => Ok(()),
    }
}

/// SendUnitData's data: `message` on connection `o_t` with sequence count `seq`.
pub(super) fn send_unit_data(o_t: u32, seq: u16, message: &[u8]) -> Vec<u8> {
    let mut d = Vec::with_capacity(22 + message.len());
    d.extend_from_slice(&0u32.to_le_bytes());
    d.extend_from_slice(&0u16.to_le_bytes());
    d.extend_from_slice(&2u16.to_le_bytes());
    d.extend_from_slice(&0x00A1u16.to_le_bytes());
    d.extend_from_slice(&4u16.to_le_bytes());
    d.extend_from_slice(&o_t.to_le_bytes());
    d.extend_from_slice(&0x00B1u16.to_le_bytes());
    d.extend_from_slice(&((2 + message.len()) as u16).to_le_bytes());
    d.extend_from_slice(&seq.to_le_bytes());
    d.extend_from_slice(message);
    d
}

/// A SendUnitData answer's sequence count and message.
pub(super) fn unit_data_reply(data: &[u8]) -> Result<(u16, &[u8]), Malformed> {
    let body = cpf_item(data, 0x00B1)?;
    let seq = u16_le(body, 0, "sequence count")?;
    Ok((seq, &body[2..]))
}

/// A reply's service, general status, extended status and data.
pub(super) struct Reply<'a> {
    pub(super) service: u8,
    pub(super) status: u8,
    pub(super) ext: Option<u16>,
    pub(super) data: &'a [u8],
}

impl Reply<'_> {
    /// Whether this is the reply to `asked`.
    pub(super) fn answers(&self, asked: u8) -> Result<(), Malformed> {
        if self.service == asked | 0x80 {
            Ok(())
        } else {
            Err(Malformed::Service {
                asked,
                got: self.service & 0x7F,
            })
        }
    }
}

pub(super) fn reply(b: &[u8]) -> Result<Reply<'_>, Malformed> {
    let head = b.get(..4).ok_or(Malformed::Short("reply"))?;
    let ext_words = usize::from(head[3]);
    let data_at = 4 + 2 * ext_words;
    let ext = if ext_words > 0 {
        Some(u16_le(b, 4, "extended status")?)
    } else {
        None
    };
    Ok(Reply {
        service: head[0],
        status: head[2],
        ext,
        data: b
            .get(data_at..)
            .ok_or(Malformed::Short("extended status"))?,
    })
}

/// Read Tag of `count` elements from `path`.
pub(super) fn read_tag(path: &[u8], count: u16) -> Vec<u8> {
    request(READ_TAG, path, &count.to_le_bytes())
}

/// Read Tag Fragmented of `count` elements from `path`, the reply's bytes from `offset`.
pub(super) fn read_fragmented(path: &[u8], count: u16, offset: u32) -> Vec<u8> {
    let mut data = count.to_le_bytes().to_vec();
    data.extend_from_slice(&offset.to_le_bytes());
    request(READ_FRAGMENTED, path, &data)
}

/// Write Tag of one element of type `code` at `path`.
pub(super) fn write_tag(path: &[u8], code: u16, value: &[u8]) -> Vec<u8> {
    let mut data = Vec::with_capacity(4 + value.len());
    data.extend_from_slice(&code.to_le_bytes());
    data.extend_from_slice(&1u16.to_le_bytes());
    data.extend_from_slice(value);
    request(WRITE_TAG, path, &data)
}

/// Multiple Service Packet of `requests` to the Message Router.
pub(super) fn multiple(requests: &[Vec<u8>]) -> Vec<u8> {
    let n = requests.len();
    let mut data = Vec::new();
    data.extend_from_slice(&(n as u16).to_le_bytes());
    let mut offset = 2 + 2 * n;
    for r in requests {
        data.extend_from_slice(&(offset as u16).to_le_bytes());
        offset += r.len();
    }
    for r in requests {
        data.extend_from_slice(r);
    }
    request(MULTIPLE, &[0x20, 0x02, 0x24, 0x01], &data)
}

/// The replies inside a Multiple Service Packet's reply data, `asked` of them.
pub(super) fn multiple_replies(data: &[u8], asked: usize) -> Result<Vec<&[u8]>, Malformed> {
    let n = usize::from(u16_le(data, 0, "reply count")?);
    if n != asked {
        return Err(Malformed::Refused(format!(
            "{n} replies to {asked} requests in one packet"
        )));
    }
    let mut offsets = Vec::with_capacity(n + 1);
    for k in 0..n {
        offsets.push(usize::from(u16_le(data, 2 + 2 * k, "offsets")?));
    }
    offsets.push(data.len());
    (0..n)
        .map(|k| {
            let (from, to) = (offsets[k], offsets[k + 1]);
            if from > to {
                return Err(Malformed::Short("offsets out of order"));
            }
            data.get(from..to).ok_or(Malformed::Short("reply"))
        })
        .collect()
}

/// An atomic type's size in bytes.
pub(super) fn value_len(code: u16) -> usize {
    super::tag::type_len(code)
}

/// A List Identity answer's vendor, product code, revision, serial number and product name.
pub(super) fn identity(data: &[u8]) -> Option<(u16, u16, String, u32, String)> {
    // Item count, then the identity item: type, length, encapsulation version, socket
    // address (16), vendor, device type, product code, revision (2), status, serial,
    // name length and name.
    let item = data.get(2..)?;
    let body = item.get(4..)?;
    let at = |i: usize| body.get(i..i + 2).map(|s| u16::from_le_bytes([s[0], s[1]]));
    let vendor = at(18)?;
    let product = at(22)?;
    let revision = format!("{}.{}", body.get(24)?, body.get(25)?);
    let serial = u32::from_le_bytes(body.get(28..32)?.try_into().ok()?);
    let len = usize::from(*body.get(32)?);
    let name = String::from_utf8_lossy(body.get(33..33 + len)?).into_owned();
    Some((vendor, product, revision, serial, name))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_packet_of_two_reads_routed_to_slot_0_is_laid_out_as_the_specification_says() {
        let a = read_tag(b"\x91\x01A\x00", 1);
        assert_eq!(a, b"\x4c\x02\x91\x01A\x00\x01\x00".to_vec());
        let packet = multiple(&[a.clone(), a.clone()]);
        // Service, path to the Message Router, count 2, offsets 6 and 14.
        assert_eq!(&packet[..6], b"\x0a\x02\x20\x02\x24\x01");
        assert_eq!(&packet[6..12], b"\x02\x00\x06\x00\x0e\x00");
        let routed = routed(&packet, &[1, 0]);
        assert_eq!(&routed[..6], b"\x52\x02\x20\x06\x24\x01");
        let len = usize::from(u16::from_le_bytes([routed[8], routed[9]]));
        assert_eq!(len, packet.len());
        assert_eq!(&routed[routed.len() - 4..], b"\x01\x00\x01\x00");
    }

    #[test]
    fn replies_are_taken_apart_and_short_ones_refused() {
        // A Multiple Service reply of two Read Tag replies: a DINT 7, and status 5.
        let one = b"\xcc\x00\x00\x00\xc4\x00\x07\x00\x00\x00".to_vec();
        let two = b"\xcc\x00\x05\x01\x00\x00".to_vec();
        let mut data = vec![2, 0, 6, 0, (6 + one.len()) as u8, 0];
        data.extend_from_slice(&one);
        data.extend_from_slice(&two);
        let parts = multiple_replies(&data, 2).expect("replies");
        let first = reply(parts[0]).expect("reply");
        assert_eq!(
            (first.service, first.status, first.data.len()),
            (0xCC, 0, 6)
        );
        let second = reply(parts[1]).expect("reply");
        assert_eq!((second.status, second.ext), (5, Some(0)));
        assert!(multiple_replies(&data, 3).is_err());
        assert!(multiple_replies(&data[..5], 2).is_err());
        assert!(reply(b"\xcc\x00").is_err());
        assert!(reply(b"\xcc\x00\x00\x02\x01").is_err());
        assert!(header(&[0u8; 10]).is_err());
        assert!(rr_data_reply(&[0u8; 7]).is_err());
        let mut bad = vec![2, 0, 9, 0, 4, 0];
        bad.extend_from_slice(&one);
        assert!(multiple_replies(&bad, 2).is_err());
    }

    #[test]
    fn connected_messages_are_laid_out_as_the_specification_says() {
        let sent = send_unit_data(9, 3, b"\x4c\x00");
        assert_eq!(&sent[6..8], b"\x02\x00");
        assert_eq!(&sent[8..16], b"\xa1\x00\x04\x00\x09\x00\x00\x00");
        assert_eq!(&sent[16..], b"\xb1\x00\x04\x00\x03\x00\x4c\x00");
        assert_eq!(unit_data_reply(&sent), Ok((3, &b"\x4c\x00"[..])));
        assert!(unit_data_reply(&sent[..19]).is_err());
    }
}

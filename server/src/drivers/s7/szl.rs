//! The PLC's system status list (SZL), read by a user-data job: its identity (order number,
//! module name, serial number) and its operating state (RUN or STOP). A PLC that does not
//! answer an SZL (S7-200, LOGO!) has no identity shown; nothing else depends on it.

use super::pdu::{Answer, Malformed, USER_DATA, message};

/// Read SZL `id` at `index`.
pub(crate) fn request(reference: u16, id: u16, index: u16) -> Vec<u8> {
    let [ih, il] = id.to_be_bytes();
    let [xh, xl] = index.to_be_bytes();
    // Request (0x11), CPU functions (0x4), read SZL (0x01), sequence 0.
    let params = [0x00, 0x01, 0x12, 0x04, 0x11, 0x44, 0x01, 0x00];
    message(
        USER_DATA,
        reference,
        &params,
        &[0xFF, 0x09, 0x00, 0x04, ih, il, xh, xl],
    )
}

/// The records of an SZL answer: each record's bytes.
pub(crate) fn records(a: &Answer<'_>) -> Result<Vec<Vec<u8>>, Malformed> {
    if let Some(why) = &a.refused {
        return Err(why.clone());
    }
    let p = a.params;
    if p.len() < 12 {
        return Err(Malformed::Truncated);
    }
    if p[10] != 0 || p[11] != 0 {
        return Err(Malformed::Refused {
            class: p[10],
            code: p[11],
        });
    }
    let d = a.data;
    let head = d.get(..12).ok_or(Malformed::Truncated)?;
    if head[0] != 0xFF {
        return Err(Malformed::Refused {
            class: 0,
            code: head[0],
        });
    }
    let size = usize::from(u16::from_be_bytes([head[8], head[9]]));
    let count = usize::from(u16::from_be_bytes([head[10], head[11]]));
    let body = &d[12..];
    // A fragmented answer (more records than one PDU) carries the first records only.
    let whole = body.len().checked_div(size).unwrap_or(0);
    Ok(body
        .chunks_exact(size.max(1))
        .take(count.min(whole))
        .map(<[u8]>::to_vec)
        .collect())
}

/// A record's text of `len` bytes from byte 2, after the record's index (NUL and space
/// padded).
pub(crate) fn text(record: &[u8], len: usize) -> Option<String> {
    let t: String = record
        .get(2..(2 + len).min(record.len()))?
        .iter()
        .take_while(|&&b| b != 0)
        .map(|&b| char::from(b))
        .collect();
    let t = t.trim().to_owned();
    (!t.is_empty()).then_some(t)
}

/// SZL ids and indexes read.
pub(crate) const MODULE_ID: u16 = 0x0111;
pub(crate) const COMPONENT_ID: u16 = 0x011C;
pub(crate) const CPU_STATE: u16 = 0x0424;
/// The text lengths of an identification record (the order number) and a component record.
pub(crate) const ORDER_LEN: usize = 20;
pub(crate) const NAME_LEN: usize = 32;
/// Component records: the module's name and its serial number.
pub(crate) const MODULE_NAME: u16 = 2;
pub(crate) const SERIAL: u16 = 5;

/// The operating state in a CPU state record.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Mode {
    Run,
    Stop,
    Other(u8),
}

pub(crate) fn mode(record: &[u8]) -> Option<Mode> {
    Some(match *record.get(3)? {
        0x08 => Mode::Run,
        0x03 | 0x04 => Mode::Stop,
        other => Mode::Other(other),
    })
}

impl std::fmt::Display for Mode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Mode::Run => f.write_str("run"),
            Mode::Stop => f.write_str("stop"),
            Mode::Other(code) => write!(f, "state {code:#04x}"),
        }
    }
}

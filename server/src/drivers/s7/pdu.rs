//! S7comm over ISO-on-TCP (RFC 1006): TPKT and COTP framing, the S7 header, the setup of
//! communication (PDU size negotiation), Read Var and Write Var with several items. Bytes
//! only: every answer is checked strictly against its request (lengths, function, item
//! count, each item's transport size and length) and a malformed one is an error naming
//! what was wrong, never a panic.

pub(crate) use super::plan::Item;

/// Why an answer is not one.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub(crate) enum Malformed {
    #[error("not a TPKT frame (version {0})")]
    Tpkt(u8),
    #[error("a frame of {0} bytes is too short")]
    Short(usize),
    #[error("COTP: expected {expected:#04x}, got {got:#04x}")]
    Cotp { expected: u8, got: u8 },
    #[error("not an S7 header (protocol id {0:#04x})")]
    Protocol(u8),
    #[error("{}", refusal(*class, *code))]
    Refused { class: u8, code: u8 },
    #[error("an answer for function {got:#04x} to a request of {expected:#04x}")]
    Function { expected: u8, got: u8 },
    #[error("{got} items answered for {expected} asked")]
    Items { expected: usize, got: usize },
    #[error("an item's data runs past the answer")]
    Truncated,
    #[error("item {item} of the answer has {got} bytes for {asked} asked")]
    ItemLength {
        item: usize,
        asked: usize,
        got: usize,
    },
    #[error("item {item} of the answer has transport size {size:#04x}, not the one asked")]
    ItemSize { item: usize, size: u8 },
    #[error("the answer has {0} bytes past its last item")]
    Trailing(usize),
    #[error("an answer to job {got} while job {expected} waits")]
    Reference { expected: u16, got: u16 },
    #[error("an answer split over COTP data frames passes {0} bytes")]
    Reassembled(usize),
}

const TPKT_VERSION: u8 = 3;
const COTP_CR: u8 = 0xE0;
const COTP_CC: u8 = 0xD0;
const COTP_DT: u8 = 0xF0;
const S7_ID: u8 = 0x32;
const JOB: u8 = 0x01;
const ACK_DATA: u8 = 0x03;
pub(crate) const USER_DATA: u8 = 0x07;
pub(crate) const SETUP: u8 = 0xF0;
pub(crate) const READ: u8 = 0x04;
pub(crate) const WRITE: u8 = 0x05;

/// The bytes of a PDU of the S7 header and payload, in a COTP data frame and TPKT.
fn tpkt(payload: &[u8]) -> Vec<u8> {
    let len = (payload.len() + 4) as u16;
    let mut out = vec![TPKT_VERSION, 0, (len >> 8) as u8, len as u8];
    out.extend_from_slice(payload);
    out
}

/// COTP connection request from `local` to `remote` TSAP, TPDU size 1024.
pub(crate) fn connect_request(local: u16, remote: u16) -> Vec<u8> {
    let [lh, ll] = local.to_be_bytes();
    let [rh, rl] = remote.to_be_bytes();
    tpkt(&[
        17, COTP_CR, 0, 0, 0, 1, 0, 0xC0, 1, 0x0A, 0xC1, 2, lh, ll, 0xC2, 2, rh, rl,
    ])
}

/// Checks a COTP connection confirm (the TPKT payload).
pub(crate) fn connect_confirm(payload: &[u8]) -> Result<(), Malformed> {
    let got = *payload.get(1).ok_or(Malformed::Short(payload.len()))?;
    if got & 0xF0 != COTP_CC {
        return Err(Malformed::Cotp {
            expected: COTP_CC,
            got,
        });
    }
    Ok(())
}

/// An S7 job in a COTP data frame.
fn job(reference: u16, params: &[u8], data: &[u8]) -> Vec<u8> {
    message(JOB, reference, params, data)
}

/// An S7 message of a kind (a job, user data) in a COTP data frame.
pub(crate) fn message(kind: u8, reference: u16, params: &[u8], data: &[u8]) -> Vec<u8> {
    let mut p = vec![2, COTP_DT, 0x80, S7_ID, kind, 0, 0];
    p.extend_from_slice(&reference.to_be_bytes());
    p.extend_from_slice(&(params.len() as u16).to_be_bytes());
    p.extend_from_slice(&(data.len() as u16).to_be_bytes());
    p.extend_from_slice(params);
    p.extend_from_slice(data);
    tpkt(&p)
}

/// Setup communication, asking for a PDU of `pdu` bytes and `parallel` jobs at a time.
pub(crate) fn setup(reference: u16, pdu: u16, parallel: u16) -> Vec<u8> {
    let [h, l] = pdu.to_be_bytes();
    let [ph, pl] = parallel.to_be_bytes();
    job(reference, &[SETUP, 0, ph, pl, ph, pl, h, l], &[])
}

fn item_spec(item: &Item) -> [u8; 12] {
    let (size, bits) = match item.bit {
        _ if item.cells() => (item.area.code(), item.byte),
        Some(b) => (0x01, item.byte * 8 + u32::from(b)),
        None => (0x02, item.byte * 8),
    };
    let [lh, ll] = item.length.to_be_bytes();
    let [dh, dl] = item.db.to_be_bytes();
    [
        0x12,
        0x0A,
        0x10,
        size,
        lh,
        ll,
        dh,
        dl,
        item.area.code(),
        (bits >> 16) as u8,
        (bits >> 8) as u8,
        bits as u8,
    ]
}

/// Read Var of `items`.
pub(crate) fn read(reference: u16, items: &[Item]) -> Vec<u8> {
    let mut params = vec![READ, items.len() as u8];
    for item in items {
        params.extend_from_slice(&item_spec(item));
    }
    job(reference, &params, &[])
}

/// Write Var of `items` with their `values` (a bit's value is one byte, 0 or 1).
pub(crate) fn write(reference: u16, items: &[(Item, Vec<u8>)]) -> Vec<u8> {
    let mut params = vec![WRITE, items.len() as u8];
    let mut data = Vec::new();
    for (n, (item, value)) in items.iter().enumerate() {
        params.extend_from_slice(&item_spec(item));
        let (size, length) = match item.bit {
            _ if item.cells() => (0x09, value.len() as u16),
            Some(_) => (0x03, 1u16),
            None => (0x04, (value.len() * 8) as u16),
        };
        data.extend_from_slice(&[0, size]);
        data.extend_from_slice(&length.to_be_bytes());
        data.extend_from_slice(value);
        if value.len() % 2 == 1 && n + 1 < items.len() {
            data.push(0);
        }
    }
    job(reference, &params, &data)
}

/// An S7 answer: its function's parameters and its data.
#[derive(Debug, PartialEq, Eq)]
pub(crate) struct Answer<'a> {
    pub(crate) reference: u16,
    pub(crate) params: &'a [u8],
    pub(crate) data: &'a [u8],
    /// The PLC's refusal of the whole job (its error class and code), if it refused it.
    pub(crate) refused: Option<Malformed>,
}

impl Answer<'_> {
    /// The answer, unless the PLC refused the job.
    fn accepted(&self) -> Result<&Self, Malformed> {
        match &self.refused {
            Some(why) => Err(why.clone()),
            None => Ok(self),
        }
    }
}

/// The COTP data frame's flag of its last data unit (EOT).
const EOT: u8 = 0x80;

/// Whether a TPKT payload is a COTP data frame that is not the last of its answer.
pub(crate) fn more_to_come(payload: &[u8]) -> bool {
    payload.get(1) == Some(&COTP_DT) && payload.get(2).is_some_and(|n| n & EOT == 0)
}

/// The user data of a COTP data frame (after its header).
pub(crate) fn data_unit(payload: &[u8]) -> Result<&[u8], Malformed> {
    let short = || Malformed::Short(payload.len());
    let cotp_len = usize::from(*payload.first().ok_or_else(short)?);
    let kind = *payload.get(1).ok_or_else(short)?;
    if kind != COTP_DT {
        return Err(Malformed::Cotp {
            expected: COTP_DT,
            got: kind,
        });
    }
    payload.get(cotp_len + 1..).ok_or_else(short)
}

/// Marks the first frame of a reassembled answer as the last data unit.
pub(crate) fn mark_last(payload: &mut [u8]) {
    if let Some(n) = payload.get_mut(2) {
        *n |= EOT;
    }
}

/// Splits a TPKT payload (COTP data frame) into the S7 answer, checking every length.
pub(crate) fn answer(payload: &[u8]) -> Result<Answer<'_>, Malformed> {
    let short = || Malformed::Short(payload.len());
    let s7 = data_unit(payload)?;
    if s7.len() < 10 {
        return Err(Malformed::Short(payload.len()));
    }
    if s7[0] != S7_ID {
        return Err(Malformed::Protocol(s7[0]));
    }
    // An acknowledgement carries an error class and code; user data (SZL) does not.
    let head = match s7[1] {
        ACK_DATA if s7.len() >= 12 => 12,
        USER_DATA => 10,
        got => {
            return Err(Malformed::Function {
                expected: ACK_DATA,
                got,
            });
        }
    };
    let reference = u16::from_be_bytes([s7[4], s7[5]]);
    let plen = usize::from(u16::from_be_bytes([s7[6], s7[7]]));
    let dlen = usize::from(u16::from_be_bytes([s7[8], s7[9]]));
    let refused = (head == 12 && (s7[10] != 0 || s7[11] != 0)).then(|| Malformed::Refused {
        class: s7[10],
        code: s7[11],
    });
    // A refusal may come without the parameters and data it announces.
    let params = s7.get(head..head + plen).unwrap_or_default();
    let data = s7.get(head + plen..head + plen + dlen).unwrap_or_default();
    if refused.is_none() && (params.len() != plen || data.len() != dlen) {
        return Err(short());
    }
    Ok(Answer {
        reference,
        params,
        data,
        refused,
    })
}

/// The PDU size and the jobs at a time (sent before their answers) the PLC granted in its
/// answer to setup communication.
pub(crate) fn granted(a: &Answer<'_>) -> Result<(u16, u16), Malformed> {
    let a = a.accepted()?;
    if a.params.first() != Some(&SETUP) {
        return Err(Malformed::Function {
            expected: SETUP,
            got: a.params.first().copied().unwrap_or(0),
        });
    }
    let b = a.params.get(2..8).ok_or(Malformed::Truncated)?;
    Ok((
        u16::from_be_bytes([b[4], b[5]]),
        u16::from_be_bytes([b[0], b[1]]),
    ))
}

/// The bytes an answer's item holds, from its transport size and length: bit and
/// byte/word/integer sizes count bits, octet strings and reals bytes; `None` for a size no
/// read answer has, or a bit count that is not whole bytes (but a single bit).
fn answered_bytes(size: u8, raw: usize) -> Option<usize> {
    match size {
        TS_BIT if raw == 1 => Some(1),
        0x04 | 0x05 if raw.is_multiple_of(8) => Some(raw / 8),
        0x07 | 0x09 => Some(raw),
        _ => None,
    }
}

/// The bytes item `item` asks for (a bit is one byte).
fn asked_bytes(item: &Item) -> usize {
    match item.bit {
        _ if item.cells() => usize::from(item.length) * 2,
        Some(_) => 1,
        None => usize::from(item.length),
    }
}

const TS_BIT: u8 = 0x03;

/// Each item's bytes, or its return code when not 0xFF (success). Every item is checked
/// against its request (`items`): its transport size (a bit for a bit) and its length, so
/// an answer longer, shorter or of another size than asked is an error, never a value
/// shifted into the next field.
pub(crate) fn read_items(
    a: &Answer<'_>,
    items: &[Item],
) -> Result<Vec<Result<Vec<u8>, u8>>, Malformed> {
    let a = a.accepted()?;
    if a.params.first() != Some(&READ) {
        return Err(Malformed::Function {
            expected: READ,
            got: a.params.first().copied().unwrap_or(0),
        });
    }
    let count = usize::from(*a.params.get(1).ok_or(Malformed::Truncated)?);
    if count != items.len() {
        return Err(Malformed::Items {
            expected: items.len(),
            got: count,
        });
    }
    let mut out = Vec::with_capacity(count);
    let mut at = 0;
    for (n, item) in items.iter().enumerate() {
        let head = a.data.get(at..at + 4).ok_or(Malformed::Truncated)?;
        let (code, size) = (head[0], head[1]);
        let raw = usize::from(u16::from_be_bytes([head[2], head[3]]));
        at += 4;
        if code != 0xFF {
            out.push(Err(code));
            continue;
        }
        let asked = asked_bytes(item);
        let len = answered_bytes(size, raw)
            .filter(|_| (size == TS_BIT) == (item.bit.is_some() && !item.cells()))
            .ok_or(Malformed::ItemSize { item: n + 1, size })?;
        if len != asked {
            return Err(Malformed::ItemLength {
                item: n + 1,
                asked,
                got: len,
            });
        }
        let bytes = a.data.get(at..at + len).ok_or(Malformed::Truncated)?;
        out.push(Ok(bytes.to_vec()));
        at += len;
        if len % 2 == 1 && n + 1 < count {
            at += 1;
        }
    }
    // A fill byte after an odd last item is tolerated (some PLCs send one); more is not.
    let fill = usize::from(
        out.last()
            .is_some_and(|i| i.as_ref().is_ok_and(|b| b.len() % 2 == 1)),
    );
    if a.data.len() > at + fill {
        return Err(Malformed::Trailing(a.data.len() - at));
    }
    Ok(out)
}

/// `n` items of several kinds (bits, bytes of several lengths, counters), for the fuzz
/// targets and property tests of the answer parsers.
#[cfg(any(fuzzing, test))]
pub(crate) fn fuzz_items(n: usize) -> Vec<Item> {
    use crate::drivers::s7::address::Area;
    (0..n)
        .map(|k| Item {
            area: if k % 7 == 6 {
                Area::Counters
            } else {
                Area::DataBlock
            },
            db: 1,
            byte: 0,
            bit: (k % 3 == 0).then_some(1),
            length: (k % 5 + 1) as u16,
        })
        .collect()
}

/// Each written item's return code: `Ok` for 0xFF.
pub(crate) fn write_items(a: &Answer<'_>, asked: usize) -> Result<Vec<Result<(), u8>>, Malformed> {
    let a = a.accepted()?;
    if a.params.first() != Some(&WRITE) {
        return Err(Malformed::Function {
            expected: WRITE,
            got: a.params.first().copied().unwrap_or(0),
        });
    }
    if a.data.len() != asked {
        return Err(Malformed::Items {
            expected: asked,
            got: a.data.len(),
        });
    }
    Ok(a.data
        .iter()
        .map(|&c| if c == 0xFF { Ok(()) } else { Err(c) })
        .collect())
}

/// What the PLC's refusal of a whole job says, and what to change on the PLC.
pub(crate) fn refusal(class: u8, code: u8) -> String {
    let what = match (class, code) {
        (0x81, 0x04) => {
            "function not available: on an S7-1200/1500 tick \"Permit access with PUT/GET communication from remote partner\" in the CPU's Protection & Security settings and download"
        }
        (0x80, 0x01) => "not allowed in the PLC's operating state (switch it to RUN)",
        (0x81, 0x03) => {
            "access not allowed: allow PUT/GET in the CPU's Protection & Security settings and lower its protection level"
        }
        (0x83, 0x04) => {
            "the PLC has no resource left for another connection: close others or give it more in the CPU's connection resources"
        }
        (0x85, 0x00) => "the job does not fit the PDU size the PLC granted",
        (0xD6, _) => {
            "the CPU's protection refuses it: lower its protection level (or set the access password) in the hardware configuration"
        }
        (0x87, _) => "access error: check the area and the address",
        _ => "refused",
    };
    format!("the PLC refused the job (error {class:02X}{code:02X}): {what}")
}

/// An item's return code for an address past the end of its block or area.
pub(crate) const OUT_OF_RANGE: u8 = 0x05;

/// What an item's return code says.
pub(crate) fn item_error(code: u8) -> &'static str {
    match code {
        0x01 => "hardware fault",
        0x03 => {
            "access denied: allow PUT/GET in the CPU's Protection & Security settings, and the block must not be know-how protected"
        }
        0x05 => {
            "address out of range: past the end of the block or area, or (S7-1200/1500) the DB has \"Optimized block access\" on; turn it off in the DB's attributes so its variables have offsets"
        }
        0x06 => "data type not supported",
        0x07 => "data type inconsistent",
        0x0A => {
            "object does not exist: no such data block (or area) in the PLC; download it or correct the address"
        }
        _ => "refused",
    }
}

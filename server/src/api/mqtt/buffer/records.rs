//! The buffer's files: a record's bytes (`[len u32][crc32 u32][body]`), a segment read
//! through on open (a torn tail cut off), the `head` file.

use super::*;

/// What a record is published as.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Kind {
    /// A JSON field message: `payload` is the JSON, published under `<prefix>/history/`.
    Json = 1,
    /// A Sparkplug metric of a device: `payload` is the encoded `Metric`, without name or alias
    /// (earlier versions kept it named).
    Sparkplug = 2,
}

/// One buffered message.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Record {
    /// When it was made (ms since the Unix epoch); `max_age` counts from here.
    pub(crate) at_ms: u64,
    pub(crate) kind: Kind,
    pub(crate) device: String,
    pub(crate) field: String,
    pub(crate) payload: Vec<u8>,
}

pub(super) fn read_head(dir: &Path) -> Option<Pos> {
    let text = std::fs::read_to_string(dir.join("head")).ok()?;
    let mut parts = text.split_whitespace();
    Some(Pos {
        seg: parts.next()?.parse().ok()?,
        off: parts.next()?.parse().ok()?,
    })
}

/// Reads a segment through: its length up to the last whole record (a torn tail is cut off
/// the file), its record count and times. Returns how many bytes' worth of records were cut.
pub(super) fn scan(path: &Path, id: u64) -> Result<(Segment, u64), BufferError> {
    let data = std::fs::read(path).map_err(err(path))?;
    let mut seg = Segment {
        id,
        len: 0,
        records: 0,
        newest_ms: 0,
        oldest_ms: 0,
    };
    let mut off = 0usize;
    while off + HEADER <= data.len() {
        let n =
            u32::from_le_bytes([data[off], data[off + 1], data[off + 2], data[off + 3]]) as usize;
        let crc = u32::from_le_bytes([data[off + 4], data[off + 5], data[off + 6], data[off + 7]]);
        let Some(body) = data.get(off + HEADER..off + HEADER + n) else {
            break;
        };
        if n > MAX_RECORD || crc32(body) != crc {
            break;
        }
        let Some(record) = decode(body) else {
            break;
        };
        if seg.oldest_ms == 0 {
            seg.oldest_ms = record.at_ms;
        }
        seg.newest_ms = record.at_ms;
        seg.records += 1;
        off += HEADER + n;
    }
    seg.len = off as u64;
    let torn = u64::from(off < data.len());
    if off < data.len() {
        tracing::warn!(
            segment = %path.display(),
            bytes = data.len() - off,
            "the MQTT buffer's last record was torn (a crash while writing): cut off"
        );
        let f = OpenOptions::new()
            .write(true)
            .open(path)
            .map_err(err(path))?;
        f.set_len(off as u64).map_err(err(path))?;
    }
    Ok((seg, torn))
}

pub(super) fn encode(r: &Record) -> Vec<u8> {
    let mut b = Vec::with_capacity(16 + r.device.len() + r.field.len() + r.payload.len());
    b.extend_from_slice(&r.at_ms.to_le_bytes());
    b.push(r.kind as u8);
    for s in [&r.device, &r.field] {
        let s = &s.as_bytes()[..s.len().min(u16::MAX as usize)];
        b.extend_from_slice(&(s.len() as u16).to_le_bytes());
        b.extend_from_slice(s);
    }
    b.extend_from_slice(&r.payload);
    b
}

pub(super) fn decode(b: &[u8]) -> Option<Record> {
    let at_ms = u64::from_le_bytes(b.get(..8)?.try_into().ok()?);
    let kind = match *b.get(8)? {
        1 => Kind::Json,
        2 => Kind::Sparkplug,
        _ => return None,
    };
    let mut rest = b.get(9..)?;
    let mut text = || -> Option<String> {
        let n = u16::from_le_bytes(rest.get(..2)?.try_into().ok()?) as usize;
        let s = String::from_utf8(rest.get(2..2 + n)?.to_vec()).ok()?;
        rest = rest.get(2 + n..)?;
        Some(s)
    };
    let device = text()?;
    let field = text()?;
    Some(Record {
        at_ms,
        kind,
        device,
        field,
        payload: rest.to_vec(),
    })
}

/// CRC-32 (IEEE 802.3, as zlib computes it).
pub(super) fn crc32(data: &[u8]) -> u32 {
    const TABLE: [u32; 256] = {
        let mut table = [0u32; 256];
        let mut i = 0;
        while i < 256 {
            let mut c = i as u32;
            let mut k = 0;
            while k < 8 {
                c = if c & 1 != 0 {
                    0xEDB8_8320 ^ (c >> 1)
                } else {
                    c >> 1
                };
                k += 1;
            }
            table[i] = c;
            i += 1;
        }
        table
    };
    let mut c = !0u32;
    for &b in data {
        c = TABLE[((c ^ u32::from(b)) & 0xFF) as usize] ^ (c >> 8);
    }
    !c
}

impl Buffer {
    /// The record at `pos` and where it ends, read through the read-ahead.
    pub(super) fn read_at(&mut self, pos: Pos) -> Result<Option<(Record, Pos)>, BufferError> {
        let Some(len) = self
            .segments
            .iter()
            .find(|s| s.id == pos.seg)
            .map(|s| s.len)
        else {
            return Ok(None);
        };
        if pos.off + HEADER as u64 > len {
            return Ok(None);
        }
        let header = self.bytes(pos.seg, pos.off, HEADER, len)?;
        let n = u32::from_le_bytes([header[0], header[1], header[2], header[3]]) as usize;
        let crc = u32::from_le_bytes([header[4], header[5], header[6], header[7]]);
        if n > MAX_RECORD || pos.off + (HEADER + n) as u64 > len {
            return Ok(None);
        }
        let body = self.bytes(pos.seg, pos.off + HEADER as u64, n, len)?;
        if crc32(&body) != crc {
            return Ok(None);
        }
        let end = Pos {
            seg: pos.seg,
            off: pos.off + (HEADER + n) as u64,
        };
        Ok(decode(&body).map(|r| (r, end)))
    }

    fn bytes(&mut self, seg: u64, off: u64, n: usize, len: u64) -> Result<Vec<u8>, BufferError> {
        if let Some((s, start, data)) = &self.ahead
            && *s == seg
            && off >= *start
            && off + n as u64 <= start + data.len() as u64
        {
            let i = (off - start) as usize;
            return Ok(data[i..i + n].to_vec());
        }
        let want = n.max(READ_AHEAD).min((len - off) as usize);
        let path = segment_path(&self.dir, seg);
        let file = File::open(&path).map_err(err(&path))?;
        let mut data = vec![0; want];
        file.read_exact_at(&mut data, off).map_err(err(&path))?;
        let out = data[..n].to_vec();
        self.ahead = Some((seg, off, data));
        Ok(out)
    }
}

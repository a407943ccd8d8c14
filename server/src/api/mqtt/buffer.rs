//! Store-and-forward: the messages that could not be published, kept on disk in order until
//! the broker acknowledged them.
//!
//! A segmented log of our own (see ARCHITECTURE.md for why not an embedded database): files
//! `<id>.seg` of records `[len u32][crc32 u32][body]`, appended with one `write` each (a
//! killed process loses nothing written; the fsync policy says what a power cut may lose),
//! and a `head` file naming the first record not yet acknowledged, replaced atomically
//! (write, then rename). Whole segments are dropped when the buffer is over `max_bytes` or
//! older than `max_age`, oldest first, and counted. On open, every segment is read through:
//! a torn record at the end (a crash in the middle of a write) is cut off.

use std::collections::VecDeque;
use std::fs::{File, OpenOptions};
use std::io::Write;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use crate::config::mqtt::{BufferConfig, Fsync};

/// Record header: length and checksum of the body.
const HEADER: usize = 8;
/// A record longer than this is not one (a corrupt length).
const MAX_RECORD: usize = 16 << 20;
/// How much is read from disk at once when replaying.
const READ_AHEAD: usize = 256 << 10;
/// How often the head is written at most while acknowledgements come in.
const HEAD_EVERY: Duration = Duration::from_millis(200);

/// What a record is published as.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Kind {
    /// A JSON field message: `payload` is the JSON, published under `<prefix>/history/`.
    Json = 1,
    /// A Sparkplug metric of a device: `payload` is the encoded `Metric`, named.
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

/// Where a record starts or ends: a segment and an offset in it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Default)]
pub(crate) struct Pos {
    seg: u64,
    off: u64,
}

/// Why the buffer cannot be used.
#[derive(Debug, thiserror::Error)]
#[error("mqtt buffer {path}: {source}")]
pub(crate) struct BufferError {
    path: String,
    source: std::io::Error,
}

fn err(path: &Path) -> impl FnOnce(std::io::Error) -> BufferError + '_ {
    move |source| BufferError {
        path: path.display().to_string(),
        source,
    }
}

#[derive(Debug)]
struct Segment {
    id: u64,
    len: u64,
    records: u64,
    /// When its newest record was made.
    newest_ms: u64,
    /// When its oldest record was made.
    oldest_ms: u64,
}

/// Counters for the status and the metrics.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(crate) struct BufferStats {
    /// Records not yet acknowledged.
    pub(crate) depth: u64,
    /// Bytes on disk.
    pub(crate) bytes: u64,
    /// Age of the oldest record kept, in seconds.
    pub(crate) oldest_age_s: u64,
    /// Records dropped (over `max_bytes` or `max_age`, or cut off as torn).
    pub(crate) dropped: u64,
}

pub(crate) struct Buffer {
    dir: PathBuf,
    max_bytes: u64,
    max_age: Duration,
    fsync: Fsync,
    segment_max: u64,
    segments: VecDeque<Segment>,
    writer: File,
    head: Pos,
    /// Records before `head` in its segment (acknowledged, not yet deleted).
    head_records: u64,
    read: Pos,
    depth: u64,
    dropped: u64,
    /// Read-ahead: the segment, the offset the bytes start at, and the bytes.
    ahead: Option<(u64, u64, Vec<u8>)>,
    unsynced: bool,
    synced_at: Instant,
    head_dirty: bool,
    head_written: Instant,
}

pub(crate) fn now_ms() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as u64)
}

fn segment_path(dir: &Path, id: u64) -> PathBuf {
    dir.join(format!("{id:020}.seg"))
}

impl Buffer {
    /// Opens (or creates) the buffer in `config.dir`.
    pub(crate) fn open(dir: &Path, config: &BufferConfig) -> Result<Buffer, BufferError> {
        std::fs::create_dir_all(dir).map_err(err(dir))?;
        let mut ids: Vec<u64> = std::fs::read_dir(dir)
            .map_err(err(dir))?
            .filter_map(|e| e.ok())
            .filter_map(|e| {
                let name = e.file_name().into_string().ok()?;
                name.strip_suffix(".seg")?.parse().ok()
            })
            .collect();
        ids.sort_unstable();
        let head = read_head(dir).unwrap_or_default();
        let mut dropped = 0;
        let mut segments = VecDeque::new();
        for id in ids {
            let path = segment_path(dir, id);
            if id < head.seg {
                let _ = std::fs::remove_file(&path);
                continue;
            }
            let (segment, torn) = scan(&path, id)?;
            dropped += torn;
            segments.push_back(segment);
        }
        let last = segments.back().map_or(head.seg.max(1), |s| s.id);
        if segments.is_empty() {
            segments.push_back(Segment {
                id: last,
                len: 0,
                records: 0,
                newest_ms: 0,
                oldest_ms: 0,
            });
        }
        let path = segment_path(dir, last);
        let writer = OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
            .map_err(err(&path))?;
        let segment_max = (config.max_bytes / 16).clamp(64 << 10, 64 << 20);
        let mut buffer = Buffer {
            dir: dir.to_owned(),
            max_bytes: config.max_bytes,
            max_age: config.max_age,
            fsync: config.fsync,
            segment_max,
            segments,
            writer,
            head: Pos::default(),
            head_records: 0,
            read: Pos::default(),
            depth: 0,
            dropped,
            ahead: None,
            unsynced: false,
            synced_at: Instant::now(),
            head_dirty: false,
            head_written: Instant::now(),
        };
        // The head where it was, if its segment is still there; else the oldest record.
        let first = buffer.segments.front().map_or(0, |s| s.id);
        buffer.head = if head.seg == first {
            head
        } else {
            Pos { seg: first, off: 0 }
        };
        buffer.head_records = buffer.count_before(buffer.head)?;
        buffer.depth = buffer.segments.iter().map(|s| s.records).sum::<u64>() - buffer.head_records;
        buffer.read = buffer.head;
        buffer.expire(now_ms());
        Ok(buffer)
    }

    /// Records in the head's segment before `pos`.
    fn count_before(&mut self, pos: Pos) -> Result<u64, BufferError> {
        let mut n = 0;
        let mut at = Pos {
            seg: pos.seg,
            off: 0,
        };
        while at.off < pos.off {
            match self.read_at(at)? {
                Some((_, end)) => {
                    at = end;
                    n += 1;
                }
                None => break,
            }
        }
        Ok(n)
    }

    pub(crate) fn stats(&self) -> BufferStats {
        let oldest = self
            .segments
            .iter()
            .find(|s| s.records > 0)
            .map_or(0, |s| s.oldest_ms);
        BufferStats {
            depth: self.depth,
            bytes: self.segments.iter().map(|s| s.len).sum(),
            oldest_age_s: if self.depth == 0 || oldest == 0 {
                0
            } else {
                now_ms().saturating_sub(oldest) / 1000
            },
            dropped: self.dropped,
        }
    }

    pub(crate) fn is_empty(&self) -> bool {
        self.depth == 0
    }

    /// Appends a record at the end.
    pub(crate) fn append(&mut self, record: &Record) -> Result<(), BufferError> {
        let body = encode(record);
        let mut bytes = Vec::with_capacity(HEADER + body.len());
        bytes.extend_from_slice(&(body.len() as u32).to_le_bytes());
        bytes.extend_from_slice(&crc32(&body).to_le_bytes());
        bytes.extend_from_slice(&body);
        if self
            .segments
            .back()
            .is_some_and(|s| s.len >= self.segment_max)
        {
            self.roll()?;
        }
        let path = self.current_path();
        self.writer.write_all(&bytes).map_err(err(&path))?;
        if let Some(s) = self.segments.back_mut() {
            s.len += bytes.len() as u64;
            s.records += 1;
            s.newest_ms = record.at_ms;
            if s.oldest_ms == 0 {
                s.oldest_ms = record.at_ms;
            }
        }
        self.depth += 1;
        self.unsynced = true;
        match self.fsync {
            Fsync::Always => self.sync()?,
            Fsync::Second if self.synced_at.elapsed() >= Duration::from_secs(1) => self.sync()?,
            _ => {}
        }
        self.trim();
        Ok(())
    }

    fn current_path(&self) -> PathBuf {
        segment_path(&self.dir, self.segments.back().map_or(0, |s| s.id))
    }

    /// Starts a new segment.
    fn roll(&mut self) -> Result<(), BufferError> {
        self.sync()?;
        let id = self.segments.back().map_or(1, |s| s.id + 1);
        let path = segment_path(&self.dir, id);
        self.writer = OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
            .map_err(err(&path))?;
        self.segments.push_back(Segment {
            id,
            len: 0,
            records: 0,
            newest_ms: 0,
            oldest_ms: 0,
        });
        Ok(())
    }

    /// Forces what was appended to disk (when the policy asks: on every append, or once a
    /// second from the front-end's timer).
    pub(crate) fn sync(&mut self) -> Result<(), BufferError> {
        if self.unsynced && self.fsync != Fsync::Never {
            let path = self.current_path();
            self.writer.sync_data().map_err(err(&path))?;
        }
        self.unsynced = false;
        self.synced_at = Instant::now();
        Ok(())
    }

    /// The timer's work: the once-a-second sync, the head, and old segments.
    pub(crate) fn tick(&mut self) -> Result<(), BufferError> {
        if self.fsync == Fsync::Second && self.unsynced {
            self.sync()?;
        }
        self.expire(now_ms());
        self.write_head(false)
    }

    /// Drops the oldest segments while the buffer is over `max_bytes`.
    fn trim(&mut self) {
        while self.segments.len() > 1
            && self.segments.iter().map(|s| s.len).sum::<u64>() > self.max_bytes
        {
            self.drop_oldest();
        }
    }

    /// Drops segments whose every record is older than `max_age`.
    fn expire(&mut self, now: u64) {
        let limit = now.saturating_sub(self.max_age.as_millis() as u64);
        while self.segments.len() > 1
            && self
                .segments
                .front()
                .is_some_and(|s| s.records > 0 && s.newest_ms < limit)
        {
            self.drop_oldest();
        }
    }

    fn drop_oldest(&mut self) {
        let Some(s) = self.segments.pop_front() else {
            return;
        };
        let unacked = if self.head.seg == s.id {
            s.records - self.head_records
        } else {
            s.records
        };
        self.dropped += unacked;
        self.depth -= unacked.min(self.depth);
        let _ = std::fs::remove_file(segment_path(&self.dir, s.id));
        let next = self.segments.front().map_or(s.id + 1, |n| n.id);
        if self.head.seg <= s.id {
            self.head = Pos { seg: next, off: 0 };
            self.head_records = 0;
            self.head_dirty = true;
        }
        if self.read.seg <= s.id {
            self.read = Pos { seg: next, off: 0 };
        }
        tracing::warn!(
            records = unacked,
            "the MQTT buffer is full or old: its oldest messages were dropped"
        );
    }

    /// The next record to replay and where it ends, or `None` when all were handed out.
    /// Records older than `max_age` are skipped (and counted).
    pub(crate) fn next(&mut self) -> Result<Option<(Record, Pos)>, BufferError> {
        let limit = now_ms().saturating_sub(self.max_age.as_millis() as u64);
        loop {
            let Some(seg) = self.segments.iter().find(|s| s.id == self.read.seg) else {
                return Ok(None);
            };
            if self.read.off >= seg.len {
                let next = self
                    .segments
                    .iter()
                    .find(|s| s.id > self.read.seg)
                    .map(|s| s.id);
                match next {
                    Some(id) => {
                        self.read = Pos { seg: id, off: 0 };
                        continue;
                    }
                    None => return Ok(None),
                }
            }
            let start = self.read;
            match self.read_at(start)? {
                Some((record, end)) => {
                    self.read = end;
                    if record.at_ms < limit {
                        // Too old to be worth sending: dropped (and acknowledged when
                        // nothing before it waits).
                        self.dropped += 1;
                        if self.head == start {
                            self.ack(end);
                        }
                        continue;
                    }
                    return Ok(Some((record, end)));
                }
                None => return Ok(None),
            }
        }
    }

    /// Replays again from the first record not acknowledged (after a connection ended).
    pub(crate) fn rewind(&mut self) {
        self.read = self.head;
    }

    /// Every record up to `end` (a position [`Self::next`] gave) was acknowledged.
    pub(crate) fn ack(&mut self, end: Pos) {
        if end <= self.head {
            return;
        }
        // Count the records passed over, then delete the segments left behind.
        while self.head < end {
            let Ok(Some((_, next))) = self.read_at(self.head) else {
                break;
            };
            self.head = next;
            self.head_records += 1;
            self.depth = self.depth.saturating_sub(1);
            let at_end = self
                .segments
                .front()
                .is_some_and(|s| s.id == self.head.seg && self.head.off >= s.len);
            if at_end && self.segments.len() > 1 {
                if let Some(s) = self.segments.pop_front() {
                    let _ = std::fs::remove_file(segment_path(&self.dir, s.id));
                }
                let id = self.segments.front().map_or(0, |s| s.id);
                self.head = Pos { seg: id, off: 0 };
                self.head_records = 0;
            }
        }
        self.head_dirty = true;
        let _ = self.write_head(false);
    }

    /// Writes the head file (at most every [`HEAD_EVERY`] unless `now`).
    pub(crate) fn write_head(&mut self, now: bool) -> Result<(), BufferError> {
        if !self.head_dirty || (!now && self.head_written.elapsed() < HEAD_EVERY) {
            return Ok(());
        }
        let path = self.dir.join("head");
        let tmp = self.dir.join("head.tmp");
        let text = format!("{} {}\n", self.head.seg, self.head.off);
        (|| {
            let mut f = File::create(&tmp)?;
            f.write_all(text.as_bytes())?;
            if self.fsync != Fsync::Never {
                f.sync_data()?;
            }
            std::fs::rename(&tmp, &path)
        })()
        .map_err(err(&path))?;
        self.head_dirty = false;
        self.head_written = Instant::now();
        Ok(())
    }

    /// The record at `pos` and where it ends, read through the read-ahead.
    fn read_at(&mut self, pos: Pos) -> Result<Option<(Record, Pos)>, BufferError> {
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

fn read_head(dir: &Path) -> Option<Pos> {
    let text = std::fs::read_to_string(dir.join("head")).ok()?;
    let mut parts = text.split_whitespace();
    Some(Pos {
        seg: parts.next()?.parse().ok()?,
        off: parts.next()?.parse().ok()?,
    })
}

/// Reads a segment through: its length up to the last whole record (a torn tail is cut off
/// the file), its record count and times. Returns how many bytes' worth of records were cut.
fn scan(path: &Path, id: u64) -> Result<(Segment, u64), BufferError> {
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

fn encode(r: &Record) -> Vec<u8> {
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

fn decode(b: &[u8]) -> Option<Record> {
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
fn crc32(data: &[u8]) -> u32 {
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

#[cfg(test)]
mod tests {
    use super::*;

    fn config(max_bytes: u64) -> BufferConfig {
        BufferConfig {
            max_bytes,
            fsync: Fsync::Never,
            ..BufferConfig::default()
        }
    }

    fn record(n: u64) -> Record {
        Record {
            at_ms: now_ms(),
            kind: Kind::Json,
            device: "pump".into(),
            field: format!("f{n}"),
            payload: n.to_le_bytes().to_vec(),
        }
    }

    fn field_no(r: &Record) -> u64 {
        u64::from_le_bytes(r.payload[..8].try_into().expect("test"))
    }

    #[test]
    fn crc32_is_zlibs() {
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
    }

    #[test]
    fn records_come_back_in_order_and_survive_a_reopen() {
        let dir = tempfile::tempdir().expect("test");
        let mut b = Buffer::open(dir.path(), &config(1 << 30)).expect("test");
        for n in 0..1000 {
            b.append(&record(n)).expect("test");
        }
        // Replay 300 and acknowledge them; the rest is still there after a reopen.
        let mut last = Pos::default();
        for n in 0..300 {
            let (r, end) = b.next().expect("test").expect("test");
            assert_eq!(field_no(&r), n);
            last = end;
        }
        b.ack(last);
        b.write_head(true).expect("test");
        assert_eq!(b.stats().depth, 700);
        drop(b);
        let mut b = Buffer::open(dir.path(), &config(1 << 30)).expect("test");
        assert_eq!(b.stats().depth, 700);
        let mut n = 300;
        while let Some((r, end)) = b.next().expect("test") {
            assert_eq!(field_no(&r), n);
            n += 1;
            b.ack(end);
        }
        assert_eq!(n, 1000);
        assert!(b.is_empty());
    }

    #[test]
    fn unacknowledged_records_are_replayed_again_after_a_rewind() {
        let dir = tempfile::tempdir().expect("test");
        let mut b = Buffer::open(dir.path(), &config(1 << 30)).expect("test");
        for n in 0..10 {
            b.append(&record(n)).expect("test");
        }
        let (_, end) = b.next().expect("test").expect("test");
        b.ack(end);
        b.next().expect("test").expect("test");
        b.next().expect("test").expect("test");
        b.rewind();
        assert_eq!(field_no(&b.next().expect("test").expect("test").0), 1);
    }

    #[test]
    fn a_torn_tail_is_cut_off_and_the_rest_kept() {
        let dir = tempfile::tempdir().expect("test");
        let mut b = Buffer::open(dir.path(), &config(1 << 30)).expect("test");
        for n in 0..5 {
            b.append(&record(n)).expect("test");
        }
        drop(b);
        let seg = std::fs::read_dir(dir.path())
            .expect("test")
            .filter_map(|e| e.ok())
            .find(|e| e.file_name().to_string_lossy().ends_with(".seg"))
            .expect("test")
            .path();
        let mut f = OpenOptions::new().append(true).open(&seg).expect("test");
        f.write_all(&[40, 0, 0, 0, 1, 2]).expect("test");
        drop(f);
        let mut b = Buffer::open(dir.path(), &config(1 << 30)).expect("test");
        assert_eq!(b.stats().depth, 5);
        b.append(&record(5)).expect("test");
        let mut seen = Vec::new();
        while let Some((r, _)) = b.next().expect("test") {
            seen.push(field_no(&r));
        }
        assert_eq!(seen, vec![0, 1, 2, 3, 4, 5]);
    }

    #[test]
    fn over_max_bytes_the_oldest_are_dropped_and_counted() {
        let dir = tempfile::tempdir().expect("test");
        // Segments of 64 KiB; a 256 KiB buffer keeps about four of them.
        let mut b = Buffer::open(dir.path(), &config(256 << 10)).expect("test");
        for n in 0..20_000 {
            b.append(&record(n)).expect("test");
        }
        let s = b.stats();
        assert!(s.bytes <= 256 << 10, "{s:?}");
        assert!(s.dropped > 0);
        assert_eq!(s.depth + s.dropped, 20_000);
        // What is left is the newest, in order.
        let (first, _) = b.next().expect("test").expect("test");
        assert_eq!(field_no(&first), s.dropped);
    }
}

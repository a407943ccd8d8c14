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

use crate::api::mqtt::config::{BufferConfig, Fsync};

mod records;
pub(crate) use records::{Kind, Record};
use records::{crc32, encode, read_head, scan};

/// Record header: length and checksum of the body.
const HEADER: usize = 8;
/// A record longer than this is not one (a corrupt length).
const MAX_RECORD: usize = 16 << 20;
/// How much is read from disk at once when replaying.
const READ_AHEAD: usize = 256 << 10;
/// How often the head is written at most while acknowledgements come in.
const HEAD_EVERY: Duration = Duration::from_millis(200);

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
}

#[cfg(test)]
mod crash_tests;
#[cfg(test)]
mod tests;

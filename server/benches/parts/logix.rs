//! A Logix controller written for the EtherNet/IP benchmark from the specifications (CIP
//! Vol. 1 and 2, Rockwell's Logix 5000 Data Access manual), answering in Rust on its own
//! threads so that neither client is bound by it: RegisterSession, List Identity,
//! SendRRData (Forward Open, Large Forward Open, Forward Close, messages routed by an
//! Unconnected Send or sent as they are), SendUnitData on the connection, and the tag
//! services Read Tag, Read Tag Fragmented and Multiple Service Packets. Its tags are DINTs
//! (`T0` ..) and one DINT array (`Counts`), every value its index.

use std::collections::HashMap;
use std::sync::Arc;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};

/// Tags by name, each its element count.
pub type Tags = Arc<HashMap<Vec<u8>, u32>>;

/// Listens on a free loopback port; the port.
pub async fn start(tags: Tags) -> anyhow::Result<u16> {
    let listener = TcpListener::bind("127.0.0.1:0").await?;
    let port = listener.local_addr()?.port();
    tokio::spawn(async move {
        while let Ok((io, _)) = listener.accept().await {
            let _ = io.set_nodelay(true);
            tokio::spawn(session(io, tags.clone()));
        }
    });
    Ok(port)
}

/// A session's state: its connection's id and size (0: none yet).
struct Session {
    tags: Tags,
    connection: u32,
    size: usize,
}

async fn session(mut io: TcpStream, tags: Tags) {
    let mut s = Session {
        tags,
        connection: 0,
        size: 0,
    };
    let mut head = [0u8; 24];
    let mut body = Vec::new();
    while io.read_exact(&mut head).await.is_ok() {
        let len = usize::from(u16::from_le_bytes([head[2], head[3]]));
        body.resize(len, 0);
        if io.read_exact(&mut body).await.is_err() {
            return;
        }
        let command = u16::from_le_bytes([head[0], head[1]]);
        let data = match command {
            0x65 => {
                head[4..8].copy_from_slice(&0x1234_5678u32.to_le_bytes());
                body.clone()
            }
            0x66 => return,
            0x63 => identity(),
            0x6F => s.rr_data(&body),
            0x70 => s.unit_data(&body),
            _ => {
                head[8..12].copy_from_slice(&1u32.to_le_bytes());
                Vec::new()
            }
        };
        head[2..4].copy_from_slice(&(data.len() as u16).to_le_bytes());
        let mut out = head.to_vec();
        out.extend_from_slice(&data);
        if io.write_all(&out).await.is_err() {
            return;
        }
    }
}

fn identity() -> Vec<u8> {
    let name = b"1756-L85E bench";
    let mut item = vec![1, 0]; // encapsulation version
    item.extend_from_slice(&[0; 16]); // socket address
    item.extend_from_slice(&1u16.to_le_bytes()); // vendor: Rockwell
    item.extend_from_slice(&14u16.to_le_bytes()); // device type: PLC
    item.extend_from_slice(&166u16.to_le_bytes()); // product code
    item.extend_from_slice(&[33, 11]); // revision
    item.extend_from_slice(&0u16.to_le_bytes()); // status
    item.extend_from_slice(&0x00C0_FFEEu32.to_le_bytes()); // serial
    item.push(name.len() as u8);
    item.extend_from_slice(name);
    item.push(3); // state
    let mut d = 1u16.to_le_bytes().to_vec();
    d.extend_from_slice(&0x0Cu16.to_le_bytes());
    d.extend_from_slice(&(item.len() as u16).to_le_bytes());
    d.extend_from_slice(&item);
    d
}

fn u16_at(b: &[u8], at: usize) -> usize {
    b.get(at..at + 2)
        .map_or(0, |s| usize::from(u16::from_le_bytes([s[0], s[1]])))
}

/// The first item of `kind` in common packet format data (after handle and timeout).
fn item(data: &[u8], kind: usize) -> Option<&[u8]> {
    let mut at = 8;
    for _ in 0..u16_at(data, 6) {
        let len = u16_at(data, at + 2);
        let body = data.get(at + 4..at + 4 + len)?;
        if u16_at(data, at) == kind {
            return Some(body);
        }
        at += 4 + len;
    }
    None
}

fn error(service: u8, status: u8) -> Vec<u8> {
    vec![service | 0x80, 0, status, 0]
}

impl Session {
    fn rr_data(&mut self, body: &[u8]) -> Vec<u8> {
        let message = item(body, 0xB2).unwrap_or(&[]);
        let reply = self.unconnected(message);
        let mut d = vec![0, 0, 0, 0, 0, 0, 2, 0, 0, 0, 0, 0, 0xB2, 0];
        d.extend_from_slice(&(reply.len() as u16).to_le_bytes());
        d.extend_from_slice(&reply);
        d
    }

    /// A message to the Connection Manager, or routed through it, or to the router.
    fn unconnected(&mut self, m: &[u8]) -> Vec<u8> {
        let service = m.first().copied().unwrap_or(0);
        let to_manager = m.get(2..6) == Some(&[0x20, 0x06, 0x24, 0x01]);
        match (service, to_manager) {
            (0x52, true) => {
                // Unconnected Send: priority and ticks, the message's length, the message.
                let len = u16_at(m, 8);
                match m.get(10..10 + len) {
                    Some(inner) => self.service(inner, 504),
                    None => error(0x52, 0x13),
                }
            }
            (0x54 | 0x5B, true) => self.forward_open(m, service == 0x5B),
            (0x4E, true) => {
                self.connection = 0;
                let mut r = vec![0xCE, 0, 0, 0];
                // Ticks, then serial, vendor and originator serial, echoed.
                r.extend_from_slice(m.get(8..16).unwrap_or(&[0; 8]));
                r.extend_from_slice(&[0, 0]);
                r
            }
            _ => self.service(m, 504),
        }
    }

    fn forward_open(&mut self, m: &[u8], large: bool) -> Vec<u8> {
        // After the path: ticks (2), O->T id (4), T->O id (4), serial (2), vendor (2),
        // originator serial (4), multiplier and reserved (4), O->T RPI (4), O->T parameters
        // (4 in a Large Forward Open, else 2).
        let p = 6;
        let Some(fixed) = m.get(p..p + 32) else {
            return error(m[0], 0x13);
        };
        let params = if large {
            u32::from_le_bytes([fixed[26], fixed[27], fixed[28], fixed[29]]) & 0xFFFF
        } else {
            u32::from(u16::from_le_bytes([fixed[26], fixed[27]])) & 0x01FF
        };
        self.size = params as usize;
        self.connection = 0x4000_0001;
        let mut r = vec![m[0] | 0x80, 0, 0, 0];
        r.extend_from_slice(&self.connection.to_le_bytes()); // O->T id, ours
        r.extend_from_slice(&fixed[6..10]); // T->O id, theirs
        r.extend_from_slice(&fixed[10..18]); // serial, vendor, originator serial
        r.extend_from_slice(&fixed[22..26]); // O->T RPI as the API
        r.extend_from_slice(&fixed[22..26]); // T->O API
        r.extend_from_slice(&[0, 0]);
        r
    }

    fn unit_data(&mut self, body: &[u8]) -> Vec<u8> {
        let data = item(body, 0xB1).unwrap_or(&[]);
        let seq = data.get(..2).unwrap_or(&[0, 0]).to_vec();
        let size = self.size.max(504);
        let reply = self.service(data.get(2..).unwrap_or(&[]), size - 2);
        let mut d = vec![0, 0, 0, 0, 0, 0, 2, 0, 0xA1, 0, 4, 0];
        d.extend_from_slice(&0x4947_0000u32.to_le_bytes());
        d.extend_from_slice(&0xB1u16.to_le_bytes());
        d.extend_from_slice(&((reply.len() + 2) as u16).to_le_bytes());
        d.extend_from_slice(&seq);
        d.extend_from_slice(&reply);
        d
    }

    /// A service of the Message Router or a tag, its reply within `room` bytes.
    fn service(&self, m: &[u8], room: usize) -> Vec<u8> {
        let service = m.first().copied().unwrap_or(0);
        let words = usize::from(m.get(1).copied().unwrap_or(0));
        let (Some(path), Some(data)) = (m.get(2..2 + 2 * words), m.get(2 + 2 * words..)) else {
            return error(service, 0x04);
        };
        match service {
            0x0A => self.multiple(data, room),
            0x4C | 0x52 => self.read(service, path, data, room),
            _ => error(service, 0x08),
        }
    }

    fn multiple(&self, data: &[u8], room: usize) -> Vec<u8> {
        let n = u16_at(data, 0);
        let mut offsets: Vec<usize> = (0..n).map(|k| u16_at(data, 2 + 2 * k)).collect();
        offsets.push(data.len());
        let mut replies = Vec::with_capacity(n);
        let mut left = room.saturating_sub(6 + 2 * n);
        for k in 0..n {
            let one = data
                .get(offsets[k]..offsets[k + 1].max(offsets[k]))
                .unwrap_or(&[]);
            let r = self.service(one, left);
            left = left.saturating_sub(r.len());
            replies.push(r);
        }
        let mut out = vec![0x8A, 0, 0, 0];
        out.extend_from_slice(&(n as u16).to_le_bytes());
        let mut at = 2 + 2 * n;
        for r in &replies {
            out.extend_from_slice(&(at as u16).to_le_bytes());
            at += r.len();
        }
        for r in &replies {
            out.extend_from_slice(r);
        }
        out
    }

    /// Read Tag (0x4C) or Read Tag Fragmented (0x52) of a DINT tag or of elements of one.
    fn read(&self, service: u8, path: &[u8], data: &[u8], room: usize) -> Vec<u8> {
        let Some((name, first)) = tag(path) else {
            return error(service, 0x04);
        };
        let Some(&elements) = self.tags.get(name) else {
            return error(service, 0x04);
        };
        let count = u16_at(data, 0) as u32;
        let offset = match service {
            0x52 => data
                .get(2..6)
                .map_or(0, |o| u32::from_le_bytes([o[0], o[1], o[2], o[3]])),
            _ => 0,
        } as usize;
        if count == 0
            || first.checked_add(count).is_none_or(|end| end > elements)
            || !offset.is_multiple_of(4)
        {
            return error(service, 0x05);
        }
        let whole = 4 * count as usize;
        let fits = (room.saturating_sub(6) / 4) * 4;
        let part = (whole.saturating_sub(offset)).min(fits);
        let mut r = vec![service | 0x80, 0, 0, 0, 0xC4, 0];
        r[2] = if offset + part < whole { 0x06 } else { 0 };
        for e in (offset / 4)..((offset + part) / 4) {
            r.extend_from_slice(&(first + e as u32).to_le_bytes());
        }
        r
    }
}

/// A symbolic segment's name and the element an element segment names (0 without one).
fn tag(path: &[u8]) -> Option<(&[u8], u32)> {
    if path.first() != Some(&0x91) {
        return None;
    }
    let len = usize::from(*path.get(1)?);
    let name = path.get(2..2 + len)?;
    let rest = path.get(2 + len + len % 2..).unwrap_or(&[]);
    let element = match rest {
        [0x28, e, ..] => u32::from(*e),
        [0x29, 0, a, b, ..] => u32::from(u16::from_le_bytes([*a, *b])),
        [0x2A, 0, a, b, c, d, ..] => u32::from_le_bytes([*a, *b, *c, *d]),
        _ => 0,
    };
    Some((name, element))
}

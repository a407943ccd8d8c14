//! MQTT control packets as a client sends and receives them, for MQTT 3.1.1 (OASIS standard,
//! protocol level 4) and MQTT 5.0 (level 5): one codec, the version a parameter. Only what
//! a publishing client needs: CONNECT, PUBLISH (QoS 0 and 1), PUBACK, SUBSCRIBE, PINGREQ and
//! DISCONNECT out; CONNACK, PUBLISH, PUBACK, SUBACK, PINGRESP and DISCONNECT in. Here the
//! fixed header and the frame a packet is read from; each kind of packet in a file of its
//! own (`connect.rs`: CONNECT and CONNACK; `publish.rs`: PUBLISH and PUBACK;
//! `subscribe.rs`: SUBSCRIBE and SUBACK; `ping.rs`; `disconnect.rs`).

mod connect;
mod disconnect;
mod ping;
mod publish;
mod subscribe;

use crate::api::mqtt::config::MqttVersion;
pub(crate) use connect::{Connect, Will, connack_reason, connect};
pub(crate) use disconnect::disconnect;
pub(crate) use ping::pingreq;
#[cfg(test)]
pub(crate) use publish::publish;
use publish::publish_head;
pub(crate) use publish::{Publish, puback, publish_size, write_publish};
pub(crate) use subscribe::subscribe;

/// The largest packet the gateway takes from a broker (MQTT 5 announces it as the Maximum
/// Packet Size). A bigger one is read past without being kept, acknowledged when it is a
/// QoS 1 publish, and reported: never the end of the connection.
pub(crate) const MAX_INCOMING: usize = 1 << 20;

/// A packet from the broker.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Incoming {
    ConnAck {
        session_present: bool,
        code: u8,
        receive_maximum: Option<u16>,
        /// The broker's Maximum Packet Size (MQTT 5): nothing bigger may be sent to it.
        maximum_packet: Option<u32>,
    },
    Publish(Publish),
    PubAck {
        pkid: u16,
        code: u8,
    },
    SubAck {
        pkid: u16,
        codes: Vec<u8>,
    },
    PingResp,
    /// MQTT 5: the broker ends the connection, with its reason.
    Disconnect {
        code: u8,
    },
    /// A packet read past: too big to keep, malformed, or of a type a client does not
    /// receive. Its framing was whole, so the connection goes on.
    Dropped {
        why: PacketError,
        /// The topic of a publish, where it could be read.
        topic: Option<String>,
        /// The packet id of a QoS 1 publish, to acknowledge it (the broker would otherwise
        /// hold it in flight).
        pkid: Option<u16>,
        /// Bytes of the packet still to come, to be read past as they arrive.
        rest: usize,
    },
}

/// Why bytes from the broker are not a packet the client understands.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub(crate) enum PacketError {
    #[error("a remaining length of more than four bytes")]
    Length,
    #[error("a packet of {0} bytes, more than the {MAX_INCOMING} accepted")]
    TooBig(usize),
    #[error("a packet of type {0} a client does not receive")]
    Unexpected(u8),
    #[error("a malformed {0} packet")]
    Malformed(&'static str),
    #[error("a topic that is not UTF-8")]
    Topic,
}

fn put_u16(out: &mut Vec<u8>, n: u16) {
    out.extend_from_slice(&n.to_be_bytes());
}

fn put_str(out: &mut Vec<u8>, s: &str) {
    put_bytes(out, s.as_bytes());
}

fn put_bytes(out: &mut Vec<u8>, b: &[u8]) {
    // Lengths are checked by the callers (topics and ids are bounded by the config).
    put_u16(out, b.len().min(usize::from(u16::MAX)) as u16);
    out.extend_from_slice(&b[..b.len().min(usize::from(u16::MAX))]);
}

fn put_varint(out: &mut Vec<u8>, mut n: usize) {
    loop {
        let mut byte = (n % 128) as u8;
        n /= 128;
        if n > 0 {
            byte |= 0x80;
        }
        out.push(byte);
        if n == 0 {
            break;
        }
    }
}

/// A packet of `kind` (the first byte) around `body`.
fn frame(first: u8, body: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(body.len() + 5);
    out.push(first);
    put_varint(&mut out, body.len());
    out.extend_from_slice(body);
    out
}

/// Takes one packet off the front of `buf`, if a whole one is there.
pub(crate) fn decode(
    version: MqttVersion,
    buf: &mut Vec<u8>,
) -> Result<Option<Incoming>, PacketError> {
    let Some(&first) = buf.first() else {
        return Ok(None);
    };
    let mut len = 0usize;
    let mut header = 1;
    loop {
        let Some(&byte) = buf.get(header) else {
            return Ok(None);
        };
        len |= usize::from(byte & 0x7F) << (7 * (header - 1));
        header += 1;
        if byte & 0x80 == 0 {
            break;
        }
        if header > 4 {
            return Err(PacketError::Length);
        }
    }
    if len > MAX_INCOMING {
        return Ok(too_big(buf, first, header, len));
    }
    if buf.len() < header + len {
        return Ok(None);
    }
    let body: Vec<u8> = buf.drain(..header + len).skip(header).collect();
    Ok(Some(parse(version, first, &body).unwrap_or_else(|why| {
        let (topic, pkid) = publish_head(first, &body);
        Incoming::Dropped {
            why,
            topic,
            pkid,
            rest: 0,
        }
    })))
}

/// A packet over [`MAX_INCOMING`]: once its head is in (a publish's topic and packet id,
/// at most 65,539 bytes), what of it is buffered is dropped and the rest is to be read past.
fn too_big(buf: &mut Vec<u8>, first: u8, header: usize, len: usize) -> Option<Incoming> {
    let body = &buf[header..];
    if first >> 4 == 3 {
        let id_len = if (first >> 1) & 3 > 0 { 2 } else { 0 };
        let topic_len = body
            .get(..2)
            .map(|b| usize::from(u16::from_be_bytes([b[0], b[1]])))?;
        if body.len() < (2 + topic_len + id_len).min(len) {
            return None;
        }
    }
    let (topic, pkid) = publish_head(first, body);
    let take = buf.len().min(header + len);
    buf.drain(..take);
    Some(Incoming::Dropped {
        why: PacketError::TooBig(len),
        topic,
        pkid,
        rest: header + len - take,
    })
}

fn parse(version: MqttVersion, first: u8, body: &[u8]) -> Result<Incoming, PacketError> {
    let v5 = version == MqttVersion::V5;
    match first >> 4 {
        2 => connect::connack(body),
        3 => publish::incoming(v5, first, body),
        4 => publish::puback_in(v5, body),
        9 => subscribe::suback(v5, body),
        13 => Ok(Incoming::PingResp),
        14 => Ok(disconnect::incoming(body)),
        other => Err(PacketError::Unexpected(other)),
    }
}

/// Reads an MQTT 5 properties block at `at`, returning where it ends.
fn skip_properties(body: &[u8], at: usize, what: &'static str) -> Result<usize, PacketError> {
    let mut len = 0usize;
    let mut i = at;
    for shift in 0..4 {
        let byte = *body.get(i).ok_or(PacketError::Malformed(what))?;
        i += 1;
        len |= usize::from(byte & 0x7F) << (7 * shift);
        if byte & 0x80 == 0 {
            return if i + len <= body.len() {
                Ok(i + len)
            } else {
                Err(PacketError::Malformed(what))
            };
        }
    }
    Err(PacketError::Malformed(what))
}

fn u16_at(body: &[u8], at: usize, what: &'static str) -> Result<u16, PacketError> {
    match body.get(at..at + 2) {
        Some(b) => Ok(u16::from_be_bytes([b[0], b[1]])),
        None => Err(PacketError::Malformed(what)),
    }
}

#[cfg(test)]
mod tests;

//! MQTT control packets as a client sends and receives them, for MQTT 3.1.1 (OASIS standard,
//! protocol level 4) and MQTT 5.0 (level 5): one codec, the version a parameter. Only what
//! a publishing client needs: CONNECT, PUBLISH (QoS 0 and 1), PUBACK, SUBSCRIBE, PINGREQ and
//! DISCONNECT out; CONNACK, PUBLISH, PUBACK, SUBACK, PINGRESP and DISCONNECT in.

use crate::api::mqtt::config::MqttVersion;

/// The largest packet the gateway takes from a broker (MQTT 5 announces it as the Maximum
/// Packet Size). A bigger one is read past without being kept, acknowledged when it is a
/// QoS 1 publish, and reported: never the end of the connection.
pub(crate) const MAX_INCOMING: usize = 1 << 20;

/// A message the broker publishes for the client if the connection ends without a
/// DISCONNECT.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Will {
    pub(crate) topic: String,
    pub(crate) payload: Vec<u8>,
    pub(crate) qos: u8,
    pub(crate) retain: bool,
}

#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Connect {
    pub(crate) client_id: String,
    pub(crate) keep_alive: u16,
    pub(crate) clean_start: bool,
    pub(crate) username: Option<String>,
    pub(crate) password: Option<Vec<u8>>,
    pub(crate) will: Option<Will>,
}

#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Publish {
    pub(crate) topic: String,
    pub(crate) payload: Vec<u8>,
    pub(crate) qos: u8,
    pub(crate) retain: bool,
    /// The packet identifier (QoS 1).
    pub(crate) pkid: u16,
}

/// A packet from the broker.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Incoming {
    ConnAck {
        session_present: bool,
        code: u8,
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

pub(crate) fn connect(version: MqttVersion, c: &Connect) -> Vec<u8> {
    let mut body = Vec::new();
    put_str(&mut body, "MQTT");
    body.push(match version {
        MqttVersion::V311 => 4,
        MqttVersion::V5 => 5,
    });
    let mut flags = 0u8;
    if c.clean_start {
        flags |= 0x02;
    }
    if let Some(w) = &c.will {
        flags |= 0x04 | (w.qos.min(1) << 3);
        if w.retain {
            flags |= 0x20;
        }
    }
    if c.password.is_some() {
        flags |= 0x40;
    }
    if c.username.is_some() {
        flags |= 0x80;
    }
    body.push(flags);
    put_u16(&mut body, c.keep_alive);
    if version == MqttVersion::V5 {
        let mut properties = Vec::new();
        // Session Expiry Interval: a kept session outlives the connection by an hour.
        if !c.clean_start {
            properties.push(0x11);
            properties.extend_from_slice(&3600u32.to_be_bytes());
        }
        // Maximum Packet Size: the broker sends nothing bigger (it drops it instead).
        properties.push(0x27);
        properties.extend_from_slice(&(MAX_INCOMING as u32).to_be_bytes());
        put_varint(&mut body, properties.len());
        body.extend_from_slice(&properties);
    }
    put_str(&mut body, &c.client_id);
    if let Some(w) = &c.will {
        if version == MqttVersion::V5 {
            put_varint(&mut body, 0);
        }
        put_str(&mut body, &w.topic);
        put_bytes(&mut body, &w.payload);
    }
    if let Some(u) = &c.username {
        put_str(&mut body, u);
    }
    if let Some(p) = &c.password {
        put_bytes(&mut body, p);
    }
    frame(0x10, &body)
}

pub(crate) fn publish(version: MqttVersion, p: &Publish) -> Vec<u8> {
    let mut body = Vec::with_capacity(p.topic.len() + p.payload.len() + 8);
    put_str(&mut body, &p.topic);
    if p.qos > 0 {
        put_u16(&mut body, p.pkid);
    }
    if version == MqttVersion::V5 {
        put_varint(&mut body, 0);
    }
    body.extend_from_slice(&p.payload);
    let mut first = 0x30 | (p.qos.min(1) << 1);
    if p.retain {
        first |= 0x01;
    }
    frame(first, &body)
}

pub(crate) fn puback(pkid: u16) -> Vec<u8> {
    // Success with no properties is the same two bytes in 3.1.1 and 5.
    frame(0x40, &pkid.to_be_bytes())
}

pub(crate) fn subscribe(version: MqttVersion, pkid: u16, filters: &[(String, u8)]) -> Vec<u8> {
    let mut body = Vec::new();
    put_u16(&mut body, pkid);
    if version == MqttVersion::V5 {
        put_varint(&mut body, 0);
    }
    for (filter, qos) in filters {
        put_str(&mut body, filter);
        body.push(*qos.min(&1));
    }
    frame(0x82, &body)
}

pub(crate) fn pingreq() -> Vec<u8> {
    vec![0xC0, 0]
}

pub(crate) fn disconnect() -> Vec<u8> {
    vec![0xE0, 0]
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

/// The topic (lossy) and QoS 1 packet id at the head of a publish's `body`, where they are.
fn publish_head(first: u8, body: &[u8]) -> (Option<String>, Option<u16>) {
    if first >> 4 != 3 {
        return (None, None);
    }
    let Ok(topic_len) = u16_at(body, 0, "PUBLISH").map(usize::from) else {
        return (None, None);
    };
    let topic = body
        .get(2..2 + topic_len)
        .map(|t| String::from_utf8_lossy(t).into_owned());
    let pkid = if (first >> 1) & 3 == 1 {
        u16_at(body, 2 + topic_len, "PUBLISH").ok()
    } else {
        None
    };
    (topic, pkid)
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

fn parse(version: MqttVersion, first: u8, body: &[u8]) -> Result<Incoming, PacketError> {
    let v5 = version == MqttVersion::V5;
    match first >> 4 {
        2 => {
            if body.len() < 2 {
                return Err(PacketError::Malformed("CONNACK"));
            }
            Ok(Incoming::ConnAck {
                session_present: body[0] & 1 == 1,
                code: body[1],
            })
        }
        3 => {
            let qos = (first >> 1) & 3;
            let topic_len = usize::from(u16_at(body, 0, "PUBLISH")?);
            let topic = body
                .get(2..2 + topic_len)
                .ok_or(PacketError::Malformed("PUBLISH"))?;
            let topic = std::str::from_utf8(topic)
                .map_err(|_| PacketError::Topic)?
                .to_owned();
            let mut at = 2 + topic_len;
            let pkid = if qos > 0 {
                let id = u16_at(body, at, "PUBLISH")?;
                at += 2;
                id
            } else {
                0
            };
            if qos > 2 {
                return Err(PacketError::Malformed("PUBLISH"));
            }
            if v5 {
                at = skip_properties(body, at, "PUBLISH")?;
            }
            Ok(Incoming::Publish(Publish {
                topic,
                payload: body[at..].to_vec(),
                qos,
                retain: first & 1 == 1,
                pkid,
            }))
        }
        4 => Ok(Incoming::PubAck {
            pkid: u16_at(body, 0, "PUBACK")?,
            code: if v5 {
                body.get(2).copied().unwrap_or(0)
            } else {
                0
            },
        }),
        9 => {
            let pkid = u16_at(body, 0, "SUBACK")?;
            let at = if v5 {
                skip_properties(body, 2, "SUBACK")?
            } else {
                2
            };
            Ok(Incoming::SubAck {
                pkid,
                codes: body[at..].to_vec(),
            })
        }
        13 => Ok(Incoming::PingResp),
        14 => Ok(Incoming::Disconnect {
            code: body.first().copied().unwrap_or(0),
        }),
        other => Err(PacketError::Unexpected(other)),
    }
}

/// What a CONNACK's return (3.1.1) or reason (5) code means.
pub(crate) fn connack_reason(version: MqttVersion, code: u8) -> &'static str {
    match (version, code) {
        (_, 0) => "accepted",
        (MqttVersion::V311, 1) => "unacceptable protocol version",
        (MqttVersion::V311, 2) => "client identifier rejected",
        (MqttVersion::V311, 3) => "server unavailable",
        (MqttVersion::V311, 4) => "bad user name or password",
        (MqttVersion::V311, 5) => "not authorized",
        (MqttVersion::V5, 0x84) => "unsupported protocol version",
        (MqttVersion::V5, 0x85) => "client identifier not valid",
        (MqttVersion::V5, 0x86) => "bad user name or password",
        (MqttVersion::V5, 0x87) => "not authorized",
        (MqttVersion::V5, 0x88) => "server unavailable",
        (MqttVersion::V5, 0x89) => "server busy",
        (MqttVersion::V5, 0x8A) => "banned",
        (MqttVersion::V5, 0x8C) => "bad authentication method",
        (MqttVersion::V5, 0x95) => "packet too large",
        (MqttVersion::V5, 0x97) => "quota exceeded",
        (MqttVersion::V5, 0x9C) => "use another server",
        (MqttVersion::V5, 0x9D) => "server moved",
        _ => "refused",
    }
}

#[cfg(test)]
#[path = "packet_tests.rs"]
mod tests;

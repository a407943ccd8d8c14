//! CONNECT (with its Will and, in MQTT 5, its properties) and CONNACK.

use super::{Incoming, MAX_INCOMING, PacketError, frame, put_bytes, put_str, put_u16, put_varint};
use crate::api::mqtt::config::MqttVersion;

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

/// A CONNACK: whether the session was kept, the return (3.1.1) or reason (5) code, and
/// the broker's Receive Maximum (MQTT 5: QoS 1 publishes it takes unacknowledged at once).
pub(super) fn connack(body: &[u8]) -> Result<Incoming, PacketError> {
    if body.len() < 2 {
        return Err(PacketError::Malformed("CONNACK"));
    }
    let (receive_maximum, maximum_packet) = match body.get(2..) {
        Some(props) if !props.is_empty() => limits(props)?,
        _ => (None, None),
    };
    Ok(Incoming::ConnAck {
        session_present: body[0] & 1 == 1,
        code: body[1],
        receive_maximum,
        maximum_packet,
    })
}

/// The Receive Maximum (0x21) and the Maximum Packet Size (0x27) of a CONNACK's properties
/// block (its length first).
fn limits(props: &[u8]) -> Result<(Option<u16>, Option<u32>), PacketError> {
    const WHAT: &str = "CONNACK properties";
    let end = super::skip_properties(props, 0, WHAT)?;
    // Past the block's length (a variable byte integer).
    let mut i = 1 + props.iter().take_while(|b| *b & 0x80 != 0).count();
    let mut found = None;
    let mut packet = None;
    while i < end {
        let id = props[i];
        i += 1;
        let len = match id {
            0x01 | 0x17 | 0x19 | 0x24 | 0x25 | 0x28 | 0x29 | 0x2A => 1,
            0x13 | 0x21 | 0x22 | 0x23 => 2,
            0x02 | 0x11 | 0x18 | 0x27 => 4,
            0x0B => {
                while props.get(i).is_some_and(|b| b & 0x80 != 0) {
                    i += 1;
                }
                1
            }
            0x03 | 0x08 | 0x12 | 0x15 | 0x16 | 0x1A | 0x1C | 0x1F | 0x09 => {
                2 + usize::from(super::u16_at(props, i, WHAT)?)
            }
            0x26 => {
                let key = 2 + usize::from(super::u16_at(props, i, WHAT)?);
                key + 2 + usize::from(super::u16_at(props, i + key, WHAT)?)
            }
            _ => return Err(PacketError::Malformed(WHAT)),
        };
        if id == 0x21 {
            // Zero is a protocol error (MQTT 5, 3.2.2.3.3): taken as no maximum given.
            found = Some(super::u16_at(props, i, WHAT)?).filter(|&m| m > 0);
        }
        if id == 0x27 {
            // Zero is a protocol error too (3.2.2.3.6).
            let b = props.get(i..i + 4).ok_or(PacketError::Malformed(WHAT))?;
            packet = Some(u32::from_be_bytes([b[0], b[1], b[2], b[3]])).filter(|&m| m > 0);
        }
        i += len;
        if i > end {
            return Err(PacketError::Malformed(WHAT));
        }
    }
    Ok((found, packet))
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

//! PUBLISH (QoS 0 and 1) both ways, and PUBACK.

use super::{Incoming, PacketError, frame, put_str, put_u16, put_varint, skip_properties, u16_at};
use crate::api::mqtt::config::MqttVersion;

#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Publish {
    pub(crate) topic: String,
    pub(crate) payload: Vec<u8>,
    pub(crate) qos: u8,
    pub(crate) retain: bool,
    /// The packet identifier (QoS 1).
    pub(crate) pkid: u16,
}

/// A PUBLISH on its own, as the tests take it.
#[cfg(test)]
pub(crate) fn publish(version: MqttVersion, p: &Publish) -> Vec<u8> {
    let mut out = Vec::with_capacity(p.topic.len() + p.payload.len() + 16);
    write_publish(
        version,
        &mut out,
        &p.topic,
        &p.payload,
        (p.qos, p.retain),
        p.pkid,
    );
    out
}

/// A PUBLISH appended to `out` as it goes on the wire (no copy of its own): `flags` are
/// the QoS and retain.
/// The bytes of a PUBLISH of `payload_len` bytes on `topic` (as [`write_publish`] writes it).
pub(crate) fn publish_size(
    version: MqttVersion,
    topic: &str,
    payload_len: usize,
    qos: u8,
) -> usize {
    let topic_len = topic.len().min(usize::from(u16::MAX));
    let v5 = version == MqttVersion::V5;
    let remaining = 2 + topic_len + if qos > 0 { 2 } else { 0 } + usize::from(v5) + payload_len;
    let varint = match remaining {
        0..128 => 1,
        128..16_384 => 2,
        16_384..2_097_152 => 3,
        _ => 4,
    };
    1 + varint + remaining
}

pub(crate) fn write_publish(
    version: MqttVersion,
    out: &mut Vec<u8>,
    topic: &str,
    payload: &[u8],
    (qos, retain): (u8, bool),
    pkid: u16,
) {
    let topic_len = topic.len().min(usize::from(u16::MAX));
    let v5 = version == MqttVersion::V5;
    let remaining = 2 + topic_len + if qos > 0 { 2 } else { 0 } + usize::from(v5) + payload.len();
    let mut first = 0x30 | (qos.min(1) << 1);
    if retain {
        first |= 0x01;
    }
    out.reserve(remaining + 5);
    out.push(first);
    put_varint(out, remaining);
    put_str(out, topic);
    if qos > 0 {
        put_u16(out, pkid);
    }
    if v5 {
        put_varint(out, 0);
    }
    out.extend_from_slice(payload);
}

pub(crate) fn puback(pkid: u16) -> Vec<u8> {
    // Success with no properties is the same two bytes in 3.1.1 and 5.
    frame(0x40, &pkid.to_be_bytes())
}

/// A PUBLISH from the broker: its topic (UTF-8), packet id (QoS 1), and payload after the
/// MQTT 5 properties.
pub(super) fn incoming(v5: bool, first: u8, body: &[u8]) -> Result<Incoming, PacketError> {
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

/// A PUBACK from the broker: its packet id and (MQTT 5) reason code.
pub(super) fn puback_in(v5: bool, body: &[u8]) -> Result<Incoming, PacketError> {
    Ok(Incoming::PubAck {
        pkid: u16_at(body, 0, "PUBACK")?,
        code: if v5 {
            body.get(2).copied().unwrap_or(0)
        } else {
            0
        },
    })
}

/// The topic (lossy) and QoS 1 packet id at the head of a publish's `body`, where they are.
pub(super) fn publish_head(first: u8, body: &[u8]) -> (Option<String>, Option<u16>) {
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

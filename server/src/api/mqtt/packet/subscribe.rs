//! SUBSCRIBE and SUBACK.

use super::{Incoming, PacketError, frame, put_str, put_u16, put_varint, skip_properties, u16_at};
use crate::api::mqtt::config::MqttVersion;

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

/// A SUBACK: its packet id and a return (3.1.1) or reason (5) code per filter.
pub(super) fn suback(v5: bool, body: &[u8]) -> Result<Incoming, PacketError> {
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

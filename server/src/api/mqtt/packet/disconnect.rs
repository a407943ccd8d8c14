//! DISCONNECT both ways: the client's (no reason, no properties) and the broker's (MQTT 5,
//! with its reason code).

use super::Incoming;

pub(crate) fn disconnect() -> Vec<u8> {
    vec![0xE0, 0]
}

/// The broker's DISCONNECT (MQTT 5): its reason code, 0 when it gives none.
pub(super) fn incoming(body: &[u8]) -> Incoming {
    Incoming::Disconnect {
        code: body.first().copied().unwrap_or(0),
    }
}

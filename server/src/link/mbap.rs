//! The MBAP header of Modbus TCP, written once for both sides: the client links
//! (`link::tcp`) send requests and read answers with it, the Modbus TCP server
//! (`api::modbus`) reads requests and sends answers with it.

/// Bytes of the header: transaction id, protocol id, length, unit id.
pub(crate) const HEADER_LEN: usize = 7;
/// The longest length field: unit id plus a 253-byte PDU.
pub(crate) const MAX_LENGTH: usize = 254;

/// A header as read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Header {
    pub(crate) transaction: u16,
    pub(crate) unit: u8,
    /// Bytes of the PDU that follows (the length field less the unit id).
    pub(crate) pdu_len: usize,
}

/// A header whose protocol id is not 0 or whose length is out of 2-254: the stream is out of
/// step, and only a new connection recovers it.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("MBAP header with protocol {protocol} and length {length}")]
pub(crate) struct Malformed {
    pub(crate) protocol: u16,
    pub(crate) length: usize,
}

impl Header {
    pub(crate) fn parse(bytes: &[u8; HEADER_LEN]) -> Result<Header, Malformed> {
        let protocol = u16::from_be_bytes([bytes[2], bytes[3]]);
        let length = usize::from(u16::from_be_bytes([bytes[4], bytes[5]]));
        if protocol != 0 || !(2..=MAX_LENGTH).contains(&length) {
            return Err(Malformed { protocol, length });
        }
        Ok(Header {
            transaction: u16::from_be_bytes([bytes[0], bytes[1]]),
            unit: bytes[6],
            pdu_len: length - 1,
        })
    }
}

/// Starts a frame in `out` (cleared): room for the header, filled by [`finish_frame`] once
/// the PDU is appended.
pub(crate) fn start_frame(out: &mut Vec<u8>) {
    out.clear();
    out.extend_from_slice(&[0; HEADER_LEN]);
}

/// Writes the header of the frame begun by [`start_frame`], for the PDU appended since.
pub(crate) fn finish_frame(out: &mut [u8], transaction: u16, unit: u8) {
    let length = ((out.len() - HEADER_LEN + 1) as u16).to_be_bytes();
    let [t0, t1] = transaction.to_be_bytes();
    out[..HEADER_LEN].copy_from_slice(&[t0, t1, 0, 0, length[0], length[1], unit]);
}

/// A whole frame: the header for `pdu`, then `pdu`.
pub(crate) fn frame(transaction: u16, unit: u8, pdu: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(HEADER_LEN + pdu.len());
    out.extend_from_slice(&transaction.to_be_bytes());
    out.extend_from_slice(&[0, 0]);
    out.extend_from_slice(&((pdu.len() + 1) as u16).to_be_bytes());
    out.push(unit);
    out.extend_from_slice(pdu);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_frame_reads_back_as_its_header() {
        let f = frame(0x1234, 7, &[0x03, 0x00, 0x01, 0x00, 0x02]);
        assert_eq!(f[..7], [0x12, 0x34, 0, 0, 0, 6, 7]);
        let header = Header::parse(f[..7].try_into().expect("7 bytes")).expect("header");
        assert_eq!(
            header,
            Header {
                transaction: 0x1234,
                unit: 7,
                pdu_len: 5
            }
        );
        let mut bad = f.clone();
        bad[2] = 1;
        assert!(Header::parse(bad[..7].try_into().expect("7 bytes")).is_err());
        bad = f;
        bad[5] = 255;
        assert!(Header::parse(bad[..7].try_into().expect("7 bytes")).is_err());
    }
}

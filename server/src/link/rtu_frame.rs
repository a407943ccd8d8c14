//! The RTU frame, one for both sides of a serial line (the links' master in `rtu.rs`, the
//! Modbus server's slave in `api/modbus_serial.rs`, the scan's judge): an address, a PDU and
//! the CRC-16/MODBUS low byte first; at least 4 bytes, at most 256; a frame ends when the
//! line has been silent for 3.5 characters (`LineTiming::silence`).

use super::frame::Request;

/// The shortest RTU frame: an address, a function code and the CRC.
pub(crate) const MIN_RTU_FRAME: usize = 4;

/// Why bytes heard are not a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Unframed {
    /// Fewer than [`MIN_RTU_FRAME`] bytes.
    Short,
    /// Its CRC does not hold.
    Crc,
}

/// `address` and `pdu` as an RTU frame.
pub(crate) fn seal(address: u8, pdu: &[u8]) -> Vec<u8> {
    let mut frame = Vec::with_capacity(pdu.len() + 3);
    frame.push(address);
    frame.extend_from_slice(pdu);
    let crc = crc16(&frame);
    frame.extend_from_slice(&crc.to_le_bytes());
    frame
}

/// A whole frame's address and PDU, once its length and CRC hold.
pub(crate) fn open(frame: &[u8]) -> Result<(u8, &[u8]), Unframed> {
    if frame.len() < MIN_RTU_FRAME {
        return Err(Unframed::Short);
    }
    let (body, crc) = frame.split_at(frame.len() - 2);
    if crc16(body) != u16::from_le_bytes([crc[0], crc[1]]) {
        return Err(Unframed::Crc);
    }
    Ok((body[0], &body[1..]))
}

/// CRC-16/MODBUS of `data`, sent low byte first.
pub fn crc16(data: &[u8]) -> u16 {
    data.iter().fold(0xFFFF, |crc, &byte| crc16_step(crc, byte))
}

/// The CRC-16/MODBUS `crc` so far with one more byte.
fn crc16_step(crc: u16, byte: u8) -> u16 {
    let mut crc = crc ^ u16::from(byte);
    for _ in 0..8 {
        crc = if crc & 1 != 0 {
            (crc >> 1) ^ 0xA001
        } else {
            crc >> 1
        };
    }
    crc
}

/// The shortest length (from the shortest frame to `rest`'s, at most the longest frame)
/// whose last two bytes are the CRC of the ones before: the CRC grown a byte at a time, so
/// that noise costs one pass over at most a frame's bytes, not one per length tried.
fn shortest_sealed(rest: &[u8]) -> Option<usize> {
    let max = rest.len().min(MAX_RTU_FRAME);
    let mut crc = 0xFFFF;
    let mut folded = 0;
    (MIN_RTU_FRAME..=max).find(|&n| {
        while folded < n - 2 {
            crc = crc16_step(crc, rest[folded]);
            folded += 1;
        }
        crc.to_le_bytes() == [rest[n - 2], rest[n - 1]]
    })
}

/// Splits bytes heard on a line into RTU frames by their CRCs: at each position, the
/// length the function code announces if its CRC holds, else the shortest length whose CRC
/// holds. Bytes no frame accounts for are noise (their count is returned).
pub(crate) fn split_frames(bytes: &[u8]) -> (Vec<&[u8]>, usize) {
    let crc_holds = |f: &[u8]| open(f).is_ok();
    let mut frames = Vec::new();
    let mut noise = 0;
    let mut at = 0;
    while at < bytes.len() {
        let rest = &bytes[at..];
        let announced = match rest {
            [_, f, ..] if f & 0x80 != 0 => Some(5),
            [_, 1..=4, count, ..] => Some(5 + usize::from(*count)),
            [_, 5 | 6 | 15 | 16, ..] => Some(8),
            [_, 0x2B, 0x0E, ..] => identification_len(rest),
            _ => None,
        };
        let len = announced
            .filter(|&n| n <= rest.len() && crc_holds(&rest[..n]))
            .or_else(|| shortest_sealed(rest));
        match len {
            Some(n) => {
                frames.push(&rest[..n]);
                at += n;
            }
            None => {
                noise += 1;
                at += 1;
            }
        }
    }
    (frames, noise)
}

/// The length of an RTU frame answering FC 43 / MEI 14 (read device identification), by
/// walking its objects: slave, 43, 14, code, conformity, more, next, count, then each
/// object's id, length and value, then the CRC.
fn identification_len(frame: &[u8]) -> Option<usize> {
    let count = *frame.get(7)?;
    let mut at = 8;
    for _ in 0..count {
        at += 2 + usize::from(*frame.get(at + 1)?);
    }
    Some(at + 2)
}

/// Whether `bytes` are one or more whole RTU frames and nothing else.
pub(crate) fn whole_frames(bytes: &[u8]) -> bool {
    let (frames, noise) = split_frames(bytes);
    !frames.is_empty() && noise == 0
}

/// The longest RTU frame: slave, 253 bytes of PDU, CRC.
const MAX_RTU_FRAME: usize = 256;

/// A whole RTU frame: slave, PDU, CRC.
pub(crate) fn rtu_frame(slave: u8, request: &Request) -> Vec<u8> {
    let mut pdu = Vec::with_capacity(6 + 2 * usize::from(request.count()));
    request.encode(&mut pdu);
    seal(slave, &pdu)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_sealed_frame_opens_to_what_was_sealed_and_a_changed_byte_does_not() {
        let frame = seal(7, &[3, 0, 1, 0, 2]);
        assert_eq!(frame.len(), 8);
        assert_eq!(open(&frame), Ok((7, &[3u8, 0, 1, 0, 2][..])));
        let mut bad = frame.clone();
        bad[3] ^= 1;
        assert_eq!(open(&bad), Err(Unframed::Crc));
        assert_eq!(open(&frame[..3]), Err(Unframed::Short));
        // The reference frame of the Modbus serial line guide: slave 1, FC 03, 0x0000, 1.
        assert_eq!(seal(1, &[3, 0, 0, 0, 1])[6..], [0x84, 0x0A]);
    }

    proptest::proptest! {
        /// The CRC grown a byte at a time finds the length trying every one would.
        #[test]
        fn the_shortest_sealed_length_is_the_one_every_length_tried_finds(
            noise in proptest::collection::vec(proptest::num::u8::ANY, 0..300),
            frame in proptest::collection::vec(proptest::num::u8::ANY, 2..40),
            at in 0usize..300,
        ) {
            let mut bytes = noise;
            let sealed = seal(frame[0], &frame[1..]);
            let at = at.min(bytes.len());
            bytes.splice(at..at, sealed);
            let tried = (MIN_RTU_FRAME..=bytes.len().min(MAX_RTU_FRAME))
                .find(|&n| open(&bytes[..n]).is_ok());
            proptest::prop_assert_eq!(shortest_sealed(&bytes), tried);
        }
    }
}

//! What the bytes heard after one probe say: nothing, one answer, two answers (two devices
//! on one id), or a garbled mix.

use crate::link::frame::split_frames;

/// What came back to one probe of `slave`; each answer is its PDU.
#[derive(Debug, Clone, PartialEq)]
pub(super) enum Heard {
    Silent,
    One(Vec<u8>),
    /// Two or more whole answers: the first.
    Two(Vec<u8>),
    /// Bytes no frame accounts for, with the one whole answer among them if there was one.
    Garbled(Option<Vec<u8>>),
}

/// Judges `bytes` heard after a probe of `slave` with `function`. Frames of other slaves
/// (a late answer to an earlier probe) are not this slave's and are left out.
pub(super) fn judge(bytes: &[u8], slave: u8, function: u8) -> Heard {
    let (frames, noise) = split_frames(bytes);
    let mine: Vec<&[u8]> = frames
        .into_iter()
        .filter(|f| f[0] == slave && f[1] & 0x7F == function)
        .collect();
    let pdu = |f: &[u8]| f[1..f.len() - 2].to_vec();
    match (mine.as_slice(), noise) {
        ([], 0) => Heard::Silent,
        ([], _) => Heard::Garbled(None),
        ([one], 0) => Heard::One(pdu(one)),
        ([one], _) => Heard::Garbled(Some(pdu(one))),
        ([first, ..], _) => Heard::Two(pdu(first)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::link::frame::crc16;

    fn frame(bytes: &[u8]) -> Vec<u8> {
        let mut f = bytes.to_vec();
        f.extend_from_slice(&crc16(bytes).to_le_bytes());
        f
    }

    #[test]
    fn one_two_garbled_and_foreign_answers() {
        let answer = frame(&[5, 3, 2, 0x12, 0x34]);
        assert_eq!(judge(&[], 5, 3), Heard::Silent);
        assert_eq!(judge(&answer, 5, 3), Heard::One(vec![3, 2, 0x12, 0x34]));
        let twice = [answer.clone(), frame(&[5, 3, 2, 0, 1])].concat();
        assert_eq!(judge(&twice, 5, 3), Heard::Two(vec![3, 2, 0x12, 0x34]));
        let mut mixed = answer.clone();
        mixed[3] ^= 0x55;
        assert_eq!(judge(&mixed, 5, 3), Heard::Garbled(None));
        let tail = [answer.clone(), vec![0xFF, 0x00]].concat();
        assert!(matches!(judge(&tail, 5, 3), Heard::Garbled(Some(_))));
        // Slave 4's late answer is not slave 5's.
        assert_eq!(judge(&frame(&[4, 3, 2, 0, 1]), 5, 3), Heard::Silent);
        assert_eq!(
            judge(&frame(&[5, 0x83, 2]), 5, 3),
            Heard::One(vec![0x83, 2])
        );
    }

    #[test]
    fn an_identification_answer_is_one_frame() {
        let mut body = vec![7, 0x2B, 0x0E, 1, 1, 0, 0, 2, 0, 3];
        body.extend_from_slice(b"ACM");
        body.extend_from_slice(&[1, 2, b'X', b'1']);
        let heard = judge(&frame(&body), 7, 0x2B);
        assert_eq!(heard, Heard::One(body[1..].to_vec()));
    }
}

//! What the bytes heard after one probe say: nothing, one answer, two answers (two devices
//! on one id), or a garbled mix.

use super::ReadAnswer;
use crate::link::rtu_frame::{self, Unframed, split_frames};
use crate::profile::RegisterKind;

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

/// The id of a whole answer to `function` heard from another slave than the one asked,
/// when nothing else was heard: a device that answers as an id of its own.
pub(super) fn foreign(bytes: &[u8], slave: u8, function: u8) -> Option<u8> {
    let (frames, noise) = split_frames(bytes);
    if noise != 0 {
        return None;
    }
    frames
        .into_iter()
        .find(|f| f[0] != slave && f[1] & 0x7F == function)
        .map(|f| f[0])
}

/// What a read heard: its data, the device's exception, nothing, or bytes that are neither
/// (checked as a poll's answer is: function, byte count, length).
pub(super) fn read_answer(
    kind: RegisterKind,
    address: u16,
    count: u16,
    heard: &Heard,
) -> ReadAnswer {
    use crate::link::frame::{Response, ResponseError};
    let request = crate::drivers::modbus::read_request(kind, address, count);
    let mut answer = ReadAnswer {
        function: request.function().code(),
        address,
        count,
        answer: "no answer",
        exception: None,
        values: Vec::new(),
    };
    let pdu = match heard {
        Heard::Silent => return answer,
        Heard::Garbled(None) => {
            answer.answer = "garbled";
            return answer;
        }
        Heard::One(pdu) | Heard::Two(pdu) | Heard::Garbled(Some(pdu)) => pdu,
    };
    match request.parse_response(pdu) {
        Ok(Response::Registers(values)) => {
            answer.answer = "data";
            answer.values = values;
        }
        Ok(Response::Bits(bits)) => {
            answer.answer = "data";
            answer.values = bits.into_iter().map(u16::from).collect();
        }
        Err(ResponseError::Exception(x)) => {
            answer.answer = "exception";
            answer.exception = Some(format!("{:02X} ({})", x.0, x.describe()));
        }
        Ok(_) | Err(ResponseError::Invalid(_)) => answer.answer = "garbled",
    }
    answer
}

/// What two garbled hearings of one probe show, in words a user can act on. A frame of this
/// slave whose CRC alone is wrong, or the same unreadable bytes twice, is one device whose
/// bytes are damaged or framed at other settings: never two devices. Bytes that differ
/// each time are noise, a missing termination or a collision: which, the bytes cannot say.
pub(super) fn garbled(first: &[u8], second: &[u8], slave: u8, function: u8) -> String {
    let bad_crc = |b: &[u8]| {
        let shaped = match (b.first(), b.get(1), b.get(2)) {
            (Some(&s), Some(&f), _) if s == slave && f == function | 0x80 => b.len() == 5,
            (Some(&s), Some(&f), Some(&n)) if s == slave && f == function => {
                b.len() == 5 + usize::from(n)
            }
            _ => false,
        };
        shaped && rtu_frame::open(b) == Err(Unframed::Crc)
    };
    if bad_crc(first) && bad_crc(second) {
        "answers whose CRC is wrong, each time: one device whose bytes are damaged on the line (noise, termination, a parity setting), not two devices".to_owned()
    } else if first == second {
        format!(
            "the same unreadable bytes each time ({}): one device at another baud rate or parity, or a faulty one, not two devices",
            hex(first)
        )
    } else {
        "unreadable bytes, different each time: noise or a missing termination, or two devices answering at once".to_owned()
    }
}

fn hex(bytes: &[u8]) -> String {
    let shown: Vec<String> = bytes.iter().take(12).map(|b| format!("{b:02X}")).collect();
    let more = if bytes.len() > 12 { " ..." } else { "" };
    format!("{}{more}", shown.join(" "))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::link::rtu_frame::crc16;

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
    fn garbled_bytes_are_told_apart_from_a_collision() {
        let mut bad = frame(&[5, 3, 2, 0x12, 0x34]);
        bad[6] ^= 0xFF;
        assert!(garbled(&bad, &bad, 5, 3).contains("CRC is wrong"));
        assert!(garbled(&bad, &bad, 5, 3).contains("not two devices"));
        let noise = [0x7E, 0x01, 0xF0];
        let same = garbled(&noise, &noise, 5, 3);
        assert!(
            same.contains("the same unreadable bytes each time (7E 01 F0)"),
            "{same}"
        );
        assert!(same.contains("another baud rate or parity"), "{same}");
        let differ = garbled(&noise, &[0x11, 0x22], 5, 3);
        assert!(differ.contains("two devices answering at once"), "{differ}");
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

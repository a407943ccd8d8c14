//! IEC 60870-5-104's APCI: every APDU starts 0x68, a length (4 to 253) and four control
//! octets, which make it an I-format (numbered, carrying an ASDU), an S-format (an
//! acknowledgement) or a U-format frame (STARTDT, STOPDT, TESTFR, each an act or a con).
//! Bytes only, both directions; a frame that is not one is an error naming what was
//! wrong, never a panic.

/// The first octet of every APDU.
pub(crate) const START: u8 = 0x68;

/// The most octets after the length octet: four control octets and an ASDU of up to 249.
pub(crate) const MAX_LENGTH: usize = 253;

/// The most octets of an ASDU.
pub(crate) const MAX_ASDU: usize = MAX_LENGTH - 4;

/// Sequence numbers count modulo 2^15.
pub(crate) const MODULO: u16 = 1 << 15;

/// Why bytes are not an APDU.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub(crate) enum Malformed {
    #[error("an APDU starts 0x68, not {0:#04x}")]
    Start(u8),
    #[error("an APDU's length is 4 to 253 octets, not {0}")]
    Length(u8),
    #[error("an S-format frame carries {0} octets after its control field")]
    Supervisory(usize),
    #[error("a U-format frame carries {0} octets after its control field")]
    Unnumbered(usize),
    #[error("an I-format frame with no ASDU")]
    Empty,
    #[error(
        "U-format control octet {0:#04x} is not one function (STARTDT, STOPDT, TESTFR act or con)"
    )]
    Function(u8),
    #[error("control octets {0:02x?} have bits set that the standard leaves 0")]
    Reserved([u8; 4]),
}

/// A U-format frame's function.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Unnumbered {
    StartAct,
    StartCon,
    StopAct,
    StopCon,
    TestAct,
    TestCon,
}

impl Unnumbered {
    fn octet(self) -> u8 {
        match self {
            Unnumbered::StartAct => 0x07,
            Unnumbered::StartCon => 0x0B,
            Unnumbered::StopAct => 0x13,
            Unnumbered::StopCon => 0x23,
            Unnumbered::TestAct => 0x43,
            Unnumbered::TestCon => 0x83,
        }
    }

    fn from_octet(octet: u8) -> Option<Unnumbered> {
        [
            Unnumbered::StartAct,
            Unnumbered::StartCon,
            Unnumbered::StopAct,
            Unnumbered::StopCon,
            Unnumbered::TestAct,
            Unnumbered::TestCon,
        ]
        .into_iter()
        .find(|u| u.octet() == octet)
    }

    pub(crate) fn name(self) -> &'static str {
        match self {
            Unnumbered::StartAct => "STARTDT act",
            Unnumbered::StartCon => "STARTDT con",
            Unnumbered::StopAct => "STOPDT act",
            Unnumbered::StopCon => "STOPDT con",
            Unnumbered::TestAct => "TESTFR act",
            Unnumbered::TestCon => "TESTFR con",
        }
    }
}

/// One APDU.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum Frame {
    /// Information: the sender's send number N(S), the receive number N(R) it acknowledges
    /// (every frame before it received), the ASDU's octets.
    I {
        send: u16,
        recv: u16,
        asdu: Vec<u8>,
    },
    /// Supervisory: acknowledges every I-frame before N(R).
    S {
        recv: u16,
    },
    U(Unnumbered),
}

impl Frame {
    /// The frame's octets. An ASDU longer than [`MAX_ASDU`] is the caller's error: the
    /// encoders here never make one.
    pub(crate) fn encode(&self) -> Vec<u8> {
        let (control, asdu): ([u8; 4], &[u8]) = match self {
            Frame::I { send, recv, asdu } => {
                let [s0, s1] = ((send % MODULO) << 1).to_le_bytes();
                let [r0, r1] = ((recv % MODULO) << 1).to_le_bytes();
                ([s0, s1, r0, r1], asdu)
            }
            Frame::S { recv } => {
                let [r0, r1] = ((recv % MODULO) << 1).to_le_bytes();
                ([0x01, 0, r0, r1], &[])
            }
            Frame::U(u) => ([u.octet(), 0, 0, 0], &[]),
        };
        debug_assert!(asdu.len() <= MAX_ASDU);
        let mut out = Vec::with_capacity(6 + asdu.len());
        out.push(START);
        out.push((4 + asdu.len()) as u8);
        out.extend_from_slice(&control);
        out.extend_from_slice(asdu);
        out
    }

    /// The first frame in `buf`, and how many octets it took; `Ok(None)` while the frame
    /// is not all there.
    pub(crate) fn decode(buf: &[u8]) -> Result<Option<(Frame, usize)>, Malformed> {
        let Some(&start) = buf.first() else {
            return Ok(None);
        };
        if start != START {
            return Err(Malformed::Start(start));
        }
        let Some(&length) = buf.get(1) else {
            return Ok(None);
        };
        let len = usize::from(length);
        if !(4..=MAX_LENGTH).contains(&len) {
            return Err(Malformed::Length(length));
        }
        if buf.len() < 2 + len {
            return Ok(None);
        }
        let control = [buf[2], buf[3], buf[4], buf[5]];
        let rest = &buf[6..2 + len];
        let number = |lo: u8, hi: u8| u16::from_le_bytes([lo, hi]) >> 1;
        let frame = if control[0] & 0x01 == 0 {
            if control[2] & 0x01 != 0 {
                return Err(Malformed::Reserved(control));
            }
            if rest.is_empty() {
                return Err(Malformed::Empty);
            }
            Frame::I {
                send: number(control[0], control[1]),
                recv: number(control[2], control[3]),
                asdu: rest.to_vec(),
            }
        } else if control[0] & 0x03 == 0x01 {
            if control[0] != 0x01 || control[1] != 0 || control[2] & 0x01 != 0 {
                return Err(Malformed::Reserved(control));
            }
            if !rest.is_empty() {
                return Err(Malformed::Supervisory(rest.len()));
            }
            Frame::S {
                recv: number(control[2], control[3]),
            }
        } else {
            if control[1..] != [0, 0, 0] {
                return Err(Malformed::Reserved(control));
            }
            if !rest.is_empty() {
                return Err(Malformed::Unnumbered(rest.len()));
            }
            Frame::U(Unnumbered::from_octet(control[0]).ok_or(Malformed::Function(control[0]))?)
        };
        Ok(Some((frame, 2 + len)))
    }
}

/// How many frames lie from `from` up to (not including) `to`, modulo 2^15.
pub(crate) fn distance(from: u16, to: u16) -> u16 {
    (to + MODULO - from % MODULO) % MODULO
}

#[cfg(test)]
mod tests {
    use super::*;

    fn one(bytes: &[u8]) -> (Frame, usize) {
        Frame::decode(bytes).expect("a frame").expect("all there")
    }

    #[test]
    fn frames_are_encoded_as_the_standard_draws_them() {
        assert_eq!(
            Frame::U(Unnumbered::StartAct).encode(),
            [0x68, 4, 0x07, 0, 0, 0]
        );
        assert_eq!(Frame::S { recv: 3 }.encode(), [0x68, 4, 0x01, 0, 6, 0]);
        let i = Frame::I {
            send: 1,
            recv: 2,
            asdu: vec![100, 1, 6, 0, 1, 0, 0, 0, 0, 20],
        };
        assert_eq!(
            i.encode(),
            [0x68, 14, 2, 0, 4, 0, 100, 1, 6, 0, 1, 0, 0, 0, 0, 20]
        );
        assert_eq!(Frame::decode(&i.encode()), Ok(Some((i, 16))));
    }

    #[test]
    fn sequence_numbers_wrap_at_two_to_the_fifteen() {
        let i = Frame::I {
            send: MODULO - 1,
            recv: MODULO - 1,
            asdu: vec![1],
        };
        let bytes = i.encode();
        assert_eq!(&bytes[2..6], [0xFE, 0xFF, 0xFE, 0xFF]);
        assert_eq!(one(&bytes).0, i);
        assert_eq!(distance(MODULO - 2, 1), 3);
        assert_eq!(distance(5, 5), 0);
    }

    #[test]
    fn a_partial_frame_waits_and_a_bad_one_is_named() {
        assert_eq!(Frame::decode(&[0x68, 4, 0x07]), Ok(None));
        assert_eq!(Frame::decode(&[]), Ok(None));
        assert_eq!(Frame::decode(&[0x69]), Err(Malformed::Start(0x69)));
        assert_eq!(Frame::decode(&[0x68, 3]), Err(Malformed::Length(3)));
        assert_eq!(Frame::decode(&[0x68, 254]), Err(Malformed::Length(254)));
        assert_eq!(
            Frame::decode(&[0x68, 4, 0x0F, 0, 0, 0]),
            Err(Malformed::Function(0x0F))
        );
        assert_eq!(Frame::decode(&[0x68, 4, 0, 0, 0, 0]), Err(Malformed::Empty));
        assert_eq!(
            Frame::decode(&[0x68, 5, 0x01, 0, 0, 0, 9]),
            Err(Malformed::Supervisory(1))
        );
        assert!(matches!(
            Frame::decode(&[0x68, 4, 0x07, 1, 0, 0]),
            Err(Malformed::Reserved(_))
        ));
    }

    #[test]
    fn two_frames_in_one_read_are_taken_one_at_a_time() {
        let mut bytes = Frame::U(Unnumbered::TestAct).encode();
        bytes.extend(Frame::S { recv: 7 }.encode());
        let (first, used) = one(&bytes);
        assert_eq!(first, Frame::U(Unnumbered::TestAct));
        let (second, _) = one(&bytes[used..]);
        assert_eq!(second, Frame::S { recv: 7 });
    }
}

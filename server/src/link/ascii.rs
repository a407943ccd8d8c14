//! Modbus ASCII framing (Modbus over serial line V1.02, 2.5.2): a frame is `:`, then the
//! address, the PDU and an LRC, each byte as two upper-case hexadecimal characters, then CR
//! LF. Pure functions and a byte-by-byte assembler, shared by the device links (the
//! master's side) and the serial server (the slave's side).

/// A frame's first character.
pub(crate) const START: u8 = b':';
/// The longest frame: `:`, 2 x (address + 253-byte PDU + LRC), CR LF.
pub(crate) const MAX_FRAME: usize = 1 + 2 * 255 + 2;

/// The LRC of `bytes`: the two's complement of their sum, modulo 256.
pub(crate) fn lrc(bytes: &[u8]) -> u8 {
    bytes
        .iter()
        .fold(0u8, |sum, b| sum.wrapping_add(*b))
        .wrapping_neg()
}

/// The characters of the frame carrying `body` (address and PDU).
pub(crate) fn encode(body: &[u8]) -> Vec<u8> {
    const HEX: &[u8; 16] = b"0123456789ABCDEF";
    let mut out = Vec::with_capacity(2 * body.len() + 5);
    out.push(START);
    for &b in body.iter().chain(std::iter::once(&lrc(body))) {
        out.push(HEX[usize::from(b >> 4)]);
        out.push(HEX[usize::from(b & 0x0F)]);
    }
    out.extend_from_slice(b"\r\n");
    out
}

/// What is wrong with an ASCII frame.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum AsciiError {
    #[error("character {0:#04x} is not a hexadecimal digit")]
    NotHex(u8),
    #[error("an odd number ({0}) of hexadecimal digits")]
    Odd(usize),
    #[error("a frame of {0} bytes is too short (address, function and LRC at least)")]
    Short(usize),
    #[error("LRC {found:#04x}, the frame's bytes make {computed:#04x}")]
    Lrc { found: u8, computed: u8 },
    #[error("no CR LF within {MAX_FRAME} characters")]
    TooLong,
}

fn nibble(c: u8) -> Result<u8, AsciiError> {
    match c {
        b'0'..=b'9' => Ok(c - b'0'),
        b'A'..=b'F' => Ok(c - b'A' + 10),
        // The specification writes upper case; lower case costs nothing to accept.
        b'a'..=b'f' => Ok(c - b'a' + 10),
        _ => Err(AsciiError::NotHex(c)),
    }
}

/// The address and PDU of a frame's characters between `:` and CR LF, its LRC checked.
pub(crate) fn decode(chars: &[u8]) -> Result<Vec<u8>, AsciiError> {
    if !chars.len().is_multiple_of(2) {
        return Err(AsciiError::Odd(chars.len()));
    }
    let bytes = chars
        .chunks_exact(2)
        .map(|pair| Ok(nibble(pair[0])? << 4 | nibble(pair[1])?))
        .collect::<Result<Vec<u8>, AsciiError>>()?;
    let Some((&found, body)) = bytes.split_last().filter(|(_, body)| body.len() >= 2) else {
        return Err(AsciiError::Short(bytes.len()));
    };
    let computed = lrc(body);
    if found != computed {
        return Err(AsciiError::Lrc { found, computed });
    }
    Ok(body.to_vec())
}

/// Collects frames from a stream of characters: everything outside a frame is dropped
/// (and counted), a `:` inside a frame starts a new one (the specification's rule: the
/// unfinished one is dropped).
#[derive(Debug, Default)]
pub(crate) struct Assembler {
    chars: Vec<u8>,
    in_frame: bool,
    /// Characters that belonged to no whole frame.
    pub(crate) dropped: usize,
}

impl Assembler {
    /// Takes one character; a frame's address and PDU (or why it is refused) when it ends
    /// a frame.
    pub(crate) fn push(&mut self, c: u8) -> Option<Result<Vec<u8>, AsciiError>> {
        if c == START {
            if self.in_frame {
                self.dropped += 1 + self.chars.len();
            }
            self.chars.clear();
            self.in_frame = true;
            return None;
        }
        if !self.in_frame {
            self.dropped += 1;
            return None;
        }
        if c == b'\n' && self.chars.last() == Some(&b'\r') {
            self.in_frame = false;
            self.chars.pop();
            let decoded = decode(&self.chars);
            self.chars.clear();
            return Some(decoded);
        }
        self.chars.push(c);
        if self.chars.len() + 1 > MAX_FRAME {
            self.dropped += 1 + self.chars.len();
            self.chars.clear();
            self.in_frame = false;
            return Some(Err(AsciiError::TooLong));
        }
        None
    }

    /// Whether a frame has begun and not ended.
    pub(crate) fn in_frame(&self) -> bool {
        self.in_frame
    }

    /// Drops an unfinished frame (after the inter-character timeout).
    pub(crate) fn reset(&mut self) {
        if self.in_frame {
            self.dropped += 1 + self.chars.len();
        }
        self.chars.clear();
        self.in_frame = false;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_specification_example_frame() {
        // Modbus over serial line V1.02, 2.5.2.1 and 6.2.2: slave 17, FC03, 107, 3 registers
        // -> ":110300 6B 0003 7E" (LRC 0x7E).
        let body = [0x11, 0x03, 0x00, 0x6B, 0x00, 0x03];
        assert_eq!(lrc(&body), 0x7E);
        assert_eq!(encode(&body), b":1103006B00037E\r\n".to_vec());
        assert_eq!(decode(b"1103006B00037E"), Ok(body.to_vec()));
        assert_eq!(decode(b"1103006b00037e"), Ok(body.to_vec()));
    }

    #[test]
    fn bad_frames_are_named() {
        assert_eq!(
            decode(b"1103006B00037F"),
            Err(AsciiError::Lrc {
                found: 0x7F,
                computed: 0x7E
            })
        );
        assert_eq!(decode(b"11G3"), Err(AsciiError::NotHex(b'G')));
        assert_eq!(decode(b"110"), Err(AsciiError::Odd(3)));
        assert_eq!(decode(b"11EF"), Err(AsciiError::Short(2)));
    }

    #[test]
    fn the_assembler_drops_noise_and_restarts_on_a_colon() {
        let mut a = Assembler::default();
        let mut frames = Vec::new();
        for &c in b"xx:0103:1103006B00037E\r\nyy".iter() {
            if let Some(f) = a.push(c) {
                frames.push(f);
            }
        }
        assert_eq!(frames, vec![Ok(vec![0x11, 0x03, 0x00, 0x6B, 0x00, 0x03])]);
        // "xx", ":0103" and "yy".
        assert_eq!(a.dropped, 2 + 5 + 2);
        assert!(!a.in_frame());
    }

    #[test]
    fn an_endless_frame_is_cut() {
        let mut a = Assembler::default();
        let mut last = None;
        a.push(START);
        for _ in 0..MAX_FRAME {
            if let Some(r) = a.push(b'0') {
                last = Some(r);
                break;
            }
        }
        assert_eq!(last, Some(Err(AsciiError::TooLong)));
    }
}

//! Wire time on a serial line: characters of 10 or 11 bits, 3.5-character silences.

use std::time::Duration;

use crate::config::{Framing, Parity, SerialSettings};

/// The fixed inter-frame silence above 19200 baud (Modbus over serial line, 2.5.1.1).
pub(crate) const FAST_SILENCE: Duration = Duration::from_micros(1750);

/// The characters of the frame whose RTU form (address, PDU, CRC) has `bytes` bytes: as
/// many in RTU; in ASCII `:`, two per byte of address, PDU and LRC, CR LF.
pub(crate) fn frame_chars(ascii: bool, bytes: usize) -> usize {
    if ascii { 2 * bytes + 1 } else { bytes }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LineTiming {
    pub(crate) baud: u32,
    /// Start bit + data bits + parity bit + stop bits: 10 or 11 for Modbus RTU.
    pub bits_per_char: u32,
    /// Whether frames are ASCII: two characters a byte and three more a frame.
    pub(crate) ascii: bool,
}

impl LineTiming {
    pub fn new(settings: &SerialSettings) -> Self {
        let parity = u32::from(settings.parity != Parity::None);
        LineTiming {
            baud: settings.baud.max(1),
            bits_per_char: 1
                + u32::from(settings.data_bits)
                + parity
                + u32::from(settings.stop_bits),
            ascii: settings.framing == Framing::Ascii,
        }
    }

    pub fn char_time(&self) -> Duration {
        Duration::from_nanos(u64::from(self.bits_per_char) * 1_000_000_000 / u64::from(self.baud))
    }

    /// The silence that separates frames: 3.5 characters, or 1.75 ms above 19200 baud.
    pub fn silence(&self) -> Duration {
        if self.baud > 19_200 {
            FAST_SILENCE
        } else {
            self.char_time() * 7 / 2
        }
    }

    /// How long the frame whose RTU form has `bytes` bytes (address, PDU, CRC) takes on
    /// the wire: as many characters in RTU; in ASCII `:`, two per byte of address, PDU and
    /// LRC, and CR LF, 2 x `bytes` + 1.
    pub fn frame_time(&self, bytes: usize) -> Duration {
        self.char_time() * self.frame_chars(bytes) as u32
    }

    /// The characters of the frame whose RTU form has `bytes` bytes.
    pub(crate) fn frame_chars(&self, bytes: usize) -> usize {
        frame_chars(self.ascii, bytes)
    }

    /// Request and response on the wire, each preceded by the inter-frame silence.
    pub fn transaction_time(&self, request_bytes: usize, response_bytes: usize) -> Duration {
        self.silence() * 2 + self.frame_time(request_bytes + response_bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(baud: u32, parity: Parity, stop_bits: u8) -> LineTiming {
        LineTiming::new(&SerialSettings {
            port: "/dev/null".into(),
            baud,
            parity,
            data_bits: 8,
            stop_bits,
            framing: Default::default(),
        })
    }

    #[test]
    fn characters_are_ten_or_eleven_bits() {
        assert_eq!(line(9600, Parity::None, 1).bits_per_char, 10);
        assert_eq!(line(9600, Parity::Even, 1).bits_per_char, 11);
        assert_eq!(line(9600, Parity::None, 2).bits_per_char, 11);
    }

    #[test]
    fn silence_is_three_and_a_half_characters_up_to_19200() {
        // 9600 8N1: 1.0417 ms per character, 3.646 ms of silence.
        let l = line(9600, Parity::None, 1);
        assert_eq!(l.char_time(), Duration::from_nanos(1_041_666));
        assert_eq!(l.silence(), Duration::from_nanos(3_645_831));
        // 19200 8E1: 0.573 ms per character, 2.005 ms of silence.
        assert_eq!(
            line(19_200, Parity::Even, 1).silence(),
            Duration::from_nanos(2_005_206)
        );
        assert_eq!(line(38_400, Parity::None, 1).silence(), FAST_SILENCE);
        assert_eq!(line(115_200, Parity::Even, 1).silence(), FAST_SILENCE);
    }

    #[test]
    fn a_read_of_ten_registers_at_9600() {
        // Request 8 bytes, response 5 + 20 bytes: 33 characters plus two silences.
        let l = line(9600, Parity::None, 1);
        let t = l.transaction_time(8, 25);
        assert_eq!(t, l.silence() * 2 + l.char_time() * 33);
        assert!(
            t > Duration::from_millis(41) && t < Duration::from_millis(42),
            "{t:?}"
        );
    }
}

//! IEC 60870-5-4's time tags: CP56Time2a (seven octets: milliseconds, minute, hour, day of
//! month and week, month, year of the century, with the invalid and summer-time bits) and
//! CP24Time2a (milliseconds and minute only). The years are 2000-2099; the clock is the
//! station's, taken as UTC (`docs/iec104.md` says so).

use crate::civil::Civil;

/// A CP56Time2a.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Cp56 {
    /// Milliseconds since 1970 of the date and time it carries.
    pub(crate) millis: i64,
    /// IV: the station says its clock is not to be trusted.
    pub(crate) invalid: bool,
    /// SU: summer time.
    pub(crate) summer: bool,
}

impl Cp56 {
    pub(crate) const LEN: usize = 7;

    pub(crate) fn at(millis: i64) -> Cp56 {
        Cp56 {
            millis,
            invalid: false,
            summer: false,
        }
    }

    pub(crate) fn decode(b: &[u8; 7]) -> Result<Cp56, String> {
        let ms = u16::from_le_bytes([b[0], b[1]]);
        if ms > 59_999 {
            return Err(format!("a CP56Time2a with {ms} milliseconds"));
        }
        let minute = b[2] & 0x3F;
        let hour = b[3] & 0x1F;
        let day = b[4] & 0x1F;
        let month = b[5] & 0x0F;
        let civil = Civil {
            year: 2000 + i64::from(b[6] & 0x7F),
            month,
            day,
            hour,
            minute,
            second: (ms / 1000) as u8,
            nanos: u32::from(ms % 1000) * 1_000_000,
        };
        if b[6] & 0x7F > 99 {
            return Err(format!("a CP56Time2a with year {}", b[6] & 0x7F));
        }
        let civil = civil
            .checked()
            .map_err(|e| format!("a CP56Time2a is {e}"))?;
        Ok(Cp56 {
            millis: civil.millis_since_1970(),
            invalid: b[2] & 0x80 != 0,
            summer: b[3] & 0x80 != 0,
        })
    }

    /// The seven octets; a time outside 2000-2099 is the caller's error (clamped to it).
    pub(crate) fn encode(&self) -> [u8; 7] {
        let lo = Civil::parse("2000-01-01T00:00:00").map_or(0, |c| c.millis_since_1970());
        let hi = Civil::parse("2099-12-31T23:59:59.999").map_or(0, |c| c.millis_since_1970());
        let c = Civil::from_millis(self.millis.clamp(lo, hi)).unwrap_or(Civil {
            year: 2000,
            month: 1,
            day: 1,
            hour: 0,
            minute: 0,
            second: 0,
            nanos: 0,
        });
        let ms = u16::from(c.second) * 1000 + (c.nanos / 1_000_000) as u16;
        let [m0, m1] = ms.to_le_bytes();
        [
            m0,
            m1,
            c.minute | if self.invalid { 0x80 } else { 0 },
            c.hour | if self.summer { 0x80 } else { 0 },
            c.day | (c.iso_weekday() << 5),
            c.month,
            (c.year - 2000) as u8,
        ]
    }
}

/// A CP24Time2a: milliseconds within the minute and the minute; the hour and date are the
/// receiver's (the station's clock at the last full time tag, here the gateway's).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Cp24 {
    pub(crate) millis: u16,
    pub(crate) minute: u8,
    pub(crate) invalid: bool,
}

impl Cp24 {
    pub(crate) fn decode(b: &[u8; 3]) -> Result<Cp24, String> {
        let millis = u16::from_le_bytes([b[0], b[1]]);
        let minute = b[2] & 0x3F;
        if millis > 59_999 || minute > 59 {
            return Err(format!("a CP24Time2a of minute {minute}, {millis} ms"));
        }
        Ok(Cp24 {
            millis,
            minute,
            invalid: b[2] & 0x80 != 0,
        })
    }

    pub(crate) fn encode(&self) -> [u8; 3] {
        let [m0, m1] = self.millis.to_le_bytes();
        [m0, m1, self.minute | if self.invalid { 0x80 } else { 0 }]
    }

    /// The time it names within the hour nearest before `now` (milliseconds since 1970).
    pub(crate) fn near(&self, now: i64) -> i64 {
        let hour = now.div_euclid(3_600_000) * 3_600_000;
        let at = hour + i64::from(self.minute) * 60_000 + i64::from(self.millis);
        if at > now + 60_000 {
            at - 3_600_000
        } else {
            at
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cp56_goes_both_ways_with_its_bits() {
        let c = Civil::parse("2026-12-03T07:08:09.123").expect("a date");
        let t = Cp56 {
            millis: c.millis_since_1970(),
            invalid: true,
            summer: false,
        };
        let b = t.encode();
        // 9123 ms, minute 8 with IV, hour 7, Thursday the 3rd, December, 2026.
        assert_eq!(b, [0xA3, 0x23, 0x88, 7, 3 | (4 << 5), 12, 26]);
        assert_eq!(Cp56::decode(&b), Ok(t));
    }

    #[test]
    fn a_cp56_out_of_range_is_named() {
        let e = Cp56::decode(&[0, 0, 0, 0, 31, 2, 26]).expect_err("February 31");
        assert!(e.contains("day 31"), "{e}");
        let e = Cp56::decode(&[0x60, 0xEA, 0, 0, 1, 1, 26]).expect_err("60000 ms");
        assert!(e.contains("60000"), "{e}");
        assert!(Cp56::decode(&[0, 0, 0, 0, 1, 13, 26]).is_err());
        assert!(Cp56::decode(&[0, 0, 60, 0, 1, 1, 26]).is_err());
    }

    #[test]
    fn a_cp24_is_placed_in_the_hour_before_now() {
        let t = Cp24::decode(&[0x10, 0x27, 59]).expect("10 s into minute 59");
        let now = Civil::parse("2026-12-03T08:00:05").expect("a date");
        let at = Civil::from_millis(t.near(now.millis_since_1970())).expect("a date");
        assert_eq!(at.to_string(), "2026-12-03T07:59:10.000");
        assert_eq!(Cp24::decode(&t.encode()), Ok(t));
    }
}

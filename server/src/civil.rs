//! Calendar dates and times of day (proleptic Gregorian, no zone), and milliseconds since
//! 1970: what the protocols that carry a clock (S7's DATE_AND_TIME and DTL, IEC 60870-5's
//! CP56Time2a) are converted through.

use std::fmt;

/// A calendar date and time of day.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Civil {
    pub(crate) year: i64,
    pub(crate) month: u8,
    pub(crate) day: u8,
    pub(crate) hour: u8,
    pub(crate) minute: u8,
    pub(crate) second: u8,
    pub(crate) nanos: u32,
}

/// Days since 1970-01-01 of a date (proleptic Gregorian).
fn days_from_civil(y: i64, m: u8, d: u8) -> i64 {
    let y = if m <= 2 { y - 1 } else { y };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let m = i64::from(m);
    let doy = (153 * (if m > 2 { m - 3 } else { m + 9 }) + 2) / 5 + i64::from(d) - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    era * 146_097 + doe - 719_468
}

fn civil_from_days(z: i64) -> (i64, u8, u8) {
    let z = z + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = (doy - (153 * mp + 2) / 5 + 1) as u8;
    let m = if mp < 10 { mp + 3 } else { mp - 9 } as u8;
    (yoe + era * 400 + i64::from(m <= 2), m, d)
}

fn days_in_month(y: i64, m: u8) -> u8 {
    match m {
        2 if (y % 4 == 0 && y % 100 != 0) || y % 400 == 0 => 29,
        2 => 28,
        4 | 6 | 9 | 11 => 30,
        _ => 31,
    }
}

impl Civil {
    /// Checks every part's range.
    pub(crate) fn checked(self) -> Result<Civil, String> {
        let bad = |what: &str, v: u32| Err(format!("not a date and time: {what} {v}"));
        if !(1..=12).contains(&self.month) {
            return bad("month", self.month.into());
        }
        if self.day == 0 || self.day > days_in_month(self.year, self.month) {
            return bad("day", self.day.into());
        }
        if self.hour > 23 {
            return bad("hour", self.hour.into());
        }
        if self.minute > 59 {
            return bad("minute", self.minute.into());
        }
        if self.second > 59 {
            return bad("second", self.second.into());
        }
        if self.nanos > 999_999_999 {
            return bad("nanosecond", self.nanos);
        }
        Ok(self)
    }

    pub(crate) fn millis_since_1970(&self) -> i64 {
        let days = days_from_civil(self.year, self.month, self.day);
        let secs = days * 86_400
            + i64::from(self.hour) * 3600
            + i64::from(self.minute) * 60
            + i64::from(self.second);
        secs * 1000 + i64::from(self.nanos / 1_000_000)
    }

    pub(crate) fn from_millis(ms: i64) -> Result<Civil, String> {
        let secs = ms.div_euclid(1000);
        let (year, month, day) = civil_from_days(secs.div_euclid(86_400));
        let of_day = secs.rem_euclid(86_400);
        Ok(Civil {
            year,
            month,
            day,
            hour: (of_day / 3600) as u8,
            minute: (of_day / 60 % 60) as u8,
            second: (of_day % 60) as u8,
            nanos: (ms.rem_euclid(1000) * 1_000_000) as u32,
        })
    }

    /// `YYYY-MM-DDTHH:MM:SS[.fraction]` (a space for the `T`, a trailing `Z`, accepted).
    pub(crate) fn parse(text: &str) -> Result<Civil, String> {
        let bad =
            || format!("`{text}` is not a date and time (write e.g. 2026-11-26T16:50:45.123)");
        let t = text.trim().trim_end_matches('Z');
        let (date, time) = t.split_once(['T', ' ']).ok_or_else(bad)?;
        let mut d = date.splitn(3, '-');
        let (clock, fraction) = time.split_once('.').unwrap_or((time, ""));
        let mut c = clock.splitn(3, ':');
        let num = |part: Option<&str>, width: usize| -> Result<i64, String> {
            let p = part.ok_or_else(bad)?;
            if p.len() != width || !p.bytes().all(|b| b.is_ascii_digit()) {
                return Err(bad());
            }
            p.parse().map_err(|_| bad())
        };
        let (year, month, day) = (num(d.next(), 4)?, num(d.next(), 2)?, num(d.next(), 2)?);
        let (hour, minute, second) = (num(c.next(), 2)?, num(c.next(), 2)?, num(c.next(), 2)?);
        if fraction.len() > 9 || !fraction.bytes().all(|b| b.is_ascii_digit()) {
            return Err(bad());
        }
        let nanos = format!("{fraction:0<9}")
            .parse::<u32>()
            .map_err(|_| bad())?;
        Civil {
            year,
            month: month as u8,
            day: day as u8,
            hour: hour as u8,
            minute: minute as u8,
            second: second as u8,
            nanos,
        }
        .checked()
    }

    /// 1 for Sunday to 7 for Saturday (as S7 counts).
    pub(crate) fn weekday(&self) -> u8 {
        ((days_from_civil(self.year, self.month, self.day) + 4).rem_euclid(7) + 1) as u8
    }

    /// 1 for Monday to 7 for Sunday (ISO 8601, as IEC 60870-5 counts).
    pub(crate) fn iso_weekday(&self) -> u8 {
        ((days_from_civil(self.year, self.month, self.day) + 3).rem_euclid(7) + 1) as u8
    }
}

impl fmt::Display for Civil {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{:04}-{:02}-{:02}T{:02}:{:02}:{:02}",
            self.year, self.month, self.day, self.hour, self.minute, self.second
        )?;
        if self.nanos.is_multiple_of(1_000_000) {
            write!(f, ".{:03}", self.nanos / 1_000_000)
        } else {
            write!(f, ".{:09}", self.nanos)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dates_go_both_ways() {
        let c = Civil::parse("2026-11-26T16:50:45.123").expect("parses");
        assert_eq!(c.to_string(), "2026-11-26T16:50:45.123");
        assert_eq!(c.weekday(), 5, "a Thursday, Sunday first");
        assert_eq!(c.iso_weekday(), 4, "a Thursday, Monday first");
        assert_eq!(c.millis_since_1970(), 1_795_711_845_123);
        assert_eq!(Civil::from_millis(c.millis_since_1970()), Ok(c));
        assert_eq!(
            Civil::from_millis(0).map(|c| c.to_string()).as_deref(),
            Ok("1970-01-01T00:00:00.000")
        );
    }

    #[test]
    fn a_bad_date_is_refused() {
        for text in [
            "2026-13-01T00:00:00",
            "2026-02-29T00:00:00",
            "2026-11-26",
            "26-11-26T1:2:3",
        ] {
            assert!(Civil::parse(text).is_err(), "{text}");
        }
    }
}

//! Dates and times as the PLC stores them: DATE_AND_TIME (eight BCD bytes, years 1990-2089,
//! milliseconds) and DTL (twelve bytes, nanoseconds), as ISO 8601 text or milliseconds since
//! 1970 (the PLC's own clock, no zone).

pub(crate) use crate::civil::Civil;

fn from_bcd(b: u8) -> Result<u8, String> {
    if b >> 4 > 9 || b & 0xF > 9 {
        return Err(format!("{b:#04x} is not BCD"));
    }
    Ok((b >> 4) * 10 + (b & 0xF))
}

fn to_bcd(n: u8) -> u8 {
    ((n / 10) << 4) | (n % 10)
}

/// A DATE_AND_TIME's eight bytes.
pub(crate) fn from_dt(b: &[u8]) -> Result<Civil, String> {
    let yy = i64::from(from_bcd(b[0])?);
    let ms = u32::from(from_bcd(b[6])?) * 10 + u32::from(from_bcd(b[7] >> 4)?);
    Civil {
        year: if yy >= 90 { 1900 + yy } else { 2000 + yy },
        month: from_bcd(b[1])?,
        day: from_bcd(b[2])?,
        hour: from_bcd(b[3])?,
        minute: from_bcd(b[4])?,
        second: from_bcd(b[5])?,
        nanos: ms * 1_000_000,
    }
    .checked()
}

/// A DATE_AND_TIME of a date in its years (1990-2089) to the millisecond.
pub(crate) fn to_dt(c: &Civil) -> Result<Vec<u8>, String> {
    if !(1990..=2089).contains(&c.year) {
        return Err(format!("a DATE_AND_TIME holds 1990-2089, not {}", c.year));
    }
    if !c.nanos.is_multiple_of(1_000_000) {
        return Err("a DATE_AND_TIME holds milliseconds, not finer".to_owned());
    }
    let ms = c.nanos / 1_000_000;
    Ok(vec![
        to_bcd((c.year % 100) as u8),
        to_bcd(c.month),
        to_bcd(c.day),
        to_bcd(c.hour),
        to_bcd(c.minute),
        to_bcd(c.second),
        to_bcd((ms / 10) as u8),
        (to_bcd((ms % 10) as u8) << 4) | c.weekday(),
    ])
}

/// A DTL's twelve bytes.
pub(crate) fn from_dtl(b: &[u8]) -> Result<Civil, String> {
    Civil {
        year: i64::from(u16::from_be_bytes([b[0], b[1]])),
        month: b[2],
        day: b[3],
        hour: b[5],
        minute: b[6],
        second: b[7],
        nanos: u32::from_be_bytes([b[8], b[9], b[10], b[11]]),
    }
    .checked()
}

/// A DTL (years 1970-2262 on the PLC; the year as it is here).
pub(crate) fn to_dtl(c: &Civil) -> Vec<u8> {
    let mut out = (c.year as u16).to_be_bytes().to_vec();
    out.extend_from_slice(&[c.month, c.day, c.weekday(), c.hour, c.minute, c.second]);
    out.extend_from_slice(&c.nanos.to_be_bytes());
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dates_go_both_ways() {
        let c = Civil::parse("2026-11-26T16:50:45.123").expect("parses");
        let dt = to_dt(&c).expect("in range");
        assert_eq!(dt, [0x26, 0x11, 0x26, 0x16, 0x50, 0x45, 0x12, 0x35]);
        assert_eq!(from_dt(&dt), Ok(c));
        assert_eq!(from_dtl(&to_dtl(&c)), Ok(c));
    }

    #[test]
    fn a_date_out_of_its_years_is_refused() {
        let c = Civil::parse("2100-01-01T00:00:00").expect("parses");
        assert!(to_dt(&c).expect_err("2100").contains("1990-2089"));
        assert!(from_dt(&[0x26, 0x13, 1, 0, 0, 0, 0, 0]).is_err());
    }
}

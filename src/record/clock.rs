//! Wall-clock times as UTC text, without a date library: the civil date of a day count
//! (Howard Hinnant's `civil_from_days`), for record file names and summaries.

use std::time::{SystemTime, UNIX_EPOCH};

/// Nanoseconds since 1970-01-01T00:00:00Z now (negative before it, saturated to `i64`).
pub fn unix_ns_now() -> i64 {
    match SystemTime::now().duration_since(UNIX_EPOCH) {
        Ok(d) => i64::try_from(d.as_nanos()).unwrap_or(i64::MAX),
        Err(e) => i64::try_from(e.duration().as_nanos()).map_or(i64::MIN, |ns| -ns),
    }
}

/// A UTC calendar time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Utc {
    pub year: i64,
    pub month: u32,
    pub day: u32,
    pub hour: u32,
    pub minute: u32,
    pub second: u32,
    pub millisecond: u32,
}

/// Year, month (1–12), day (1–31) of the day `days` after 1970-01-01 (proleptic Gregorian).
pub fn civil_from_days(days: i64) -> (i64, u32, u32) {
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097); // 0 ..= 146 096
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365; // 0 ..= 399
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100); // 0 ..= 365
    let mp = (5 * doy + 2) / 153; // 0 ..= 11, March first
    let day = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let month = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    let year = yoe + era * 400 + i64::from(month <= 2);
    (year, month, day)
}

impl Utc {
    pub fn from_unix_ns(unix_ns: i64) -> Utc {
        const NS_PER_DAY: i64 = 86_400 * 1_000_000_000;
        let days = unix_ns.div_euclid(NS_PER_DAY);
        let ns_of_day = unix_ns.rem_euclid(NS_PER_DAY);
        let (year, month, day) = civil_from_days(days);
        let secs = ns_of_day / 1_000_000_000;
        Utc {
            year,
            month,
            day,
            hour: (secs / 3600) as u32,
            minute: (secs / 60 % 60) as u32,
            second: (secs % 60) as u32,
            millisecond: (ns_of_day / 1_000_000 % 1000) as u32,
        }
    }

    /// `20261121T235959Z`: sorts like the time, safe in file names.
    pub fn file_stamp(&self) -> String {
        format!(
            "{:04}{:02}{:02}T{:02}{:02}{:02}Z",
            self.year, self.month, self.day, self.hour, self.minute, self.second
        )
    }
}

impl std::fmt::Display for Utc {
    /// `2026-11-21 23:59:59.123 UTC`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{:04}-{:02}-{:02} {:02}:{:02}:{:02}.{:03} UTC",
            self.year, self.month, self.day, self.hour, self.minute, self.second, self.millisecond
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn civil_dates_of_known_days() {
        assert_eq!(civil_from_days(0), (1970, 1, 1));
        assert_eq!(civil_from_days(-1), (1969, 12, 31));
        assert_eq!(civil_from_days(11_016), (2000, 2, 29));
        assert_eq!(civil_from_days(20_413), (2025, 11, 21));
    }

    #[test]
    fn stamps_and_display() {
        // 2026-11-21T23:59:59.5Z
        let ns = (20_778i64 * 86_400 + 86_399) * 1_000_000_000 + 500_000_000;
        let t = Utc::from_unix_ns(ns);
        assert_eq!(t.file_stamp(), "20261121T235959Z");
        assert_eq!(t.to_string(), "2026-11-21 23:59:59.500 UTC");
        assert_eq!(Utc::from_unix_ns(-1).file_stamp(), "19691231T235959Z");
        let _ = Utc::from_unix_ns(i64::MIN).file_stamp();
        let _ = Utc::from_unix_ns(i64::MAX).file_stamp();
    }
}

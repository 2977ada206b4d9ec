//! Wall-clock times as UTC text, for record file names and summaries. The calendar arithmetic
//! is the `time` crate's, built with `std` only (no formatting macros, no time-zone database):
//! it and its four small dependencies took 4.6 s of CPU to build at this project's dependency
//! optimisation level (even with its `formatting` feature, not used here), against 19.1 s for
//! `jiff` with `std` only, measured on the 2-core development machine. The text is assembled
//! here from its fields.

use std::time::{SystemTime, UNIX_EPOCH};
use time::OffsetDateTime;

/// Nanoseconds since 1970-01-01T00:00:00Z now (negative before it, saturated to `i64`).
pub fn unix_ns_now() -> i64 {
    match SystemTime::now().duration_since(UNIX_EPOCH) {
        Ok(d) => i64::try_from(d.as_nanos()).unwrap_or(i64::MAX),
        Err(e) => i64::try_from(e.duration().as_nanos()).map_or(i64::MIN, |ns| -ns),
    }
}

/// A UTC calendar time (proleptic Gregorian).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Utc(OffsetDateTime);

impl Utc {
    /// The time `unix_ns` nanoseconds after 1970-01-01T00:00:00Z. Every `i64` is in range
    /// (years 1677–2262).
    pub fn from_unix_ns(unix_ns: i64) -> Utc {
        Utc(
            OffsetDateTime::from_unix_timestamp_nanos(i128::from(unix_ns))
                .unwrap_or(OffsetDateTime::UNIX_EPOCH),
        )
    }

    /// `20261121T235959Z`: sorts like the time, safe in file names.
    pub fn file_stamp(&self) -> String {
        let t = self.0;
        format!(
            "{:04}{:02}{:02}T{:02}{:02}{:02}Z",
            t.year(),
            u8::from(t.month()),
            t.day(),
            t.hour(),
            t.minute(),
            t.second()
        )
    }
}

impl Utc {
    /// `2026-11-21`.
    pub fn date(&self) -> String {
        let t = self.0;
        format!("{:04}-{:02}-{:02}", t.year(), u8::from(t.month()), t.day())
    }

    /// `2026-11-21 23:59`.
    pub fn minute(&self) -> String {
        let t = self.0;
        format!("{} {:02}:{:02}", self.date(), t.hour(), t.minute())
    }

    /// `2026-11-21T23:59:59Z` (ISO 8601, whole seconds).
    pub fn iso(&self) -> String {
        let t = self.0;
        format!(
            "{}T{:02}:{:02}:{:02}Z",
            self.date(),
            t.hour(),
            t.minute(),
            t.second()
        )
    }

    /// `2026-11-21T23:59:59.123456Z` (ISO 8601, to the microsecond).
    pub fn iso_micros(&self) -> String {
        let t = self.0;
        format!(
            "{}T{:02}:{:02}:{:02}.{:06}Z",
            self.date(),
            t.hour(),
            t.minute(),
            t.second(),
            t.microsecond()
        )
    }

    /// Parse `YYYY-MM-DD`, `YYYY-MM-DDTHH:MM`, `YYYY-MM-DDTHH:MM:SS` (a space for the `T`,
    /// and a trailing `Z`, are accepted) as UTC: ns since 1970-01-01.
    pub fn parse_unix_ns(text: &str) -> Option<i64> {
        let text = text.trim().trim_end_matches(['Z', 'z']);
        let (date, time) = match text.split_once(['T', 't', ' ']) {
            Some((d, t)) => (d, Some(t)),
            None => (text, None),
        };
        let mut d = date.split('-');
        let year: i32 = d.next()?.parse().ok()?;
        let month: u8 = d.next()?.parse().ok()?;
        let day: u8 = d.next()?.parse().ok()?;
        if d.next().is_some() {
            return None;
        }
        let (mut hour, mut minute, mut second) = (0u8, 0u8, 0u8);
        if let Some(time) = time {
            let mut t = time.split(':');
            hour = t.next()?.parse().ok()?;
            minute = t.next()?.parse().ok()?;
            if let Some(s) = t.next() {
                second = s.parse().ok()?;
            }
            if t.next().is_some() {
                return None;
            }
        }
        let date =
            time::Date::from_calendar_date(year, time::Month::try_from(month).ok()?, day).ok()?;
        let time = time::Time::from_hms(hour, minute, second).ok()?;
        let ns = time::PrimitiveDateTime::new(date, time)
            .assume_utc()
            .unix_timestamp_nanos();
        i64::try_from(ns).ok()
    }
}

impl std::fmt::Display for Utc {
    /// `2026-11-21 23:59:59.123 UTC`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let t = self.0;
        write!(
            f,
            "{:04}-{:02}-{:02} {:02}:{:02}:{:02}.{:03} UTC",
            t.year(),
            u8::from(t.month()),
            t.day(),
            t.hour(),
            t.minute(),
            t.second(),
            t.millisecond()
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const NS_PER_DAY: i64 = 86_400 * 1_000_000_000;

    #[test]
    fn civil_dates_of_known_days() {
        let date = |days: i64| Utc::from_unix_ns(days * NS_PER_DAY).file_stamp();
        assert_eq!(date(0), "19700101T000000Z");
        assert_eq!(date(-1), "19691231T000000Z");
        assert_eq!(date(11_016), "20000229T000000Z");
        assert_eq!(date(20_413), "20251121T000000Z");
    }

    #[test]
    fn dates_parse_as_utc_and_print_back() {
        let ns = Utc::parse_unix_ns("2026-11-21T23:59:59Z").unwrap();
        assert_eq!(Utc::from_unix_ns(ns).iso(), "2026-11-21T23:59:59Z");
        assert_eq!(Utc::from_unix_ns(ns).minute(), "2026-11-21 23:59");
        let day = Utc::parse_unix_ns("2026-11-21").unwrap();
        assert_eq!(
            Utc::from_unix_ns(day).to_string(),
            "2026-11-21 00:00:00.000 UTC"
        );
        assert_eq!(
            Utc::parse_unix_ns("2026-11-21 08:30"),
            Some(day + 510 * 60 * 1_000_000_000)
        );
        for bad in [
            "",
            "2026-13-01",
            "2026-02-30",
            "2026-1",
            "21.11.2026",
            "2026-11-21T25:00",
        ] {
            assert_eq!(Utc::parse_unix_ns(bad), None, "{bad}");
        }
    }

    #[test]
    fn stamps_and_display() {
        // 2026-11-21T23:59:59.5Z
        let ns = (20_778i64 * 86_400 + 86_399) * 1_000_000_000 + 500_000_000;
        let t = Utc::from_unix_ns(ns);
        assert_eq!(t.file_stamp(), "20261121T235959Z");
        assert_eq!(t.to_string(), "2026-11-21 23:59:59.500 UTC");
        assert_eq!(t.iso_micros(), "2026-11-21T23:59:59.500000Z");
        assert_eq!(
            Utc::from_unix_ns(ns + 123_456_789).iso_micros(),
            "2026-11-21T23:59:59.623456Z"
        );
        assert_eq!(
            Utc::from_unix_ns(-1).iso_micros(),
            "1969-12-31T23:59:59.999999Z"
        );
        assert_eq!(Utc::from_unix_ns(-1).file_stamp(), "19691231T235959Z");
        assert_eq!(
            Utc::from_unix_ns(i64::MIN).to_string(),
            "1677-09-21 00:12:43.145 UTC"
        );
        assert_eq!(
            Utc::from_unix_ns(i64::MAX).to_string(),
            "2262-04-11 23:47:16.854 UTC"
        );
    }
}

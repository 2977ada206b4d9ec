//! The rhythm of incoming goals, so that a telemetry poll is not started just before the next
//! goal is due. An autopilot sends its outputs at a steady rate (50 Hz is a 20 ms period); a
//! poll holds the half-duplex bus for about 3 ms at 115 200 bit/s, and a goal that arrives
//! while one is in flight waits for it. When the goals keep a steady period, the bus master
//! leaves the bus free from shortly before each expected goal until it arrives (or until its
//! arrival window has passed), and polls in the rest of the period.
//!
//! Plain data and arithmetic on instants handed in: no clock, no I/O.

use std::time::{Duration, Instant};

/// Goals closer together than this belong to one autopilot message.
const SAME_MESSAGE: Duration = Duration::from_millis(1);
/// Periods shorter than this leave no room to gate polls without starving telemetry.
const MIN_PERIOD: Duration = Duration::from_millis(4);
/// The rhythm is trusted for this many periods after the last goal.
const TRUSTED_PERIODS: u32 = 3;
/// Intervals measured before the rhythm is trusted.
const MIN_SAMPLES: u32 = 4;
/// Slack added to the arrival window on both sides, besides twice the measured jitter.
const SLACK: Duration = Duration::from_micros(300);

/// The measured period and jitter of goal messages.
#[derive(Debug, Clone, Copy, Default)]
pub struct GoalRhythm {
    last: Option<Instant>,
    period: Option<Duration>,
    jitter: Duration,
    /// Intervals that agreed with the period so far.
    samples: u32,
    /// Intervals in a row shorter than half the period.
    short_in_a_row: u32,
}

impl GoalRhythm {
    /// A goal message arrived at `now`.
    pub fn goal_at(&mut self, now: Instant) {
        let Some(last) = self.last else {
            self.last = Some(now);
            return;
        };
        let interval = now.saturating_duration_since(last);
        if interval < SAME_MESSAGE {
            return;
        }
        self.last = Some(now);
        match self.period {
            None if interval < Duration::from_secs(1) => self.period = Some(interval),
            None => {}
            Some(p) => {
                // Short intervals are jitter, until three in a row say the stream is faster
                // than the one measured: then it is learnt afresh.
                if interval < p / 2 {
                    self.short_in_a_row += 1;
                    if self.short_in_a_row >= 3 {
                        *self = GoalRhythm {
                            last: Some(now),
                            period: Some(interval),
                            ..GoalRhythm::default()
                        };
                    } else {
                        self.jitter = (self.jitter * 7 + p - interval) / 8;
                    }
                    return;
                }
                self.short_in_a_row = 0;
                // Skipped messages (unchanged outputs) show as whole multiples: not a new period.
                if interval > p + p / 2 {
                    return;
                }
                let deviation = interval.abs_diff(p);
                self.period = Some((p * 7 + interval) / 8);
                self.jitter = (self.jitter * 7 + deviation) / 8;
                self.samples = self.samples.saturating_add(1);
            }
        }
    }

    /// The measured period, once one is known.
    pub fn period(&self) -> Option<Duration> {
        self.period
    }

    /// If a transaction of length `busy` started at `now` would still hold the bus when the
    /// next goal is expected, the instant until which the bus should stay free (the end of the
    /// goal's arrival window); `None` when it may start.
    pub fn hold_until(&self, now: Instant, busy: Duration) -> Option<Instant> {
        let (last, period) = (self.last?, self.period?);
        if self.samples < MIN_SAMPLES
            || period < MIN_PERIOD
            || self.jitter * 4 > period
            || busy * 2 > period
        {
            return None;
        }
        let since = now.saturating_duration_since(last);
        if since > period * TRUSTED_PERIODS {
            return None;
        }
        let spread = self.jitter * 2 + SLACK;
        // The expected arrival whose window has not ended yet.
        let periods = (since.saturating_sub(spread).as_nanos() / period.as_nanos()) as u32 + 1;
        let next = last + period * periods;
        let opens = next.checked_sub(spread)?;
        let closes = next + spread;
        (now + busy > opens && now < closes).then_some(closes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ms(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    fn steady(t0: Instant, n: u32, period: Duration) -> GoalRhythm {
        let mut r = GoalRhythm::default();
        for k in 0..n {
            r.goal_at(t0 + period * k);
        }
        r
    }

    #[test]
    fn a_steady_50_hz_stream_is_measured() {
        let t0 = Instant::now();
        let r = steady(t0, 20, ms(20));
        assert_eq!(r.period(), Some(ms(20)));
    }

    #[test]
    fn a_faster_stream_replaces_a_slow_one() {
        let t0 = Instant::now();
        let mut r = steady(t0, 5, ms(100));
        for k in 1..=10 {
            r.goal_at(t0 + ms(400) + ms(20) * k);
        }
        assert_eq!(r.period(), Some(ms(20)));
    }

    #[test]
    fn a_poll_that_would_overlap_the_next_goal_waits_for_it() {
        let t0 = Instant::now();
        let r = steady(t0, 20, ms(20));
        let last = t0 + ms(20) * 19;
        let busy = Duration::from_micros(3200);
        // Just after a goal: plenty of room.
        assert_eq!(r.hold_until(last + ms(1), busy), None);
        assert_eq!(r.hold_until(last + ms(16), busy), None);
        // 17 ms after it a 3.2 ms poll would run into the goal due at 20 ms.
        let closes = last + ms(20) + SLACK;
        assert_eq!(r.hold_until(last + ms(17), busy), Some(closes));
        assert_eq!(r.hold_until(last + ms(20), busy), Some(closes));
        // The goal is late: once its window has closed, polling goes on.
        assert_eq!(r.hold_until(closes, busy), None);
        // One skipped message (unchanged outputs): the next expected goal is gated too.
        assert_eq!(
            r.hold_until(last + ms(38), busy),
            Some(last + ms(40) + SLACK)
        );
    }

    #[test]
    fn fast_irregular_or_old_rhythms_gate_nothing() {
        let t0 = Instant::now();
        let busy = Duration::from_micros(3200);
        // 400 Hz: a poll does not fit between two goals; gating would starve telemetry.
        let r = steady(t0, 50, Duration::from_micros(2500));
        assert_eq!(r.hold_until(t0 + ms(124), busy), None);
        // Irregular arrivals: the jitter grows past a quarter of the period.
        let mut r = GoalRhythm::default();
        let offsets = [
            0u64, 9, 1, 8, 0, 9, 2, 8, 1, 9, 0, 8, 0, 9, 1, 8, 0, 9, 2, 8,
        ];
        for (k, jitter) in offsets.iter().enumerate() {
            r.goal_at(t0 + ms(20 * k as u64 + jitter));
        }
        let last = t0 + ms(20 * 19 + 8);
        assert!((0..20).all(|k| r.hold_until(last + ms(k), busy).is_none()));
        // Too few goals to know a rhythm.
        let r = steady(t0, 4, ms(20));
        assert_eq!(r.hold_until(t0 + ms(78), busy), None);
        // The stream stopped: after three periods nothing is expected any more.
        let r = steady(t0, 20, ms(20));
        assert_eq!(r.hold_until(t0 + ms(20 * 19 + 77), busy), None);
    }
}

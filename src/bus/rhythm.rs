//! The rhythm of the autopilot's output messages, so that no poll holds the bus when a goal
//! comes. An autopilot sends its outputs at a steady rate (50 Hz is a 20 ms period), in one or
//! several messages per tick (SERVO_OUTPUT_RAW ports 0 and 1, ACTUATOR_OUTPUT_STATUS), whether
//! they changed or not; a poll holds the half-duplex bus for 2–3 ms at 115 200 bit/s, and a goal
//! that arrives while one is in flight waits for it. When the messages keep a steady period,
//! the bus master leaves the bus free from shortly before each expected tick until it arrives
//! (or, for a late tick, until a good part of the period has passed), and polls in the rest of
//! the period.
//!
//! Every output message is an arrival, changed or not: a hold of the aircraft's outputs for
//! seconds keeps the rhythm, so that the step that ends it finds the bus free.
//!
//! The expected tick is predicted from a smoothed phase, not from the last arrival alone: with
//! arrivals that jitter by ±1 ms around a steady clock, the next one is within ±1 ms of the
//! prediction, where the last arrival alone would leave ±2 ms. The rhythm comes back by itself:
//! after a silence of more than [`TRUSTED_PERIODS`] periods the phase is taken afresh from the
//! first tick back, and [`RELEARN_AFTER`] intervals in a row that agree with each other but
//! not with the period (a stream slowed down during a log transfer, or granted at a lower rate)
//! set a new period; a faster stream is learnt after three short intervals.
//!
//! The messages of one tick are counted and timed from the tick's first, so that the bus
//! master can wait for the rest of a tick ([`GoalRhythm::rest_of_tick`]) and send one long
//! packet for all of it.
//!
//! Plain data and arithmetic on instants handed in: no clock, no I/O.

use std::time::{Duration, Instant};

/// Messages closer together than this belong to one autopilot tick, at the least.
const SAME_TICK: Duration = Duration::from_millis(1);
/// Periods shorter than this leave no room to gate polls without starving telemetry.
const MIN_PERIOD: Duration = Duration::from_millis(4);
/// The rhythm is trusted for this many periods after the last tick.
pub const TRUSTED_PERIODS: u32 = 3;
/// Intervals measured before the rhythm is trusted.
const MIN_SAMPLES: u32 = 4;
/// Slack added to the arrival window on both sides, besides the measured jitter.
const SLACK: Duration = Duration::from_micros(300);
/// The window opens this many mean deviations before the predicted tick.
const SPREAD_DEVIATIONS: u32 = 3;
/// Intervals in a row that agree with each other, and not with the period, that set a new one.
pub const RELEARN_AFTER: u32 = 3;
/// Messages of one tick whose offsets are kept.
const TICK_MESSAGES: usize = 8;
/// Waiting for the rest of a tick allows this much besides the offset the tick before had: a
/// second message a little later than the last (its sender preempted between its two sends)
/// still leaves with the first. Splitting costs more: the second message's goals wait for the
/// whole first packet on the wire (2.4 ms for four servos at 115 200 bit/s).
const REST_SLACK: Duration = Duration::from_micros(250);

/// The messages of one tick: how many, and when each came after the first.
#[derive(Debug, Clone, Copy, Default)]
struct TickMessages {
    count: u32,
    offsets: [Duration; TICK_MESSAGES],
}

impl TickMessages {
    fn add(&mut self, offset: Duration) {
        if let Some(slot) = self.offsets.get_mut(self.count as usize) {
            *slot = offset;
        }
        self.count = self.count.saturating_add(1);
    }

    /// How many messages came within `within` of the first, and the offset of the latest.
    fn within(&self, within: Duration) -> (u32, Duration) {
        let kept = &self.offsets[..(self.count as usize).min(TICK_MESSAGES)];
        kept.iter()
            .filter(|o| **o <= within)
            .fold((0, Duration::ZERO), |(n, latest), o| {
                (n + 1, latest.max(*o))
            })
    }
}

/// The measured period, phase and jitter of the autopilot's ticks.
#[derive(Debug, Clone, Copy, Default)]
pub struct GoalRhythm {
    /// When the latest tick began (its first message).
    last: Option<Instant>,
    /// When the latest tick was due by the smoothed phase.
    anchor: Option<Instant>,
    /// The latest message of any tick.
    latest: Option<Instant>,
    period: Option<Duration>,
    /// Mean deviation of ticks from their predicted instant.
    jitter: Duration,
    /// Intervals that agreed with the period so far.
    samples: u32,
    /// Messages in a row that came less than half a period after the tick before.
    short_in_a_row: u32,
    /// Intervals in a row that disagree with the period (the latest of them), and how many.
    disagreeing: Option<(Duration, u32)>,
    /// Messages closer than this to the one before belong to the same tick.
    same_tick: Duration,
    /// The messages of the latest tick, and of the one before it.
    tick: TickMessages,
    previous_tick: TickMessages,
    /// How long before the latest tick the one before it began.
    tick_interval: Option<Duration>,
}

impl GoalRhythm {
    /// A rhythm in which messages less than `same_tick` apart (at least 1 ms) belong to one
    /// autopilot tick.
    pub fn new(same_tick: Duration) -> Self {
        GoalRhythm {
            same_tick: same_tick.max(SAME_TICK),
            ..GoalRhythm::default()
        }
    }

    /// An output message of the autopilot arrived at `now`, whatever it carried.
    pub fn message_at(&mut self, now: Instant) {
        let previous = self.latest.replace(now);
        let (Some(last), Some(anchor), Some(previous)) = (self.last, self.anchor, previous) else {
            self.begin_tick(now);
            self.anchor = Some(now);
            return;
        };
        let gap = now.saturating_duration_since(previous);
        if gap < self.same_tick {
            self.tick.add(now.saturating_duration_since(last));
            return;
        }
        let interval = now.saturating_duration_since(last);
        let Some(p) = self.period else {
            self.begin_tick(now);
            self.anchor = Some(now);
            if interval < Duration::from_secs(1) {
                self.period = Some(interval);
            }
            return;
        };
        // Messages in a row less than half a period apart say the stream is faster than the
        // one measured (one or two are several messages of one tick): it is learnt afresh.
        if gap < p / 2 {
            self.short_in_a_row += 1;
            if self.short_in_a_row >= 3 {
                *self = GoalRhythm {
                    last: Some(now),
                    anchor: Some(now),
                    latest: Some(now),
                    period: Some(gap),
                    tick: self.tick,
                    previous_tick: self.previous_tick,
                    ..GoalRhythm::new(self.same_tick)
                };
                self.begin_tick(now);
                return;
            }
        } else {
            self.short_in_a_row = 0;
        }
        // The tick this message belongs to: the nearest whole number of periods after the
        // anchor. None: a later message of the latest tick (another port, a late message).
        // Several: ticks were skipped (messages lost, or the stream slowed down).
        let periods =
            (now.saturating_duration_since(anchor).as_nanos() + p.as_nanos() / 2) / p.as_nanos();
        if periods == 0 {
            self.tick.add(interval);
            return;
        }
        self.begin_tick(now);
        if self.relearn(interval, p, now) {
            return;
        }
        if interval > p * TRUSTED_PERIODS {
            // Back after a silence: the autopilot may have restarted with another phase. The
            // period is kept, the phase taken from this tick.
            self.anchor = Some(now);
            return;
        }
        let periods = u32::try_from(periods).unwrap_or(u32::MAX);
        let predicted = anchor + p * periods;
        // An alpha-beta tracker of phase and period: half the deviation moves the phase, an
        // eighth of it (per period) the period. A tick far off its prediction (a late message)
        // counts for no more than twice the window's early side.
        let bound = self.early() * 2;
        let (late, deviation) = match now.checked_duration_since(predicted) {
            Some(d) => (true, d),
            None => (false, predicted.saturating_duration_since(now)),
        };
        let error = deviation.min(bound);
        let shift = |t: Instant, d: Duration| {
            if late {
                t + d
            } else {
                t.checked_sub(d).unwrap_or(t)
            }
        };
        self.anchor = Some(shift(predicted, error / 2));
        let correction = error / 8 / periods;
        self.period = Some(if late {
            p + correction
        } else {
            p.saturating_sub(correction)
        });
        self.jitter = (self.jitter * 7 + deviation.min(bound)) / 8;
        if periods == 1 && interval >= p / 2 && interval <= p + p / 2 {
            self.samples = self.samples.saturating_add(1);
        }
    }

    /// A tick began at `now`: the one that ended becomes the previous tick.
    fn begin_tick(&mut self, now: Instant) {
        if self.tick.count > 0 {
            self.previous_tick = self.tick;
        }
        self.tick_interval = self.last.map(|last| now.saturating_duration_since(last));
        self.tick = TickMessages::default();
        self.tick.add(Duration::ZERO);
        self.last = Some(now);
    }

    /// Count an interval between ticks that disagrees with the period `p` by more than an
    /// eighth; after [`RELEARN_AFTER`] of them in a row that agree with each other, the latest
    /// becomes the period and this tick the phase (true). A tick that agrees with `p` resets
    /// the count.
    fn relearn(&mut self, interval: Duration, p: Duration, now: Instant) -> bool {
        let agrees = |a: Duration, b: Duration| a.abs_diff(b) <= b / 8;
        if agrees(interval, p) {
            self.disagreeing = None;
            return false;
        }
        let count = match self.disagreeing {
            Some((before, n)) if agrees(interval, before) => n + 1,
            _ => 1,
        };
        self.disagreeing = Some((interval, count));
        if count < RELEARN_AFTER {
            return false;
        }
        self.period = Some(interval);
        self.anchor = Some(now);
        self.jitter = Duration::ZERO;
        self.samples = MIN_SAMPLES;
        self.disagreeing = None;
        true
    }

    /// The measured period, once one is known.
    pub fn period(&self) -> Option<Duration> {
        self.period
    }

    /// The latest message of any tick.
    pub fn latest_message(&self) -> Option<Instant> {
        self.latest
    }

    /// When the latest tick began, while the rhythm is trusted at `now` (see
    /// [`GoalRhythm::window`]), with the period.
    pub fn tick(&self, now: Instant) -> Option<(Instant, Duration)> {
        self.window(now)?;
        Some((self.last?, self.period?))
    }

    /// Whether the latest tick has had fewer messages so far than the tick before it (a
    /// message of it is still to come), seen at `now` while the rhythm is trusted.
    pub fn tick_incomplete(&self, now: Instant) -> bool {
        self.tick(now).is_some() && self.tick.count < self.previous_tick.count
    }

    /// Whether the latest tick has had as many messages as the tick before it (nothing more of
    /// it is expected), seen at `now` while the rhythm is trusted.
    pub fn tick_complete(&self, now: Instant) -> bool {
        self.tick(now).is_some()
            && self.previous_tick.count > 0
            && self.tick.count >= self.previous_tick.count
    }

    /// While the latest tick, begun at most `within` ago, still lacks messages that the tick
    /// before it had within `within` of its start: when the last of them is expected (its
    /// offset in the tick before, and a little slack). `None` when nothing more is expected
    /// that soon, or the tick before is older than [`TRUSTED_PERIODS`] periods.
    pub fn rest_of_tick(&self, now: Instant, within: Duration) -> Option<Instant> {
        let (last, period, interval) = (self.last?, self.period?, self.tick_interval?);
        if now.saturating_duration_since(last) > within || interval > period * TRUSTED_PERIODS {
            return None;
        }
        let (expected, latest) = self.previous_tick.within(within);
        let (had, _) = self.tick.within(within);
        if had >= expected {
            return None;
        }
        let until = last + latest + REST_SLACK.max(latest / 2);
        (until > now).then_some(until)
    }

    /// How long before the predicted tick the bus is kept free.
    fn early(&self) -> Duration {
        self.jitter * SPREAD_DEVIATIONS + SLACK
    }

    /// If a transaction of length `busy` started at `now` would still hold the bus when the
    /// next tick is expected, the instant until which the bus should stay free (the end of the
    /// tick's arrival window); `None` when it may start.
    ///
    /// The window opens three mean deviations (plus a slack) before the
    /// predicted tick and closes as long after it, or half a period after it if that
    /// is later: a tick that comes late (a delayed message) still finds the bus free, at the
    /// cost of some polls in that one period.
    pub fn hold_until(&self, now: Instant, busy: Duration) -> Option<Instant> {
        let (opens, closes) = self.window(now)?;
        (busy * 2 <= self.period? && now + busy > opens && now < closes).then_some(closes)
    }

    /// The arrival window of the expected tick that has not ended at `now` (opens, closes),
    /// or `None` when the rhythm gates nothing (not known, irregular, too fast, or stopped).
    pub fn window(&self, now: Instant) -> Option<(Instant, Instant)> {
        let (last, anchor, period) = (self.last?, self.anchor?, self.period?);
        let early = self.early();
        if self.samples < MIN_SAMPLES || period < MIN_PERIOD || early * 4 > period {
            return None;
        }
        if now.saturating_duration_since(last) > period * TRUSTED_PERIODS {
            return None;
        }
        let late = early.max(period / 2);
        let since = now.saturating_duration_since(anchor).saturating_sub(late);
        let periods = (since.as_nanos() / period.as_nanos()) as u32 + 1;
        let next = anchor + period * periods;
        Some((next.checked_sub(early)?, next + late))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ms(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    fn steady(t0: Instant, n: u32, period: Duration) -> GoalRhythm {
        let mut r = GoalRhythm::new(ms(2));
        for k in 0..n {
            r.message_at(t0 + period * k);
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
            r.message_at(t0 + ms(400) + ms(20) * k);
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
        // 17 ms after it a 3.2 ms poll would run into the goal due at 20 ms. The bus is held
        // until half a period after the expected goal, for a goal that comes late.
        let closes = last + ms(20) + ms(10);
        assert_eq!(r.hold_until(last + ms(17), busy), Some(closes));
        assert_eq!(r.hold_until(last + ms(20), busy), Some(closes));
        assert_eq!(r.hold_until(last + ms(27), busy), Some(closes));
        // The goal is later still: once its window has closed, polling goes on.
        assert_eq!(r.hold_until(closes, busy), None);
        // One skipped message (unchanged outputs): the next expected goal is gated too.
        assert_eq!(
            r.hold_until(last + ms(38), busy),
            Some(last + ms(40) + ms(10))
        );
    }

    /// Arrivals spread uniformly over ±1 ms around a steady 50 Hz clock (a deterministic
    /// sequence that covers the range).
    fn jittery(t0: Instant, n: u32) -> (GoalRhythm, Vec<Instant>) {
        let mut r = GoalRhythm::new(ms(2));
        let mut at = Vec::new();
        let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
        for k in 0..n {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let offset = (x % 2001) as i64 - 1000;
            let tick = t0 + ms(20) * (k + 1);
            let t = if offset >= 0 {
                tick + Duration::from_micros(offset as u64)
            } else {
                tick - Duration::from_micros(offset.unsigned_abs())
            };
            at.push(t);
            r.message_at(t);
        }
        (r, at)
    }

    #[test]
    fn a_jittery_tick_is_expected_from_the_smoothed_phase_and_always_finds_the_bus_free() {
        let t0 = Instant::now();
        let (r0, at) = jittery(t0, 200);
        let busy = Duration::from_micros(2300);
        // Replay: before every arrival after the first 20, a poll started as late as the rhythm
        // allows ends before the goal arrives.
        let mut r = GoalRhythm::new(ms(2));
        let mut latest_start_slack = Duration::MAX;
        for (k, &a) in at.iter().enumerate() {
            if k >= 20 {
                let prev = at[k - 1];
                // The latest instant after the previous goal at which a poll may still start.
                let mut t = prev + ms(3);
                let mut last_ok = None;
                while t < a {
                    if r.hold_until(t, busy).is_none() {
                        last_ok = Some(t);
                    } else {
                        break;
                    }
                    t += Duration::from_micros(50);
                }
                let start = last_ok.expect("room for a poll after a tick");
                assert!(
                    start + busy <= a,
                    "tick {k}: a poll started at {start:?} ends after the goal"
                );
                latest_start_slack = latest_start_slack.min(a - (start + busy));
            }
            r.message_at(a);
        }
        assert_eq!(r0.period(), r.period());
        let p = r.period().unwrap();
        assert!(p.abs_diff(ms(20)) < Duration::from_micros(200), "{p:?}");
        // The window is not wider than it must be: the bus stays free for less than 5 ms
        // before a tick.
        assert!(latest_start_slack < ms(5), "{latest_start_slack:?}");
    }

    #[test]
    fn messages_of_one_tick_and_late_messages_do_not_move_the_phase() {
        let t0 = Instant::now();
        let mut r = GoalRhythm::new(ms(2));
        for k in 0..40u32 {
            let tick = t0 + ms(20) * k;
            r.message_at(tick);
            // Port 1 a tenth of a millisecond later, a third message 1.5 ms later, and now and
            // then a message 7 ms late.
            r.message_at(tick + Duration::from_micros(100));
            r.message_at(tick + Duration::from_micros(1600));
            if k % 10 == 5 {
                r.message_at(tick + ms(7));
            }
        }
        assert_eq!(r.period(), Some(ms(20)));
        let last = t0 + ms(20) * 39;
        let busy = Duration::from_micros(2300);
        assert_eq!(r.hold_until(last + ms(10), busy), None);
        assert_eq!(
            r.hold_until(last + ms(18), busy),
            Some(last + ms(20) + ms(10))
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
        let mut r = GoalRhythm::new(ms(2));
        let offsets = [
            0u64, 9, 1, 8, 0, 9, 2, 8, 1, 9, 0, 8, 0, 9, 1, 8, 0, 9, 2, 8,
        ];
        for (k, jitter) in offsets.iter().enumerate() {
            r.message_at(t0 + ms(20 * k as u64 + jitter));
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

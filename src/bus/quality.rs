//! The reply quality of one servo: "degraded" when too many of its requests get a bad reply (a
//! garbled one, or none), told apart from "lost", which only silence causes (see
//! `Servo::on_timeout`).
//!
//! The bus master judges every servo of the bus at the same instants, once per [`WINDOW`]: the
//! share of the servo's requests in the window that got no good reply. Each bad reply counts
//! once: a garbled reply is a missed reply (the servo's `timeouts`), never also a bad sum.
//! Hysteresis keeps the state calm: a servo becomes degraded above [`DEGRADED_ABOVE`] and is
//! well again only below [`OK_BELOW`], so a share that wanders between 20 and 30 % gives one
//! "degraded" and nothing more.
//!
//! The misses of a silent run still going on when a window ends are left to the next window:
//! the run ends either in a reply (then they are bad replies) or in "lost" (then they are not:
//! silence has its own event). A window with fewer than [`MIN_REQUESTS`] requests is left
//! open and judged later, over a longer span. A servo that is lost forgets its state without a word: "lost"
//! and "back" say more. A servo being re-initialised keeps it, and starts a new window once
//! it is polled again.
//!
//! There is no separate verdict for the bus: a noisy line makes every servo on it degraded,
//! each named once, and the names show that it is the whole bus. One text for the bus instead
//! would have to wait for every servo's judgement and would hide a servo that recovers alone.

use std::time::Duration;

/// The window over which the share of bad replies is measured.
pub const WINDOW: Duration = Duration::from_secs(2);
/// Above this share of bad replies a servo is degraded ...
pub const DEGRADED_ABOVE: f64 = 0.15;
/// ... and below this share it is well again.
pub const OK_BELOW: f64 = 0.05;
/// A window with fewer requests than this says nothing yet: it is judged later, longer.
pub const MIN_REQUESTS: u64 = 20;

/// A change of a servo's reply quality.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum QualityChange {
    /// The share of bad replies, in %, in the window that made it degraded.
    Degraded {
        percent: u8,
    },
    Recovered,
}

/// What a servo's counters say when a window is judged.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Counts {
    /// Requests answered with a good reply.
    pub answered: u64,
    /// Requests answered with a garbled reply or not at all, but for those of a silent run
    /// still going on.
    pub missed: u64,
}

/// The reply-quality watch of one servo.
#[derive(Debug, Clone, Copy, Default)]
pub struct ReplyWatch {
    /// The counters when the open window started; `None`: none open.
    base: Option<Counts>,
    /// The share of bad replies (%) of the latest window judged, while degraded.
    degraded: Option<u8>,
}

impl ReplyWatch {
    /// `Some(percent)` while the servo is degraded: its latest window's share of bad replies.
    pub fn degraded(&self) -> Option<u8> {
        self.degraded
    }

    /// The servo is not polled for telemetry (being re-initialised): no window is open until
    /// [`ReplyWatch::judge`] sees it polled again; the state is kept.
    pub fn pause(&mut self) {
        self.base = None;
    }

    /// The servo is lost: its state goes without a word.
    pub fn forget(&mut self) {
        *self = ReplyWatch::default();
    }

    /// Judge the open window at a window's end, with the servo's counters now, and open the
    /// next one.
    pub fn judge(&mut self, now: Counts) -> Option<QualityChange> {
        let Some(base) = self.base else {
            self.base = Some(now);
            return None;
        };
        let missed = now.missed.saturating_sub(base.missed);
        let requests = now.answered.saturating_sub(base.answered) + missed;
        if requests < MIN_REQUESTS {
            return None;
        }
        self.base = Some(now);
        let share = missed as f64 / requests as f64;
        let percent = (share * 100.0).round() as u8;
        match self.degraded {
            None if share > DEGRADED_ABOVE => {
                self.degraded = Some(percent);
                Some(QualityChange::Degraded { percent })
            }
            Some(_) if share < OK_BELOW => {
                self.degraded = None;
                Some(QualityChange::Recovered)
            }
            Some(_) => {
                self.degraded = Some(percent);
                None
            }
            None => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn counts(answered: u64, missed: u64) -> Counts {
        Counts { answered, missed }
    }

    #[test]
    fn above_15_percent_degrades_and_only_below_5_percent_recovers() {
        let mut w = ReplyWatch::default();
        assert_eq!(w.judge(counts(0, 0)), None);
        // 100 requests, 16 bad.
        assert_eq!(
            w.judge(counts(84, 16)),
            Some(QualityChange::Degraded { percent: 16 })
        );
        assert_eq!(w.degraded(), Some(16));
        // 6 %: still degraded, with the newer share.
        assert_eq!(w.judge(counts(178, 22)), None);
        assert_eq!(w.degraded(), Some(6));
        // 4 %: well again.
        assert_eq!(w.judge(counts(274, 26)), Some(QualityChange::Recovered));
        assert_eq!(w.degraded(), None);
    }

    #[test]
    fn exactly_15_percent_is_not_degraded() {
        let mut w = ReplyWatch::default();
        w.judge(counts(0, 0));
        assert_eq!(w.judge(counts(85, 15)), None);
    }

    #[test]
    fn a_quiet_window_is_left_open_and_judged_later() {
        let mut w = ReplyWatch::default();
        w.judge(counts(0, 0));
        // Too few requests: not judged, however many are bad.
        assert_eq!(w.judge(counts(10, 9)), None);
        // Judged later over the whole span: 150 good, 50 bad = 25 %.
        assert_eq!(
            w.judge(counts(150, 50)),
            Some(QualityChange::Degraded { percent: 25 })
        );
    }

    #[test]
    fn a_lost_servo_forgets_a_paused_one_keeps_its_state() {
        let mut w = ReplyWatch::default();
        w.judge(counts(0, 0));
        w.judge(counts(70, 30));
        assert_eq!(w.degraded(), Some(30));
        w.pause();
        assert_eq!(w.degraded(), Some(30));
        // The first window after the pause only opens; its lifetime history says nothing.
        // Were the lifetime history judged, its 51 % would keep the servo degraded, with 51 %.
        assert_eq!(w.judge(counts(1000, 1000)), None);
        assert_eq!(w.degraded(), Some(30));
        w.forget();
        assert_eq!(w.degraded(), None);
    }
}

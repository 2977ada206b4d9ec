//! The quality of a bus's replies, as the ground station should hear of it: corrupted or lost
//! replies from servos that are otherwise online (a noisy line, a loose connector) are a fault
//! of their own, announced when they pass 10 % of the requests over a window and cleared when
//! they fall below 2 %. Servos that are offline are left out: they have their own event.

use crate::bus::{BusStatus, Health};
use crate::protocol::ServoId;
use std::time::{Duration, Instant};

/// Requests with a bad or missing reply above this share make the bus degraded.
pub const DEGRADED_ABOVE: f64 = 0.10;
/// ... and below this share it is well again.
pub const OK_BELOW: f64 = 0.02;
/// The window the share is measured over.
pub const WINDOW: Duration = Duration::from_secs(2);
/// Fewer requests than this in a window say nothing either way.
const MIN_REQUESTS: u64 = 20;

/// A change of a bus's reply quality.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum QualityChange {
    Degraded { percent: u8 },
    Recovered,
}

/// Lifetime counters of one servo: replies taken, replies missed, and whether it answers.
#[derive(Debug, Clone, Copy)]
struct ServoCount {
    id: ServoId,
    answered: u64,
    missed: u64,
    answering: bool,
}

/// The counters at the start of the current window.
#[derive(Debug, Clone)]
struct Window {
    start: Instant,
    servos: Vec<ServoCount>,
    bad_sums: u64,
}

/// The reply-quality watch of one bus.
#[derive(Debug, Default)]
pub struct ReplyQuality {
    window: Option<Window>,
    degraded: bool,
}

fn counts(status: &BusStatus) -> Vec<ServoCount> {
    status
        .servos
        .iter()
        .map(|s| ServoCount {
            id: s.id,
            answered: s.answered,
            missed: s.timeouts,
            answering: matches!(s.health, Health::Online | Health::Stale | Health::Starting),
        })
        .collect()
}

impl ReplyQuality {
    pub fn is_degraded(&self) -> bool {
        self.degraded
    }

    /// Look at the bus's status at `now`; a change of quality comes out once per window. Only
    /// servos that answered at both ends of the window count, with what changed in it.
    pub fn update(&mut self, status: &BusStatus, now: Instant) -> Option<QualityChange> {
        let servos = counts(status);
        let Some(window) = &self.window else {
            self.window = Some(Window {
                start: now,
                servos,
                bad_sums: status.counters.bad_sums,
            });
            return None;
        };
        if now.duration_since(window.start) < WINDOW {
            return None;
        }
        let (mut requests, mut bad) = (0u64, 0u64);
        for now_count in servos.iter().filter(|c| c.answering) {
            let Some(then) = window
                .servos
                .iter()
                .find(|c| c.id == now_count.id && c.answering)
            else {
                continue;
            };
            let missed = now_count.missed.saturating_sub(then.missed);
            requests += now_count.answered.saturating_sub(then.answered) + missed;
            bad += missed;
        }
        bad += status.counters.bad_sums.saturating_sub(window.bad_sums);
        self.window = Some(Window {
            start: now,
            servos,
            bad_sums: status.counters.bad_sums,
        });
        if requests < MIN_REQUESTS {
            return None;
        }
        let share = (bad as f64 / requests as f64).min(1.0);
        if !self.degraded && share > DEGRADED_ABOVE {
            self.degraded = true;
            Some(QualityChange::Degraded {
                percent: (share * 100.0).round() as u8,
            })
        } else if self.degraded && share < OK_BELOW {
            self.degraded = false;
            Some(QualityChange::Recovered)
        } else {
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bus::{BusCounters, ForceState, ServoStatus};
    use crate::protocol::ReplyFlags;

    fn servo(id: u8, health: Health, answered: u64, missed: u64) -> ServoStatus {
        ServoStatus {
            id: ServoId::new(id).unwrap(),
            name: format!("s{id}"),
            health,
            telemetry: None,
            telemetry_at: None,
            position_at: None,
            age: None,
            flags: ReplyFlags::default(),
            goal: None,
            force: ForceState::On,
            stalled: false,
            identity: Default::default(),
            consecutive_timeouts: 0,
            telemetry_count: answered,
            answered,
            timeouts: missed,
        }
    }

    fn bus(at: Instant, servos: Vec<ServoStatus>, bad_sums: u64) -> BusStatus {
        BusStatus {
            name: "b".into(),
            port_open: true,
            servos,
            counters: BusCounters {
                bad_sums,
                ..Default::default()
            },
            at,
        }
    }

    #[test]
    fn a_bad_share_above_10_percent_degrades_and_below_2_percent_recovers() {
        let t0 = Instant::now();
        let mut q = ReplyQuality::default();
        let on = Health::Online;
        assert_eq!(
            q.update(
                &bus(t0, vec![servo(1, on, 0, 0), servo(2, on, 0, 0)], 0),
                t0
            ),
            None
        );
        // 2 s: 200 requests, 30 lost + 10 bad sums = 20 %.
        let t1 = t0 + WINDOW;
        let s1 = bus(t1, vec![servo(1, on, 80, 20), servo(2, on, 90, 10)], 10);
        assert_eq!(
            q.update(&s1, t1),
            Some(QualityChange::Degraded { percent: 20 })
        );
        // 5 %: still degraded (hysteresis).
        let t2 = t1 + WINDOW;
        let s2 = bus(t2, vec![servo(1, on, 175, 25), servo(2, on, 185, 15)], 10);
        assert_eq!(q.update(&s2, t2), None);
        assert!(q.is_degraded());
        // 1 %: recovered.
        let t3 = t2 + WINDOW;
        let s3 = bus(t3, vec![servo(1, on, 274, 26), servo(2, on, 284, 16)], 10);
        assert_eq!(q.update(&s3, t3), Some(QualityChange::Recovered));
    }

    #[test]
    fn servos_going_offline_or_coming_back_do_not_count() {
        let t0 = Instant::now();
        let mut q = ReplyQuality::default();
        let (on, off) = (Health::Online, Health::Offline);
        q.update(
            &bus(t0, vec![servo(1, on, 1000, 300), servo(2, on, 100, 0)], 0),
            t0,
        );
        // Servo 1 goes offline inside the window (its misses are its own event); servo 2 is clean.
        let t1 = t0 + WINDOW;
        let s1 = bus(t1, vec![servo(1, off, 1010, 310), servo(2, on, 200, 0)], 0);
        assert_eq!(q.update(&s1, t1), None);
        // Servo 1 comes back with its lifetime history: the window says nothing bad.
        let t2 = t1 + WINDOW;
        let s2 = bus(t2, vec![servo(1, on, 1011, 320), servo(2, on, 300, 0)], 0);
        assert_eq!(q.update(&s2, t2), None);
        assert!(!q.is_degraded());
    }

    #[test]
    fn a_quiet_window_says_nothing() {
        let t0 = Instant::now();
        let mut q = ReplyQuality::default();
        q.update(&bus(t0, vec![servo(1, Health::Online, 0, 0)], 0), t0);
        let t1 = t0 + WINDOW;
        assert_eq!(
            q.update(&bus(t1, vec![servo(1, Health::Online, 5, 5)], 0), t1),
            None
        );
    }
}

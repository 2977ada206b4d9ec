//! Which received messages reach the bridge's loop. The loop runs at real-time priority (in
//! `run`), above every ordinary program on the companion computer, so what it is handed must
//! not be anyone's to choose: the links' readers (a normal thread) pass on only
//!
//! - the kinds of message the core acts on ([`BridgeCore::handles`]): an autopilot's other
//!   streams (attitude, GPS, …) and a ground station's joystick stay on the readers' thread;
//! - from any sender but the autopilot, at most [`BUDGET_PER_SECOND`] a second on average
//!   (bursts of [`BURST`]), per system and component on each link: enough for a ground
//!   station's parameter download or a burst of commands, and a stranger's flood of valid
//!   frames costs the loop that much and no more. [`TRACKED`] senders have a budget each; a
//!   sender silent for [`FORGET_AFTER`] gives its place to a new one, and the senders beyond
//!   share one budget, so that ever new ids buy no more. The autopilot's messages on its own
//!   link (once it is known: its HEARTBEAT, or the mapping's ids) always pass.
//!
//! Without signing, anyone may claim the autopilot's ids: the budget guards the loop's time
//! against a flood of valid frames only where signing keeps strangers' frames out.
//!
//! Sans-IO: handed the messages, the autopilot's identity and the time.

use super::core::{AUTOPILOT_LINK, BridgeCore, LinkId};
use mavlink::MavHeader;
use mavlink::dialects::common::MavMessage;
use std::time::{Duration, Instant};

/// Messages a second a system other than the autopilot may pass to the loop, on average.
pub const BUDGET_PER_SECOND: f64 = 100.0;
/// As many at once, after a quiet spell.
pub const BURST: f64 = 200.0;
/// Senders with a budget of their own on one link; those beyond share one.
pub const TRACKED: usize = 16;
/// A sender silent this long gives its budget's place to a new sender (its budget would be
/// full again anyway).
pub const FORGET_AFTER: Duration = Duration::from_secs(10);
/// How often, at most, the messages dropped for want of budget are said.
pub const SAY_EVERY: Duration = Duration::from_secs(10);

/// What becomes of a received message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    /// To the loop.
    Pass,
    /// Of a kind the core does not act on: dropped, as the core would.
    NotHandled,
    /// Its sender spent its budget: dropped and counted.
    OverBudget,
}

/// A token bucket.
#[derive(Clone, Copy, Debug)]
struct Bucket {
    tokens: f64,
    at: Instant,
}

impl Bucket {
    fn full(now: Instant) -> Bucket {
        Bucket {
            tokens: BURST,
            at: now,
        }
    }

    fn take(&mut self, now: Instant) -> bool {
        let refill = now.saturating_duration_since(self.at).as_secs_f64() * BUDGET_PER_SECOND;
        self.tokens = (self.tokens + refill).min(BURST);
        self.at = now;
        if self.tokens >= 1.0 {
            self.tokens -= 1.0;
            true
        } else {
            false
        }
    }
}

/// The admission of one link's messages.
#[derive(Debug)]
pub struct Admission {
    link: LinkId,
    /// Each system and component heard, with its bucket (which knows when it was last used).
    buckets: Vec<((u8, u8), Bucket)>,
    /// The bucket of the senders beyond [`TRACKED`].
    shared: Bucket,
    dropped: u64,
    said: Option<(Instant, u64)>,
}

impl Admission {
    pub fn new(link: LinkId, now: Instant) -> Admission {
        Admission {
            link,
            buckets: Vec::new(),
            shared: Bucket::full(now),
            dropped: 0,
            said: None,
        }
    }

    /// Judge a message from `header` on this link at `now`; `autopilot`: the autopilot's system
    /// and component, once known.
    pub fn judge(
        &mut self,
        header: &MavHeader,
        message: &MavMessage,
        autopilot: Option<(u8, u8)>,
        now: Instant,
    ) -> Verdict {
        if !BridgeCore::handles(message) {
            return Verdict::NotHandled;
        }
        let Ok(system) = u8::try_from(header.system_id) else {
            return Verdict::NotHandled;
        };
        let from = (system, header.component_id);
        if self.link == AUTOPILOT_LINK && Some(from) == autopilot {
            return Verdict::Pass;
        }
        let slot = match self.buckets.iter().position(|(s, _)| *s == from) {
            Some(i) => Some(i),
            None if self.buckets.len() < TRACKED => {
                self.buckets.push((from, Bucket::full(now)));
                Some(self.buckets.len() - 1)
            }
            // The place of the sender silent longest, if it has been silent long enough.
            None => (0..self.buckets.len())
                .min_by_key(|&i| self.buckets[i].1.at)
                .filter(|&i| now.saturating_duration_since(self.buckets[i].1.at) >= FORGET_AFTER)
                .inspect(|&i| self.buckets[i] = (from, Bucket::full(now))),
        };
        let bucket = match slot {
            Some(i) => &mut self.buckets[i].1,
            None => &mut self.shared,
        };
        if bucket.take(now) {
            Verdict::Pass
        } else {
            self.dropped += 1;
            Verdict::OverBudget
        }
    }

    /// Messages dropped for want of budget since the start.
    pub fn dropped(&self) -> u64 {
        self.dropped
    }

    /// What to say of the drops at `now`, at most every [`SAY_EVERY`]: the count since it was
    /// last said.
    pub fn news(&mut self, now: Instant) -> Option<String> {
        let (last_at, last_count) = self.said.unwrap_or((now - SAY_EVERY, 0));
        if self.dropped == last_count || now.saturating_duration_since(last_at) < SAY_EVERY {
            return None;
        }
        self.said = Some((now, self.dropped));
        Some(format!(
            "MAVLink link {}: {} messages from systems other than the autopilot dropped, over \
             their {BUDGET_PER_SECOND} a second ({} since the start)",
            self.link,
            self.dropped - last_count,
            self.dropped
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mavlink::dialects::common::{ATTITUDE_DATA, HEARTBEAT_DATA, SERVO_OUTPUT_RAW_DATA};

    fn header(system: u8, component: u8) -> MavHeader {
        MavHeader {
            system_id: u32::from(system),
            component_id: component,
            sequence: 0,
        }
    }

    fn heartbeat() -> MavMessage {
        MavMessage::HEARTBEAT(HEARTBEAT_DATA::default())
    }

    #[test]
    fn a_kind_the_core_ignores_stays_with_the_reader() {
        let now = Instant::now();
        let mut a = Admission::new(AUTOPILOT_LINK, now);
        let attitude = MavMessage::ATTITUDE(ATTITUDE_DATA::default());
        assert_eq!(
            a.judge(&header(1, 1), &attitude, Some((1, 1)), now),
            Verdict::NotHandled
        );
        let outputs = MavMessage::SERVO_OUTPUT_RAW(SERVO_OUTPUT_RAW_DATA::default());
        assert_eq!(
            a.judge(&header(1, 1), &outputs, Some((1, 1)), now),
            Verdict::Pass
        );
    }

    #[test]
    fn a_stranger_gets_its_budget_and_the_autopilot_all_it_sends() {
        let t0 = Instant::now();
        let mut a = Admission::new(AUTOPILOT_LINK, t0);
        let passed = |a: &mut Admission, from: (u8, u8), at: Instant, n: usize| {
            (0..n)
                .filter(|_| {
                    a.judge(&header(from.0, from.1), &heartbeat(), Some((1, 1)), at)
                        == Verdict::Pass
                })
                .count()
        };
        // A flood at one instant: the burst, then nothing.
        assert_eq!(passed(&mut a, (9, 1), t0, 1000), BURST as usize);
        assert_eq!(a.dropped(), 1000 - BURST as u64);
        // The autopilot, meanwhile: everything.
        assert_eq!(passed(&mut a, (1, 1), t0, 1000), 1000);
        // A second later, a second's budget.
        let t1 = t0 + Duration::from_secs(1);
        assert_eq!(passed(&mut a, (9, 1), t1, 1000), BUDGET_PER_SECOND as usize);
        // On another link the autopilot's ids are anyone's.
        let mut gcs = Admission::new(AUTOPILOT_LINK + 1, t0);
        assert_eq!(passed(&mut gcs, (1, 1), t0, 1000), BURST as usize);
    }

    #[test]
    fn systems_beyond_those_tracked_share_one_budget() {
        let t0 = Instant::now();
        let mut a = Admission::new(AUTOPILOT_LINK, t0);
        for system in 0..TRACKED as u8 {
            assert_eq!(
                a.judge(&header(100 + system, 1), &heartbeat(), None, t0),
                Verdict::Pass
            );
        }
        // Every new system from now on draws from one bucket.
        let passed = (0..1000u32)
            .filter(|i| {
                let system = 200 + (i % 50) as u8;
                a.judge(&header(system, 1), &heartbeat(), None, t0) == Verdict::Pass
            })
            .count();
        assert_eq!(passed, BURST as usize);
    }

    #[test]
    fn a_sender_silent_for_long_gives_its_place_to_a_new_one() {
        let t0 = Instant::now();
        let mut a = Admission::new(1, t0);
        for system in 0..TRACKED as u8 {
            a.judge(&header(100 + system, 1), &heartbeat(), None, t0);
        }
        // Use up the shared budget.
        for _ in 0..1000 {
            a.judge(&header(250, 1), &heartbeat(), None, t0);
        }
        let late = t0 + FORGET_AFTER;
        // Systems 101.. speak again; system 100 stays silent and gives its place.
        for system in 1..TRACKED as u8 {
            a.judge(&header(100 + system, 1), &heartbeat(), None, late);
        }
        let passed = |a: &mut Admission, system: u8, at: Instant| {
            (0..1000)
                .filter(|_| a.judge(&header(system, 1), &heartbeat(), None, at) == Verdict::Pass)
                .count()
        };
        assert_eq!(
            passed(&mut a, 7, late),
            BURST as usize,
            "a budget of its own"
        );
        // Every place is taken by a sender heard within FORGET_AFTER: the next new ones share
        // one budget (full again since t0), which the first of them uses up.
        assert_eq!(passed(&mut a, 8, late), BURST as usize);
        assert_eq!(passed(&mut a, 9, late), 0, "the same budget as system 8's");
    }

    #[test]
    fn drops_are_said_at_most_every_ten_seconds_with_the_count_since() {
        let t0 = Instant::now();
        let mut a = Admission::new(1, t0);
        for _ in 0..250 {
            a.judge(&header(9, 1), &heartbeat(), None, t0);
        }
        let said = a.news(t0).expect("50 dropped");
        assert!(said.contains("link 1: 50 messages"), "{said}");
        for _ in 0..10 {
            a.judge(&header(9, 1), &heartbeat(), None, t0);
        }
        assert_eq!(a.news(t0 + Duration::from_secs(5)), None);
        let said = a.news(t0 + SAY_EVERY).expect("10 more");
        assert!(
            said.contains(": 10 messages") && said.contains("(60 since"),
            "{said}"
        );
        assert_eq!(a.news(t0 + 3 * SAY_EVERY), None, "nothing new");
    }
}

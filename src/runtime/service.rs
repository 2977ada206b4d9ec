//! The bridge as a systemd service (`Type=notify`, `WatchdogSec=`): what it tells systemd, and
//! when.
//!
//! - `READY=1` once the MAVLink links are bound and every bus thread has made its first attempt
//!   to open its port (opened it, or found it missing: a bridge without its adapter still
//!   serves the other buses, and keeps trying). A start that has not got that far in
//!   [`READY_WAIT`] says which bus it waited for, and is ready all the same.
//! - `WATCHDOG=1` every quarter of the watchdog timeout, from the main loop itself, and only
//!   while every bus thread has turned since the last look ([`crate::bus::BusHandle::turns`]).
//!   A stuck loop sends nothing; a stuck bus thread stops the pings as surely. systemd then
//!   kills the bridge and starts it again (see [`crate::deploy::systemd_unit`]). A bus thread
//!   that hangs just after a look that saw it turn still earns the next look's ping, so the
//!   kill comes at most a timeout and a quarter after the hang (at every half timeout, it would
//!   be a timeout and a half); a stopped process, at most a timeout after it.
//! - `STOPPING=1` when a stop begins.
//!
//! Outside systemd (no `NOTIFY_SOCKET`, no `WATCHDOG_USEC`) none of this does anything.

use std::time::{Duration, Instant};

/// How long the start waits for every bus thread's first attempt to open its port before it
/// tells systemd it is ready anyway.
pub const READY_WAIT: Duration = Duration::from_secs(5);

/// The shortest watchdog timeout that cannot restart a healthy bridge: a bus thread turns at
/// least every 100 ms, and the looks (and pings) come every quarter timeout, 250 ms here.
pub const SHORTEST_WATCHDOG: Duration = Duration::from_secs(1);

/// Looks at the bus threads (each a ping if they all turned) per watchdog timeout.
const LOOKS_PER_TIMEOUT: u32 = 4;

/// Send `states` to systemd; a failure is logged (the service manager would then restart a
/// bridge that runs: worth a line in the log, not a stop).
pub fn notify(states: &[sd_notify::NotifyState]) {
    if let Err(e) = sd_notify::notify(states) {
        tracing::warn!("cannot notify systemd ({states:?}): {e}");
    }
}

/// What one look at the bus threads found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Verdict {
    /// Not yet time for a ping.
    NotDue,
    /// Every bus thread turned since the last look: ping.
    Alive,
    /// These buses (indices) did not turn since the last look: no ping.
    Stuck(Vec<usize>),
}

/// The watchdog's side in the main loop: when the next ping is due, and whether every bus
/// thread has turned since the last look.
#[derive(Debug)]
pub struct Watchdog {
    period: Duration,
    due: Instant,
    turns: Vec<u64>,
    /// The stuck buses already told in the log.
    told: Vec<usize>,
}

impl Watchdog {
    /// The watchdog systemd asked for (`WATCHDOG_USEC`, for this process), if any.
    pub fn from_env(turns: Vec<u64>, now: Instant) -> Option<Self> {
        let timeout = sd_notify::watchdog_enabled()?;
        if timeout < SHORTEST_WATCHDOG {
            tracing::warn!(
                "the service's watchdog timeout of {timeout:?} is shorter than {SHORTEST_WATCHDOG:?}: a bus thread that waits 100 ms between turns may look stuck"
            );
        }
        tracing::info!(
            "systemd watchdog: {timeout:?}, pinged every {:?}",
            timeout / LOOKS_PER_TIMEOUT
        );
        Some(Self::new(timeout, turns, now))
    }

    /// A watchdog of `timeout`, pinged every quarter of it, starting from the bus threads' turns
    /// `turns` at `now`.
    pub fn new(timeout: Duration, turns: Vec<u64>, now: Instant) -> Self {
        let period = timeout / LOOKS_PER_TIMEOUT;
        Watchdog {
            period,
            due: now + period,
            turns,
            told: Vec::new(),
        }
    }

    /// The time between two pings.
    pub fn period(&self) -> Duration {
        self.period
    }

    /// When the next look is due.
    pub fn due_at(&self) -> Instant {
        self.due
    }

    /// Look at the bus threads' turns `turns` (one count per bus, in order) if a ping is due at
    /// `now`.
    pub fn check(&mut self, now: Instant, turns: &[u64]) -> Verdict {
        if now < self.due {
            return Verdict::NotDue;
        }
        self.due = now + self.period;
        let stuck: Vec<usize> = turns
            .iter()
            .enumerate()
            .filter(|(i, t)| self.turns.get(*i) == Some(t))
            .map(|(i, _)| i)
            .collect();
        self.turns = turns.to_vec();
        if stuck.is_empty() {
            Verdict::Alive
        } else {
            Verdict::Stuck(stuck)
        }
    }

    /// The buses of `stuck` not told yet (and forget those that turn again): each stuck spell
    /// is logged once.
    pub fn untold(&mut self, stuck: &[usize]) -> Vec<usize> {
        self.told.retain(|b| stuck.contains(b));
        let new: Vec<usize> = stuck
            .iter()
            .copied()
            .filter(|b| !self.told.contains(b))
            .collect();
        self.told.extend(&new);
        new
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TIMEOUT: Duration = Duration::from_secs(2);

    #[test]
    fn a_ping_is_due_every_quarter_timeout_and_not_before() {
        let t0 = Instant::now();
        let mut w = Watchdog::new(TIMEOUT, vec![1, 1], t0);
        assert_eq!(w.due_at(), t0 + Duration::from_millis(500));
        assert_eq!(
            w.check(t0 + Duration::from_millis(499), &[5, 5]),
            Verdict::NotDue
        );
        assert_eq!(
            w.check(t0 + Duration::from_millis(500), &[5, 5]),
            Verdict::Alive
        );
        assert_eq!(w.due_at(), t0 + Duration::from_secs(1));
    }

    #[test]
    fn a_bus_that_did_not_turn_since_the_last_look_stops_the_ping() {
        let t0 = Instant::now();
        let mut w = Watchdog::new(TIMEOUT, vec![1, 1, 1], t0);
        let look = w.period();
        assert_eq!(w.check(t0 + look, &[9, 1, 4]), Verdict::Stuck(vec![1]));
        // It turns again: pings again; another bus stands still.
        assert_eq!(w.check(t0 + 2 * look, &[9, 2, 8]), Verdict::Stuck(vec![0]));
        assert_eq!(w.check(t0 + 3 * look, &[10, 3, 9]), Verdict::Alive);
    }

    /// The worst case of a hang: the bus thread turns once more just after a look, then hangs.
    /// The next look still sees that turn and pings; systemd kills the bridge a timeout after
    /// that last ping. The kill must come within a timeout and a quarter of the hang.
    #[test]
    fn a_hung_bus_thread_is_killed_within_a_timeout_and_a_quarter() {
        let t0 = Instant::now();
        let mut w = Watchdog::new(TIMEOUT, vec![0], t0);
        let step = Duration::from_millis(10);
        let hang = t0 + Duration::from_millis(2_010);
        let (mut now, mut turns, mut last_ping) = (t0, 0, t0);
        while now < hang + 2 * TIMEOUT {
            now += step;
            if now <= hang {
                turns += 1;
            }
            if w.check(now, &[turns]) == Verdict::Alive {
                last_ping = now;
            }
        }
        let killed = last_ping + TIMEOUT;
        assert!(
            killed - hang <= TIMEOUT + TIMEOUT / 4,
            "killed {:?} after the hang (timeout {TIMEOUT:?})",
            killed - hang
        );
    }

    #[test]
    fn a_bus_that_never_tried_its_port_is_stuck() {
        let t0 = Instant::now();
        let mut w = Watchdog::new(TIMEOUT, vec![0], t0);
        assert_eq!(w.check(t0 + TIMEOUT, &[0]), Verdict::Stuck(vec![0]));
    }

    #[test]
    fn each_stuck_spell_is_told_once() {
        let mut w = Watchdog::new(TIMEOUT, vec![0, 0], Instant::now());
        assert_eq!(w.untold(&[1]), vec![1]);
        assert_eq!(w.untold(&[1]), Vec::<usize>::new());
        assert_eq!(w.untold(&[0, 1]), vec![0]);
        assert_eq!(w.untold(&[]), Vec::<usize>::new());
        assert_eq!(w.untold(&[1]), vec![1], "a new spell is told again");
    }
}

//! The MAVLink loop's thread within a budget. In `run` the loop's thread is a real-time one
//! (SCHED_FIFO [`super::LOOP_PRIORITY`]), and it reads and writes the links itself: every
//! socket, every datagram parsed and every signature checked, so that the autopilot's datagram
//! reaches the loop with no hop between threads and waits for no ordinary program (a camera,
//! ROS, a logger). What keeps a flood (a stranger's valid frames, bad signatures, garbage)
//! from holding a core at real-time priority is a budget: every [`LOOK_EVERY`] the
//! [`Governor`] reads the thread's CPU time, and over [`BUDGET`] of a core the thread runs as a
//! normal one until its work stays under half of it for [`CALM_FOR`]. A flood then costs the
//! time every ordinary program shares, never the real-time threads'; the bus threads, which
//! write the goals and read the replies, keep their own priority throughout.

use std::time::{Duration, Instant};

/// The share of a core the loop's thread may take and stay a real-time one: ten times what
/// it takes with four servos, an autopilot at 50 Hz and a ground station (1–2 %), and room for
/// a slower computer.
pub const BUDGET: f64 = 0.25;

/// How often the [`Governor`] looks at the thread's CPU time.
pub const LOOK_EVERY: Duration = Duration::from_millis(100);

/// How long the work must stay under half the budget before the thread is a real-time one
/// again.
pub const CALM_FOR: Duration = Duration::from_secs(1);

/// The first stretch of the loop's work that is not judged: its first turns answer what came
/// while it started (the buses' first events, the first views), a spell of work no flood makes.
pub const GRACE: Duration = Duration::from_secs(1);

/// Keep the calling thread, a real-time one at `priority`, within [`BUDGET`] from [`GRACE`] on:
/// a normal thread from the look that sees more, a real-time one again after [`CALM_FOR`] under
/// half of it. Runs until the runtime stops (or, if the way back to real-time scheduling is
/// refused, for good as a normal thread, said at warning level).
pub async fn govern(priority: i32) {
    tokio::time::sleep(GRACE).await;
    let mut governor = Governor::new(lj9da_realtime::thread_cpu_time(), Instant::now());
    let mut every = tokio::time::interval(LOOK_EVERY);
    every.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        every.tick().await;
        let (cpu, now) = (lj9da_realtime::thread_cpu_time(), Instant::now());
        match governor.look(cpu, now) {
            Some(Change::Normal { share }) => match lj9da_realtime::request_normal() {
                Ok(()) => tracing::warn!(
                    "the MAVLink loop took {:.0} % of a core (more than its budget of {:.0} %; \
                     a flood of input?): it runs as a normal thread until that calms; the bus \
                     threads keep their real-time priority",
                    share * 100.0,
                    BUDGET * 100.0
                ),
                Err(e) => tracing::warn!("the MAVLink loop cannot leave real-time scheduling: {e}"),
            },
            Some(Change::Realtime { calm_for }) => match lj9da_realtime::request_fifo(priority) {
                Ok(()) => tracing::info!(
                    "the MAVLink loop's work calm for {:.1} s: it runs at SCHED_FIFO {priority} again",
                    calm_for.as_secs_f64()
                ),
                Err(e) => {
                    tracing::warn!(
                        "the MAVLink loop cannot return to real-time scheduling: {e}; it stays \
                         a normal thread"
                    );
                    return;
                }
            },
            None => {}
        }
    }
}

/// What the [`Governor`] asks of the thread.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Change {
    /// Over budget: `share` of a core in the last look.
    Normal { share: f64 },
    /// Calm for `calm_for`.
    Realtime { calm_for: Duration },
}

/// A thread's budget, from its CPU time: a real-time thread while its work takes at most
/// [`BUDGET`] of a core, a normal one from the look that sees more, until [`CALM_FOR`] under
/// half of it.
#[derive(Debug)]
pub struct Governor {
    realtime: bool,
    cpu: Duration,
    at: Instant,
    /// Since when the thread, a normal one, has stayed under half the budget.
    calm_since: Option<Instant>,
}

impl Governor {
    /// A real-time thread that has used `cpu` by `now`.
    pub fn new(cpu: Duration, now: Instant) -> Self {
        Governor {
            realtime: true,
            cpu,
            at: now,
            calm_since: None,
        }
    }

    /// The thread has used `cpu` by `now`: what it should become, if anything.
    pub fn look(&mut self, cpu: Duration, now: Instant) -> Option<Change> {
        let wall = now.saturating_duration_since(self.at);
        if wall.is_zero() {
            return None;
        }
        let share = cpu.saturating_sub(self.cpu).as_secs_f64() / wall.as_secs_f64();
        (self.cpu, self.at) = (cpu, now);
        if self.realtime {
            if share > BUDGET {
                self.realtime = false;
                self.calm_since = None;
                return Some(Change::Normal { share });
            }
            return None;
        }
        if share > BUDGET / 2.0 {
            self.calm_since = None;
            return None;
        }
        let since = *self.calm_since.get_or_insert(now - wall);
        let calm_for = now - since;
        if calm_for >= CALM_FOR {
            self.realtime = true;
            self.calm_since = None;
            return Some(Change::Realtime { calm_for });
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Over its budget the thread becomes a normal one at the look that sees it, stays one
    /// while the work goes on, and is a real-time one again after a calm second.
    #[test]
    fn the_governor_takes_real_time_away_over_budget_and_gives_it_back_after_a_calm_second() {
        let t0 = Instant::now();
        let ms = Duration::from_millis;
        let mut g = Governor::new(ms(0), t0);
        // Ordinary work: 2 % of a core.
        assert_eq!(g.look(ms(2), t0 + ms(100)), None);
        // Within the budget: 24 %.
        assert_eq!(g.look(ms(26), t0 + ms(200)), None);
        // A flood: 90 ms of 100.
        assert!(matches!(
            g.look(ms(116), t0 + ms(300)),
            Some(Change::Normal { share }) if (share - 0.9).abs() < 1e-9
        ));
        // It goes on (at normal priority the thread gets what it can): no change.
        let mut cpu = ms(116);
        let mut at = t0 + ms(300);
        for _ in 0..20 {
            cpu += ms(60);
            at += ms(100);
            assert_eq!(g.look(cpu, at), None);
        }
        // Calm, but under a second: still a normal thread; a relapse restarts the count.
        for _ in 0..5 {
            cpu += ms(1);
            at += ms(100);
            assert_eq!(g.look(cpu, at), None);
        }
        cpu += ms(15);
        at += ms(100);
        assert_eq!(g.look(cpu, at), None, "15 % is over half the budget");
        for _ in 0..9 {
            cpu += ms(1);
            at += ms(100);
            assert_eq!(g.look(cpu, at), None);
        }
        cpu += ms(1);
        at += ms(100);
        assert_eq!(
            g.look(cpu, at),
            Some(Change::Realtime { calm_for: ms(1000) })
        );
        // Real-time again, and judged against the budget again.
        assert_eq!(
            g.look(cpu + ms(24), at + ms(100)),
            None,
            "24 % is within it"
        );
        assert!(matches!(
            g.look(cpu + ms(24) + ms(26), at + ms(200)),
            Some(Change::Normal { .. })
        ));
    }
}

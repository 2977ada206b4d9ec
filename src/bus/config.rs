//! What one bus is: its port speed, its servos, and the timing rules the bus master follows.
//!
//! Plain data with defaults; nothing here talks to a port or reads a clock.

use crate::protocol::{BaudRate, Ma10, MmCenti, Ms10, Percent, ServoId};
use crate::serial::rs485::Rs485Mode;
use std::time::Duration;

/// One servo on the bus, as the mapping file describes it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ServoSetup {
    pub id: ServoId,
    /// A name for logs and the ground station (e.g. `"aileron_l"`).
    pub name: String,
    /// Travel time sent with every new goal (register 32), `None` for the servo's full speed.
    pub goal_time: Option<Ms10>,
    /// Max force (register 35) written at start-up, `None` to leave the servo's value.
    pub max_force: Option<Percent>,
}

impl ServoSetup {
    /// A servo with no goal time and the servo's own max force.
    pub fn new(id: ServoId, name: impl Into<String>) -> Self {
        ServoSetup {
            id,
            name: name.into(),
            goal_time: None,
            max_force: None,
        }
    }
}

/// When a servo counts as stalled: its present position stays further than `tolerance` from
/// the goal on the wire, while its supply current is at least `current`, for `time`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StallConfig {
    pub tolerance: MmCenti,
    pub time: Duration,
    pub current: Ma10,
}

impl Default for StallConfig {
    /// 0.50 mm, 500 ms, 1.50 A.
    fn default() -> Self {
        StallConfig {
            tolerance: MmCenti(50),
            time: Duration::from_millis(500),
            current: Ma10(150),
        }
    }
}

/// A wait that starts at `first` and doubles after every failure, up to `max`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Backoff {
    pub first: Duration,
    pub max: Duration,
}

impl Backoff {
    /// The wait after `current` failed again: double it, at least `first`, at most `max`.
    pub fn after(self, current: Duration) -> Duration {
        current
            .saturating_mul(2)
            .max(self.first)
            .min(self.max.max(self.first))
    }
}

/// One RS485 bus and the rules its bus master follows.
#[derive(Debug, Clone, PartialEq)]
pub struct BusConfig {
    /// A name for logs and events (e.g. `"left wing"`).
    pub name: String,
    /// The port speed; every servo on the bus must use it (register 6).
    pub baud: BaudRate,
    /// The servos on the bus, in the order their entries appear in a long packet.
    pub servos: Vec<ServoSetup>,
    /// Allowance for the servo's and the adapter's latency, added to every reply timeout.
    pub turnaround: Duration,
    /// Consecutive silent reply timeouts after which a servo is offline ...
    pub offline_after_timeouts: u32,
    /// ... once it has also been silent this long. A servo whose replies arrive garbled (bad
    /// sums) is answering: it is counted among the bad replies, never taken for lost.
    pub offline_after_silence: Duration,
    /// Telemetry older than this makes an online servo stale.
    pub stale_after: Duration,
    /// Speed of the first move after force ON (soft start), in mm/s. Zero, negative or not a
    /// number switches soft start off.
    pub soft_start_speed_mm_s: f64,
    pub stall: StallConfig,
    /// How often an offline servo is asked whether it is back.
    pub probe_backoff: Backoff,
    /// How often a refused force-ON is tried again (never while the servo reports a
    /// temperature error).
    pub force_retry_backoff: Backoff,
    /// How often the driver tries to reopen a port that disappeared.
    pub port_reopen_backoff: Backoff,
    /// Return delay assumed before a servo's register 7 has been read.
    pub assumed_return_delay: Duration,
    /// Shortest time between two telemetry polls of one servo; zero polls in all spare bus time.
    /// Keep it well below `stale_after`, or every servo reads as stale between polls.
    pub telemetry_min_interval: Duration,
    /// How often each servo's force state and goal register (registers 30–41) are read back,
    /// to notice a servo that restarted without missing enough replies to go offline.
    pub verify_interval: Duration,
    /// How often each servo's temperature and voltage are read (the full registers 42–59);
    /// the polls between read position and current alone (registers 42–49), which hold the
    /// bus for less time.
    pub full_telemetry_interval: Duration,
    /// After a goal, no poll starts for this long: the other messages of the same autopilot
    /// tick (SERVO_OUTPUT_RAW port 1, ACTUATOR_OUTPUT_STATUS, a command) find the bus free.
    pub tick_gather: Duration,
    /// The RS485 mode set on the port each time it opens (`None`: the port's setting is left
    /// as it is). A driver that refuses it keeps the port closed.
    pub rs485: Option<Rs485Mode>,
}

impl BusConfig {
    pub const DEFAULT_TURNAROUND: Duration = Duration::from_millis(2);
    pub const DEFAULT_OFFLINE_AFTER_TIMEOUTS: u32 = 3;
    pub const DEFAULT_OFFLINE_AFTER_SILENCE: Duration = Duration::from_millis(300);
    pub const DEFAULT_FULL_TELEMETRY_INTERVAL: Duration = Duration::from_millis(50);
    pub const DEFAULT_TICK_GATHER: Duration = Duration::from_millis(2);
    pub const DEFAULT_STALE_AFTER: Duration = Duration::from_millis(500);
    pub const DEFAULT_SOFT_START_SPEED_MM_S: f64 = 10.0;

    /// A bus with the default timing rules.
    pub fn new(name: impl Into<String>, baud: BaudRate, servos: Vec<ServoSetup>) -> Self {
        BusConfig {
            name: name.into(),
            baud,
            servos,
            turnaround: Self::DEFAULT_TURNAROUND,
            offline_after_timeouts: Self::DEFAULT_OFFLINE_AFTER_TIMEOUTS,
            offline_after_silence: Self::DEFAULT_OFFLINE_AFTER_SILENCE,
            stale_after: Self::DEFAULT_STALE_AFTER,
            soft_start_speed_mm_s: Self::DEFAULT_SOFT_START_SPEED_MM_S,
            stall: StallConfig::default(),
            probe_backoff: Backoff {
                first: Duration::from_millis(100),
                max: Duration::from_secs(2),
            },
            force_retry_backoff: Backoff {
                first: Duration::from_millis(500),
                max: Duration::from_secs(8),
            },
            port_reopen_backoff: Backoff {
                first: Duration::from_millis(100),
                max: Duration::from_secs(2),
            },
            assumed_return_delay: Duration::from_millis(5),
            telemetry_min_interval: Duration::ZERO,
            verify_interval: Duration::from_secs(1),
            full_telemetry_interval: Self::DEFAULT_FULL_TELEMETRY_INTERVAL,
            tick_gather: Self::DEFAULT_TICK_GATHER,
            rs485: None,
        }
    }

    /// Wire time of `bytes` bytes at the bus speed.
    pub fn wire_time(&self, bytes: usize) -> Duration {
        Duration::from_nanos(self.baud.wire_time_ns(bytes))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn backoff_doubles_from_first_up_to_max() {
        let b = Backoff {
            first: Duration::from_millis(100),
            max: Duration::from_secs(2),
        };
        assert_eq!(b.after(Duration::ZERO), Duration::from_millis(100));
        assert_eq!(
            b.after(Duration::from_millis(100)),
            Duration::from_millis(200)
        );
        assert_eq!(b.after(Duration::from_millis(1500)), Duration::from_secs(2));
        assert_eq!(b.after(Duration::MAX), Duration::from_secs(2));
    }

    #[test]
    fn defaults_follow_the_design() {
        let c = BusConfig::new("b", BaudRate::B115200, vec![]);
        assert_eq!(c.turnaround, Duration::from_millis(2));
        assert_eq!(c.offline_after_timeouts, 3);
        assert_eq!(c.stale_after, Duration::from_millis(500));
        assert_eq!(c.wire_time(20), Duration::from_nanos(1_736_111));
    }
}

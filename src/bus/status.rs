//! A snapshot of one bus: each servo's health, telemetry and the age of that telemetry, and the
//! bus master's counters. Plain data, cloned out of the bus master for the MAVLink side.

use crate::protocol::{Celsius, MmCenti, PositionLimits, ReplyFlags, ServoId, Telemetry};
use std::time::{Duration, Instant};

/// How a servo is doing, worst first in [`Health::severity`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Health {
    /// Being read at start-up (or after it came back); not commanded yet.
    Starting,
    /// Answering, with telemetry younger than `stale_after`.
    Online,
    /// Answering now and then, but its latest telemetry is older than `stale_after`.
    Stale,
    /// Missed `offline_after_timeouts` replies in a row; probed with back-off.
    Offline,
    /// Not an LJ9DA41; never commanded.
    WrongModel,
    /// Reports a temperature error: force is OFF until it is power-cycled.
    TemperatureError,
}

impl Health {
    /// 0 for fine, larger for worse, for "the worst servo on the bus".
    pub fn severity(self) -> u8 {
        match self {
            Health::Online => 0,
            Health::Starting => 1,
            Health::Stale => 2,
            Health::Offline => 3,
            Health::TemperatureError => 4,
            Health::WrongModel => 5,
        }
    }
}

/// Force Enable (register 36) as far as the bus master knows it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ForceState {
    /// Not read yet (or the servo restarted).
    Unknown,
    Off,
    On,
    Brake,
}

/// What the bus master reads from a servo at start-up (and again when it comes back): each
/// field `None` until read.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ServoIdentity {
    /// Registers 0–1.
    pub model: Option<u16>,
    /// Register 2.
    pub firmware: Option<u8>,
    /// Registers 8–11 (when valid).
    pub limits: Option<PositionLimits>,
    /// Register 5.
    pub reversed: Option<bool>,
    /// Register 7.
    pub return_delay: Option<Duration>,
    /// Registers 14–15.
    pub temperature_limit: Option<Celsius>,
}

/// One servo's state.
#[derive(Debug, Clone, PartialEq)]
pub struct ServoStatus {
    pub id: ServoId,
    pub name: String,
    pub health: Health,
    /// The latest registers 42–59 (position, load, temperature, voltage).
    pub telemetry: Option<Telemetry>,
    /// When that telemetry arrived.
    pub telemetry_at: Option<Instant>,
    /// When its position was refreshed by a read between two full ones (of the position and
    /// current, registers 42–49, or in bus time too short for that of the position alone,
    /// registers 42–43), if it was since; `age` stays that of the full telemetry.
    pub position_at: Option<Instant>,
    /// `position_at` when that read refreshed the current too (registers 42–49), `None` when
    /// it read the position alone.
    pub motion_at: Option<Instant>,
    /// Its age at the time of the snapshot.
    pub age: Option<Duration>,
    /// The status bits of the servo's latest reply (bit 1, undefined, removed).
    pub flags: ReplyFlags,
    /// The latest goal position put on the wire (clamped to the servo's limits).
    pub goal: Option<MmCenti>,
    pub force: ForceState,
    pub stalled: bool,
    /// What start-up read from the servo.
    pub identity: ServoIdentity,
    /// Replies missed in a row.
    pub consecutive_timeouts: u32,
    /// Full telemetry polls (registers 42–59) answered.
    pub telemetry_count: u64,
    /// Requests answered with a good reply, of every kind: with `timeouts`, the share of
    /// requests that went unanswered or garbled.
    pub answered: u64,
    /// Replies missed in all (garbled or never came).
    pub timeouts: u64,
    /// `Some(percent)` while too many of its replies are bad: the share of bad replies in the
    /// latest window judged (see [`super::quality`]).
    pub degraded: Option<u8>,
}

/// What the bus master counted since it started.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct BusCounters {
    /// Long packets written.
    pub command_frames: u64,
    /// Telemetry polls written.
    pub polls: u64,
    /// Position-and-current reads written (registers 42–49, between two full polls).
    pub motion_polls: u64,
    /// Position-only reads written (bus time left before a goal, too short for a poll).
    pub position_polls: u64,
    /// Replies to telemetry polls received (full, and position and current).
    pub telemetry_replies: u64,
    /// Start-up reads, probes, force writes and read-backs written.
    pub other_requests: u64,
    /// Replies that did not arrive in time.
    pub timeouts: u64,
    /// Return packets rejected for a bad checksum.
    pub bad_sums: u64,
    /// Bytes skipped that started no packet (and other malformed candidates).
    pub garbage_bytes: u64,
    /// Echoes of our own packets (adapters that hear themselves), skipped.
    pub echoes: u64,
    /// The bytes of those echoes.
    pub echo_bytes: u64,
    /// Valid replies nobody was waiting for (wrong ID, wrong registers, too late).
    pub unexpected_replies: u64,
    /// Goals handed to `set_goal` for servos of this bus.
    pub goals_received: u64,
    /// Position goals that reached the wire in a long packet.
    pub goals_sent: u64,
    /// Position goals replaced by a newer goal before they reached the wire.
    pub goals_superseded: u64,
    /// Position goals equal to the one already on the wire (nothing to send).
    pub goals_unchanged: u64,
    /// `set_goal` calls for an ID that is not on this bus (ignored).
    pub goals_unknown_id: u64,
    /// Bytes written.
    pub bytes_sent: u64,
    /// Bytes received (including echoes and garbage).
    pub bytes_received: u64,
    /// Wire time of the bytes written plus that of the valid replies received, in ns: the
    /// numerator of bus utilisation.
    pub wire_busy_ns: u64,
    /// Times the bus thread ran more than 0.5 ms after the instant it slept until: the machine
    /// did not schedule it in time (an overloaded companion computer, or a virtual machine's
    /// host), and the bus sat idle meanwhile.
    pub late_wakeups: u64,
}

/// A snapshot of one bus.
#[derive(Debug, Clone, PartialEq)]
pub struct BusStatus {
    pub name: String,
    /// Whether the driver has the serial port open (always true for a bare bus master).
    pub port_open: bool,
    pub servos: Vec<ServoStatus>,
    pub counters: BusCounters,
    /// The time the snapshot describes (ages are measured to it).
    pub at: Instant,
    /// Position-and-current reads asked per servo per second (`None`: as often as the bus
    /// allows, `telemetry_hz = "max"`).
    pub telemetry_asked_hz: Option<f32>,
    /// What the bus thread has used so far (zero for a bare bus master).
    pub thread: ThreadUsage,
}

/// The bus thread's use of the computer since it started (`getrusage(RUSAGE_THREAD)`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ThreadUsage {
    /// CPU time, user and system.
    pub cpu: std::time::Duration,
    /// Times it went to sleep and was woken (voluntary context switches): on a virtual
    /// machine, each costs the thread more CPU than the work of a transaction.
    pub wakeups: u64,
}

impl BusStatus {
    pub fn servo(&self, id: ServoId) -> Option<&ServoStatus> {
        self.servos.iter().find(|s| s.id == id)
    }

    /// The worst health on the bus (`None` for a bus without servos).
    pub fn worst_health(&self) -> Option<Health> {
        self.servos
            .iter()
            .map(|s| s.health)
            .max_by_key(|h| h.severity())
    }
}

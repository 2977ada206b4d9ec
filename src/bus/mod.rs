//! The bus master: one RS485 bus, every servo commanded in one frame, telemetry in the time left
//! over.
//!
//! Two layers, one file per idea:
//! - [`master`]: [`BusMaster`], the sans-IO scheduler. It is handed goals, received bytes and
//!   the current time, and answers with the next bytes to write and the next deadline. It
//!   never does I/O and never reads a clock, so its tests run at microsecond precision without
//!   sleeping. `servo` is its per-servo record (start-up phase, force, goals, stall watch).
//! - [`driver`]: the thin shell ([`spawn_bus`], [`BusHandle`]) that runs one bus master in a
//!   thread of its own over a serial port, reading it on the bus master's clock (one wake-up
//!   per reply) and reopening it when it disappears. Several buses run side by side, one
//!   thread each. It never decides what to send; it carries bytes and time.
//!
//! [`quality`] judges each servo's share of bad replies (degraded, or well).
//!
//! Plain data: [`config`] (what the bus is), [`goal`] (what is asked of a servo), [`status`]
//! (what is known of it), [`event`] (what happened), [`transmit`] (what to write next).
//!
//! # What the bus master does
//! - **Commands.** When any servo's position goal differs from the one on the wire, the next
//!   bus slot carries one long packet with an entry for every commanded servo (goal position,
//!   and goal time when configured or needed). Goals are coalesced: only the newest per servo
//!   matters. The first move after force ON uses a soft start: a goal time that makes the
//!   move run at `soft_start_speed_mm_s`.
//! - **Telemetry.** In bus time not needed for commands, one servo at a time is polled
//!   (reply code 09: registers 42–59), round-robin. Nothing is sent while a reply is pending;
//!   a reply's timeout is the request's and the reply's wire time, plus the servo's return
//!   delay (register 7), plus `turnaround`.
//! - **Start-up.** Each servo: registers 0–29 (model number, firmware, reverse, return delay,
//!   limits; a model other than 0x7510 is refused), then max force (if configured) and
//!   registers 30–41 (force state, goal, goal time), then one telemetry poll. Force is
//!   switched ON when the first position goal arrives (the servo then takes its present
//!   position as goal, so nothing jumps).
//! - **Health.** Starting, online, stale, offline (after `offline_after_timeouts` silent
//!   timeouts in a row, then probed with back-off), wrong model, temperature error (no force-ON is tried
//!   while the servo reports it). A servo that answers again, or whose force is found OFF by
//!   the periodic read-back of registers 30–41, is re-initialised. Apart from its health, a
//!   servo that answers is degraded while too many of its replies are bad (see [`quality`]).
//! - **Stall.** A servo whose position stays further than the tolerance from its goal while
//!   drawing at least the configured current, for the configured time, is reported stalled.
//!
//! # Deviations from the API sketch the bridge was planned against
//! - [`BusHandle::output_message`] (added) takes one autopilot output message: a tick of its
//!   rhythm, with the goals of several servos at once (none when the outputs held still), and,
//!   when no reply is pending, writes their one long packet from the caller's thread before
//!   returning: the fastest path from a goal to the wire.
//!   [`BusHandle::set_goal`] wakes the driver task, which writes within its wake-up time; goals
//!   set one by one meanwhile share one long packet. The goal channel of the sketch is
//!   replaced by a mutex around the bus master and the port's write side (see [`driver`]).
//! - The driver publishes the status when it changes and at least every 100 ms, then the
//!   events (so a reader reacting to an event finds a status at least as new).
//! - `BusMaster::status()` measures ages to the latest time handed in;
//!   [`BusMaster::status_at`] takes the time explicitly. [`ServoStatus`] also carries
//!   `telemetry_at` so a reader can compute the age at its own time.
//! - [`TxKind`] has two more kinds, `Verify` (periodic read-back) and `Probe` (an offline
//!   servo), and `Final` for shutdown packets. [`Transmit`] also says whether a reply is now
//!   awaited and the packet's wire time.
//! - [`BusEvent`] has two more events: `ServoRestarted` (force found OFF without a temperature
//!   error: the servo restarted) and `ForceRefused`.
//! - `Goal::Hold` keeps the servo on its last goal: it gets no entry in long packets until
//!   the next position goal. A force-OFF servo stays OFF.
//! - Soft start applies to the first move after every force ON by the bus master (start-up,
//!   re-initialisation, after `Goal::Off`/`Goal::Brake`). It lasts until the servo is within
//!   the stall tolerance of its goal or the soft-start time has passed; a goal that changes
//!   meanwhile is also approached at the soft-start speed (unlike PWM mode, where any change
//!   of the input ends the soft start).
//! - An offline servo whose force was ON keeps its entry in long packets (its receive line
//!   may still work); a servo being re-initialised gets none until its force state is known.
//! - Extra configuration (with defaults): `probe_backoff` (100 ms doubling to 2 s),
//!   `force_retry_backoff` (0.5 s to 8 s), `port_reopen_backoff` (100 ms to 2 s),
//!   `assumed_return_delay` (5 ms, until register 7 is read), `telemetry_min_interval` (0),
//!   `verify_interval` (1 s).
//! - [`BusMaster`] also has `status_at`, `take_changed`, `reply_pending`, `counters`,
//!   `handle_port_lost`/`handle_port_back` (the driver reports the port), `shutdown_requested`,
//!   `is_shut_down` and `wire_idle_at`. A long packet is never queued more than one frame ahead
//!   of the wire.

pub mod config;
pub mod driver;
pub mod event;
#[cfg(feature = "fault-switch")]
pub mod fault_switch;
pub mod goal;
pub mod master;
pub mod quality;
pub mod rhythm;
mod servo;
pub mod status;
pub mod transmit;

#[cfg(test)]
mod tests;

pub use config::{Backoff, BusConfig, ServoSetup, StallConfig};
pub use driver::{BusHandle, StatusObserver, spawn_bus, spawn_bus_observed};
pub use event::BusEvent;
pub use goal::{Goal, ShutdownForce};
pub use master::BusMaster;
pub use status::{
    BusCounters, BusStatus, ForceState, Health, ServoIdentity, ServoStatus, ThreadUsage,
};
pub use transmit::{Transmit, TxKind};

//! Feeding the recorder from the buses: bus statuses in, telemetry and health records out.
//!
//! A [`StatusFeed`] is handed the [`BusStatus`]es a bus publishes and records what is new in
//! them: each servo's telemetry sample and each read of its position (and current) between two
//! full ones (once, stamped with the time its reply arrived), and its health or stall state
//! when either changes. It finds a servo's index in the record by its bus name and ID. Bus
//! events can be recorded through it too.
//!
//! As the bus's status observer ([`spawn_bus_observed`](crate::bus::spawn_bus_observed)) it is
//! called in the bus thread with every status, so it sees every sample. Fed from a status watch
//! ([`BusHandle::watch_status`](crate::bus::BusHandle::watch_status)), which keeps only the
//! newest status, a sample replaced before the feed looked is not recorded;
//! [`StatusFeed::missed_samples`] counts those (from the servo's telemetry counter), and the
//! record says so in a warning event, so the loss is known, not silent. Each servo's reply
//! counts (good, and garbled or missing) are recorded when they changed, at most once per
//! [`REPLIES_EVERY`].
//!
//! ```no_run
//! # fn feed(cfg: lj9da_bridge::bus::BusConfig, port: std::path::PathBuf,
//! #         record: lj9da_bridge::record::RecordHandle,
//! #         servos: Vec<lj9da_bridge::record::RecordServo>) {
//! use lj9da_bridge::bus::spawn_bus_observed;
//! use lj9da_bridge::record::StatusFeed;
//! let mut feed = StatusFeed::new(record, &servos);
//! let bus = spawn_bus_observed(cfg, port, Box::new(move |status| feed.observe(status)));
//! # }
//! ```

use super::format::{RecordServo, severity};
use super::writer::RecordHandle;
use crate::bus::{BusEvent, BusStatus, Health};
use crate::protocol::Motion;
use std::time::{Duration, Instant};

/// The shortest time between two replies records of a servo.
pub const REPLIES_EVERY: Duration = Duration::from_secs(1);

#[derive(Debug, Clone, Default)]
struct Seen {
    telemetry_at: Option<Instant>,
    telemetry_count: Option<u64>,
    position_at: Option<Instant>,
    state: Option<(Health, bool)>,
    /// When the latest replies record was written, and its counts.
    replies: Option<(Instant, u64, u64)>,
}

/// Turns bus statuses and events into records.
#[derive(Debug, Clone)]
pub struct StatusFeed {
    handle: RecordHandle,
    /// (bus, ID) of each servo index.
    servos: Vec<(String, u8)>,
    seen: Vec<Seen>,
    missed: u64,
}

impl StatusFeed {
    /// A feed for the servos of the record's servo table.
    pub fn new(handle: RecordHandle, servos: &[RecordServo]) -> Self {
        StatusFeed {
            handle,
            servos: servos.iter().map(|s| (s.bus.clone(), s.id)).collect(),
            seen: vec![Seen::default(); servos.len()],
            missed: 0,
        }
    }

    /// The servo index of servo `id` on bus `bus`.
    pub fn index_of(&self, bus: &str, id: u8) -> Option<usize> {
        self.servos.iter().position(|(b, i)| b == bus && *i == id)
    }

    /// Record what is new in a status of the bus it names: telemetry samples and position
    /// reads not yet recorded, and health or stall changes. Servos not in the table are ignored.
    pub fn observe(&mut self, status: &BusStatus) {
        for servo in &status.servos {
            let Some(index) = self.index_of(&status.name, servo.id.get()) else {
                continue;
            };
            let Some(seen) = self.seen.get_mut(index) else {
                continue;
            };
            if let (Some(telemetry), Some(at)) = (servo.telemetry, servo.telemetry_at)
                && seen.telemetry_at != Some(at)
            {
                if let Some(before) = seen.telemetry_count {
                    let missed = servo
                        .telemetry_count
                        .saturating_sub(before)
                        .saturating_sub(1);
                    if missed > 0 {
                        self.missed += missed;
                        self.handle.event(
                            Some(index),
                            severity::WARNING,
                            format!(
                                "{missed} telemetry samples not recorded (replaced before the \
                                 record saw them)"
                            ),
                        );
                    }
                }
                self.handle.telemetry(at, index, &telemetry, servo.flags);
                seen.telemetry_at = Some(at);
                seen.telemetry_count = Some(servo.telemetry_count);
            }
            if let (Some(telemetry), Some(at)) = (servo.telemetry, servo.position_at)
                && seen.position_at != Some(at)
            {
                if servo.motion_at == Some(at) {
                    let motion = Motion {
                        present_position: telemetry.present_position,
                        present_time: telemetry.present_time,
                        present_load: telemetry.present_load,
                    };
                    self.handle.motion(at, index, motion, servo.flags);
                } else {
                    self.handle
                        .position(at, index, telemetry.present_position, servo.flags);
                }
                seen.position_at = Some(at);
            }
            let counts = (servo.answered, servo.timeouts);
            let due = match seen.replies {
                None => counts != (0, 0),
                Some((at, answered, missed)) => {
                    (answered, missed) != counts
                        && status.at.saturating_duration_since(at) >= REPLIES_EVERY
                }
            };
            if due {
                self.handle.replies(status.at, index, counts.0, counts.1);
                seen.replies = Some((status.at, counts.0, counts.1));
            }
            let state = (servo.health, servo.stalled);
            if seen.state != Some(state) {
                self.handle.health(status.at, index, state.0, state.1);
                seen.state = Some(state);
            }
        }
    }

    /// Record a bus event of the bus called `bus`, with the severity a ground station would
    /// give it, now.
    pub fn bus_event(&self, bus: &str, event: &BusEvent) {
        let servo = event.servo().and_then(|id| self.index_of(bus, id.get()));
        let severity = match event {
            BusEvent::ServoOnline { .. } => severity::INFO,
            BusEvent::ServoBack { .. }
            | BusEvent::PortBack
            | BusEvent::TemperatureAlarm { on: false, .. }
            | BusEvent::Stalled { on: false, .. } => severity::NOTICE,
            BusEvent::RepliesOk { .. } => severity::INFO,
            BusEvent::ServoRestarted { .. }
            | BusEvent::ForceRefused { .. }
            | BusEvent::TemperatureAlarm { on: true, .. }
            | BusEvent::RepliesDegraded { .. } => severity::WARNING,
            BusEvent::WrongModel { .. }
            | BusEvent::Stalled { on: true, .. }
            | BusEvent::FlashWriteError { .. } => severity::ERROR,
            BusEvent::ServoLost { .. }
            | BusEvent::TemperatureError { .. }
            | BusEvent::PortLost { .. } => severity::CRITICAL,
        };
        self.handle
            .event(servo, severity, format!("bus {bus}: {event}"));
    }

    /// Telemetry samples the servos answered that this feed never saw (a newer status had
    /// replaced them).
    pub fn missed_samples(&self) -> u64 {
        self.missed
    }

    /// The recorder this feed writes to.
    pub fn handle(&self) -> &RecordHandle {
        &self.handle
    }
}

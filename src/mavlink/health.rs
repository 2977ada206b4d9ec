//! What the MAVLink side knows of each servo: a report per servo (from the bus master's status)
//! and the events that become STATUSTEXT. Kept apart from the bus types so that the telemetry
//! code depends on meaning, not on how the bus master stores it.

/// The state of one servo as the ground station should see it, best first.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum ServoState {
    /// Answering, data fresh.
    Online,
    /// Not yet initialised (start-up, or no goal yet).
    Starting,
    /// Answering, but the latest data is older than it should be.
    Stale,
    /// Not answering.
    Offline,
    /// Answering but unusable: wrong model, or force switched off by the temperature limit.
    Fault,
}

/// One servo's latest state and telemetry.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ServoReport {
    pub state: Option<ServoState>,
    pub position_mm: Option<f32>,
    pub current_a: Option<f32>,
    pub temperature_c: Option<f32>,
    pub voltage_v: Option<f32>,
    pub temperature_alarm: bool,
    pub temperature_error: bool,
    pub stalled: bool,
    /// Replies lost or rejected since start.
    pub error_count: u32,
    /// The servo's model number (registers 0–1), once read.
    pub model: Option<u16>,
    /// The servo's firmware version (register 2), once read.
    pub firmware: Option<u8>,
    /// `Some(percent)` while too many of its replies are bad (it still answers): the share
    /// of bad replies lately (see [`crate::bus::quality`]).
    pub degraded: Option<u8>,
}

impl ServoReport {
    pub fn state(&self) -> ServoState {
        self.state.unwrap_or(ServoState::Starting)
    }

    pub fn online(&self) -> bool {
        matches!(self.state(), ServoState::Online | ServoState::Stale)
    }
}

/// A temperature read from a servo, and how old that reading was when the event was told.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct TemperatureReading {
    pub celsius: i16,
    pub age: std::time::Duration,
}

/// Something that happened to one servo.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ServoEvent {
    /// Stopped answering.
    Lost,
    /// Answering again after being lost.
    Back,
    TemperatureAlarm {
        on: bool,
        /// The latest temperature read and its age, when the alarm goes on; `None` when no
        /// fresh reading is at hand (and for the all-clear). The bus master holds the event
        /// until the temperature is read after the flag, so the reading is normally of the
        /// moment; when that read did not come in time, the age says how old it is.
        reading: Option<TemperatureReading>,
    },
    /// The servo hit its temperature limit and switched force off; it needs a power cycle.
    TemperatureError {
        /// The latest temperature read, if a fresh one is at hand. The flag may come in a
        /// reply that carries no temperature (a position read, a write's answer), so this
        /// reading can predate the event: the servo may be hotter by now.
        last_read: Option<TemperatureReading>,
    },
    Stalled {
        on: bool,
    },
    WrongModel {
        found: u16,
    },
    FlashWriteError,
    /// Too many of its replies are bad, `percent` of them, while it keeps answering.
    RepliesDegraded {
        percent: u8,
    },
    /// A degraded servo's replies are good again.
    RepliesOk,
}

/// Something that happened to the bridge as a whole.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub enum BridgeEvent {
    Servo {
        servo: usize,
        event: ServoEvent,
    },
    FailsafeEntered {
        timeout_ms: u32,
    },
    FailsafeLeft,
    /// The output messages keep coming, but none has carried this servo's channel for the
    /// failsafe timeout (e.g. PX4 streams SERVO_OUTPUT_RAW port 0 only, and the servo is on
    /// channel 17): the servo has taken its failsafe action.
    ChannelMissing {
        servo: usize,
        channel: u8,
        timeout_ms: u32,
    },
    /// A message carries the servo's channel again: its failsafe is over.
    ChannelBack {
        servo: usize,
        channel: u8,
    },
    /// The autopilot refused to send the configured output message (not for its rate).
    SourceRefused {
        source: crate::config::Source,
    },
    PortLost {
        bus: String,
    },
    PortBack {
        bus: String,
    },
    /// ArduPilot's safety switch went on (servos off its `BRD_SAFETY_MASK` do as the mapping's
    /// `[bridge] while_safe` says: `servos`) or off.
    Safety {
        on: bool,
        servos: crate::config::bridge::ForceAction,
    },
}

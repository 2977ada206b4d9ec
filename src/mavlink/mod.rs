//! The MAVLink side of the bridge: autopilot outputs in, servo health out.
//!
//! - [`outputs`]: SERVO_OUTPUT_RAW / ACTUATOR_OUTPUT_STATUS as channel values.
//! - [`admission`]: which received messages reach the loop: the kinds the core acts on, and a
//!   budget for every system but the autopilot.
//! - [`commands`]: COMMAND_LONG / COMMAND_INT in one form, and which are the bridge's.
//! - [`core`]: the sans-IO bridge logic (autopilot, mapping, commands, failsafe, stream
//!   requests, telemetry schedule).
//! - [`param_server`]: the parameter protocol (list, read, set) served by the bridge's component.
//! - [`params`]: the MAVLink parameters, and the mapping-file edit each change makes.
//! - [`peers`]: who a listening UDP link answers: every system heard on it recently.
//! - [`schedule`]: when each telemetry carrier goes out, and values only on change.
//! - [`telemetry`]: HEARTBEAT, NAMED_VALUE_FLOAT, ESC_INFO/ESC_STATUS and STATUSTEXT builders.
//! - [`statustext`]: event texts, severities and the flood guard.
//! - [`health`]: the servo reports and events the telemetry is made from.
//! - [`signing`]: MAVLink 2 signing: incoming messages checked and counted, outgoing ones
//!   signed, timestamps that survive a restart.

pub mod admission;
pub mod commands;
pub mod core;
pub mod health;
pub mod outbox;
pub mod outputs;
pub mod param_server;
pub mod params;
pub mod peers;
pub mod rate;
pub mod schedule;
pub mod signing;
pub mod statustext;
pub mod telemetry;

pub use self::core::{BridgeCore, LinkId, Outgoing};
pub use health::{BridgeEvent, ServoEvent, ServoReport, ServoState, TemperatureReading};
pub use mavlink::dialects::common::MavMessage;

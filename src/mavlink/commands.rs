//! Commands as the bridge reads them: COMMAND_LONG and COMMAND_INT brought to one form, and
//! which of them are the bridge's to carry out and answer.
//!
//! Addressing (MAVLink: target 0 means "every system" / "every component"):
//! - Addressed to the bridge's own component (system = the vehicle's or 0): carried out if
//!   supported, and always answered with a COMMAND_ACK (UNSUPPORTED for any other command).
//! - Broadcast to every component (`target_component = 0`), per command:
//!   - MAV_CMD_DO_SET_SERVO: **not** carried out, not answered. The autopilot carries it out on
//!     its own output (ArduPilot moves an output whose function is unassigned) and answers it;
//!     the new value then reaches the bridge in SERVO_OUTPUT_RAW like any other output. Acting
//!     on it directly as well would act twice, and answer twice.
//!   - MAV_CMD_DO_SET_ACTUATOR: carried out for the servos whose mapping names an `actuator`,
//!     answered only if one of them moved (the autopilot answers for its own outputs). A servo
//!     with an `actuator` key must not also be read from an output the autopilot assigns to
//!     that actuator set, or it would be moved twice.
//!   - anything else: not the bridge's; no answer, so that the autopilot's answer stands alone.
//! - Addressed to another component: ignored.

use mavlink::dialects::common::{COMMAND_INT_DATA, COMMAND_LONG_DATA, MavCmd};

/// COMMAND_INT carries "no value" for an actuator as INT32_MAX in `x` and `y`.
const INT_NO_VALUE: i32 = i32::MAX;
/// COMMAND_INT carries an actuator value in `x` and `y` scaled by 1e7.
const INT_ACTUATOR_SCALE: f32 = 1e7;

/// A command from either carrier: params 1–7 as COMMAND_LONG has them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Command {
    pub command: MavCmd,
    pub target_system: u8,
    pub target_component: u8,
    pub params: [f32; 7],
}

impl Command {
    pub fn from_long(c: &COMMAND_LONG_DATA) -> Self {
        Command {
            command: c.command,
            target_system: c.target_system,
            target_component: c.target_component,
            params: [
                c.param1, c.param2, c.param3, c.param4, c.param5, c.param6, c.param7,
            ],
        }
    }

    /// COMMAND_INT's params 5 and 6 are the integers `x` and `y`: for DO_SET_ACTUATOR they are
    /// actuator values × 1e7 (INT32_MAX: leave it), as the MAVLink spec defines; for other
    /// commands they are taken as they are.
    pub fn from_int(c: &COMMAND_INT_DATA) -> Self {
        let (x, y) = if c.command == MavCmd::MAV_CMD_DO_SET_ACTUATOR {
            let value = |v: i32| {
                if v == INT_NO_VALUE {
                    f32::NAN
                } else {
                    v as f32 / INT_ACTUATOR_SCALE
                }
            };
            (value(c.x), value(c.y))
        } else {
            (c.x as f32, c.y as f32)
        };
        Command {
            command: c.command,
            target_system: c.target_system,
            target_component: c.target_component,
            params: [c.param1, c.param2, c.param3, c.param4, x, y, c.z],
        }
    }
}

/// What the bridge does with a command (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Handling {
    /// Addressed to the bridge: carry it out if supported, and always answer.
    Own,
    /// Broadcast, and one the bridge acts on: carry it out, answer only if it did something.
    Broadcast,
    /// Not the bridge's.
    Ignore,
}

/// How to handle `cmd` for the bridge `(system, component)`.
pub fn handling(cmd: &Command, own: (u8, u8)) -> Handling {
    let (system, component) = own;
    if cmd.target_system != system && cmd.target_system != 0 {
        return Handling::Ignore;
    }
    if cmd.target_component == component {
        return Handling::Own;
    }
    if cmd.target_component != 0 {
        return Handling::Ignore;
    }
    match cmd.command {
        MavCmd::MAV_CMD_DO_SET_ACTUATOR => Handling::Broadcast,
        _ => Handling::Ignore,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cmd(command: MavCmd, target: (u8, u8)) -> Command {
        Command {
            command,
            target_system: target.0,
            target_component: target.1,
            params: [0.0; 7],
        }
    }

    #[test]
    fn broadcast_do_set_servo_is_the_autopilots_and_do_set_actuator_is_shared() {
        let own = (7, 140);
        use MavCmd::*;
        assert_eq!(
            handling(&cmd(MAV_CMD_DO_SET_SERVO, (7, 140)), own),
            Handling::Own
        );
        assert_eq!(
            handling(&cmd(MAV_CMD_DO_SET_SERVO, (0, 140)), own),
            Handling::Own
        );
        assert_eq!(
            handling(&cmd(MAV_CMD_DO_SET_SERVO, (7, 0)), own),
            Handling::Ignore
        );
        assert_eq!(
            handling(&cmd(MAV_CMD_DO_SET_ACTUATOR, (7, 0)), own),
            Handling::Broadcast
        );
        assert_eq!(
            handling(&cmd(MAV_CMD_DO_SET_ACTUATOR, (0, 0)), own),
            Handling::Broadcast
        );
        assert_eq!(
            handling(&cmd(MAV_CMD_REQUEST_MESSAGE, (7, 0)), own),
            Handling::Ignore
        );
        assert_eq!(
            handling(&cmd(MAV_CMD_DO_SET_ACTUATOR, (8, 0)), own),
            Handling::Ignore
        );
        assert_eq!(
            handling(&cmd(MAV_CMD_DO_SET_SERVO, (7, 1)), own),
            Handling::Ignore
        );
    }

    #[test]
    fn command_int_carries_actuator_values_scaled_by_1e7_and_int32_max_leaves_one() {
        let c = COMMAND_INT_DATA {
            command: MavCmd::MAV_CMD_DO_SET_ACTUATOR,
            param1: 0.25,
            x: 5_000_000,
            y: i32::MAX,
            z: 1.0,
            ..Default::default()
        };
        let c = Command::from_int(&c);
        assert_eq!(c.params[0], 0.25);
        assert_eq!(c.params[4], 0.5);
        assert!(c.params[5].is_nan());
        assert_eq!(c.params[6], 1.0);
    }
}

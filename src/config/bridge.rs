//! The `[bridge]` table: how the bridge itself behaves, apart from any one servo.

use super::error::{ConfigError, Scope};
use super::raw::RawBridge;
use crate::protocol::ForceMode;
use std::fmt;
use toml::Spanned;

/// What the servos' force is left at, where the bridge sends no goal: when it stops (Ctrl-C,
/// SIGTERM) and while the autopilot's safety switch is on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum ForceAction {
    /// Force stays on at the last goal: the servos hold where they are, as they do when the
    /// bridge disappears without warning.
    #[default]
    Hold,
    /// Force off: the rods are free.
    Off,
    /// Brake: the rods move by hand with light resistance.
    Brake,
}

impl ForceAction {
    /// The Force Enable value to leave the servos in.
    pub const fn force_mode(self) -> ForceMode {
        match self {
            ForceAction::Hold => ForceMode::On,
            ForceAction::Off => ForceMode::Off,
            ForceAction::Brake => ForceMode::Brake,
        }
    }
}

impl fmt::Display for ForceAction {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            ForceAction::Hold => "hold",
            ForceAction::Off => "off",
            ForceAction::Brake => "brake",
        })
    }
}

/// Where the servos' goals come from: one source, never both.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum CommandSource {
    /// The autopilot's MAVLink outputs (SERVO_OUTPUT_RAW or ACTUATOR_OUTPUT_STATUS) and
    /// DO_SET_SERVO / DO_SET_ACTUATOR.
    #[default]
    Mavlink,
    /// DroneCAN's `uavcan.equipment.actuator.ArrayCommand` (the `[dronecan]` table). MAVLink
    /// still carries health and parameters, and moves nothing.
    DroneCan,
}

impl fmt::Display for CommandSource {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            CommandSource::Mavlink => "mavlink",
            CommandSource::DroneCan => "dronecan",
        })
    }
}

/// The `[bridge]` table.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct BridgeSection {
    /// What the servos do when the bridge stops (default hold).
    pub on_exit: ForceAction,
    /// What a servo off the autopilot's safety mask does while ArduPilot's safety switch is on
    /// (default hold: what an LJ9DA41 on the autopilot's own PWM output does when the safety
    /// stops its pulses).
    pub while_safe: ForceAction,
    /// Where the goals come from (default MAVLink).
    pub commands: CommandSource,
}

impl BridgeSection {
    pub(crate) fn from_raw(raw: &RawBridge, scope: &Scope<'_>) -> Result<Self, ConfigError> {
        Ok(BridgeSection {
            on_exit: force_action(raw.on_exit.as_ref(), "on_exit", "an exit action", scope)?,
            while_safe: force_action(
                raw.while_safe.as_ref(),
                "while_safe",
                "an action for the safety switch",
                scope,
            )?,
            commands: match &raw.commands {
                None => CommandSource::default(),
                Some(v) => match v.get_ref().trim().to_ascii_lowercase().as_str() {
                    "mavlink" => CommandSource::Mavlink,
                    "dronecan" => CommandSource::DroneCan,
                    other => {
                        return Err(scope.error_on(
                            v,
                            "commands",
                            format!(
                                "\"{other}\" is not a source of the servos' goals; use \"mavlink\" \
                                 or \"dronecan\""
                            ),
                        ));
                    }
                },
            },
        })
    }
}

/// `key`'s value, `"hold"`, `"off"` or `"brake"` (hold when it is not set); anything else is
/// not `what`.
fn force_action(
    value: Option<&Spanned<String>>,
    key: &str,
    what: &str,
    scope: &Scope<'_>,
) -> Result<ForceAction, ConfigError> {
    let Some(value) = value else {
        return Ok(ForceAction::default());
    };
    match value.get_ref().trim().to_ascii_lowercase().as_str() {
        "hold" => Ok(ForceAction::Hold),
        "off" => Ok(ForceAction::Off),
        "brake" => Ok(ForceAction::Brake),
        other => Err(scope.error_on(
            value,
            key,
            format!("\"{other}\" is not {what}; use \"hold\", \"off\" or \"brake\""),
        )),
    }
}

//! The `[bridge]` table: how the bridge itself behaves, apart from any one servo.

use super::error::{ConfigError, Scope};
use super::raw::RawBridge;
use crate::protocol::ForceMode;
use std::fmt;

/// What the servos are left doing when the bridge stops (Ctrl-C, SIGTERM).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum ExitAction {
    /// Force stays on at the last goal: the servos hold where they are, as they do when the
    /// bridge disappears without warning.
    #[default]
    Hold,
    /// Force off: the rods are free.
    Off,
    /// Brake: the rods move by hand with light resistance.
    Brake,
}

impl ExitAction {
    /// The Force Enable value to leave the servos in.
    pub const fn force_mode(self) -> ForceMode {
        match self {
            ExitAction::Hold => ForceMode::On,
            ExitAction::Off => ForceMode::Off,
            ExitAction::Brake => ForceMode::Brake,
        }
    }
}

impl fmt::Display for ExitAction {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            ExitAction::Hold => "hold",
            ExitAction::Off => "off",
            ExitAction::Brake => "brake",
        })
    }
}

/// The `[bridge]` table.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct BridgeSection {
    /// What the servos do when the bridge stops (default hold).
    pub on_exit: ExitAction,
}

impl BridgeSection {
    pub(crate) fn from_raw(raw: &RawBridge, scope: &Scope<'_>) -> Result<Self, ConfigError> {
        let on_exit = match &raw.on_exit {
            None => ExitAction::default(),
            Some(value) => {
                match value.get_ref().trim().to_ascii_lowercase().as_str() {
                    "hold" => ExitAction::Hold,
                    "off" => ExitAction::Off,
                    "brake" => ExitAction::Brake,
                    other => {
                        return Err(scope.error_on(
                        value,
                        "on_exit",
                        format!("\"{other}\" is not an exit action; use \"hold\", \"off\" or \"brake\""),
                    ));
                    }
                }
            }
        };
        Ok(BridgeSection { on_exit })
    }
}

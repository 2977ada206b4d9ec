//! What the rest of the bridge asks of a servo, and what it leaves behind at shutdown.

use crate::protocol::MmCenti;

/// The newest wish for one servo. Only the newest matters: a goal that has not reached the
/// wire when the next one arrives is replaced.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Goal {
    /// Move to this position (clamped to the servo's position limits). Switches force ON
    /// first if it is off.
    Position(MmCenti),
    /// Stay where the last goal put it: no new command. A servo that is force-OFF stays OFF.
    Hold,
    /// Force OFF (the rod is free).
    Off,
    /// Brake: the rod moves by hand with light resistance.
    Brake,
}

/// What the bus master leaves the servos in when it shuts down.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ShutdownForce {
    /// Send the newest goals still waiting, then nothing: every servo holds its last goal.
    AsIs,
    /// Switch every servo's force OFF.
    Off,
    /// Switch every servo to brake (the rod moves by hand with light resistance).
    Brake,
}

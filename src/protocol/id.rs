//! Servo IDs and packet destinations.

use super::error::ProtocolError;
use std::fmt;

/// A servo ID in 1–127, the range register 4 accepts. Constructing one is the only way to
/// address a single servo, so an out-of-range ID can never reach the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct ServoId(u8);

impl ServoId {
    pub const MIN: u8 = 1;
    pub const MAX: u8 = 127;

    pub const fn new(id: u8) -> Result<Self, ProtocolError> {
        if id >= Self::MIN && id <= Self::MAX {
            Ok(Self(id))
        } else {
            Err(ProtocolError::InvalidId { id })
        }
    }

    pub const fn get(self) -> u8 {
        self.0
    }

    /// Every valid ID, 1 to 127.
    pub fn all() -> impl Iterator<Item = ServoId> {
        (Self::MIN..=Self::MAX).map(ServoId)
    }
}

impl TryFrom<u8> for ServoId {
    type Error = ProtocolError;
    fn try_from(id: u8) -> Result<Self, Self::Error> {
        Self::new(id)
    }
}

impl fmt::Display for ServoId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.0.fmt(f)
    }
}

/// Where a short packet goes: one servo, or every servo on the bus (ID 255, never answered).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Destination {
    Servo(ServoId),
    Broadcast,
}

impl Destination {
    /// The ID byte used for broadcast packets.
    pub const BROADCAST_ID: u8 = 255;

    pub const fn id_byte(self) -> u8 {
        match self {
            Destination::Servo(id) => id.get(),
            Destination::Broadcast => Self::BROADCAST_ID,
        }
    }
}

impl From<ServoId> for Destination {
    fn from(id: ServoId) -> Self {
        Destination::Servo(id)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_outside_1_to_127_are_refused() {
        assert!(ServoId::new(0).is_err());
        assert!(ServoId::new(128).is_err());
        assert!(ServoId::new(255).is_err());
        assert_eq!(ServoId::new(1).unwrap().get(), 1);
        assert_eq!(ServoId::new(127).unwrap().get(), 127);
        assert_eq!(ServoId::all().count(), 127);
    }

    #[test]
    fn broadcast_is_id_255() {
        assert_eq!(Destination::Broadcast.id_byte(), 255);
    }
}

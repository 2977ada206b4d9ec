//! What the bus master tells the rest of the bridge about, once, when it happens: the material
//! for STATUSTEXT messages and logs. The current state of every servo is in
//! [`BusStatus`](super::BusStatus); events are its edges.

use crate::protocol::ServoId;
use std::fmt;

/// Something that happened on the bus.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum BusEvent {
    /// The servo finished its start-up (or its re-initialisation) and is polled for telemetry.
    ServoOnline { id: ServoId },
    /// The servo missed `offline_after_timeouts` replies in a row (or never answered).
    ServoLost { id: ServoId },
    /// An offline servo answered again; it is being re-initialised.
    ServoBack { id: ServoId },
    /// The servo's force was found OFF although the bus master had switched it ON, with no
    /// temperature error: it restarted. It is being re-initialised.
    ServoRestarted { id: ServoId },
    /// The device at this ID is not an LJ9DA41; it is never commanded.
    WrongModel { id: ServoId, found: u16 },
    /// The temperature alarm flag (10 °C below the limit) went on or off.
    TemperatureAlarm { id: ServoId, on: bool },
    /// The servo reached its temperature limit and switched force OFF. It refuses force ON
    /// until it is power-cycled; the bus master does not try.
    TemperatureError { id: ServoId },
    /// The servo asked for force ON kept force OFF (e.g. its rod is outside the position
    /// limits); it is tried again with back-off.
    ForceRefused { id: ServoId },
    /// The servo stopped following its goal while drawing high current (or started again).
    Stalled { id: ServoId, on: bool },
    /// The servo reports a failed flash write.
    FlashWriteError { id: ServoId },
    /// More than [`super::quality::DEGRADED_ABOVE`] of the servo's requests in a window got a
    /// garbled reply or none, while it kept answering: `percent` of them.
    RepliesDegraded { id: ServoId, percent: u8 },
    /// A degraded servo's share of bad replies fell below [`super::quality::OK_BELOW`].
    RepliesOk { id: ServoId },
    /// The serial port failed or disappeared; the driver is reopening it.
    PortLost { reason: String },
    /// The serial port is open again.
    PortBack,
}

impl BusEvent {
    /// The servo the event is about, if any.
    pub fn servo(&self) -> Option<ServoId> {
        match self {
            BusEvent::ServoOnline { id }
            | BusEvent::ServoLost { id }
            | BusEvent::ServoBack { id }
            | BusEvent::ServoRestarted { id }
            | BusEvent::WrongModel { id, .. }
            | BusEvent::TemperatureAlarm { id, .. }
            | BusEvent::TemperatureError { id }
            | BusEvent::ForceRefused { id }
            | BusEvent::Stalled { id, .. }
            | BusEvent::FlashWriteError { id }
            | BusEvent::RepliesDegraded { id, .. }
            | BusEvent::RepliesOk { id } => Some(*id),
            BusEvent::PortLost { .. } | BusEvent::PortBack => None,
        }
    }

    /// Whether the event is trouble (a warning in a log) rather than news of things going
    /// well again (information).
    pub fn is_trouble(&self) -> bool {
        !matches!(
            self,
            BusEvent::ServoOnline { .. }
                | BusEvent::ServoBack { .. }
                | BusEvent::PortBack
                | BusEvent::RepliesOk { .. }
                | BusEvent::TemperatureAlarm { on: false, .. }
                | BusEvent::Stalled { on: false, .. }
        )
    }
}

impl fmt::Display for BusEvent {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            BusEvent::ServoOnline { id } => write!(f, "servo {id} online"),
            BusEvent::ServoLost { id } => write!(f, "servo {id} lost: no reply"),
            BusEvent::ServoBack { id } => write!(f, "servo {id} back, re-initialising"),
            BusEvent::ServoRestarted { id } => {
                write!(f, "servo {id} restarted (force found off), re-initialising")
            }
            BusEvent::WrongModel { id, found } => write!(
                f,
                "servo {id} is model 0x{found:04X}, not an LJ9DA41 (0x7510): not commanded"
            ),
            BusEvent::TemperatureAlarm { id, on: true } => {
                write!(f, "servo {id} temperature alarm")
            }
            BusEvent::TemperatureAlarm { id, on: false } => {
                write!(f, "servo {id} temperature alarm cleared")
            }
            BusEvent::TemperatureError { id } => write!(
                f,
                "servo {id} over temperature: force off until power-cycled"
            ),
            BusEvent::ForceRefused { id } => write!(
                f,
                "servo {id} refused force on (rod outside its limits?), retrying"
            ),
            BusEvent::Stalled { id, on: true } => write!(f, "servo {id} stalled"),
            BusEvent::Stalled { id, on: false } => write!(f, "servo {id} moving again"),
            BusEvent::FlashWriteError { id } => write!(f, "servo {id} flash write error"),
            BusEvent::RepliesDegraded { id, percent } => {
                write!(f, "servo {id} degraded: {percent}% of its replies bad")
            }
            BusEvent::RepliesOk { id } => write!(f, "servo {id} replies ok"),
            BusEvent::PortLost { reason } => write!(f, "serial port lost: {reason}"),
            BusEvent::PortBack => f.write_str("serial port back"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trouble_is_what_went_wrong_not_what_came_right() {
        let id = ServoId::new(3).unwrap();
        for event in [
            BusEvent::ServoLost { id },
            BusEvent::TemperatureAlarm { id, on: true },
            BusEvent::Stalled { id, on: true },
            BusEvent::PortLost {
                reason: "end of file".into(),
            },
        ] {
            assert!(event.is_trouble(), "{event}");
        }
        for event in [
            BusEvent::ServoOnline { id },
            BusEvent::TemperatureAlarm { id, on: false },
            BusEvent::Stalled { id, on: false },
            BusEvent::PortBack,
        ] {
            assert!(!event.is_trouble(), "{event}");
        }
    }
}

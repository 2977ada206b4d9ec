//! Configuration of a simulated bus.

use std::path::PathBuf;
use std::time::Duration;

use thiserror::Error;

use crate::fault::Fault;
use crate::servo::memory_map::{self, BAUD_TABLE};

/// Settings of one simulated bus.
#[derive(Debug, Clone, PartialEq)]
pub struct SimConfig {
    /// One servo per entry, with this ID in flash (1–127; duplicates are allowed and collide like real ones).
    pub ids: Vec<u8>,
    /// Bit rate stored in every servo's flash (one of the register-6 rates). Also the pty's initial speed.
    pub baud: u32,
    /// Supply voltage of every servo.
    pub voltage_v: f32,
    /// Ambient temperature.
    pub ambient_c: f32,
    /// The servo's own turnaround, added to the Return Delay Time before a reply's first byte.
    pub processing_latency: Duration,
    /// Return Delay Time stored in every servo's flash (register 7, ms; the factory value is 0).
    pub return_delay_ms: u8,
    /// Seed of the fault generator: the same seed replays the same corrupted and dropped replies.
    pub seed: u64,
    /// Create a symlink here pointing at the current pty slave (kept across `disconnect_port` /
    /// `reconnect_port`).
    pub link: Option<PathBuf>,
    /// Faults present from the start: `(None, fault)` bus-wide, `(Some(id), fault)` for one servo.
    pub faults: Vec<(Option<u8>, Fault)>,
}

impl Default for SimConfig {
    fn default() -> Self {
        SimConfig {
            ids: vec![1],
            baud: 115_200,
            voltage_v: 12.0,
            ambient_c: 25.0,
            processing_latency: Duration::from_micros(150),
            return_delay_ms: 0,
            seed: 1,
            link: None,
            faults: Vec::new(),
        }
    }
}

/// Why a [`SimConfig`] cannot be simulated.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ConfigError {
    #[error("no servos: give at least one ID (1–127)")]
    NoServos,
    #[error("servo ID {0} is outside 1–127: the LJ9DA41 accepts IDs 1–127 only")]
    IdOutOfRange(u8),
    #[error("{0} bit/s is not an LJ9DA41 rate; use one of {rates}", rates = supported_rates())]
    UnsupportedBaud(u32),
    #[error("supply voltage {0} V is not a number ≥ 0")]
    BadVoltage(f32),
    #[error("ambient temperature {0} °C is not a number")]
    BadAmbient(f32),
    #[error("fault probability {0} is outside 0…1")]
    BadProbability(f64),
    #[error("fault for servo {0}, which is not on the bus (IDs: {1:?})")]
    UnknownFaultId(u8, Vec<u8>),
}

fn supported_rates() -> String {
    BAUD_TABLE
        .iter()
        .map(|(_, baud)| baud.to_string())
        .collect::<Vec<_>>()
        .join(", ")
}

impl SimConfig {
    /// Check every field; the error says which value is wrong and what is allowed.
    pub fn validate(&self) -> Result<(), ConfigError> {
        if self.ids.is_empty() {
            return Err(ConfigError::NoServos);
        }
        if let Some(&id) = self.ids.iter().find(|id| !(1..=127).contains(*id)) {
            return Err(ConfigError::IdOutOfRange(id));
        }
        if memory_map::code_from_baud(self.baud).is_none() {
            return Err(ConfigError::UnsupportedBaud(self.baud));
        }
        if !self.voltage_v.is_finite() || self.voltage_v < 0.0 {
            return Err(ConfigError::BadVoltage(self.voltage_v));
        }
        if !self.ambient_c.is_finite() {
            return Err(ConfigError::BadAmbient(self.ambient_c));
        }
        for (id, fault) in &self.faults {
            if let Some(id) = id
                && !self.ids.contains(id)
            {
                return Err(ConfigError::UnknownFaultId(*id, self.ids.clone()));
            }
            if let Fault::CorruptReplies { probability } | Fault::DropReplies { probability } =
                fault
                && !(0.0..=1.0).contains(probability)
            {
                return Err(ConfigError::BadProbability(*probability));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_config_is_valid() {
        assert_eq!(SimConfig::default().validate(), Ok(()));
    }

    #[test]
    fn unsupported_baud_is_refused_with_the_list() {
        let error = SimConfig {
            baud: 921_600,
            ..SimConfig::default()
        }
        .validate()
        .unwrap_err();
        assert_eq!(error, ConfigError::UnsupportedBaud(921_600));
        assert!(error.to_string().contains("460800"));
    }

    #[test]
    fn ids_outside_1_to_127_are_refused() {
        let error = SimConfig {
            ids: vec![1, 128],
            ..SimConfig::default()
        }
        .validate()
        .unwrap_err();
        assert_eq!(error, ConfigError::IdOutOfRange(128));
    }
}

//! The `[[bus]]` tables: one RS485 line, its serial port and its baud rate.

use super::error::{ConfigError, Scope};
use super::raw::RawBus;
use crate::protocol::BaudRate;
use std::path::PathBuf;

/// The largest turnaround allowance a bus may ask for.
const TURNAROUND_MAX_MS: f64 = 100.0;

/// One `[[bus]]` table.
#[derive(Debug, Clone, PartialEq)]
pub struct BusSection {
    /// The name servos refer to with `bus = "…"`.
    pub name: String,
    /// The serial port of the RS485 adapter (`/dev/ttyUSB0`). `lj9da-bridge sitl` replaces it
    /// with the simulated servos' pseudo-terminal.
    pub port: PathBuf,
    /// The servos' baud rate (register 6); only the rates of the servo's table are accepted.
    /// Default 115 200 bit/s, the factory setting.
    pub baud: BaudRate,
    /// Extra time allowed for a reply to start, in ms, on top of the wire time: the servos'
    /// Return Delay Time plus the adapter's latency. `None`: the bus master's own allowance.
    pub turnaround_ms: Option<f32>,
}

/// A bus or servo name: 1–32 ASCII letters, digits, `_` or `-`.
pub(crate) fn check_name(name: &str) -> Result<(), String> {
    if name.is_empty() {
        return Err("the name is empty".to_string());
    }
    if name.chars().count() > 32 {
        return Err(format!("\"{name}\" is longer than 32 characters"));
    }
    if let Some(bad) = name
        .chars()
        .find(|c| !(c.is_ascii_alphanumeric() || matches!(c, '_' | '-')))
    {
        return Err(format!(
            "\"{name}\" contains {bad:?}; use ASCII letters, digits, '_' and '-'"
        ));
    }
    Ok(())
}

impl BusSection {
    pub(crate) fn from_raw(raw: &RawBus, scope: &Scope<'_>) -> Result<Self, ConfigError> {
        check_name(raw.name.get_ref()).map_err(|r| scope.error_on(&raw.name, "name", r))?;
        let port = raw.port.get_ref().trim();
        if port.is_empty() {
            return Err(scope.error_on(
                &raw.port,
                "port",
                "the serial port is empty; e.g. port = \"/dev/ttyUSB0\"",
            ));
        }
        let baud = match &raw.baud {
            None => BaudRate::DEFAULT,
            Some(b) => u32::try_from(*b.get_ref())
                .ok()
                .and_then(|bps| BaudRate::from_bits_per_second(bps).ok())
                .ok_or_else(|| {
                    scope.error_on(
                        b,
                        "baud",
                        format!(
                            "{} bit/s is not a rate the LJ9DA41 supports; use one of {}",
                            b.get_ref(),
                            BaudRate::ALL
                                .iter()
                                .map(|r| r.bits_per_second().to_string())
                                .collect::<Vec<_>>()
                                .join(", ")
                        ),
                    )
                })?,
        };
        let turnaround_ms = match &raw.turnaround_ms {
            None => None,
            Some(t) => {
                let ms = *t.get_ref();
                if ms.is_finite() && (0.0..=TURNAROUND_MAX_MS).contains(&ms) {
                    Some(ms as f32)
                } else {
                    return Err(scope.error_on(
                        t,
                        "turnaround_ms",
                        format!("{ms} ms is outside 0–{TURNAROUND_MAX_MS} ms"),
                    ));
                }
            }
        };
        Ok(BusSection {
            name: raw.name.get_ref().clone(),
            port: PathBuf::from(port),
            baud,
            turnaround_ms,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_short_plain_identifiers() {
        assert!(check_name("wing").is_ok());
        assert!(check_name("tail_2-b").is_ok());
        assert!(check_name("").unwrap_err().contains("empty"));
        assert!(check_name("left wing").unwrap_err().contains("' '"));
        assert!(check_name(&"x".repeat(33)).unwrap_err().contains("32"));
    }
}

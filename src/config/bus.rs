//! The `[[bus]]` tables: one RS485 line, its serial port and its baud rate.

use super::error::{ConfigError, Scope};
use super::raw::{RawBus, RawRate, RawRs485};
use crate::protocol::BaudRate;
use crate::serial::rs485::{MAX_DELAY_MS, Rs485Mode};
use std::path::PathBuf;
use std::time::Duration;

/// The largest turnaround allowance a bus may ask for.
const TURNAROUND_MAX_MS: f64 = 100.0;

/// How often each servo's position and current are read.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum TelemetryRate {
    /// At most this many times a second per servo; the rest of the bus is left idle, so that
    /// goals find it free and the bridge's CPU stays low.
    Hz(f32),
    /// In every moment the goals leave free (`"max"`): 80–90 reads a second per servo with four
    /// servos at 115 200 bit/s, over 200 at 460 800.
    Max,
}

impl TelemetryRate {
    /// 50 Hz: the bridge's own consumers need less (the ground station gets values at 1 Hz and
    /// on change, the flight record keeps about 14 a second, stall detection needs tens), and a
    /// 20 ms picture of each rod is finer than any control loop that reads it back.
    pub const DEFAULT: TelemetryRate = TelemetryRate::Hz(50.0);
    /// The rates a mapping may ask for (besides `"max"`).
    pub const RANGE_HZ: std::ops::RangeInclusive<f32> = 1.0..=1000.0;

    /// The shortest time between two reads of one servo (zero: as often as the bus allows).
    pub fn min_interval(self) -> Duration {
        match self {
            TelemetryRate::Hz(hz) => Duration::from_secs_f64(1.0 / f64::from(hz)),
            TelemetryRate::Max => Duration::ZERO,
        }
    }
}

impl std::fmt::Display for TelemetryRate {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            TelemetryRate::Hz(hz) => write!(f, "{hz} Hz"),
            TelemetryRate::Max => f.write_str("max"),
        }
    }
}

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
    /// How often each servo's position and current are read (`telemetry_hz`, a number or
    /// `"max"`); default [`TelemetryRate::DEFAULT`].
    pub telemetry: TelemetryRate,
    /// The kernel's RS485 mode for the port (`rs485 = { … }`), for a UART whose transceiver's
    /// driver enable is on RTS; `None`: the port's RS485 setting is left as it is.
    pub rs485: Option<Rs485Mode>,
    /// The speed of the bridge's first move of a servo whose force it switches on (its first
    /// goal, and the first after force off or brake), in mm/s: the soft start. Default
    /// [`SOFT_START_DEFAULT_MM_S`].
    pub soft_start_mm_s: f64,
}

/// The soft start's default speed: a full 50 mm move in 5 s, half of one in 2.5 s.
pub const SOFT_START_DEFAULT_MM_S: f64 = crate::bus::BusConfig::DEFAULT_SOFT_START_SPEED_MM_S;

/// The servo's top speed (no load, 14.8 V): a soft start no faster than that.
pub const SOFT_START_MAX_MM_S: f64 = 105.0;

/// The slowest soft start accepted: a full move in 50 s.
pub const SOFT_START_MIN_MM_S: f64 = 1.0;

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
        let telemetry = match &raw.telemetry_hz {
            None => TelemetryRate::DEFAULT,
            Some(rate) => telemetry_rate(rate.get_ref())
                .map_err(|reason| scope.error_on(rate, "telemetry_hz", reason))?,
        };
        let rs485 = match &raw.rs485 {
            None => None,
            Some(r) => Some(rs485_mode(r.get_ref(), turnaround_ms, scope)?),
        };
        let soft_start_mm_s = match &raw.soft_start_mm_s {
            None => SOFT_START_DEFAULT_MM_S,
            Some(v) => {
                let speed = *v.get_ref();
                if !(speed.is_finite()
                    && (SOFT_START_MIN_MM_S..=SOFT_START_MAX_MM_S).contains(&speed))
                {
                    return Err(scope.error_on(
                        v,
                        "soft_start_mm_s",
                        format!(
                            "{speed} mm/s is outside {SOFT_START_MIN_MM_S}–{SOFT_START_MAX_MM_S} \
                             mm/s (the servo's top speed); the soft start cannot be switched off: \
                             without it a servo jumps to its first goal at full speed"
                        ),
                    ));
                }
                speed
            }
        };
        Ok(BusSection {
            name: raw.name.get_ref().clone(),
            port: PathBuf::from(port),
            baud,
            turnaround_ms,
            telemetry,
            rs485,
            soft_start_mm_s,
        })
    }
}

/// `rs485 = { … }`: one RTS polarity (RTS high while sending unless told otherwise), delays
/// the kernel grants (0–100 ms), and a delay before sending that the bus's reply allowance
/// covers: the request leaves that much later, and so does the reply.
fn rs485_mode(
    raw: &RawRs485,
    turnaround_ms: Option<f32>,
    scope: &Scope<'_>,
) -> Result<Rs485Mode, ConfigError> {
    let flag = |v: &Option<toml::Spanned<bool>>| v.as_ref().map(|v| *v.get_ref());
    let (on_send, after_send) = match (flag(&raw.rts_on_send), flag(&raw.rts_after_send)) {
        (None, None) => (true, false),
        (Some(on), None) => (on, !on),
        (None, Some(after)) => (!after, after),
        (Some(on), Some(after)) if on != after => (on, after),
        (Some(on), Some(_)) => {
            let value = raw.rts_after_send.as_ref().expect("given");
            return Err(scope.error_on(
                value,
                "rts_after_send",
                format!(
                    "rts_on_send and rts_after_send are both {on}: RTS would stay {} and the \
                     transceiver never switch direction; set exactly one to true \
                     (rts_on_send = true when RTS drives DE and /RE directly, the usual wiring)",
                    if on { "high" } else { "low" }
                ),
            ));
        }
    };
    let delay = |v: &Option<toml::Spanned<i64>>, key: &str| -> Result<u32, ConfigError> {
        match v {
            None => Ok(0),
            Some(d) => u32::try_from(*d.get_ref())
                .ok()
                .filter(|ms| *ms <= MAX_DELAY_MS)
                .ok_or_else(|| {
                    scope.error_on(
                        d,
                        key,
                        format!(
                            "{} ms is outside 0–{MAX_DELAY_MS} ms (the kernel grants at most \
                             {MAX_DELAY_MS} ms)",
                            d.get_ref()
                        ),
                    )
                }),
        }
    };
    let before = delay(&raw.delay_before_send_ms, "delay_before_send_ms")?;
    let after = delay(&raw.delay_after_send_ms, "delay_after_send_ms")?;
    if before > 0 {
        let default_ms = crate::bus::BusConfig::DEFAULT_TURNAROUND.as_secs_f32() * 1000.0;
        let allowance = turnaround_ms.unwrap_or(default_ms);
        let needed = before as f32 + default_ms;
        if allowance < needed {
            let value = raw.delay_before_send_ms.as_ref().expect("given");
            return Err(scope.error_on(
                value,
                "delay_before_send_ms",
                format!(
                    "every packet leaves {before} ms late, and its reply with it, beyond this \
                     bus's reply allowance of {allowance} ms{}; set turnaround_ms = {needed} \
                     (or more) in this [[bus]] table, or lower the delay",
                    if turnaround_ms.is_none() {
                        " (the default turnaround_ms)"
                    } else {
                        ""
                    }
                ),
            ));
        }
    }
    Ok(Rs485Mode {
        rts_on_send: on_send,
        rts_after_send: after_send,
        delay_before_send_ms: before,
        delay_after_send_ms: after,
        rx_during_tx: flag(&raw.rx_during_tx).unwrap_or(false),
    })
}

fn telemetry_rate(raw: &RawRate) -> Result<TelemetryRate, String> {
    let range = TelemetryRate::RANGE_HZ;
    match raw {
        RawRate::Word(w) if w == "max" => Ok(TelemetryRate::Max),
        RawRate::Word(w) => Err(format!(
            "\"{w}\" is not a rate; write a number of Hz ({}–{}) or \"max\"",
            range.start(),
            range.end()
        )),
        RawRate::Hz(hz) if hz.is_finite() && range.contains(&(*hz as f32)) => {
            Ok(TelemetryRate::Hz(*hz as f32))
        }
        RawRate::Hz(hz) => Err(format!(
            "{hz} Hz is outside {}–{} Hz; write \"max\" to read as often as the bus allows",
            range.start(),
            range.end()
        )),
    }
}

/// About how many position-and-current reads a second each of `servos` servos can have on a
/// bus at `baud` that also carries a long packet every `goal_period`: the wire time of one
/// read (request, reply, and a reaction allowance), shared among the servos, in the time the
/// goals leave, less a fifth for start-up, full and verify reads and the gaps the goals'
/// rhythm keeps free.
pub fn max_telemetry_hz(baud: BaudRate, servos: usize, goal_period: Duration) -> f32 {
    if servos == 0 {
        return 0.0;
    }
    // Request 8 bytes, reply 16 (registers 42–49), 150 µs to react.
    let read = Duration::from_nanos(baud.wire_time_ns(24)) + Duration::from_micros(150);
    let frame = Duration::from_nanos(baud.wire_time_ns(8 + 5 * servos));
    let free = 1.0 - frame.as_secs_f64() / goal_period.as_secs_f64().max(1e-3);
    (free.max(0.0) * 0.8 / (read.as_secs_f64() * servos as f64)) as f32
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

    fn rate(toml: &str) -> Result<TelemetryRate, String> {
        #[derive(serde::Deserialize)]
        struct T {
            telemetry_hz: RawRate,
        }
        telemetry_rate(&toml::from_str::<T>(toml).unwrap().telemetry_hz)
    }

    #[test]
    fn a_telemetry_rate_is_a_number_of_hz_or_max() {
        assert_eq!(rate("telemetry_hz = 50"), Ok(TelemetryRate::Hz(50.0)));
        assert_eq!(rate("telemetry_hz = 12.5"), Ok(TelemetryRate::Hz(12.5)));
        assert_eq!(rate("telemetry_hz = \"max\""), Ok(TelemetryRate::Max));
        assert!(
            rate("telemetry_hz = 0")
                .unwrap_err()
                .contains("outside 1–1000 Hz")
        );
        assert!(rate("telemetry_hz = 5000").unwrap_err().contains("\"max\""));
        assert!(
            rate("telemetry_hz = \"fast\"")
                .unwrap_err()
                .contains("not a rate")
        );
        assert_eq!(
            TelemetryRate::Hz(50.0).min_interval(),
            Duration::from_millis(20)
        );
        assert_eq!(TelemetryRate::Max.min_interval(), Duration::ZERO);
    }

    #[test]
    fn the_wire_allows_fewer_reads_per_servo_with_more_servos_and_more_at_a_higher_baud() {
        let p = Duration::from_millis(20);
        let four = max_telemetry_hz(BaudRate::B115200, 4, p);
        // 24 bytes at 115 200 bit/s and 150 µs: 2.23 ms a read.
        assert!((75.0..95.0).contains(&four), "{four}");
        assert!(max_telemetry_hz(BaudRate::B115200, 8, p) < four / 1.8);
        assert!(max_telemetry_hz(BaudRate::B460800, 4, p) > 2.5 * four);
        assert_eq!(max_telemetry_hz(BaudRate::B115200, 0, p), 0.0);
    }
}

//! The `[[servo]]` tables and the mapping from an autopilot output to a servo position.
//!
//! The mapping is the servo's own PWM mode (protocol reference, section 2), so that a servo moves
//! the same whether it hangs on a PWM wire or on the bridge: 920 µs ↔ −25.00 mm, 1520 µs ↔ 0.00
//! mm, 2120 µs ↔ +25.00 mm, 24 µs per mm, rounded to the nearest 0.01 mm (halves away from
//! zero), then reversed if the channel says so, then clamped to the channel's travel. A value
//! the servo would not take as a pulse (0, 65535, anything outside the channel's PWM range)
//! means "no output": the servo holds where it is, as it does in PWM mode.

use super::bus::check_name;
use super::error::{ConfigError, Scope};
use super::mavlink::{Quantity, TelemetryConfig, quantities};
use super::raw::RawServo;
use crate::dronecan::messages::CommandType;
use crate::protocol::{MmCenti, Ms10, Percent, PositionLimits, ServoId};
use std::fmt;
use toml::Spanned;

/// What a DroneCAN command's unitless value (−1…+1) is to a servo.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum UnitlessLaw {
    /// ArduPilot's: its output pulse `p` sent as `(p − 1000) / 500 − 1` (`AP_DroneCAN`'s
    /// servo output), taken back to `1500 + 500 × value` µs and mapped as a pulse: a servo
    /// moves as it does for the same output over MAVLink, within 1000–2000 µs.
    #[default]
    ArduPilotPulse,
    /// Normalised: −1 ↔ −25.00 mm, +1 ↔ +25.00 mm, as [`ServoConfig::map_normalized`].
    Normalized,
}

/// The longest label: NAMED_VALUE_FLOAT names hold 10 characters, and the bridge names each
/// servo's values `<label>_<quantity>` with a three-letter quantity (`ail_l_pos`).
pub const LABEL_MAX_LEN: usize = 6;

/// The narrowest and widest pulse a PWM range may use, in µs.
pub const PWM_LIMITS_US: (u16, u16) = (500, 2500);

/// The outputs an autopilot has: SERVO_OUTPUT_RAW port 0 carries 1–16, port 1 carries 17–32.
pub const CHANNELS: std::ops::RangeInclusive<u8> = 1..=32;

/// The actuator numbers MAV_CMD_DO_SET_ACTUATOR can address: index 0–20, six params each.
pub const ACTUATORS: std::ops::RangeInclusive<u8> = 1..=126;

/// The largest goal time the servo's register holds (65 535 × 10 ms, rounded down to 10 ms).
pub const GOAL_TIME_MAX_MS: u32 = 655_350;

/// A channel's PWM range: `min_us` ↔ −25.00 mm, `trim_us` ↔ 0.00 mm, `max_us` ↔ +25.00 mm,
/// linear on each side of the trim. A mapping file guarantees `500 ≤ min < trim < max ≤ 2500`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct PwmRange {
    pub min_us: u16,
    pub trim_us: u16,
    pub max_us: u16,
}

impl PwmRange {
    /// The servo's own PWM mode: 920 / 1520 / 2120 µs, 24 µs per mm.
    pub const SERVO_DEFAULT: PwmRange = PwmRange {
        min_us: 920,
        trim_us: 1520,
        max_us: 2120,
    };

    /// Whether `us` is a pulse this range accepts.
    pub fn contains(self, us: u16) -> bool {
        (self.min_us..=self.max_us).contains(&us)
    }

    /// The position the servo's PWM law gives for `us`, before reverse and travel: 0.01 mm =
    /// (us − trim) × 2500 / (max − trim) above the trim and (us − trim) × 2500 / (trim − min)
    /// below it, rounded half away from zero. For the default range this is (us − 1520) × 25 / 6.
    /// `None` outside the range, or if the range is degenerate.
    pub fn law(self, us: u16) -> Option<MmCenti> {
        if !self.contains(us) {
            return None;
        }
        let offset = i64::from(us) - i64::from(self.trim_us);
        let span = if offset >= 0 {
            i64::from(self.max_us) - i64::from(self.trim_us)
        } else {
            i64::from(self.trim_us) - i64::from(self.min_us)
        };
        if span <= 0 {
            return None;
        }
        let centi = div_round_half_away(offset * i64::from(MmCenti::STROKE_END), span);
        let stroke = i64::from(MmCenti::STROKE_END);
        i16::try_from(centi.clamp(-stroke, stroke))
            .ok()
            .map(MmCenti)
    }
}

impl Default for PwmRange {
    fn default() -> Self {
        Self::SERVO_DEFAULT
    }
}

/// `num / den` rounded to the nearest integer, halves away from zero (`den > 0`).
fn div_round_half_away(num: i64, den: i64) -> i64 {
    let magnitude = (2 * num.abs() + den) / (2 * den);
    if num < 0 { -magnitude } else { magnitude }
}

/// What a servo does when the autopilot's outputs stop arriving (`failsafe_timeout_ms`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum FailsafeAction {
    /// Stay where it is, force on (what the servo does in PWM mode when the pulses stop).
    #[default]
    Hold,
    /// Force off: the rod is free.
    Off,
    /// Brake: the rod moves by hand with light resistance.
    Brake,
    /// Go to this rod position (the servo's own coordinates, + = extend; not reversed).
    Position(MmCenti),
}

impl fmt::Display for FailsafeAction {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            FailsafeAction::Hold => f.write_str("hold"),
            FailsafeAction::Off => f.write_str("off"),
            FailsafeAction::Brake => f.write_str("brake"),
            FailsafeAction::Position(p) => write!(f, "{:+.2} mm", p.mm()),
        }
    }
}

/// One `[[servo]]` table: which autopilot output drives which servo, and how.
#[derive(Debug, Clone, PartialEq)]
pub struct ServoConfig {
    /// The servo's name in logs and STATUSTEXT (`aileron_left`); unique in the file.
    pub name: String,
    /// The short name of its NAMED_VALUE_FLOAT values (≤ [`LABEL_MAX_LEN`] characters), unique
    /// in the file. Default: the name if it is short enough, else `s<n>` for the n-th servo.
    pub label: String,
    /// The `[[bus]]` it is on.
    pub bus: String,
    /// Its ID on that bus (unique per bus).
    pub id: ServoId,
    /// The autopilot output, 1–32 (SERVO_OUTPUT_RAW port 0 = 1–16, port 1 = 17–32).
    pub channel: u8,
    /// The channel's PWM range (default 920 / 1520 / 2120 µs).
    pub pwm: PwmRange,
    /// The rod travel the bridge allows, in the servo's own coordinates (default ±25.00 mm).
    /// Every mapped position is clamped into it, after reverse.
    pub travel: PositionLimits,
    /// Negate the mapped position (a low pulse extends the rod). The bridge does this itself;
    /// the servo's own Reverse register is left alone.
    pub reverse: bool,
    /// If set, each move is sent with this Goal Time (the servo takes this long to get there,
    /// never faster than its top speed).
    pub goal_time_ms: Option<u32>,
    /// If set, the servo's Max Force register is set to this at start.
    pub max_force_percent: Option<Percent>,
    /// What to do when the outputs stop arriving (default hold).
    pub failsafe: FailsafeAction,
    /// If set, the servo also follows MAV_CMD_DO_SET_ACTUATOR sent to the bridge's component:
    /// actuator n is param ((n − 1) mod 6) + 1 of the command whose param 7 (index) is
    /// (n − 1) div 6, so actuators 1–6 are params 1–6 of index 0. See [`Self::map_normalized`].
    pub actuator: Option<u8>,
    /// The actuator id of DroneCAN's ArrayCommand it follows (with `[dronecan]`), 0–255;
    /// default its channel, as ArduPilot numbers them (`SERVOn` is actuator n). PX4 numbers
    /// from 0: channel − 1.
    pub dronecan_id: u8,
    /// The quantities its NAMED_VALUE_FLOATs carry; `None`: `[telemetry] named_values`.
    pub named_values: Option<Vec<Quantity>>,
}

impl ServoConfig {
    /// The quantities this servo's NAMED_VALUE_FLOATs carry: its own list, else `telemetry`'s.
    pub fn named_values<'a>(&'a self, telemetry: &'a TelemetryConfig) -> &'a [Quantity] {
        self.named_values
            .as_deref()
            .unwrap_or(&telemetry.named_values)
    }

    /// The position for a PWM output of `us` µs, or `None` for "no output" (the servo holds):
    /// `us` is 0, 65535 or outside the channel's PWM range.
    pub fn map_pwm(&self, us: u16) -> Option<MmCenti> {
        if us == 0 || us == u16::MAX {
            return None;
        }
        self.pwm.law(us).map(|p| self.reverse_and_clamp(p))
    }

    /// The position for a normalised output −1…+1 (MAV_CMD_DO_SET_ACTUATOR): −1 ↔ −25.00 mm,
    /// 0 ↔ 0.00 mm, +1 ↔ +25.00 mm, rounded to 0.01 mm, then reversed and clamped like a PWM
    /// output. The PWM range plays no part. `None` (leave it) for NaN and outside −1…+1.
    pub fn map_normalized(&self, v: f32) -> Option<MmCenti> {
        if !(-1.0..=1.0).contains(&v) {
            return None;
        }
        let centi = (f64::from(v) * f64::from(MmCenti::STROKE_END)).round();
        // `v` is within −1…+1, so `centi` is within ±2500.
        Some(self.reverse_and_clamp(MmCenti(centi as i16)))
    }

    /// The position for a DroneCAN actuator command (`uavcan.equipment.actuator.Command`), or
    /// `None` (leave it) for a value that is not a number and for the types a linear servo
    /// has no use for (force, speed, unknown):
    /// - PWM, µs (ArduPilot with `CAN_D1_UC_OPTION` "send servo as PWM"): as [`Self::map_pwm`],
    ///   the MAVLink path's law exactly;
    /// - unitless, −1…+1: as `unitless` says (ArduPilot's pulse, or normalised);
    /// - position, metres: that rod position in mm, within ±25.00 mm, then reversed and
    ///   clamped like the others.
    pub fn map_can_command(
        &self,
        command_type: CommandType,
        value: f32,
        unitless: UnitlessLaw,
    ) -> Option<MmCenti> {
        if !value.is_finite() {
            return None;
        }
        match command_type {
            CommandType::Pwm => {
                let us = value.round();
                (0.0..=f32::from(u16::MAX))
                    .contains(&us)
                    .then(|| self.map_pwm(us as u16))?
            }
            CommandType::Unitless => match unitless {
                UnitlessLaw::ArduPilotPulse => {
                    let us = 1500.0 + 500.0 * value.clamp(-1.0, 1.0);
                    self.map_pwm(us.round() as u16)
                }
                UnitlessLaw::Normalized => self.map_normalized(value.clamp(-1.0, 1.0)),
            },
            CommandType::Position => {
                let end = f64::from(MmCenti::STROKE_END) / 100.0;
                let mm = (f64::from(value) * 1000.0).clamp(-end, end);
                MmCenti::from_mm(mm).ok().map(|p| self.reverse_and_clamp(p))
            }
            CommandType::Force | CommandType::Speed | CommandType::Other(_) => None,
        }
    }

    fn reverse_and_clamp(&self, position: MmCenti) -> MmCenti {
        let position = if self.reverse {
            MmCenti(position.0.saturating_neg())
        } else {
            position
        };
        self.travel.clamp(position)
    }

    /// Where this channel arrives in SERVO_OUTPUT_RAW from ArduPilot: `(port, index)` with
    /// `index` 0 for `servo1_raw` … 15 for `servo16_raw`. PX4 numbers its ports by output
    /// driver instance, which this formula also covers (channel 17 = port 1, first output).
    pub fn servo_output_raw_slot(&self) -> (u8, usize) {
        let zero_based = self.channel.saturating_sub(1);
        (zero_based / 16, usize::from(zero_based % 16))
    }

    /// The goal time in the servo's register unit.
    pub fn goal_time(&self) -> Option<Ms10> {
        self.goal_time_ms.map(Ms10::from_millis)
    }

    /// Read one `[[servo]]` table; `index` is its place in the file (from 0), for its default
    /// label. Checks that need the other tables (bus, duplicates) are the caller's.
    pub(crate) fn from_raw(
        raw: &RawServo,
        index: usize,
        scope: &Scope<'_>,
    ) -> Result<Self, ConfigError> {
        let name = raw.name.get_ref().clone();
        check_name(&name).map_err(|r| scope.error_on(&raw.name, "name", r))?;
        let label = match &raw.label {
            Some(label) => {
                check_label(label.get_ref()).map_err(|r| scope.error_on(label, "label", r))?;
                label.get_ref().clone()
            }
            None if check_label(&name).is_ok() => name.clone(),
            None => format!("s{}", index + 1),
        };

        let id = u8::try_from(*raw.id.get_ref())
            .ok()
            .and_then(|id| ServoId::new(id).ok())
            .ok_or_else(|| {
                scope.error_on(
                    &raw.id,
                    "id",
                    format!("{} is outside 1–127", raw.id.get_ref()),
                )
            })?;

        let channel = u8::try_from(*raw.channel.get_ref())
            .ok()
            .filter(|c| CHANNELS.contains(c))
            .ok_or_else(|| {
                scope.error_on(
                    &raw.channel,
                    "channel",
                    format!(
                        "{} is outside 1–32 (SERVO_OUTPUT_RAW port 0 carries outputs 1–16, port 1 carries 17–32)",
                        raw.channel.get_ref()
                    ),
                )
            })?;

        let pwm = pwm_range(raw, scope)?;
        let travel = travel(raw, scope)?;

        let goal_time_ms = match &raw.goal_time_ms {
            None => None,
            Some(t) => Some(
                u32::try_from(*t.get_ref())
                    .ok()
                    .filter(|ms| *ms <= GOAL_TIME_MAX_MS)
                    .ok_or_else(|| {
                        scope.error_on(
                            t,
                            "goal_time_ms",
                            format!(
                                "{} ms is outside 0–{GOAL_TIME_MAX_MS} ms (the register counts 10 ms steps up to 65535)",
                                t.get_ref()
                            ),
                        )
                    })?,
            ),
        };

        let max_force_percent = match &raw.max_force_percent {
            None => None,
            Some(f) => Some(
                u8::try_from(*f.get_ref())
                    .ok()
                    .filter(|p| *p >= 1)
                    .and_then(|p| Percent::new(p).ok())
                    .ok_or_else(|| {
                        scope.error_on(
                            f,
                            "max_force_percent",
                            format!(
                                "{} % is outside 1–100 % (0 % would leave the servo unable to move)",
                                f.get_ref()
                            ),
                        )
                    })?,
            ),
        };

        let failsafe = match &raw.failsafe {
            None => FailsafeAction::default(),
            Some(value) => failsafe(value, travel, scope)?,
        };

        let actuator = match &raw.actuator {
            None => None,
            Some(a) => Some(
                u8::try_from(*a.get_ref())
                    .ok()
                    .filter(|n| ACTUATORS.contains(n))
                    .ok_or_else(|| {
                        scope.error_on(
                            a,
                            "actuator",
                            format!(
                                "{} is outside 1–126 (MAV_CMD_DO_SET_ACTUATOR: actuators 1–6 are params 1–6 of index 0, 7–12 of index 1, …)",
                                a.get_ref()
                            ),
                        )
                    })?,
            ),
        };

        let dronecan_id = match &raw.dronecan_id {
            None => channel,
            Some(a) => u8::try_from(*a.get_ref()).map_err(|_| {
                scope.error_on(
                    a,
                    "dronecan_id",
                    format!(
                        "{} is outside 0–255 (ArrayCommand's actuator_id is one byte)",
                        a.get_ref()
                    ),
                )
            })?,
        };

        let named_values = raw
            .named_values
            .as_ref()
            .map(|list| quantities(list, scope))
            .transpose()?;

        Ok(ServoConfig {
            name,
            label,
            bus: raw.bus.get_ref().clone(),
            id,
            channel,
            pwm,
            travel,
            reverse: raw.reverse.unwrap_or(false),
            goal_time_ms,
            max_force_percent,
            failsafe,
            actuator,
            dronecan_id,
            named_values,
        })
    }
}

/// A label: 1–6 ASCII letters, digits or `_`.
pub(crate) fn check_label(label: &str) -> Result<(), String> {
    if label.is_empty() {
        return Err("the label is empty".to_string());
    }
    if label.chars().count() > LABEL_MAX_LEN {
        return Err(format!(
            "\"{label}\" is longer than {LABEL_MAX_LEN} characters (NAMED_VALUE_FLOAT names hold 10: <label>_pos)"
        ));
    }
    if let Some(bad) = label
        .chars()
        .find(|c| !(c.is_ascii_alphanumeric() || *c == '_'))
    {
        return Err(format!(
            "\"{label}\" contains {bad:?}; use ASCII letters, digits and '_'"
        ));
    }
    Ok(())
}

fn pwm_range(raw: &RawServo, scope: &Scope<'_>) -> Result<PwmRange, ConfigError> {
    let (lowest, highest) = PWM_LIMITS_US;
    let read = |value: &Option<Spanned<i64>>, key: &str, default: u16| match value {
        None => Ok(default),
        Some(v) => u16::try_from(*v.get_ref())
            .ok()
            .filter(|us| (lowest..=highest).contains(us))
            .ok_or_else(|| {
                scope.error_on(
                    v,
                    key,
                    format!("{} µs is outside {lowest}–{highest} µs", v.get_ref()),
                )
            }),
    };
    let default = PwmRange::SERVO_DEFAULT;
    let range = PwmRange {
        min_us: read(&raw.pwm_min_us, "pwm_min_us", default.min_us)?,
        trim_us: read(&raw.pwm_trim_us, "pwm_trim_us", default.trim_us)?,
        max_us: read(&raw.pwm_max_us, "pwm_max_us", default.max_us)?,
    };
    let pairs = [
        (
            ("pwm_min_us", &raw.pwm_min_us, range.min_us),
            ("pwm_trim_us", &raw.pwm_trim_us, range.trim_us),
        ),
        (
            ("pwm_trim_us", &raw.pwm_trim_us, range.trim_us),
            ("pwm_max_us", &raw.pwm_max_us, range.max_us),
        ),
    ];
    for ((low_key, low, low_us), (high_key, high, high_us)) in pairs {
        if low_us >= high_us {
            let reason = format!(
                "{low_key} {low_us} µs must be below {high_key} {high_us} µs (min < trim < max)"
            );
            // Blame the key the file sets: the upper one if both are set.
            return Err(match (high, low) {
                (Some(h), _) => scope.error_on(h, high_key, reason),
                (None, Some(l)) => scope.error_on(l, low_key, reason),
                (None, None) => scope.error_on(&raw.name, high_key, reason),
            });
        }
    }
    Ok(range)
}

fn travel(raw: &RawServo, scope: &Scope<'_>) -> Result<PositionLimits, ConfigError> {
    let mm = |value: f64, span: std::ops::Range<usize>, key: &str| {
        MmCenti::from_mm(value).map_err(|_| {
            scope.error(
                span,
                key,
                format!(
                    "{value} mm is beyond the stroke (−25.00 … +25.00 mm); a limit beyond it can break the servo"
                ),
            )
        })
    };
    let full = PositionLimits::FULL_STROKE;
    let (min, max, span, key) = match (&raw.travel_mm, &raw.min_mm, &raw.max_mm) {
        (Some(pair), None, None) => {
            let [low, high] = pair.get_ref().as_slice() else {
                return Err(scope.error_on(
                    pair,
                    "travel_mm",
                    format!(
                        "expected two numbers [min, max], e.g. travel_mm = [-20.0, 20.0]; got {}",
                        pair.get_ref().len()
                    ),
                ));
            };
            (
                mm(*low, pair.span(), "travel_mm")?,
                mm(*high, pair.span(), "travel_mm")?,
                pair.span(),
                "travel_mm",
            )
        }
        (Some(pair), _, _) => {
            let (other, key) = match (&raw.min_mm, &raw.max_mm) {
                (Some(m), _) => (m.span(), "min_mm"),
                (None, Some(m)) => (m.span(), "max_mm"),
                (None, None) => (pair.span(), "travel_mm"),
            };
            return Err(scope.error(
                other,
                key,
                "travel is already set by travel_mm; use either travel_mm = [min, max] or min_mm / max_mm",
            ));
        }
        (None, min_mm, max_mm) => {
            let min = match min_mm {
                Some(m) => mm(*m.get_ref(), m.span(), "min_mm")?,
                None => full.minus(),
            };
            let max = match max_mm {
                Some(m) => mm(*m.get_ref(), m.span(), "max_mm")?,
                None => full.plus(),
            };
            let (span, key) = match (min_mm, max_mm) {
                (Some(m), _) if min.0 > 0 => (m.span(), "min_mm"),
                (_, Some(m)) => (m.span(), "max_mm"),
                (Some(m), None) => (m.span(), "min_mm"),
                (None, None) => (raw.name.span(), "travel_mm"),
            };
            (min, max, span, key)
        }
    };
    if min >= max {
        return Err(scope.error(
            span,
            key,
            format!(
                "the travel's minimum {:+.2} mm must be below its maximum {:+.2} mm",
                min.mm(),
                max.mm()
            ),
        ));
    }
    PositionLimits::new(min, max).map_err(|_| {
        scope.error(
            span,
            key,
            format!(
                "the travel {:+.2} … {:+.2} mm must include 0.00 mm: the servo's limits are a minus limit in −25.00 … 0.00 mm and a plus limit in 0.00 … +25.00 mm",
                min.mm(),
                max.mm()
            ),
        )
    })
}

fn failsafe(
    value: &Spanned<toml::Value>,
    travel: PositionLimits,
    scope: &Scope<'_>,
) -> Result<FailsafeAction, ConfigError> {
    let position_mm = match value.get_ref() {
        toml::Value::String(s) => {
            return match s.trim().to_ascii_lowercase().as_str() {
                "hold" => Ok(FailsafeAction::Hold),
                "off" => Ok(FailsafeAction::Off),
                "brake" => Ok(FailsafeAction::Brake),
                _ => Err(scope.error_on(
                    value,
                    "failsafe",
                    format!(
                        "\"{s}\" is not a failsafe action; use \"hold\", \"off\", \"brake\" or a position in mm (e.g. failsafe = 0.0)"
                    ),
                )),
            };
        }
        toml::Value::Integer(i) => *i as f64,
        toml::Value::Float(f) => *f,
        other => {
            return Err(scope.error_on(
                value,
                "failsafe",
                format!(
                    "a {} is not a failsafe action; use \"hold\", \"off\", \"brake\" or a position in mm (e.g. failsafe = 0.0)",
                    other.type_str()
                ),
            ));
        }
    };
    let position = MmCenti::from_mm(position_mm)
        .ok()
        .filter(|p| travel.contains(*p))
        .ok_or_else(|| {
            scope.error_on(
                value,
                "failsafe",
                format!(
                    "position {position_mm} mm is outside the servo's travel ({:+.2} … {:+.2} mm)",
                    travel.minus().mm(),
                    travel.plus().mm()
                ),
            )
        })?;
    Ok(FailsafeAction::Position(position))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn servo() -> ServoConfig {
        ServoConfig {
            name: "aileron_left".into(),
            label: "s1".into(),
            bus: "wing".into(),
            id: ServoId::new(1).unwrap(),
            channel: 1,
            pwm: PwmRange::SERVO_DEFAULT,
            travel: PositionLimits::FULL_STROKE,
            reverse: false,
            goal_time_ms: None,
            max_force_percent: None,
            failsafe: FailsafeAction::Hold,
            actuator: None,
            dronecan_id: 1,
            named_values: None,
        }
    }

    #[test]
    fn rounding_is_half_away_from_zero() {
        assert_eq!(div_round_half_away(25, 2), 13);
        assert_eq!(div_round_half_away(-25, 2), -13);
        assert_eq!(div_round_half_away(24, 2), 12);
        assert_eq!(div_round_half_away(7500, 600), 13);
        assert_eq!(div_round_half_away(10_000, 600), 17);
        assert_eq!(div_round_half_away(0, 600), 0);
    }

    #[test]
    fn the_default_law_is_25_over_6_per_microsecond() {
        let s = servo();
        for us in 920..=2120u16 {
            let exact = (f64::from(us) - 1520.0) * 25.0 / 6.0;
            assert_eq!(s.map_pwm(us), Some(MmCenti(exact.round() as i16)), "{us}");
        }
    }

    #[test]
    fn a_degenerate_range_maps_nothing_instead_of_dividing_by_zero() {
        let mut s = servo();
        s.pwm = PwmRange {
            min_us: 1500,
            trim_us: 1500,
            max_us: 1500,
        };
        assert_eq!(s.map_pwm(1500), None);
        assert_eq!(s.map_pwm(1499), None);
    }

    #[test]
    fn servo_output_raw_slots_follow_the_port_rule() {
        let mut s = servo();
        for (channel, slot) in [(1, (0, 0)), (16, (0, 15)), (17, (1, 0)), (32, (1, 15))] {
            s.channel = channel;
            assert_eq!(s.servo_output_raw_slot(), slot);
        }
    }

    #[test]
    fn labels_fit_named_value_float_names() {
        assert!(check_label("ail_l").is_ok());
        assert!(check_label("elev").is_ok());
        assert!(
            check_label("aileron")
                .unwrap_err()
                .contains("longer than 6")
        );
        assert!(check_label("a.b").unwrap_err().contains("'.'"));
        assert!(check_label("").is_err());
        assert!(format!("{}_pos", "abcdef").len() <= 10);
    }

    #[test]
    fn failsafe_actions_print_as_written() {
        assert_eq!(FailsafeAction::Hold.to_string(), "hold");
        assert_eq!(
            FailsafeAction::Position(MmCenti(1250)).to_string(),
            "+12.50 mm"
        );
        assert_eq!(
            FailsafeAction::Position(MmCenti(-300)).to_string(),
            "-3.00 mm"
        );
    }

    #[test]
    fn a_dronecan_command_moves_the_servo_as_the_same_output_over_mavlink() {
        let s = servo();
        let can = |t, v, law| s.map_can_command(t, v, law);
        // PWM: the MAVLink path's law, no output included.
        for us in (0..=2400u16).step_by(7).chain([u16::MAX]) {
            assert_eq!(
                can(CommandType::Pwm, f32::from(us), UnitlessLaw::ArduPilotPulse),
                s.map_pwm(us),
                "{us} µs"
            );
        }
        // ArduPilot's unitless value of its pulse p, through the wire's float16: p again,
        // within the half-µs float16 loses near the ends.
        use crate::dronecan::float16;
        for p in 1000..=2000u16 {
            let sent = (f32::from(p) - 1000.0) / 500.0 - 1.0;
            let wire = float16::to_f32(float16::from_f32(sent));
            let got = can(CommandType::Unitless, wire, UnitlessLaw::ArduPilotPulse).unwrap();
            let want = s.map_pwm(p).unwrap();
            assert!((got.0 - want.0).abs() <= 5, "{p} µs: {got:?} for {want:?}");
        }
        let normalized = |v| can(CommandType::Unitless, v, UnitlessLaw::Normalized);
        assert_eq!(normalized(1.0), Some(MmCenti(2500)));
        assert_eq!(normalized(-0.5), Some(MmCenti(-1250)));
        assert_eq!(normalized(3.0), Some(MmCenti(2500)));
        // A position in metres: that many mm, within the stroke; reversed like the others.
        let position = |s: &ServoConfig, m| {
            s.map_can_command(CommandType::Position, m, UnitlessLaw::Normalized)
        };
        assert_eq!(position(&s, 0.0125), Some(MmCenti(1250)));
        assert_eq!(position(&s, 0.1), Some(MmCenti(2500)));
        let reversed = ServoConfig {
            reverse: true,
            ..servo()
        };
        assert_eq!(position(&reversed, 0.0125), Some(MmCenti(-1250)));
        for (t, v) in [
            (CommandType::Force, 1.0),
            (CommandType::Speed, 1.0),
            (CommandType::Other(9), 1.0),
            (CommandType::Unitless, f32::NAN),
            (CommandType::Pwm, -3.0),
        ] {
            assert_eq!(can(t, v, UnitlessLaw::ArduPilotPulse), None, "{t:?} {v}");
        }
    }
}

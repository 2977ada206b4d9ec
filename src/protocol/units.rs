//! Physical quantities in the servo's register units. The name of each type is its unit, so a
//! value in 0.01 mm can never be mistaken for one in 10 ms.

use super::error::ProtocolError;
use std::fmt;

/// A position in 0.01 mm (registers 8–11, 30–31, 42–43). 0 is mid-stroke, + extends.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub struct MmCenti(pub i16);

impl MmCenti {
    /// The end of the stroke: ±25.00 mm. Limits beyond it can break the servo.
    pub const STROKE_END: i16 = 2500;

    pub fn mm(self) -> f64 {
        f64::from(self.0) / 100.0
    }

    /// The nearest 0.01 mm value to `mm`, refused if it lies beyond ±25.00 mm (or is not a number).
    pub fn from_mm(mm: f64) -> Result<Self, ProtocolError> {
        let centi = (mm * 100.0).round();
        if !centi.is_finite() || centi.abs() > f64::from(Self::STROKE_END) {
            return Err(ProtocolError::PositionOutOfStroke { mm });
        }
        Ok(MmCenti(centi as i16))
    }

    /// `self`, refused if it lies beyond ±25.00 mm.
    pub fn within_stroke(self) -> Result<Self, ProtocolError> {
        if self.0.unsigned_abs() > Self::STROKE_END as u16 {
            Err(ProtocolError::PositionOutOfStroke { mm: self.mm() })
        } else {
            Ok(self)
        }
    }

    pub fn to_le_bytes(self) -> [u8; 2] {
        self.0.to_le_bytes()
    }
}

impl fmt::Display for MmCenti {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:+.2} mm", self.mm())
    }
}

/// A duration in 10 ms (Goal Time, Present Time).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub struct Ms10(pub u16);

impl Ms10 {
    pub fn millis(self) -> u32 {
        u32::from(self.0) * 10
    }

    /// The nearest whole number of 10 ms to `ms`, saturated to the register's range.
    pub fn from_millis(ms: u32) -> Self {
        Ms10(u16::try_from(ms.saturating_add(5) / 10).unwrap_or(u16::MAX))
    }
}

impl fmt::Display for Ms10 {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} ms", self.millis())
    }
}

/// A supply current in 10 mA (Present Load).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub struct Ma10(pub u16);

impl Ma10 {
    pub fn amps(self) -> f64 {
        f64::from(self.0) / 100.0
    }
}

impl fmt::Display for Ma10 {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} mA", u32::from(self.0) * 10)
    }
}

/// A temperature in whole °C (Present Temperature, Temperature Limit).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub struct Celsius(pub i16);

impl fmt::Display for Celsius {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} °C", self.0)
    }
}

/// A voltage in 10 mV (Present Voltage).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub struct Mv10(pub u16);

impl Mv10 {
    pub fn volts(self) -> f64 {
        f64::from(self.0) / 100.0
    }
}

impl fmt::Display for Mv10 {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:.2} V", self.volts())
    }
}

/// A percentage 0–100 (Max Force). Larger values are refused rather than saturated.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Percent(u8);

impl Percent {
    pub const FULL: Percent = Percent(100);

    pub fn new(percent: u8) -> Result<Self, ProtocolError> {
        if percent <= 100 {
            Ok(Percent(percent))
        } else {
            Err(ProtocolError::MaxForceOutOfRange { percent })
        }
    }

    pub fn get(self) -> u8 {
        self.0
    }
}

impl fmt::Display for Percent {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} %", self.0)
    }
}

/// Punch (registers 28–29): minimum drive current in 0.00208 % of the maximum, 0 … 0x7FFF.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Punch(u16);

impl Punch {
    pub const MAX: u16 = 0x7FFF;

    pub fn new(raw: u16) -> Result<Self, ProtocolError> {
        if raw <= Self::MAX {
            Ok(Punch(raw))
        } else {
            Err(ProtocolError::PunchOutOfRange { raw })
        }
    }

    pub fn get(self) -> u16 {
        self.0
    }

    /// The punch as a percentage of the maximum current.
    pub fn percent(self) -> f64 {
        f64::from(self.0) * 0.002_08
    }
}

/// The two position limits (registers 8–11): plus in 0 … +25.00 mm, minus in −25.00 … 0 mm.
/// The manual: "setting a position beyond this can break the servo; never do it".
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct PositionLimits {
    plus: MmCenti,
    minus: MmCenti,
}

impl PositionLimits {
    /// The factory limits, ±25.00 mm, which are also the widest allowed.
    pub const FULL_STROKE: PositionLimits = PositionLimits {
        plus: MmCenti(MmCenti::STROKE_END),
        minus: MmCenti(-MmCenti::STROKE_END),
    };

    pub fn new(minus: MmCenti, plus: MmCenti) -> Result<Self, ProtocolError> {
        Ok(PositionLimits {
            plus: Self::check_plus(plus)?,
            minus: Self::check_minus(minus)?,
        })
    }

    /// A plus limit must lie in 0 … +25.00 mm.
    pub fn check_plus(plus: MmCenti) -> Result<MmCenti, ProtocolError> {
        if (0..=MmCenti::STROKE_END).contains(&plus.0) {
            Ok(plus)
        } else {
            Err(ProtocolError::LimitOutOfRange {
                which: "plus",
                mm: plus.mm(),
                allowed: "0.00 … +25.00 mm",
            })
        }
    }

    /// A minus limit must lie in −25.00 … 0 mm.
    pub fn check_minus(minus: MmCenti) -> Result<MmCenti, ProtocolError> {
        if (-MmCenti::STROKE_END..=0).contains(&minus.0) {
            Ok(minus)
        } else {
            Err(ProtocolError::LimitOutOfRange {
                which: "minus",
                mm: minus.mm(),
                allowed: "−25.00 … 0.00 mm",
            })
        }
    }

    pub fn plus(self) -> MmCenti {
        self.plus
    }

    pub fn minus(self) -> MmCenti {
        self.minus
    }

    /// `position` clamped into the limits, as the servo clamps a goal.
    pub fn clamp(self, position: MmCenti) -> MmCenti {
        MmCenti(position.0.clamp(self.minus.0, self.plus.0))
    }

    pub fn contains(self, position: MmCenti) -> bool {
        (self.minus.0..=self.plus.0).contains(&position.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn positions_beyond_25_mm_are_refused() {
        assert_eq!(MmCenti::from_mm(25.0).unwrap(), MmCenti(2500));
        assert_eq!(MmCenti::from_mm(-25.0).unwrap(), MmCenti(-2500));
        assert!(MmCenti::from_mm(25.01).is_err());
        assert!(MmCenti::from_mm(f64::NAN).is_err());
        assert!(MmCenti(2501).within_stroke().is_err());
        assert!(MmCenti(i16::MIN).within_stroke().is_err());
    }

    #[test]
    fn limits_must_stay_on_their_side_and_within_the_stroke() {
        assert!(PositionLimits::new(MmCenti(-2000), MmCenti(2000)).is_ok());
        assert!(PositionLimits::new(MmCenti(-2501), MmCenti(2000)).is_err());
        assert!(PositionLimits::new(MmCenti(-2000), MmCenti(2501)).is_err());
        assert!(PositionLimits::new(MmCenti(10), MmCenti(2000)).is_err());
        assert!(PositionLimits::new(MmCenti(-2000), MmCenti(-10)).is_err());
        let l = PositionLimits::new(MmCenti(-1000), MmCenti(500)).unwrap();
        assert_eq!(l.clamp(MmCenti(900)), MmCenti(500));
        assert_eq!(l.clamp(MmCenti(-1900)), MmCenti(-1000));
    }

    #[test]
    fn max_force_above_100_and_punch_above_7fff_are_refused() {
        assert!(Percent::new(100).is_ok());
        assert!(Percent::new(101).is_err());
        assert!(Punch::new(0x7FFF).is_ok());
        assert!(Punch::new(0x8000).is_err());
    }

    #[test]
    fn goal_time_rounds_to_10_ms() {
        assert_eq!(Ms10::from_millis(5000), Ms10(500));
        assert_eq!(Ms10::from_millis(14), Ms10(1));
        assert_eq!(Ms10::from_millis(15), Ms10(2));
        assert_eq!(Ms10::from_millis(u32::MAX), Ms10(u16::MAX));
    }
}

//! The simulated servo's physics: how fast the rod moves, what current it draws, how hot it gets.
//!
//! Figures from the maker's specification table (protocol spec, section 1) where it gives them; the rest are
//! modelling choices, named here so that they are easy to find and change:
//! - speed 105 mm/s without load at 14.8 V, scaled linearly with the supply voltage and reduced when Max
//!   Force is set below 30 %; an external load slows the rod linearly, to a stop at the available thrust;
//! - current 70 mA standing, 260 mA moving without load, plus about 10 mA per newton of load, up to the stall
//!   current (5 A at 14.8 V and 100 % Max Force) when the rod is blocked;
//! - temperature: a first-order model, `T → ambient + R_th × (current × voltage)` with time constant τ.
//!   A stalled servo at 12 V reaches the 75 °C alarm in about 25 s and the 85 °C limit in about 32 s;
//! - wear ([`Wear`], none by default): friction that draws extra current in proportion to the rod's
//!   speed (a dry rod, a failing gear) — everywhere and both ways, only while the rod extends (a seal
//!   or a burr that drags one way), or only over part of the stroke (a scored patch of the rod) —
//!   and a stiff spot over part of the stroke where the rod meets an extra load (a bent linkage),
//!   moving or holding there. All of them heat the servo through the current, as any current does.
//!
//! Everything here is pure arithmetic on `f64`; no clock.

use std::time::Duration;

/// Supply voltage at which the maker's figures are given.
pub const NOMINAL_VOLTAGE_V: f64 = 14.8;
/// Rod speed without load at 14.8 V and 100 % Max Force.
pub const NO_LOAD_SPEED_MM_S: f64 = 105.0;
/// Below this Max Force the speed falls in proportion.
pub const FULL_SPEED_MIN_FORCE_PERCENT: f64 = 30.0;
/// Maximum thrust at 14.8 V and 100 % Max Force.
pub const MAX_THRUST_N: f64 = 480.0;
/// Supply current of a powered servo that is not moving (force off, on or brake).
pub const STANDING_CURRENT_A: f64 = 0.07;
/// Supply current while moving without load.
pub const MOVING_CURRENT_A: f64 = 0.26;
/// Supply current with the rod blocked, at 14.8 V and 100 % Max Force.
pub const STALL_CURRENT_A: f64 = 5.0;
/// Temperature rise per watt at steady state.
pub const THERMAL_RESISTANCE_C_PER_W: f64 = 3.0;
/// Time constant of the temperature model.
pub const THERMAL_TIME_CONSTANT_S: f64 = 60.0;
/// Extra heating of the "overheat" fault.
pub const OVERHEAT_RATE_C_PER_S: f64 = 15.0;
/// The "overheat" fault stops heating here.
pub const OVERHEAT_CEILING_C: f64 = 130.0;
/// Internal position resolution (the register unit is 0.01 mm; values step by 0.02 mm).
pub const RESOLUTION_MM: f64 = 0.02;
/// Mechanical end of travel on each side of the centre.
pub const MECHANICAL_STROKE_MM: f64 = 25.0;

/// A stiff spot: over the physical stroke `from_mm`–`to_mm` the rod meets an extra `load_n`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StiffSpot {
    pub from_mm: f64,
    pub to_mm: f64,
    pub load_n: f64,
}

/// Friction over part of the stroke only: over the physical stroke `from_mm`–`to_mm` the rod
/// draws an extra `a_per_mm_s` A per mm/s of its speed, either way.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrictionSpot {
    pub from_mm: f64,
    pub to_mm: f64,
    pub a_per_mm_s: f64,
}

impl FrictionSpot {
    fn covers(&self, rod_mm: f64) -> bool {
        rod_mm >= self.from_mm.min(self.to_mm) && rod_mm <= self.from_mm.max(self.to_mm)
    }
}

/// A servo's wear: what binding (a dry rod, a bent linkage, a failing gear) does to it.
/// `Wear::default()` is no wear; every part adds to the others.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Wear {
    /// Extra current per mm/s of rod speed while it moves, either way, A·s/mm (≥ 0). 0.002 adds
    /// 0.1 A at 50 mm/s, some 40 % of the current of a move without load.
    pub friction_a_per_mm_s: f64,
    /// Extra current per mm/s of rod speed while the rod extends (its physical position rises),
    /// and none while it retracts, A·s/mm (≥ 0).
    pub friction_extend_a_per_mm_s: f64,
    /// Extra friction over part of the stroke only.
    pub friction_spot: Option<FrictionSpot>,
    pub stiff_spot: Option<StiffSpot>,
}

impl Wear {
    /// The extra load at physical rod position `rod_mm`, newtons.
    pub fn load_n_at(&self, rod_mm: f64) -> f64 {
        match self.stiff_spot {
            Some(spot)
                if spot.load_n.is_finite()
                    && rod_mm >= spot.from_mm.min(spot.to_mm)
                    && rod_mm <= spot.from_mm.max(spot.to_mm) =>
            {
                spot.load_n.max(0.0)
            }
            _ => 0.0,
        }
    }

    /// The friction current (the part both ways and everywhere) at rod speed `speed_mm_s`, A.
    pub fn friction_current_a(&self, speed_mm_s: f64) -> f64 {
        let k = self.friction_a_per_mm_s;
        if k.is_finite() && k > 0.0 {
            k * speed_mm_s.abs()
        } else {
            0.0
        }
    }

    /// All the friction current of a rod at physical position `rod_mm` moving at
    /// `velocity_mm_s` (positive: extending), A: [`Wear::friction_current_a`], plus the
    /// extending friction while it extends, plus the friction spot's while it is on it.
    pub fn moving_friction_current_a(&self, rod_mm: f64, velocity_mm_s: f64) -> f64 {
        let usable = |k: f64| k.is_finite() && k > 0.0;
        let mut current = self.friction_current_a(velocity_mm_s);
        let k = self.friction_extend_a_per_mm_s;
        if usable(k) && velocity_mm_s > 0.0 {
            current += k * velocity_mm_s;
        }
        if let Some(spot) = self.friction_spot
            && usable(spot.a_per_mm_s)
            && spot.covers(rod_mm)
        {
            current += spot.a_per_mm_s * velocity_mm_s.abs();
        }
        current
    }
}

/// How a servo is driven at one moment.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Drive {
    pub voltage_v: f64,
    /// Register 35, capped at 100.
    pub max_force_percent: f64,
    /// External load opposing the rod, newtons (≥ 0).
    pub load_n: f64,
}

impl Drive {
    fn voltage_factor(&self) -> f64 {
        (self.voltage_v / NOMINAL_VOLTAGE_V).max(0.0)
    }

    fn force_fraction(&self) -> f64 {
        (self.max_force_percent / 100.0).clamp(0.0, 1.0)
    }

    /// Speed without load: 105 mm/s × V/14.8, reduced below 30 % Max Force.
    pub fn no_load_speed_mm_s(&self) -> f64 {
        let force_factor = (self.max_force_percent / FULL_SPEED_MIN_FORCE_PERCENT).clamp(0.0, 1.0);
        NO_LOAD_SPEED_MM_S * self.voltage_factor() * force_factor
    }

    /// Thrust available against a load.
    pub fn available_thrust_n(&self) -> f64 {
        MAX_THRUST_N * self.voltage_factor() * self.force_fraction()
    }

    /// Whether the load is at least the thrust available (the rod cannot move).
    pub fn overloaded(&self) -> bool {
        self.available_thrust_n() <= 0.0 || self.load_n.max(0.0) >= self.available_thrust_n()
    }

    /// Speed under the load: falls linearly to 0 at the available thrust.
    pub fn speed_mm_s(&self) -> f64 {
        if self.overloaded() {
            return 0.0;
        }
        self.no_load_speed_mm_s() * (1.0 - self.load_n.max(0.0) / self.available_thrust_n())
    }

    /// Current drawn to push against the load.
    fn load_current_a(&self) -> f64 {
        self.load_n.max(0.0) / MAX_THRUST_N * (STALL_CURRENT_A - MOVING_CURRENT_A)
    }

    /// Current while moving.
    pub fn moving_current_a(&self) -> f64 {
        (MOVING_CURRENT_A + self.load_current_a()).min(self.stall_current_a().max(MOVING_CURRENT_A))
    }

    /// Current while holding position, force on.
    pub fn holding_current_a(&self) -> f64 {
        (STANDING_CURRENT_A + self.load_current_a())
            .min(self.stall_current_a().max(STANDING_CURRENT_A))
    }

    /// Current with the rod blocked.
    pub fn stall_current_a(&self) -> f64 {
        (STALL_CURRENT_A * self.voltage_factor() * self.force_fraction()).max(STANDING_CURRENT_A)
    }
}

/// Temperature after `dt` at constant `power_w`, relaxing toward `ambient_c + R_th × power_w`.
pub fn temperature_after(temperature_c: f64, ambient_c: f64, power_w: f64, dt: Duration) -> f64 {
    let steady = ambient_c + THERMAL_RESISTANCE_C_PER_W * power_w.max(0.0);
    let decay = (-dt.as_secs_f64() / THERMAL_TIME_CONSTANT_S).exp();
    steady + (temperature_c - steady) * decay
}

/// A position in mm as the Present Position register shows it: 0.01 mm units on the 0.02 mm grid.
pub fn quantise_mm_centi(position_mm: f64) -> i16 {
    let steps = (position_mm / RESOLUTION_MM).round();
    (steps * 2.0).clamp(f64::from(i16::MIN), f64::from(i16::MAX)) as i16
}

/// `Duration` from seconds, never panicking (negative, NaN and huge values are clamped).
pub fn duration_from_secs(seconds: f64) -> Duration {
    Duration::try_from_secs_f64(seconds.max(0.0)).unwrap_or(Duration::from_secs(u32::MAX.into()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn drive(voltage_v: f64, max_force_percent: f64, load_n: f64) -> Drive {
        Drive {
            voltage_v,
            max_force_percent,
            load_n,
        }
    }

    #[test]
    fn speed_is_105_mm_s_at_14v8_without_load() {
        assert!((drive(14.8, 100.0, 0.0).speed_mm_s() - 105.0).abs() < 1e-9);
    }

    #[test]
    fn speed_scales_with_voltage_and_low_max_force() {
        let full = drive(14.8, 100.0, 0.0).speed_mm_s();
        assert!((drive(7.4, 100.0, 0.0).speed_mm_s() - full / 2.0).abs() < 1e-9);
        assert!((drive(14.8, 15.0, 0.0).speed_mm_s() - full / 2.0).abs() < 1e-9);
        assert!((drive(14.8, 50.0, 0.0).speed_mm_s() - full).abs() < 1e-9);
    }

    #[test]
    fn a_load_above_the_thrust_stops_the_rod() {
        assert!(drive(14.8, 100.0, 500.0).overloaded());
        assert_eq!(drive(14.8, 100.0, 500.0).speed_mm_s(), 0.0);
        assert!(drive(14.8, 100.0, 100.0).speed_mm_s() < 105.0);
    }

    #[test]
    fn currents_have_the_spec_levels() {
        let unloaded = drive(14.8, 100.0, 0.0);
        assert!((unloaded.holding_current_a() - 0.07).abs() < 1e-9);
        assert!((unloaded.moving_current_a() - 0.26).abs() < 1e-9);
        assert!(unloaded.stall_current_a() > 3.0);
        assert!(drive(14.8, 100.0, 100.0).moving_current_a() > 1.0);
    }

    #[test]
    fn temperature_relaxes_toward_the_steady_state() {
        let after_long = temperature_after(25.0, 25.0, 10.0, Duration::from_secs(3600));
        assert!((after_long - 55.0).abs() < 0.01);
        let cooling = temperature_after(80.0, 25.0, 0.0, Duration::from_secs(60));
        assert!(cooling < 80.0 && cooling > 25.0);
    }

    #[test]
    fn wear_adds_current_with_speed_and_a_load_over_its_stiff_spot() {
        let wear = Wear {
            friction_a_per_mm_s: 0.002,
            stiff_spot: Some(StiffSpot {
                from_mm: 5.0,
                to_mm: 2.0,
                load_n: 50.0,
            }),
            ..Wear::default()
        };
        assert!((wear.friction_current_a(-50.0) - 0.1).abs() < 1e-12);
        assert_eq!(wear.load_n_at(3.0), 50.0);
        assert_eq!(wear.load_n_at(6.0), 0.0);
        assert_eq!(Wear::default().friction_current_a(100.0), 0.0);
        assert_eq!(Wear::default().load_n_at(0.0), 0.0);
    }

    #[test]
    fn extending_and_spot_friction_add_current_only_where_they_act() {
        let one_way = Wear {
            friction_extend_a_per_mm_s: 0.002,
            ..Wear::default()
        };
        assert!((one_way.moving_friction_current_a(0.0, 50.0) - 0.1).abs() < 1e-12);
        assert_eq!(one_way.moving_friction_current_a(0.0, -50.0), 0.0);
        let spot = Wear {
            friction_spot: Some(FrictionSpot {
                from_mm: 4.0,
                to_mm: 2.0,
                a_per_mm_s: 0.002,
            }),
            ..Wear::default()
        };
        assert!((spot.moving_friction_current_a(3.0, -50.0) - 0.1).abs() < 1e-12);
        assert!((spot.moving_friction_current_a(3.0, 50.0) - 0.1).abs() < 1e-12);
        assert_eq!(spot.moving_friction_current_a(4.5, 50.0), 0.0);
        // All together add up; the part both ways is what friction_current_a gives.
        let all = Wear {
            friction_a_per_mm_s: 0.001,
            ..Wear {
                friction_spot: spot.friction_spot,
                ..one_way
            }
        };
        assert!((all.moving_friction_current_a(3.0, 50.0) - 0.25).abs() < 1e-12);
        assert!((all.moving_friction_current_a(3.0, -50.0) - 0.15).abs() < 1e-12);
        assert_eq!(
            all.moving_friction_current_a(9.0, -50.0),
            all.friction_current_a(-50.0)
        );
        // No wear: nothing, anywhere, either way.
        for (at, v) in [(0.0, 30.0), (3.0, -30.0)] {
            assert_eq!(Wear::default().moving_friction_current_a(at, v), 0.0);
        }
    }

    #[test]
    fn positions_are_reported_on_the_0_02_mm_grid() {
        assert_eq!(quantise_mm_centi(9.0), 900);
        assert_eq!(quantise_mm_centi(9.011), 902);
        assert_eq!(quantise_mm_centi(-12.02), -1202);
        assert_eq!(quantise_mm_centi(0.009) % 2, 0);
    }
}

//! PWM-mode parity: an autopilot output moves a servo through the bridge exactly as it would
//! move the same servo on a PWM wire (protocol reference, section 2), and "no output" holds.

use lj9da_bridge::config::{Config, FailsafeAction, PwmRange, ServoConfig};
use lj9da_bridge::protocol::{MmCenti, PositionLimits, ServoId};
use proptest::prelude::*;

fn servo() -> ServoConfig {
    ServoConfig {
        name: "aileron_left".into(),
        label: "ail_l".into(),
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

fn limits(minus: i16, plus: i16) -> PositionLimits {
    PositionLimits::new(MmCenti(minus), MmCenti(plus)).unwrap()
}

fn at(us: u16) -> Option<i16> {
    servo().map_pwm(us).map(|p| p.0)
}

#[test]
fn the_end_points_and_centre_match_the_servo_pwm_mode() {
    assert_eq!(at(920), Some(-2500));
    assert_eq!(at(1520), Some(0));
    assert_eq!(at(2120), Some(2500));
}

#[test]
fn twenty_four_microseconds_make_one_millimetre() {
    assert_eq!(at(1544), Some(100));
    assert_eq!(at(1496), Some(-100));
    assert_eq!(at(1760), Some(1000));
}

#[test]
fn positions_are_rounded_to_the_nearest_hundredth_of_a_millimetre() {
    // 25/6 = 4.17 → 4
    assert_eq!(at(1521), Some(4));
    assert_eq!(at(1519), Some(-4));
    // 2 × 25/6 = 8.33 → 8
    assert_eq!(at(1522), Some(8));
}

#[test]
fn halves_round_away_from_zero() {
    // 3 × 25/6 = 12.5 → 13, and −12.5 → −13
    assert_eq!(at(1523), Some(13));
    assert_eq!(at(1517), Some(-13));
    // 9 × 25/6 = 37.5 → 38
    assert_eq!(at(1529), Some(38));
}

#[test]
fn no_output_and_out_of_range_pulses_hold() {
    for us in [0, 65535, 919, 2121, 900, 500, 3000] {
        assert_eq!(at(us), None, "{us} µs");
    }
}

#[test]
fn reverse_negates_the_position() {
    let mut s = servo();
    s.reverse = true;
    assert_eq!(s.map_pwm(920), Some(MmCenti(2500)));
    assert_eq!(s.map_pwm(2120), Some(MmCenti(-2500)));
    assert_eq!(s.map_pwm(1544), Some(MmCenti(-100)));
    assert_eq!(s.map_pwm(1520), Some(MmCenti(0)));
    assert_eq!(s.map_pwm(0), None);
}

#[test]
fn travel_limits_clamp_after_reverse() {
    let mut s = servo();
    s.travel = limits(-1000, 500);
    assert_eq!(s.map_pwm(2120), Some(MmCenti(500)));
    assert_eq!(s.map_pwm(920), Some(MmCenti(-1000)));
    assert_eq!(s.map_pwm(1544), Some(MmCenti(100)));
    s.reverse = true;
    // 920 µs is −25 mm, reversed +25 mm, clamped to the plus limit +5 mm.
    assert_eq!(s.map_pwm(920), Some(MmCenti(500)));
    assert_eq!(s.map_pwm(2120), Some(MmCenti(-1000)));
    // Still no output outside the range, whatever the travel.
    assert_eq!(s.map_pwm(2121), None);
}

#[test]
fn a_custom_range_is_scaled_on_each_side_of_its_trim() {
    let mut s = servo();
    s.pwm = PwmRange {
        min_us: 1100,
        trim_us: 1500,
        max_us: 1900,
    };
    assert_eq!(s.map_pwm(1100), Some(MmCenti(-2500)));
    assert_eq!(s.map_pwm(1500), Some(MmCenti(0)));
    assert_eq!(s.map_pwm(1900), Some(MmCenti(2500)));
    // 400 µs for 25 mm: 16 µs per mm, 1 µs = 6.25 → 6
    assert_eq!(s.map_pwm(1516), Some(MmCenti(100)));
    assert_eq!(s.map_pwm(1501), Some(MmCenti(6)));
    // 2 µs = 12.5 → 13, half away from zero on both sides
    assert_eq!(s.map_pwm(1502), Some(MmCenti(13)));
    assert_eq!(s.map_pwm(1498), Some(MmCenti(-13)));
    assert_eq!(s.map_pwm(1099), None);
    assert_eq!(s.map_pwm(1901), None);
    // The servo's own 920 and 2120 are outside this range: hold.
    assert_eq!(s.map_pwm(920), None);
}

#[test]
fn an_asymmetric_range_scales_each_side_separately() {
    let mut s = servo();
    s.pwm = PwmRange {
        min_us: 1000,
        trim_us: 1400,
        max_us: 2000,
    };
    assert_eq!(s.map_pwm(1000), Some(MmCenti(-2500)));
    assert_eq!(s.map_pwm(1400), Some(MmCenti(0)));
    assert_eq!(s.map_pwm(2000), Some(MmCenti(2500)));
    assert_eq!(s.map_pwm(1200), Some(MmCenti(-1250)));
    assert_eq!(s.map_pwm(1700), Some(MmCenti(1250)));
}

#[test]
fn normalised_values_span_the_stroke() {
    let s = servo();
    assert_eq!(s.map_normalized(-1.0), Some(MmCenti(-2500)));
    assert_eq!(s.map_normalized(0.0), Some(MmCenti(0)));
    assert_eq!(s.map_normalized(1.0), Some(MmCenti(2500)));
    assert_eq!(s.map_normalized(0.5), Some(MmCenti(1250)));
    assert_eq!(s.map_normalized(-0.04), Some(MmCenti(-100)));
}

#[test]
fn normalised_nan_and_values_beyond_one_are_left_alone() {
    let s = servo();
    assert_eq!(s.map_normalized(f32::NAN), None);
    assert_eq!(s.map_normalized(1.01), None);
    assert_eq!(s.map_normalized(-1.5), None);
    assert_eq!(s.map_normalized(f32::INFINITY), None);
    assert_eq!(s.map_normalized(f32::NEG_INFINITY), None);
}

#[test]
fn normalised_values_are_reversed_and_clamped_like_pwm() {
    let mut s = servo();
    s.reverse = true;
    s.travel = limits(-2000, 1000);
    assert_eq!(s.map_normalized(1.0), Some(MmCenti(-2000)));
    assert_eq!(s.map_normalized(-1.0), Some(MmCenti(1000)));
    assert_eq!(s.map_normalized(0.2), Some(MmCenti(-500)));
}

#[test]
fn the_mapping_in_a_file_is_the_same_law() {
    let c = Config::parse(
        "[mavlink]\nconnection = \"udpin:0.0.0.0:14560\"\n[[bus]]\nname = \"b\"\nport = \"/dev/ttyUSB0\"\n[[servo]]\nname = \"s\"\nbus = \"b\"\nid = 1\nchannel = 1\nreverse = true\ntravel_mm = [-20, 10]\n",
        "law.toml",
    )
    .unwrap();
    let s = &c.servos[0];
    assert_eq!(s.map_pwm(1544), Some(MmCenti(-100)));
    assert_eq!(s.map_pwm(920), Some(MmCenti(1000)));
    assert_eq!(s.map_pwm(2120), Some(MmCenti(-2000)));
    assert_eq!(s.map_pwm(65535), None);
}

fn any_servo() -> impl Strategy<Value = ServoConfig> {
    (
        500u16..2498,
        1u16..1000,
        1u16..1000,
        -2500i16..=0,
        0i16..=2500,
        any::<bool>(),
    )
        .prop_map(|(min, below, above, minus, plus, reverse)| {
            let trim = (min + below).min(2499);
            let max = (trim + above).min(2500);
            let mut s = servo();
            s.pwm = PwmRange {
                min_us: min,
                trim_us: trim,
                max_us: max,
            };
            s.travel = limits(minus, plus);
            s.reverse = reverse;
            s
        })
        .prop_filter("a valid range", |s| {
            s.pwm.min_us < s.pwm.trim_us && s.pwm.trim_us < s.pwm.max_us
        })
}

proptest! {
    #[test]
    fn the_mapping_is_monotonic_and_stays_inside_the_travel(s in any_servo(), a in any::<u16>(), b in any::<u16>()) {
        let (lo, hi) = if a <= b { (a, b) } else { (b, a) };
        let (p_lo, p_hi) = (s.map_pwm(lo), s.map_pwm(hi));
        for (us, p) in [(lo, p_lo), (hi, p_hi)] {
            match p {
                Some(p) => {
                    prop_assert!(s.pwm.contains(us) && us != 0 && us != 65535);
                    prop_assert!(s.travel.contains(p), "{us} µs → {p:?} outside {:?}", s.travel);
                }
                None => prop_assert!(!s.pwm.contains(us)),
            }
        }
        if let (Some(p_lo), Some(p_hi)) = (p_lo, p_hi) {
            if s.reverse {
                prop_assert!(p_lo >= p_hi);
            } else {
                prop_assert!(p_lo <= p_hi);
            }
        }
    }

    #[test]
    fn the_default_range_is_exactly_25_over_6_rounded(us in 920u16..=2120) {
        let exact = (f64::from(us) - 1520.0) * 25.0 / 6.0;
        prop_assert_eq!(servo().map_pwm(us), Some(MmCenti(exact.round() as i16)));
    }

    #[test]
    fn normalised_mapping_is_monotonic_and_inside_the_travel(s in any_servo(), a in -1.0f32..=1.0, b in -1.0f32..=1.0) {
        let (lo, hi) = if a <= b { (a, b) } else { (b, a) };
        let p_lo = s.map_normalized(lo).unwrap();
        let p_hi = s.map_normalized(hi).unwrap();
        prop_assert!(s.travel.contains(p_lo) && s.travel.contains(p_hi));
        if s.reverse { prop_assert!(p_lo >= p_hi) } else { prop_assert!(p_lo <= p_hi) }
    }
}

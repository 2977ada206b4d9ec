use super::*;
use crate::bus::{ForceState, ServoIdentity, ServoStatus};
use crate::mavlink::ServoState;
use crate::protocol::{Celsius, Ma10, MmCenti, Ms10, Mv10, ReplyFlags, Telemetry};
use std::time::Duration;

/// A servo whose latest reading (1.5 mm, 0.3 A, 86 °C, 12 V) is `age` old.
fn status(health: Health, age: Option<Duration>) -> ServoStatus {
    ServoStatus {
        id: ServoId::new(4).unwrap(),
        name: "rudder".into(),
        health,
        telemetry: Some(Telemetry {
            present_position: MmCenti(150),
            present_time: Ms10(0),
            present_load: Ma10(30),
            present_temperature: Celsius(86),
            present_voltage: Mv10(1200),
        }),
        telemetry_at: age.map(|a| Instant::now() - a),
        position_at: None,
        motion_at: None,
        age,
        flags: ReplyFlags(0),
        goal: None,
        force: ForceState::Off,
        stalled: false,
        identity: ServoIdentity::default(),
        consecutive_timeouts: 0,
        telemetry_count: 100,
        answered: 100,
        timeouts: 0,
        degraded: None,
    }
}

fn telemetry_of(r: &ServoReport) -> [Option<f32>; 4] {
    [r.position_mm, r.current_a, r.temperature_c, r.voltage_v]
}

#[test]
fn a_fresh_reading_goes_out_whatever_the_servos_health() {
    let fresh = Some(Duration::from_millis(20));
    for health in [
        Health::Starting,
        Health::Online,
        Health::Stale,
        Health::Offline,
        Health::WrongModel,
        Health::TemperatureError,
    ] {
        let r = report_of(&status(health, fresh), true);
        assert_eq!(
            telemetry_of(&r),
            [Some(1.5), Some(0.3), Some(86.0), Some(12.0)],
            "{health:?}"
        );
    }
}

#[test]
fn a_servo_in_temperature_error_reports_its_temperature_and_its_fault() {
    let mut s = status(Health::TemperatureError, Some(Duration::from_millis(15)));
    s.flags = ReplyFlags(ReplyFlags::TEMPERATURE_ERROR);
    let r = report_of(&s, true);
    assert_eq!(r.state, Some(ServoState::Fault));
    assert!(r.temperature_error);
    assert_eq!(r.temperature_c, Some(86.0));
}

#[test]
fn a_reading_older_than_fresh_for_is_not_passed_on_as_present() {
    for health in [Health::Online, Health::Stale, Health::TemperatureError] {
        let r = report_of(&status(health, Some(FRESH_FOR)), true);
        assert_eq!(telemetry_of(&r), [None; 4], "{health:?}");
    }
    let mut never_read = status(Health::Online, None);
    never_read.telemetry = None;
    assert_eq!(telemetry_of(&report_of(&never_read, true)), [None; 4]);
}

#[test]
fn a_servo_behind_a_closed_port_is_offline_whatever_it_last_was() {
    for health in [
        Health::Starting,
        Health::Online,
        Health::Stale,
        Health::Offline,
    ] {
        let r = report_of(&status(health, Some(Duration::from_millis(20))), false);
        assert_eq!(r.state, Some(ServoState::Offline), "{health:?}");
        assert_eq!(
            crate::mavlink::telemetry::state_bits(&r, false),
            crate::mavlink::telemetry::state_bit::OFFLINE,
            "{health:?}: the applet's bit for a servo it must act on"
        );
    }
}

fn trim_set(value: i64) -> ParamSet {
    ParamSet {
        index: 0,
        name: "S1_PWM_TRIM".into(),
        value: value as f32,
        edits: vec![crate::config::edit::Edit::Set {
            section: crate::config::edit::Section::Servo(0),
            key: "pwm_trim_us",
            value: value.into(),
        }],
    }
}

#[test]
fn the_mapping_writer_makes_changes_in_order_and_refuses_without_a_file() {
    let (tx, _rx) = spawn_mapping_writer(None);
    assert!(tx.try_send(trim_set(1500)).is_err(), "no file: refused");

    let file = MappingFile::in_memory(
        crate::config::SITL_DEFAULT_TOML,
        crate::config::SITL_DEFAULT_ORIGIN,
    )
    .unwrap();
    let (tx, mut rx) = spawn_mapping_writer(Some(file));
    let results: Vec<_> = [1500, 9999, 1510]
        .into_iter()
        .map(|value| {
            tx.blocking_send(trim_set(value)).unwrap();
            let (set, result) = rx.blocking_recv().unwrap();
            (set.value, result.map(|c| c.servos[0].pwm.trim_us))
        })
        .collect();
    assert_eq!(results[0], (1500.0, Ok(1500)));
    assert!(results[1].1.is_err(), "{results:?}");
    assert_eq!(results[2], (1510.0, Ok(1510)));
}

#[test]
fn an_image_s_own_host_name_is_not_taken_for_an_aircraft_s() {
    for name in [
        "raspberrypi",
        "RaspberryPi",
        "raspberrypi.local",
        "debian",
        "tegra-ubuntu",
    ] {
        assert!(is_image_default(name), "{name}");
    }
    for name in ["wing-07", "raspberrypi-07", "plane", ""] {
        assert!(!is_image_default(name), "{name}");
    }
}

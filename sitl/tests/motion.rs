//! Motion, force and current (protocol spec 1, 6, 7): speed, clamping to the limits, reverse, goal time and
//! present time, force-on semantics, brake, current levels. Virtual time: nothing sleeps.

mod common;

use std::time::Duration;

use common::{VirtualBus, force, goal, read, request, write};
use lj9da_sim::{Force, SimConfig};

const GOAL_9MM_IN_5S: [u8; 12] = [
    0xFA, 0xAF, 0x01, 0x00, 0x1E, 0x04, 0x01, 0x84, 0x03, 0xF4, 0x01, 0x68,
];
const PLUS_LIMIT_20MM: [u8; 10] = [0xFA, 0xAF, 0x01, 0x00, 0x08, 0x02, 0x01, 0xD0, 0x07, 0xDD];
const MINUS_LIMIT_20MM: [u8; 10] = [0xFA, 0xAF, 0x01, 0x00, 0x0A, 0x02, 0x01, 0x30, 0xF8, 0xC0];
const FORCE_ON: [u8; 9] = [0xFA, 0xAF, 0x01, 0x00, 0x24, 0x01, 0x01, 0x01, 0x24];
const BRAKE: [u8; 9] = [0xFA, 0xAF, 0x01, 0x00, 0x24, 0x01, 0x01, 0x02, 0x27];

fn position(bus: &mut VirtualBus, id: u8) -> i16 {
    bus.status(id).i16_at(0x2A).expect("present position")
}

fn servo_on(voltage_v: f32) -> VirtualBus {
    let mut bus = VirtualBus::new(SimConfig {
        voltage_v,
        ..SimConfig::default()
    });
    bus.transact(&FORCE_ON);
    bus
}

/// Time for the rod to get within 0.02 mm of `target` (0.01 mm), sampled every millisecond.
fn time_to_reach(bus: &mut VirtualBus, target: i16) -> Duration {
    let start = bus.now;
    for _ in 0..10_000 {
        let servo = bus.model.snapshot(bus.now, 1).expect("servo");
        if (servo.position_mm * 100.0 - f32::from(target)).abs() < 2.0 {
            return bus.now - start;
        }
        bus.wait(Duration::from_millis(1));
    }
    panic!("never reached {target}");
}

#[test]
fn the_rod_moves_at_105_mm_s_at_14v8() {
    let mut bus = servo_on(14.8);
    bus.write(&goal(1, 2100));
    let elapsed = time_to_reach(&mut bus, 2100);
    // 21 mm at 105 mm/s = 200 ms (+ packet wire time).
    assert!((195..=210).contains(&elapsed.as_millis()), "{elapsed:?}");
}

#[test]
fn the_rod_is_slower_at_12_v() {
    let mut bus = servo_on(12.0);
    bus.write(&goal(1, 2100));
    let elapsed = time_to_reach(&mut bus, 2100);
    // 105 × 12 / 14.8 = 85.1 mm/s: 21 mm in 247 ms.
    assert!((240..=255).contains(&elapsed.as_millis()), "{elapsed:?}");
}

#[test]
fn a_low_max_force_slows_the_rod() {
    let mut bus = servo_on(14.8);
    bus.transact(&write(1, 0x23, &[15]));
    bus.write(&goal(1, 2100));
    let elapsed = time_to_reach(&mut bus, 2100);
    assert!(
        (395..=410).contains(&elapsed.as_millis()),
        "half speed at 15 %: {elapsed:?}"
    );
}

#[test]
fn the_rod_stops_at_the_goal() {
    let mut bus = servo_on(12.0);
    bus.transact(&goal(1, 900));
    bus.wait(Duration::from_millis(300));
    assert_eq!(position(&mut bus, 1), 900);
    bus.transact(&goal(1, -900));
    bus.wait(Duration::from_millis(300));
    assert_eq!(position(&mut bus, 1), -900);
}

#[test]
fn the_goal_is_clamped_to_the_position_limits() {
    let mut bus = servo_on(12.0);
    bus.transact(&PLUS_LIMIT_20MM);
    bus.transact(&MINUS_LIMIT_20MM);
    bus.transact(&goal(1, 2500));
    assert_eq!(bus.reply(&read(1, 0x1E, 2)).i16_at(0x1E), Some(2000));
    bus.wait(Duration::from_millis(400));
    assert_eq!(position(&mut bus, 1), 2000);
    bus.transact(&goal(1, -2400));
    bus.wait(Duration::from_millis(600));
    assert_eq!(position(&mut bus, 1), -2000);
}

#[test]
fn reverse_mirrors_the_direction() {
    let mut bus = servo_on(12.0);
    bus.transact(&write(1, 0x05, &[0x01]));
    bus.transact(&goal(1, 900));
    bus.wait(Duration::from_millis(300));
    let servo = bus.model.snapshot(bus.now, 1).expect("servo");
    assert!(
        (servo.rod_mm + 9.0).abs() < 0.02,
        "the rod retracts: {}",
        servo.rod_mm
    );
    assert_eq!(
        position(&mut bus, 1),
        900,
        "present position is in the reversed frame"
    );
}

#[test]
fn reverse_mirrors_the_limits() {
    let mut bus = servo_on(12.0);
    bus.transact(&PLUS_LIMIT_20MM);
    bus.transact(&write(1, 0x0A, &(-1000i16).to_le_bytes()));
    bus.transact(&write(1, 0x05, &[0x01]));
    // Logical +15 mm is physical −15 mm, beyond the −10 mm limit.
    bus.transact(&goal(1, 1500));
    assert_eq!(bus.reply(&read(1, 0x1E, 2)).i16_at(0x1E), Some(1000));
    // Logical −25 mm is physical +25 mm, beyond the +20 mm limit.
    bus.transact(&goal(1, -2500));
    assert_eq!(bus.reply(&read(1, 0x1E, 2)).i16_at(0x1E), Some(-2000));
}

#[test]
fn goal_time_spreads_the_move_and_present_time_counts_it() {
    let mut bus = servo_on(12.0);
    bus.transact(&GOAL_9MM_IN_5S);
    bus.wait(Duration::from_millis(2450));
    let halfway = bus.status(1);
    let position = halfway.i16_at(0x2A).expect("position");
    let present_time = halfway.u16_at(0x2C).expect("present time");
    assert!(
        (430..=470).contains(&position),
        "halfway through 9 mm in 5 s: {position}"
    );
    assert!(
        (245..=252).contains(&present_time),
        "present time in 10 ms: {present_time}"
    );
    bus.wait(Duration::from_millis(2650));
    let done = bus.status(1);
    assert_eq!(done.i16_at(0x2A), Some(900));
    assert_eq!(
        done.u16_at(0x2C),
        Some(0),
        "present time is 0 once the goal time has passed"
    );
}

#[test]
fn present_time_is_0_without_a_goal_time() {
    let mut bus = servo_on(12.0);
    bus.transact(&goal(1, 900));
    assert_eq!(bus.status(1).u16_at(0x2C), Some(0));
}

#[test]
fn a_goal_time_faster_than_the_max_speed_is_stretched() {
    let mut bus = servo_on(14.8);
    // 21 mm in 10 ms asked; 200 ms at 105 mm/s is the best the servo can do.
    bus.write(&write(1, 0x1E, &[0x34, 0x08, 0x01, 0x00]));
    let elapsed = time_to_reach(&mut bus, 2100);
    assert!(elapsed >= Duration::from_millis(195), "{elapsed:?}");
}

#[test]
fn present_position_is_reported_on_the_0_02_mm_grid() {
    let mut bus = servo_on(12.0);
    for target in [901, 333, -777, 1] {
        bus.transact(&goal(1, target));
        for _ in 0..30 {
            bus.wait(Duration::from_millis(7));
            let position = position(&mut bus, 1);
            assert_eq!(position % 2, 0, "odd position {position}");
        }
    }
}

#[test]
fn force_is_off_at_power_up_and_the_rod_does_not_move() {
    let mut bus = VirtualBus::with_ids(&[1]);
    assert_eq!(
        bus.model.snapshot(bus.now, 1).expect("servo").force,
        Force::Off
    );
    bus.transact(&goal(1, 900));
    bus.wait(Duration::from_millis(500));
    assert_eq!(position(&mut bus, 1), 0);
    assert_eq!(
        bus.reply(&read(1, 0x1E, 2)).i16_at(0x1E),
        Some(900),
        "the goal is stored"
    );
}

#[test]
fn force_on_sets_the_goal_to_the_present_position() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.model.move_rod(bus.now, 1, 3.0);
    bus.transact(&goal(1, 900));
    bus.transact(&FORCE_ON);
    assert_eq!(bus.reply(&read(1, 0x1E, 2)).i16_at(0x1E), Some(300));
    bus.wait(Duration::from_millis(300));
    assert_eq!(position(&mut bus, 1), 300, "no jump when enabling");
}

#[test]
fn force_on_is_refused_while_the_rod_is_outside_the_limits() {
    let mut bus = servo_on(12.0);
    bus.transact(&goal(1, 2200));
    bus.wait(Duration::from_millis(400));
    bus.transact(&force(1, 0));
    bus.transact(&PLUS_LIMIT_20MM);
    bus.transact(&FORCE_ON);
    assert_eq!(
        bus.reply(&read(1, 0x24, 1)).data,
        [0x00],
        "register stays 00h"
    );
    bus.model.move_rod(bus.now, 1, 19.0);
    bus.transact(&FORCE_ON);
    assert_eq!(
        bus.reply(&read(1, 0x24, 1)).data,
        [0x01],
        "accepted once back inside"
    );
}

#[test]
fn brake_mode_holds_the_rod() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.transact(&BRAKE);
    assert_eq!(bus.reply(&read(1, 0x24, 1)).data, [0x02]);
    bus.transact(&goal(1, 900));
    bus.wait(Duration::from_millis(300));
    assert_eq!(position(&mut bus, 1), 0);
}

#[test]
fn force_off_stops_a_move() {
    let mut bus = servo_on(12.0);
    bus.transact(&goal(1, 2000));
    bus.transact(&force(1, 0));
    let stopped_at = position(&mut bus, 1);
    bus.wait(Duration::from_millis(300));
    assert_eq!(position(&mut bus, 1), stopped_at);
    assert!(stopped_at < 2000);
}

#[test]
fn current_is_70_ma_standing_and_260_ma_moving() {
    let mut bus = servo_on(12.0);
    let load = |bus: &mut VirtualBus| bus.status(1).u16_at(0x30).expect("present load");
    assert_eq!(load(&mut bus), 7);
    bus.transact(&goal(1, 2000));
    assert_eq!(load(&mut bus), 26, "moving");
    bus.wait(Duration::from_millis(400));
    assert_eq!(load(&mut bus), 7, "arrived");
    bus.transact(&force(1, 0));
    assert!(load(&mut bus) > 0, "not 0 with force off");
}

#[test]
fn an_external_load_raises_the_current() {
    let mut bus = servo_on(12.0);
    bus.model.set_load_n(bus.now, 1, 100.0);
    bus.transact(&goal(1, 2000));
    let moving = bus.status(1).u16_at(0x30).expect("present load");
    assert!(moving > 100, "100 N costs about 1 A: {moving}");
}

#[test]
fn the_present_voltage_is_the_supply() {
    let mut bus = VirtualBus::new(SimConfig {
        voltage_v: 11.1,
        ..SimConfig::default()
    });
    assert_eq!(bus.status(1).u16_at(0x34), Some(1110));
    bus.model.set_voltage_v(bus.now, Some(1), 14.8);
    assert_eq!(bus.status(1).u16_at(0x34), Some(1480));
}

#[test]
fn servos_on_one_bus_move_independently() {
    let mut bus = VirtualBus::with_ids(&[1, 2]);
    bus.transact(&force(1, 1));
    bus.transact(&force(2, 1));
    bus.transact(&goal(1, 1000));
    bus.transact(&goal(2, -500));
    bus.wait(Duration::from_millis(300));
    assert_eq!(position(&mut bus, 1), 1000);
    assert_eq!(position(&mut bus, 2), -500);
    assert_eq!(bus.transact(&request(3, 0x09)), Vec::<u8>::new());
}

//! Temperature (protocol spec 7, manual 3.5): heating with current, cooling toward ambient, the alarm flag
//! from 75 °C, the error flag and force off at 85 °C, latched until a reboot below the limit.

mod common;

use std::time::Duration;

use common::{VirtualBus, force, goal, read, request};
use lj9da_sim::{Fault, FaultKind, ShortPacket, SimConfig, SpecialCommand};

const ALARM: u8 = 0x20;
const ERROR: u8 = 0x80;

fn temperature(bus: &mut VirtualBus) -> u16 {
    bus.status(1).u16_at(0x32).expect("temperature")
}

fn reboot(bus: &mut VirtualBus) {
    bus.transact(&ShortPacket::special(1, SpecialCommand::Reboot).encode());
    bus.wait(Duration::from_millis(100));
}

/// A servo pushing against a blocked rod.
fn stalled_servo() -> VirtualBus {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.transact(&force(1, 1));
    bus.model.inject(bus.now, Some(1), Fault::Stall);
    bus.transact(&goal(1, 1000));
    bus
}

#[test]
fn a_stalled_servo_heats_up_raises_the_alarm_then_trips() {
    let mut bus = stalled_servo();
    let mut alarm_at = None;
    let mut error_at = None;
    for tenth in 1..=1200 {
        bus.wait(Duration::from_millis(100));
        let status = bus.status(1);
        let celsius = status.u16_at(0x32).expect("temperature");
        if status.flags & ALARM != 0 && alarm_at.is_none() {
            alarm_at = Some(tenth);
            assert!(celsius >= 75, "alarm below 75 °C: {celsius}");
        }
        if status.flags & ERROR != 0 {
            error_at = Some(tenth);
            // Force went off at 85 °C; it may have cooled a little by the time of this sample.
            assert!(celsius >= 84, "error at {celsius} °C");
            break;
        }
    }
    let (alarm_at, error_at) = (alarm_at.expect("no alarm"), error_at.expect("no error"));
    assert!(alarm_at < error_at);
    assert!(
        (150..=600).contains(&error_at),
        "tripped after {error_at} × 100 ms"
    );
    assert_eq!(
        bus.reply(&read(1, 0x24, 1)).data,
        [0x00],
        "force switched off"
    );
}

#[test]
fn the_error_is_latched_until_a_reboot_below_the_limit() {
    let mut bus = stalled_servo();
    bus.wait(Duration::from_secs(60));
    assert_ne!(bus.status(1).flags & ERROR, 0);
    bus.model.clear(bus.now, Some(1), FaultKind::Stall);

    // Cooling: below the limit, but still latched and refusing force on.
    bus.wait(Duration::from_secs(30));
    assert!(temperature(&mut bus) < 85);
    assert_ne!(bus.status(1).flags & ERROR, 0, "latched");
    bus.transact(&force(1, 1));
    assert_eq!(
        bus.reply(&read(1, 0x24, 1)).data,
        [0x00],
        "force on refused while latched"
    );

    reboot(&mut bus);
    assert_eq!(
        bus.status(1).flags & ERROR,
        0,
        "cleared by a reboot below the limit"
    );
    bus.transact(&force(1, 1));
    assert_eq!(bus.reply(&read(1, 0x24, 1)).data, [0x01]);
}

#[test]
fn a_reboot_at_or_above_the_limit_keeps_the_error() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.model.set_temperature_c(bus.now, 1, 90.0);
    assert_ne!(bus.status(1).flags & ERROR, 0);
    reboot(&mut bus);
    assert_ne!(bus.status(1).flags & ERROR, 0);
    bus.transact(&force(1, 1));
    assert_eq!(bus.reply(&read(1, 0x24, 1)).data, [0x00]);
}

#[test]
fn the_alarm_follows_the_temperature_without_latching() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.model.set_temperature_c(bus.now, 1, 74.0);
    assert_eq!(bus.status(1).flags & ALARM, 0);
    bus.model.set_temperature_c(bus.now, 1, 78.0);
    assert_eq!(bus.status(1).flags & (ALARM | ERROR), ALARM);
    bus.wait(Duration::from_secs(120));
    assert_eq!(bus.status(1).flags & ALARM, 0, "cooled down");
}

#[test]
fn temperature_falls_toward_ambient() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.model.set_temperature_c(bus.now, 1, 70.0);
    bus.wait(Duration::from_secs(600));
    let celsius = temperature(&mut bus);
    assert!((25..=28).contains(&celsius), "{celsius} °C");
}

#[test]
fn moving_warms_the_servo_only_a_little() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.transact(&force(1, 1));
    for step in 0..300 {
        bus.transact(&goal(1, if step % 2 == 0 { 2000 } else { -2000 }));
        bus.wait(Duration::from_millis(500));
    }
    let celsius = temperature(&mut bus);
    assert!(
        (27..=40).contains(&celsius),
        "{celsius} °C after 2.5 min of moves"
    );
}

#[test]
fn the_overheat_fault_trips_within_seconds() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.transact(&force(1, 1));
    bus.model.overheat(bus.now, 1);
    bus.wait(Duration::from_secs(5));
    assert_ne!(bus.status(1).flags & ERROR, 0);
    assert_eq!(bus.reply(&read(1, 0x24, 1)).data, [0x00]);
}

#[test]
fn a_hot_ambient_raises_the_alarm() {
    let mut bus = VirtualBus::new(SimConfig {
        ambient_c: 80.0,
        ..SimConfig::default()
    });
    assert_eq!(bus.status(1).flags & (ALARM | ERROR), ALARM);
    assert_eq!(bus.transact(&request(1, 0x01)), [0x07]);
}

//! RAM and flash: what survives a reboot or power cycle, the flash write's busy time, the factory reset,
//! and ID / baud-rate changes (protocol spec 4.1, 6, 7).

mod common;

use std::time::Duration;

use common::{VirtualBus, force, goal, read, request, write, write_reply};
use lj9da_sim::{BusEvent, DamageKind, IgnoreReason, ShortPacket, SpecialCommand};

const SET_ID_5: [u8; 9] = [0xFA, 0xAF, 0x01, 0x00, 0x04, 0x01, 0x01, 0x05, 0x00];
const SET_BAUD_38400: [u8; 9] = [0xFA, 0xAF, 0x01, 0x00, 0x06, 0x01, 0x01, 0x04, 0x03];
const PLUS_LIMIT_20MM: [u8; 10] = [0xFA, 0xAF, 0x01, 0x00, 0x08, 0x02, 0x01, 0xD0, 0x07, 0xDD];

fn flash(id: u8) -> Vec<u8> {
    ShortPacket::special(id, SpecialCommand::WriteFlash).encode()
}

fn reboot(id: u8) -> Vec<u8> {
    ShortPacket::special(id, SpecialCommand::Reboot).encode()
}

fn factory_reset(id: u8) -> Vec<u8> {
    ShortPacket::special(id, SpecialCommand::FactoryReset).encode()
}

fn answers(bus: &mut VirtualBus, id: u8) -> bool {
    bus.transact(&request(id, 0x01)) == [0x07]
}

#[test]
fn a_new_id_takes_effect_on_receipt() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.transact(&SET_ID_5);
    assert!(answers(&mut bus, 5));
    assert!(!answers(&mut bus, 1));
}

#[test]
fn a_new_id_is_lost_at_reboot_without_a_flash_write() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.transact(&SET_ID_5);
    bus.transact(&reboot(5));
    bus.wait(Duration::from_millis(100));
    assert!(answers(&mut bus, 1));
    assert!(!answers(&mut bus, 5));
}

#[test]
fn a_new_id_is_lost_at_power_cycle_without_a_flash_write() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.transact(&SET_ID_5);
    bus.model.power_cycle(bus.now, 5);
    bus.wait(Duration::from_millis(100));
    assert!(answers(&mut bus, 1));
}

#[test]
fn a_new_id_survives_reboot_after_a_flash_write() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.transact(&SET_ID_5);
    bus.transact(&flash(5));
    bus.wait(Duration::from_secs(1));
    bus.transact(&reboot(5));
    bus.wait(Duration::from_millis(100));
    assert!(answers(&mut bus, 5));
    assert!(!answers(&mut bus, 1));
    bus.model.power_cycle(bus.now, 5);
    bus.wait(Duration::from_millis(100));
    assert!(answers(&mut bus, 5), "and a power cycle");
}

#[test]
fn the_servo_is_deaf_for_about_a_second_while_writing_flash() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.transact(&flash(1));
    for _ in 0..8 {
        assert!(!answers(&mut bus, 1), "answered during the flash write");
        bus.wait(Duration::from_millis(50));
    }
    bus.wait(Duration::from_millis(500));
    assert!(answers(&mut bus, 1), "still deaf 1 s after the flash write");
    let busy = bus
        .events()
        .into_iter()
        .filter(|event| {
            matches!(
                event,
                BusEvent::Ignored {
                    reason: IgnoreReason::FlashWriteBusy,
                    ..
                }
            )
        })
        .count();
    assert_eq!(busy, 8);
}

#[test]
fn writes_during_the_flash_write_are_ignored() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.transact(&flash(1));
    bus.transact(&write(1, 0x23, &[0x20]));
    bus.wait(Duration::from_secs(1));
    assert_eq!(bus.reply(&read(1, 0x23, 1)).data, [0x64]);
}

#[test]
fn the_flash_write_saves_registers_4_to_29_only() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.transact(&PLUS_LIMIT_20MM);
    bus.transact(&write(1, 0x07, &[0x02]));
    bus.transact(&write(1, 0x23, &[0x30]));
    bus.transact(&flash(1));
    bus.wait(Duration::from_secs(1));
    bus.transact(&reboot(1));
    bus.wait(Duration::from_millis(100));
    assert_eq!(bus.reply(&read(1, 0x08, 2)).i16_at(0x08), Some(2000));
    assert_eq!(bus.reply(&read(1, 0x07, 1)).data, [0x02]);
    assert_eq!(
        bus.reply(&read(1, 0x23, 1)).data,
        [0x64],
        "max force is RAM"
    );
}

#[test]
fn reboot_restores_the_power_on_ram() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.transact(&force(1, 1));
    bus.transact(&goal(1, 500));
    bus.transact(&write(1, 0x20, &[0x10, 0x00]));
    bus.transact(&write(1, 0x23, &[0x30]));
    bus.wait(Duration::from_millis(200));
    bus.transact(&reboot(1));
    bus.wait(Duration::from_millis(100));
    let ram = bus.reply(&request(1, 0x0B));
    assert_eq!(
        &ram.data[..7],
        &[0x00, 0x00, 0x00, 0x00, 0x00, 0x64, 0x00],
        "goal, goal time, max force, force off"
    );
    assert_eq!(ram.data.len(), 12);
}

#[test]
fn the_servo_is_deaf_briefly_while_booting() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.write(&reboot(1));
    bus.wait(Duration::from_millis(5));
    assert!(!answers(&mut bus, 1), "answered while booting");
    bus.wait(Duration::from_millis(100));
    assert!(answers(&mut bus, 1));
}

#[test]
fn factory_reset_restores_the_defaults_and_id_1_even_after_reboot() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.transact(&PLUS_LIMIT_20MM);
    bus.transact(&SET_ID_5);
    bus.transact(&flash(5));
    bus.wait(Duration::from_secs(1));
    bus.transact(&factory_reset(5));
    bus.wait(Duration::from_secs(1));
    assert!(answers(&mut bus, 1));
    assert!(!answers(&mut bus, 5));
    assert_eq!(bus.reply(&read(1, 0x08, 2)).i16_at(0x08), Some(2500));
    bus.transact(&reboot(1));
    bus.wait(Duration::from_millis(100));
    assert!(answers(&mut bus, 1), "the reset reached flash");
}

#[test]
fn a_baud_change_takes_effect_on_receipt_and_is_lost_at_reboot() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.transact(&SET_BAUD_38400);
    assert!(!answers(&mut bus, 1), "the host is still at 115 200");
    assert!(bus.model.stats().baud_mismatches >= 1);
    bus.host_baud = 38_400;
    assert!(answers(&mut bus, 1), "the host followed to 38 400");
    bus.transact(&reboot(1));
    bus.wait(Duration::from_millis(100));
    assert!(!answers(&mut bus, 1), "back at the flashed 115 200");
    bus.host_baud = 115_200;
    assert!(answers(&mut bus, 1));
}

#[test]
fn a_baud_change_survives_reboot_after_a_flash_write() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.transact(&SET_BAUD_38400);
    bus.host_baud = 38_400;
    bus.transact(&flash(1));
    bus.wait(Duration::from_secs(1));
    bus.transact(&reboot(1));
    bus.wait(Duration::from_millis(100));
    assert!(answers(&mut bus, 1));
    assert_eq!(
        bus.model.snapshot(bus.now, 1).expect("servo").baud,
        Some(38_400)
    );
}

#[test]
fn an_ack_requested_with_a_baud_change_reaches_the_host_as_noise() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.transact(&write_reply(1, 0x06, &[0x04], 0x01));
    let reply = bus.events().into_iter().find_map(|event| match event {
        BusEvent::Reply(reply) => Some(reply),
        _ => None,
    });
    let reply = reply.expect("the servo answered");
    assert!(reply.baud_mismatch);
    assert_eq!(
        reply.bytes.len(),
        3,
        "one byte at 38 400 spans three byte times at 115 200"
    );
}

#[test]
fn losing_power_during_a_flash_write_is_damage_and_sets_the_flash_error_flag() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.transact(&SET_ID_5);
    bus.transact(&flash(5));
    bus.model.unplug(bus.now, 5);
    bus.model.plug(bus.now, 5);
    bus.wait(Duration::from_millis(100));
    let reply = bus.status(1);
    assert_eq!(reply.flags & 0x08, 0x08, "flash-write error flag");
    assert!(bus.events().iter().any(|event| matches!(
        event,
        BusEvent::Damage(damage) if damage.kind == DamageKind::PowerLostDuringFlashWrite
    )));
    bus.transact(&flash(1));
    bus.wait(Duration::from_secs(1));
    assert_eq!(
        bus.status(1).flags & 0x08,
        0,
        "a good flash write clears it"
    );
}

//! Short, long, broadcast and special packets (protocol spec 4.1, 4.2), with the spec's test vectors byte
//! for byte.

mod common;

use std::time::Duration;

use common::{VirtualBus, force, goal, read, request, write, write_reply};
use lj9da_sim::{BusEvent, DamageKind, IgnoreReason};

/// Every host packet of spec section 5.
const SPEC_HOST_VECTORS: [&[u8]; 19] = [
    &[0xFA, 0xAF, 0x01, 0x00, 0x1E, 0x02, 0x01, 0x00, 0x00, 0x1C],
    &[0xFA, 0xAF, 0x01, 0x00, 0x1E, 0x02, 0x01, 0x84, 0x03, 0x9B],
    &[0xFA, 0xAF, 0x01, 0x00, 0x1E, 0x02, 0x01, 0x7C, 0xFC, 0x9C],
    &[
        0xFA, 0xAF, 0x01, 0x00, 0x1E, 0x04, 0x01, 0x84, 0x03, 0xF4, 0x01, 0x68,
    ],
    &[0xFA, 0xAF, 0x01, 0x00, 0x24, 0x01, 0x01, 0x01, 0x24],
    &[0xFA, 0xAF, 0x01, 0x00, 0x24, 0x01, 0x01, 0x00, 0x25],
    &[0xFA, 0xAF, 0x01, 0x00, 0x24, 0x01, 0x01, 0x02, 0x27],
    &[0xFA, 0xAF, 0x01, 0x00, 0x23, 0x01, 0x01, 0x50, 0x72],
    &[0xFA, 0xAF, 0x01, 0x00, 0x04, 0x01, 0x01, 0x05, 0x00],
    &[0xFA, 0xAF, 0x01, 0x00, 0x06, 0x01, 0x01, 0x04, 0x03],
    &[0xFA, 0xAF, 0x01, 0x00, 0x07, 0x01, 0x01, 0x01, 0x07],
    &[0xFA, 0xAF, 0x01, 0x00, 0x08, 0x02, 0x01, 0xD0, 0x07, 0xDD],
    &[0xFA, 0xAF, 0x01, 0x00, 0x0A, 0x02, 0x01, 0x30, 0xF8, 0xC0],
    &[0xFA, 0xAF, 0x01, 0x00, 0x1C, 0x02, 0x01, 0x20, 0x01, 0x3F],
    &[
        0xFA, 0xAF, 0x01, 0x00, 0x18, 0x06, 0x01, 0x01, 0x01, 0x10, 0x10, 0x20, 0x01, 0x3F,
    ],
    &[0xFA, 0xAF, 0x01, 0x40, 0xFF, 0x00, 0x00, 0xBE],
    &[0xFA, 0xAF, 0x01, 0x20, 0xFF, 0x00, 0x00, 0xDE],
    &[0xFA, 0xAF, 0x01, 0x10, 0xFF, 0xFF, 0x00, 0x11],
    &[0xFA, 0xAF, 0x01, 0x0F, 0x2A, 0x02, 0x00, 0x26],
];
const LONG_VECTOR: [u8; 17] = [
    0xFA, 0xAF, 0x00, 0x00, 0x1E, 0x03, 0x03, 0x01, 0x64, 0x00, 0x02, 0x64, 0x00, 0x05, 0xF4, 0x01,
    0xED,
];

#[test]
fn every_spec_host_vector_is_a_packet_servo_1_acts_on() {
    for vector in SPEC_HOST_VECTORS {
        // A fresh bus per vector: some change the ID or the baud rate or make the servo busy.
        let mut bus = VirtualBus::with_ids(&[1]);
        bus.write(vector);
        bus.wait(Duration::from_millis(10));
        let packets: Vec<_> = bus
            .events()
            .into_iter()
            .filter_map(|event| match event {
                BusEvent::Packet(packet) => Some(packet),
                _ => None,
            })
            .collect();
        assert_eq!(packets.len(), 1, "{vector:02X?}");
        assert_eq!(packets[0].bytes, vector);
        assert_eq!(packets[0].acted, vec![1], "{vector:02X?}");
        assert_eq!(bus.model.stats().bad_sums, 0);
    }
}

#[test]
fn the_spec_goal_vector_sets_the_goal_register() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.transact(SPEC_HOST_VECTORS[1]);
    assert_eq!(bus.reply(&read(1, 0x1E, 2)).i16_at(0x1E), Some(900));
    bus.transact(SPEC_HOST_VECTORS[2]);
    assert_eq!(bus.reply(&read(1, 0x1E, 2)).i16_at(0x1E), Some(-900));
}

#[test]
fn the_six_byte_compliance_vector_writes_registers_24_to_29() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.transact(SPEC_HOST_VECTORS[14]);
    assert_eq!(
        bus.reply(&read(1, 0x18, 6)).data,
        [0x01, 0x01, 0x10, 0x10, 0x20, 0x01]
    );
}

#[test]
fn a_long_packet_only_affects_the_listed_vids_and_gets_no_reply() {
    let mut bus = VirtualBus::with_ids(&[1, 2, 3, 5]);
    for id in [1, 2, 3, 5] {
        bus.transact(&force(id, 1));
    }
    assert!(
        bus.transact(&LONG_VECTOR).is_empty(),
        "a long packet is never answered"
    );
    let goal_of = |bus: &mut VirtualBus, id| bus.reply(&read(id, 0x1E, 2)).i16_at(0x1E);
    assert_eq!(goal_of(&mut bus, 1), Some(100));
    assert_eq!(goal_of(&mut bus, 2), Some(100));
    assert_eq!(goal_of(&mut bus, 3), Some(0), "ID 3 is not in the packet");
    assert_eq!(goal_of(&mut bus, 5), Some(500));
}

#[test]
fn a_long_packet_event_lists_the_goal_positions() {
    let mut bus = VirtualBus::with_ids(&[1, 2, 5]);
    bus.transact(&LONG_VECTOR);
    let event = bus.events().into_iter().find_map(|event| match event {
        BusEvent::Packet(packet) => Some(packet),
        _ => None,
    });
    let packet = event.expect("packet event");
    assert!(packet.packet.is_long());
    assert_eq!(
        packet.packet.goal_positions(),
        vec![(1, 100), (2, 100), (5, 500)]
    );
    assert_eq!(packet.acted, vec![1, 2, 5]);
}

#[test]
fn a_long_packet_with_goal_and_goal_time_sets_both() {
    let mut bus = VirtualBus::with_ids(&[1, 2]);
    let packet = lj9da_sim::LongPacket::write(
        0x1E,
        &[
            (1, &[0x84, 0x03, 0xF4, 0x01]),
            (2, &[0x7C, 0xFC, 0x64, 0x00]),
        ],
    );
    bus.transact(&packet.encode());
    assert_eq!(bus.reply(&read(1, 0x1E, 4)).data, [0x84, 0x03, 0xF4, 0x01]);
    assert_eq!(bus.reply(&read(2, 0x1E, 4)).data, [0x7C, 0xFC, 0x64, 0x00]);
}

#[test]
fn broadcast_id_255_acts_on_every_servo_and_never_replies() {
    let mut bus = VirtualBus::with_ids(&[1, 2, 3]);
    assert!(
        bus.transact(&write_reply(255, 0x23, &[0x50], 0x01))
            .is_empty(),
        "no ACK to a broadcast"
    );
    assert!(
        bus.transact(&request(255, 0x09)).is_empty(),
        "no status reply to a broadcast"
    );
    for id in [1, 2, 3] {
        assert_eq!(
            bus.reply(&read(id, 0x23, 1)).data,
            [0x50],
            "servo {id} took the max force"
        );
    }
}

#[test]
fn a_packet_with_a_bad_sum_is_ignored() {
    let mut bus = VirtualBus::with_ids(&[1]);
    let mut bad = goal(1, 900);
    *bad.last_mut().expect("sum") ^= 0x01;
    assert!(bus.transact(&bad).is_empty());
    let mut bad_request = request(1, 0x01);
    *bad_request.last_mut().expect("sum") ^= 0x80;
    assert!(
        bus.transact(&bad_request).is_empty(),
        "no ACK to a packet with a bad sum"
    );
    assert_eq!(bus.reply(&read(1, 0x1E, 2)).i16_at(0x1E), Some(0));
    assert_eq!(bus.model.stats().bad_sums, 2);
    assert!(
        bus.events()
            .iter()
            .any(|event| matches!(event, BusEvent::BadSum { .. }))
    );
}

#[test]
fn a_packet_after_garbage_is_still_understood() {
    let mut bus = VirtualBus::with_ids(&[1]);
    let mut bytes = vec![0x00, 0xFA, 0x13, 0xFA, 0xAF, 0x01];
    bytes.extend_from_slice(&request(1, 0x01));
    assert_eq!(bus.transact(&bytes), [0x07]);
    assert!(bus.model.stats().garbage_bytes >= 3);
}

#[test]
fn read_only_and_reserved_registers_ignore_writes() {
    let protected: Vec<u8> = [0, 1, 2, 3, 12, 13, 14, 15]
        .into_iter()
        .chain(16..=23)
        .chain([34])
        .chain(37..=59)
        .collect();
    let mut bus = VirtualBus::with_ids(&[1]);
    let before = [
        bus.reply(&request(1, 0x03)).data,
        bus.reply(&request(1, 0x05)).data,
    ]
    .concat();
    for &register in &protected {
        assert_eq!(
            bus.transact(&write_reply(1, register, &[0xAA], 0x01)),
            [0x07],
            "register {register}"
        );
    }
    let after = [
        bus.reply(&request(1, 0x03)).data,
        bus.reply(&request(1, 0x05)).data,
    ]
    .concat();
    for &register in &protected {
        assert_eq!(
            after[usize::from(register)],
            before[usize::from(register)],
            "register {register} changed"
        );
    }
}

#[test]
fn a_write_spanning_protected_registers_changes_only_the_writable_ones() {
    let mut bus = VirtualBus::with_ids(&[1]);
    // Registers 32–36: goal time (RW), reserved 34, max force 35 (RW), force 36 (RW).
    bus.transact(&write(1, 0x20, &[0x10, 0x00, 0xAA, 0x40, 0x00]));
    assert_eq!(
        bus.reply(&read(1, 0x20, 5)).data,
        [0x10, 0x00, 0x00, 0x40, 0x00]
    );
}

#[test]
fn a_write_with_a_reply_request_is_applied_then_answered() {
    let mut bus = VirtualBus::with_ids(&[1]);
    assert_eq!(bus.transact(&write_reply(1, 0x23, &[0x50], 0x01)), [0x07]);
    let reply = bus.reply(&write_reply(1, 0x20, &[0xF4, 0x01], 0x0B));
    assert_eq!(
        reply.u16_at(0x20),
        Some(500),
        "the reply shows the value just written"
    );
    assert_eq!(reply.data[35 - 30], 0x50);
}

#[test]
fn the_new_id_answers_a_write_that_changes_it() {
    let mut bus = VirtualBus::with_ids(&[1]);
    let reply = bus.reply(&write_reply(1, 0x04, &[0x09], 0x09));
    assert_eq!(reply.id, 9);
}

#[test]
fn a_short_packet_with_count_above_one_is_ignored() {
    let mut bus = VirtualBus::with_ids(&[1]);
    let packet = lj9da_sim::ShortPacket {
        id: 1,
        flag: 0x01,
        address: 0x23,
        length: 1,
        count: 2,
        data: vec![0x50, 0x50],
    };
    assert!(bus.transact(&packet.encode()).is_empty());
    assert_eq!(bus.reply(&read(1, 0x23, 1)).data, [0x64]);
    assert!(bus.events().iter().any(|event| matches!(
        event,
        BusEvent::Ignored {
            reason: IgnoreReason::CountAboveOne,
            ..
        }
    )));
}

#[test]
fn flash_write_and_reboot_in_one_packet_are_refused() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.transact(&write(1, 0x04, &[0x05]));
    let combined = lj9da_sim::ShortPacket {
        id: 5,
        flag: 0x60,
        address: 0xFF,
        length: 0,
        count: 0,
        data: vec![],
    };
    bus.transact(&combined.encode());
    bus.wait(Duration::from_millis(1500));
    assert_eq!(bus.status(5).id, 5, "neither rebooted nor busy");
    assert_eq!(
        bus.model.snapshot(bus.now, 5).expect("servo").flash[0],
        1,
        "nothing flashed"
    );
}

#[test]
fn the_factory_reset_is_also_accepted_with_the_data_byte_of_the_manual_text() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.transact(&write(1, 0x04, &[0x05]));
    let text_form = [
        0xFA,
        0xAF,
        0x05,
        0x10,
        0xFF,
        0xFF,
        0x00,
        0xFF,
        (0x05 ^ 0x10 ^ 0xFF ^ 0xFF) ^ 0xFF,
    ];
    bus.transact(&text_form);
    bus.wait(Duration::from_secs(1));
    assert_eq!(bus.status(1).id, 1);
}

#[test]
fn forbidden_values_are_stored_and_reported_as_damage() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.transact(&write(1, 0x08, &3000i16.to_le_bytes()));
    bus.transact(&write(1, 0x0A, &(-2600i16).to_le_bytes()));
    bus.transact(&write(1, 0x04, &[0x00]));
    let damage: Vec<DamageKind> = bus
        .events()
        .into_iter()
        .filter_map(|event| match event {
            BusEvent::Damage(damage) => Some(damage.kind),
            _ => None,
        })
        .collect();
    assert_eq!(
        damage,
        vec![
            DamageKind::PositionLimitBeyondStroke {
                register: 8,
                value_mm_centi: 3000
            },
            DamageKind::PositionLimitBeyondStroke {
                register: 10,
                value_mm_centi: -2600
            },
            DamageKind::ForbiddenId(0),
        ]
    );
    assert_eq!(bus.model.stats().damage_events, 3);
    let servo = bus.model.snapshot(bus.now, 0).expect("servo now has ID 0");
    assert_eq!(
        &servo.registers[8..12],
        &[0xB8, 0x0B, 0xD8, 0xF5],
        "the values were written"
    );
}

#[test]
fn an_unknown_baud_code_is_damage_and_silences_the_servo() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.transact(&write(1, 0x06, &[0x0B]));
    assert!(bus.events().iter().any(|event| matches!(
        event,
        BusEvent::Damage(damage) if damage.kind == DamageKind::UnknownBaudCode(0x0B)
    )));
    assert!(bus.transact(&request(1, 0x01)).is_empty());
    bus.model.power_cycle(bus.now, 1);
    bus.wait(Duration::from_millis(100));
    assert_eq!(
        bus.transact(&request(1, 0x01)),
        [0x07],
        "the flashed rate is back after a power cycle"
    );
}

#[test]
fn a_healthy_session_causes_no_damage() {
    let mut bus = VirtualBus::with_ids(&[1, 2]);
    for vector in [
        &LONG_VECTOR[..],
        SPEC_HOST_VECTORS[4],
        SPEC_HOST_VECTORS[11],
        SPEC_HOST_VECTORS[12],
    ] {
        bus.transact(vector);
    }
    assert_eq!(bus.model.stats().damage_events, 0);
}

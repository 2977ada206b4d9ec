//! The memory map and every reply code (protocol spec 4.1, 4.3, 6), driven with raw packets in virtual time.

mod common;

use common::{VirtualBus, read, request};
use lj9da_sim::{BusEvent, IgnoreReason};

/// Spec section 5: "read 2 bytes at 2Ah".
const READ_2_AT_2A: [u8; 8] = [0xFA, 0xAF, 0x01, 0x0F, 0x2A, 0x02, 0x00, 0x26];
/// Spec section 5: "read registers 42–59".
const READ_42_59: [u8; 8] = [0xFA, 0xAF, 0x01, 0x09, 0x00, 0x00, 0x01, 0x09];

#[test]
fn reply_code_0011_returns_registers_0_to_29_with_the_factory_defaults() {
    let mut bus = VirtualBus::with_ids(&[1]);
    let reply = bus.reply(&request(1, 0x03));
    assert_eq!(
        (reply.id, reply.address, reply.count, reply.data.len()),
        (1, 0x00, 1, 30)
    );
    let expected: [u8; 30] = [
        0x10, 0x75, 0x01, 0x00, // model 7510h, firmware 01h, reserved
        0x01, 0x00, 0x07, 0x00, // ID 1, reverse 0, 115 200 bit/s, return delay 0
        0xC4, 0x09, 0x3C, 0xF6, // limits +25.00 / −25.00 mm
        0x00, 0x00, 0x55, 0x00, // reserved, temperature limit 85 °C
        0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, // reserved
        0x08, 0x08, 0x00, 0x00, 0xC4, 0x09, // margins, slopes, punch
    ];
    assert_eq!(reply.data, expected);
}

#[test]
fn reply_code_0101_returns_registers_30_to_59_with_the_power_on_values() {
    let mut bus = VirtualBus::with_ids(&[1]);
    let reply = bus.reply(&request(1, 0x05));
    assert_eq!((reply.address, reply.data.len()), (0x1E, 30));
    assert_eq!(
        &reply.data[0..4],
        &[0, 0, 0, 0],
        "goal position and goal time 0"
    );
    assert_eq!(reply.data[35 - 30], 0x64, "max force 100 %");
    assert_eq!(reply.data[36 - 30], 0x00, "force off at power-up");
    assert_eq!(
        &reply.data[37 - 30..42 - 30],
        &[0x01, 0x64, 0x00, 0x00, 0x00]
    );
    assert_eq!(reply.u16_at(48), Some(7), "70 mA standing");
    assert_eq!(reply.u16_at(50), Some(25), "ambient 25 °C");
    assert_eq!(reply.u16_at(52), Some(1200), "12.00 V");
    assert_eq!(&reply.data[54 - 30..59 - 30], &[0; 5]);
    assert_eq!(reply.data[59 - 30], 0xFF);
}

#[test]
fn reply_code_0111_returns_registers_20_to_29() {
    let mut bus = VirtualBus::with_ids(&[1]);
    let reply = bus.reply(&request(1, 0x07));
    assert_eq!((reply.address, reply.data.len()), (0x14, 10));
    assert_eq!(reply.data, [0, 0, 0, 0, 0x08, 0x08, 0x00, 0x00, 0xC4, 0x09]);
}

#[test]
fn reply_code_1001_returns_registers_42_to_59_in_26_bytes() {
    let mut bus = VirtualBus::with_ids(&[1]);
    let answer = bus.transact(&READ_42_59);
    assert_eq!(answer.len(), 26);
    assert_eq!(&answer[..7], &[0xFD, 0xDF, 0x01, 0x00, 0x2A, 0x12, 0x01]);
    let reply = bus.reply(&READ_42_59);
    assert_eq!(reply.i16_at(42), Some(0));
    assert_eq!(reply.u16_at(52), Some(1200));
}

#[test]
fn reply_code_1011_returns_registers_30_to_41() {
    let mut bus = VirtualBus::with_ids(&[1]);
    let reply = bus.reply(&request(1, 0x0B));
    assert_eq!((reply.address, reply.data.len()), (0x1E, 12));
    assert_eq!(
        &reply.data[5..],
        &[0x64, 0x00, 0x01, 0x64, 0x00, 0x00, 0x00]
    );
}

#[test]
fn reply_code_1111_returns_length_bytes_from_address() {
    let mut bus = VirtualBus::with_ids(&[1]);
    let reply = bus.reply(&READ_2_AT_2A);
    assert_eq!((reply.address, reply.data.len()), (0x2A, 2));
    let model = bus.reply(&read(1, 0x00, 3));
    assert_eq!(
        model.data,
        [0x10, 0x75, 0x01],
        "model number 7510h little-endian, firmware 01h"
    );
    let last = bus.reply(&read(1, 0x3B, 1));
    assert_eq!(last.data, [0xFF]);
}

#[test]
fn reply_code_1111_beyond_register_59_gets_no_reply() {
    let mut bus = VirtualBus::with_ids(&[1]);
    assert!(bus.transact(&read(1, 0x3A, 3)).is_empty());
    assert!(bus.transact(&read(1, 0x00, 0)).is_empty());
    let ignored = bus.events().into_iter().any(|event| {
        matches!(
            event,
            BusEvent::Ignored {
                reason: IgnoreReason::ReadOutOfMap {
                    address: 0x3A,
                    length: 3
                },
                ..
            }
        )
    });
    assert!(ignored);
}

#[test]
fn ack_is_the_single_raw_byte_07() {
    let mut bus = VirtualBus::with_ids(&[1]);
    assert_eq!(bus.transact(&request(1, 0x01)), [0x07]);
}

#[test]
fn reply_codes_outside_the_table_get_no_reply() {
    let mut bus = VirtualBus::with_ids(&[1]);
    for code in [0x02, 0x04, 0x06, 0x08, 0x0A, 0x0C, 0x0D, 0x0E] {
        assert!(
            bus.transact(&request(1, code)).is_empty(),
            "code {code:04b}"
        );
    }
}

#[test]
fn reply_code_0000_gets_no_reply() {
    let mut bus = VirtualBus::with_ids(&[1]);
    assert!(bus.transact(&request(1, 0x00)).is_empty());
}

#[test]
fn return_flags_are_clear_on_a_healthy_servo() {
    let mut bus = VirtualBus::with_ids(&[1]);
    assert_eq!(bus.status(1).flags, 0);
}

#[test]
fn each_servo_answers_with_its_own_id() {
    let mut bus = VirtualBus::with_ids(&[3, 7]);
    assert_eq!(bus.status(3).id, 3);
    assert_eq!(bus.status(7).id, 7);
    assert!(bus.transact(&request(1, 0x09)).is_empty());
}

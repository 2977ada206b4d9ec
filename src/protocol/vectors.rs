//! Every test vector of the protocol reference, section 5, byte for byte.

use super::packet::ExpectedReply;
use super::*;

fn hex(s: &str) -> Vec<u8> {
    s.split_whitespace()
        .map(|b| u8::from_str_radix(b, 16).expect("test vector is hex"))
        .collect()
}

fn one() -> Destination {
    Destination::Servo(ServoId::new(1).unwrap())
}

fn id(n: u8) -> ServoId {
    ServoId::new(n).unwrap()
}

#[test]
fn goal_position_0_mm() {
    let p = ShortPacket::goal_position(one(), MmCenti(0)).unwrap();
    assert_eq!(p.to_bytes(), hex("FA AF 01 00 1E 02 01 00 00 1C"));
}

#[test]
fn goal_position_plus_9_mm() {
    let p = ShortPacket::goal_position(one(), MmCenti::from_mm(9.0).unwrap()).unwrap();
    assert_eq!(p.to_bytes(), hex("FA AF 01 00 1E 02 01 84 03 9B"));
}

#[test]
fn goal_position_minus_9_mm() {
    let p = ShortPacket::goal_position(one(), MmCenti::from_mm(-9.0).unwrap()).unwrap();
    assert_eq!(p.to_bytes(), hex("FA AF 01 00 1E 02 01 7C FC 9C"));
}

#[test]
fn goal_plus_9_mm_in_5_s() {
    let p =
        ShortPacket::goal_position_with_time(one(), MmCenti(900), Ms10::from_millis(5000)).unwrap();
    assert_eq!(p.to_bytes(), hex("FA AF 01 00 1E 04 01 84 03 F4 01 68"));
}

#[test]
fn force_on_off_brake() {
    assert_eq!(
        ShortPacket::force(one(), ForceMode::On).to_bytes(),
        hex("FA AF 01 00 24 01 01 01 24")
    );
    assert_eq!(
        ShortPacket::force(one(), ForceMode::Off).to_bytes(),
        hex("FA AF 01 00 24 01 01 00 25")
    );
    assert_eq!(
        ShortPacket::force(one(), ForceMode::Brake).to_bytes(),
        hex("FA AF 01 00 24 01 01 02 27")
    );
}

#[test]
fn max_force_80_percent() {
    let p = ShortPacket::max_force(one(), Percent::new(80).unwrap());
    assert_eq!(p.to_bytes(), hex("FA AF 01 00 23 01 01 50 72"));
}

#[test]
fn set_id_1_to_5() {
    assert_eq!(
        ShortPacket::set_id(id(1), id(5)).to_bytes(),
        hex("FA AF 01 00 04 01 01 05 00")
    );
}

#[test]
fn baud_38400() {
    let p = ShortPacket::baud_rate(one(), BaudRate::from_bits_per_second(38_400).unwrap());
    assert_eq!(p.to_bytes(), hex("FA AF 01 00 06 01 01 04 03"));
}

#[test]
fn return_delay_1_ms() {
    assert_eq!(
        ShortPacket::return_delay(one(), 1).to_bytes(),
        hex("FA AF 01 00 07 01 01 01 07")
    );
}

#[test]
fn plus_limit_20_mm() {
    let p = ShortPacket::plus_limit(one(), MmCenti(2000)).unwrap();
    assert_eq!(p.to_bytes(), hex("FA AF 01 00 08 02 01 D0 07 DD"));
}

#[test]
fn minus_limit_minus_20_mm() {
    let p = ShortPacket::minus_limit(one(), MmCenti(-2000)).unwrap();
    assert_eq!(p.to_bytes(), hex("FA AF 01 00 0A 02 01 30 F8 C0"));
}

#[test]
fn punch_0120h() {
    let p = ShortPacket::punch(one(), Punch::new(0x0120).unwrap());
    assert_eq!(p.to_bytes(), hex("FA AF 01 00 1C 02 01 20 01 3F"));
}

#[test]
fn margins_slopes_and_punch_in_one_write() {
    let p = ShortPacket::write(
        one(),
        0x18,
        &[0x01, 0x01, 0x10, 0x10, 0x20, 0x01],
        ReplyRequest::None,
    )
    .unwrap();
    assert_eq!(
        p.to_bytes(),
        hex("FA AF 01 00 18 06 01 01 01 10 10 20 01 3F")
    );
}

#[test]
fn write_flash() {
    assert_eq!(
        ShortPacket::write_flash(one()).to_bytes(),
        hex("FA AF 01 40 FF 00 00 BE")
    );
}

#[test]
fn reboot() {
    assert_eq!(
        ShortPacket::reboot(one()).to_bytes(),
        hex("FA AF 01 20 FF 00 00 DE")
    );
}

#[test]
fn factory_reset_in_the_examples_form_without_data() {
    assert_eq!(
        ShortPacket::factory_reset(one()).to_bytes(),
        hex("FA AF 01 10 FF FF 00 11")
    );
}

#[test]
fn read_2_bytes_at_2ah() {
    let p = ShortPacket::read(id(1), 0x2A, 2).unwrap();
    assert_eq!(p.to_bytes(), hex("FA AF 01 0F 2A 02 00 26"));
    assert_eq!(
        p.expected_reply(),
        ExpectedReply::Registers {
            address: 0x2A,
            length: 2
        }
    );
}

#[test]
fn request_registers_42_to_59() {
    let p = ShortPacket::request(id(1), ReplyRequest::Registers42To59);
    assert_eq!(p.to_bytes(), hex("FA AF 01 09 00 00 01 09"));
    assert_eq!(
        p.expected_reply(),
        ExpectedReply::Registers {
            address: 42,
            length: 18
        }
    );
    assert_eq!(p.expected_reply().wire_len(), 26);
}

#[test]
fn long_packet_ids_1_2_to_1_mm_and_5_to_5_mm() {
    let goals = [
        GoalEntry {
            id: id(1),
            position: MmCenti(100),
            time: None,
        },
        GoalEntry {
            id: id(2),
            position: MmCenti(100),
            time: None,
        },
        GoalEntry {
            id: id(5),
            position: MmCenti(500),
            time: None,
        },
    ];
    let p = LongPacket::goals(&goals).unwrap();
    let expected = hex("FA AF 00 00 1E 03 03 01 64 00 02 64 00 05 F4 01 ED");
    assert_eq!(p.to_bytes(), expected);
    assert_eq!(p.wire_len(), 8 + 3 * 3);
}

#[test]
fn reply_42_to_59_decodes_to_the_documented_values() {
    let bytes =
        hex("FD DF 01 00 2A 12 01 4E FB 00 00 00 00 06 00 2D 00 56 04 00 00 00 00 00 00 F4");
    let mut d = Decoder::new();
    d.push(&bytes);
    let Some(Ok(Decoded::Reply(reply))) = d.poll() else {
        panic!("the spec's reply vector must decode");
    };
    assert_eq!(reply.id, 1);
    assert_eq!(reply.to_bytes(), bytes, "re-encoding gives the same bytes");
    let t = reply.telemetry().unwrap();
    assert_eq!(t.present_position, MmCenti(-1202));
    assert_eq!(t.present_load, Ma10(6));
    assert_eq!(t.present_load.to_string(), "60 mA");
    assert_eq!(t.present_temperature, Celsius(45));
    assert_eq!(t.present_voltage, Mv10(1110));
    assert!((t.present_voltage.volts() - 11.10).abs() < 1e-9);
    assert_eq!(d.poll(), None);
}

#[test]
fn broadcast_uses_id_255_and_expects_no_reply() {
    let p = ShortPacket::write(Destination::Broadcast, 0x24, &[1], ReplyRequest::Ack).unwrap();
    assert_eq!(p.to_bytes()[2], 0xFF);
    assert_eq!(p.expected_reply(), ExpectedReply::Nothing);
}

#[test]
fn every_request_only_reply_code_is_encoded() {
    for (reply, flag, span) in [
        (ReplyRequest::Ack, 0x01, None),
        (ReplyRequest::Registers0To29, 0x03, Some((0, 30))),
        (ReplyRequest::Registers30To59, 0x05, Some((30, 30))),
        (ReplyRequest::Registers20To29, 0x07, Some((20, 10))),
        (ReplyRequest::Registers42To59, 0x09, Some((42, 18))),
        (ReplyRequest::Registers30To41, 0x0B, Some((30, 12))),
    ] {
        let bytes = ShortPacket::request(id(3), reply).to_bytes();
        assert_eq!(&bytes[..7], &[0xFA, 0xAF, 3, flag, 0, 0, 1]);
        assert_eq!(bytes[7], 3 ^ flag ^ 1);
        assert_eq!(reply.register_span(), span);
    }
    assert_eq!(
        ShortPacket::request(id(3), ReplyRequest::Ack).expected_reply(),
        ExpectedReply::Ack
    );
}

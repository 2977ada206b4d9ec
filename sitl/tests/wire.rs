//! The line in virtual time: wire time of host bytes and replies, the return delay, half-duplex collisions,
//! duplicate IDs, bit-rate mismatches, event timestamps.

mod common;

use std::time::Duration;

use common::{VirtualBus, request, write};
use lj9da_sim::bus::byte_time;
use lj9da_sim::{BusEvent, SimConfig};

const RETURN_DELAY_1MS: [u8; 9] = [0xFA, 0xAF, 0x01, 0x00, 0x07, 0x01, 0x01, 0x01, 0x07];

#[test]
fn a_reply_leaves_after_the_request_latency_and_takes_its_wire_time() {
    let mut bus = VirtualBus::with_ids(&[1]);
    let byte = byte_time(115_200);
    let sent_at = bus.now;
    bus.write(&request(1, 0x09));
    let reply = bus.wait(Duration::from_millis(20));
    assert_eq!(reply.len(), 26);
    let reply_start = sent_at + byte * 8 + Duration::from_micros(150);
    for (index, tx) in reply.iter().enumerate() {
        let index = u32::try_from(index).expect("index");
        assert_eq!(tx.at, reply_start + byte * (index + 1), "byte {index}");
    }
    assert!(reply[25].at - reply[0].at >= Duration::from_micros(2_170));
}

#[test]
fn the_end_of_a_reply_is_announced_once_only_its_last_byte_is_queued() {
    let mut bus = VirtualBus::with_ids(&[1]);
    let byte = byte_time(115_200);
    let sent_at = bus.now;
    bus.write(&request(1, 0x09));
    assert_eq!(
        bus.model.transmission_ends_at(),
        None,
        "request still arriving"
    );
    let last_at = sent_at + byte * 8 + Duration::from_micros(150) + byte * 26;
    let halfway = bus.wait(last_at - sent_at - byte * 13);
    assert_eq!(halfway.len(), 13);
    assert_eq!(
        bus.model.transmission_ends_at(),
        None,
        "13 bytes still queued"
    );
    // Step to just before the last byte: 25 bytes handed over, one queued.
    let early = bus.wait(byte * 13 - Duration::from_nanos(1));
    assert_eq!(halfway.len() + early.len(), 25);
    assert_eq!(bus.model.transmission_ends_at(), Some(last_at));
    let last = bus.wait(Duration::from_nanos(1));
    assert_eq!(last.len(), 1);
    assert_eq!(bus.model.transmission_ends_at(), None, "nothing queued");
}

/// A real-time runtime following `next_wake` hands a reply over in two pieces: the first byte at
/// its instant, the rest at the last byte's instant; no byte is ever handed before it is complete.
#[test]
fn a_runtime_wakes_for_the_first_and_the_last_byte_of_a_reply_only() {
    let mut bus = VirtualBus::with_ids(&[1]);
    let byte = byte_time(115_200);
    let sent_at = bus.now;
    bus.write(&request(1, 0x09));
    let first_at = sent_at + byte * 8 + Duration::from_micros(150) + byte;
    let last_at = first_at + byte * 25;
    let mut wakes = Vec::new();
    let mut handed = Vec::new();
    while let Some(at) = bus.model.next_wake() {
        assert!(wakes.len() < 10, "{wakes:?}");
        let ends_reply = bus.model.reply_end_due();
        bus.model.advance(at);
        let bytes = bus.model.poll_transmit(at);
        if !bytes.is_empty() {
            assert!(bytes.iter().all(|tx| tx.at <= at));
            wakes.push((at, bytes.len(), ends_reply));
            handed.extend(bytes);
        }
    }
    assert_eq!(
        wakes,
        vec![(first_at, 1, None), (last_at, 25, Some(last_at))],
        "the first byte at its instant, the other 25 together at the end"
    );
    assert_eq!(handed.len(), 26);
    assert_eq!(bus.model.reply_end_due(), None, "nothing queued");
}

#[test]
fn the_return_delay_time_postpones_the_reply() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.transact(&RETURN_DELAY_1MS);
    let sent_at = bus.now;
    bus.write(&request(1, 0x01));
    let ack = bus.wait(Duration::from_millis(20));
    let expected =
        sent_at + byte_time(115_200) * 9 + Duration::from_millis(1) + Duration::from_micros(150);
    assert_eq!(ack.len(), 1);
    assert_eq!(ack[0].at, expected);
}

#[test]
fn host_bytes_written_faster_than_the_wire_arrive_at_wire_speed() {
    let mut bus = VirtualBus::with_ids(&[1]);
    let sent_at = bus.now;
    let mut two = write(1, 0x23, &[0x20]);
    two.extend(write(1, 0x23, &[0x30]));
    bus.write(&two);
    bus.wait(Duration::from_millis(20));
    let byte = byte_time(115_200);
    let packets: Vec<_> = bus
        .events()
        .into_iter()
        .filter_map(|event| match event {
            BusEvent::Packet(packet) => Some(packet),
            _ => None,
        })
        .collect();
    assert_eq!(packets.len(), 2);
    assert_eq!(packets[0].completed_at, sent_at + byte * 9);
    assert_eq!(
        packets[1].completed_at,
        sent_at + byte * 18,
        "queued behind the first on the wire"
    );
    assert_eq!(packets[0].first_byte_at, sent_at);
    assert_eq!(packets[1].first_byte_at, sent_at, "both came in one read()");
}

#[test]
fn a_packet_completes_only_when_its_last_byte_has_arrived() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.write(&write(1, 0x23, &[0x20]));
    // 9 bytes take 781 µs: at 700 µs the servo has not seen the packet yet.
    bus.wait(Duration::from_micros(700));
    assert_eq!(
        bus.model.snapshot(bus.now, 1).expect("servo").registers[0x23],
        0x64
    );
    bus.wait(Duration::from_micros(100));
    assert_eq!(
        bus.model.snapshot(bus.now, 1).expect("servo").registers[0x23],
        0x20
    );
}

#[test]
fn talking_over_a_reply_is_a_collision() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.write(&request(1, 0x09));
    // Halfway through the 26-byte reply the host sends another request.
    let mut answer: Vec<u8> = bus
        .wait(Duration::from_micros(694 + 150 + 1_000))
        .iter()
        .map(|tx| tx.byte)
        .collect();
    bus.write(&request(1, 0x01));
    answer.extend(bus.wait(Duration::from_millis(20)).iter().map(|tx| tx.byte));
    assert_eq!(
        answer.len(),
        26,
        "no ACK: the request sent over the reply was not understood"
    );
    assert!(
        lj9da_sim::ReturnPacket::parse(&answer).is_none(),
        "the reply was garbled"
    );
    assert_eq!(bus.model.stats().collisions, 1);
    let events = bus.events();
    assert!(
        events
            .iter()
            .any(|event| matches!(event, BusEvent::Collision { id: 1, .. }))
    );
    assert!(events.iter().any(|event| matches!(event, BusEvent::Packet(packet) if packet.collided && packet.acted.is_empty())));
}

#[test]
fn a_request_sent_right_behind_another_talks_over_its_reply() {
    let mut bus = VirtualBus::with_ids(&[1]);
    let mut two = request(1, 0x01);
    two.extend(request(1, 0x01));
    bus.write(&two);
    let answer: Vec<u8> = bus
        .wait(Duration::from_millis(20))
        .iter()
        .map(|tx| tx.byte)
        .collect();
    // The first ACK starts 150 µs after the first request, while the second request is still on the line.
    assert_eq!(answer.len(), 1);
    assert_ne!(answer, [0x07]);
    assert_eq!(bus.model.stats().collisions, 1);
}

#[test]
fn waiting_for_the_reply_avoids_collisions() {
    let mut bus = VirtualBus::with_ids(&[1, 2]);
    for _ in 0..20 {
        bus.reply(&request(1, 0x09));
        bus.reply(&request(2, 0x09));
    }
    assert_eq!(bus.model.stats().collisions, 0);
}

#[test]
fn two_servos_with_the_same_id_collide() {
    let mut bus = VirtualBus::with_ids(&[1, 1]);
    let answer = bus.transact(&request(1, 0x09));
    assert_eq!(answer.len(), 26, "one reply's worth of bytes");
    assert!(lj9da_sim::ReturnPacket::parse(&answer).is_none());
    assert_eq!(bus.model.stats().collisions, 1);
    bus.model.unplug(bus.now, 1);
    assert!(
        lj9da_sim::ReturnPacket::parse(&bus.transact(&request(1, 0x09))).is_some(),
        "one left: clean"
    );
}

#[test]
fn a_servo_ignores_packets_sent_at_another_bit_rate() {
    let mut bus = VirtualBus::new(SimConfig {
        baud: 57_600,
        ..SimConfig::default()
    });
    bus.host_baud = 115_200;
    assert!(bus.transact(&write(1, 0x23, &[0x20])).is_empty());
    assert!(bus.transact(&request(1, 0x01)).is_empty());
    assert_eq!(bus.model.stats().baud_mismatches, 2);
    bus.host_baud = 57_600;
    assert_eq!(bus.transact(&request(1, 0x01)), [0x07]);
    assert_eq!(
        bus.reply(&common::read(1, 0x23, 1)).data,
        [0x64],
        "the write at the wrong rate was noise"
    );
}

#[test]
fn the_wire_time_follows_the_bit_rate() {
    let mut bus = VirtualBus::new(SimConfig {
        baud: 9_600,
        ..SimConfig::default()
    });
    let sent_at = bus.now;
    bus.write(&request(1, 0x09));
    let reply = bus.wait(Duration::from_millis(100));
    assert_eq!(reply.len(), 26);
    let byte = byte_time(9_600);
    assert_eq!(
        reply[25].at,
        sent_at + byte * 34 + Duration::from_micros(150)
    );
}

#[test]
fn servos_at_different_rates_share_the_line() {
    let mut bus = VirtualBus::with_ids(&[1, 2]);
    bus.transact(&write(2, 0x06, &[0x05]));
    assert_eq!(bus.transact(&request(1, 0x01)), [0x07]);
    assert!(bus.transact(&request(2, 0x01)).is_empty());
    bus.host_baud = 57_600;
    assert_eq!(bus.transact(&request(2, 0x01)), [0x07]);
    assert!(bus.transact(&request(1, 0x01)).is_empty());
}

#[test]
fn a_partial_packet_is_abandoned_after_a_silence() {
    let mut bus = VirtualBus::with_ids(&[1]);
    // A host died after the head of a 60-byte write.
    bus.write(&[0xFA, 0xAF, 0x01, 0x00, 0x00, 0x3C, 0x01]);
    bus.wait(Duration::from_millis(30));
    assert_eq!(
        bus.transact(&request(1, 0x01)),
        [0x07],
        "the next host's request is understood"
    );
    assert!(bus.model.stats().garbage_bytes >= 1);
}

#[test]
fn without_a_silence_a_bogus_head_delays_but_does_not_lose_the_packet() {
    let mut bus = VirtualBus::with_ids(&[1]);
    let mut bytes = vec![0xFA, 0xAF, 0x01, 0x00, 0x00, 0x04, 0x01];
    bytes.extend(request(1, 0x01));
    assert_eq!(bus.transact(&bytes), [0x07]);
    assert_eq!(bus.model.stats().bad_sums, 1);
}

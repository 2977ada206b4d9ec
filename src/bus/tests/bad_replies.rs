//! What the decoder makes of bytes that are not the awaited reply: echoes of the request and
//! garbage on the line are skipped; a reply with a bad sum, or garbled in its length, frees
//! the bus once as many bytes as a reply have come and counts as a timeout; one garbled in its
//! header, a few byte times after them (never under the tail of a reply that noise came
//! before, nor of one begun); a garbled reply from another servo or of another length, and a
//! clean reply from another servo, leave the request waiting.

use super::*;
use crate::bus::master::QUIET_AFTER_GARBLED_BYTES;

#[test]
fn echoes_and_garbage_on_the_line_are_skipped() {
    let mut rig = Rig::with_ids(&[1, 2]);
    rig.echo = true;
    rig.noise = vec![0x00, 0xFF, 0x07, 0xFD, 0x11, 0xFA, 0x12, 0x34];
    rig.run(ms(100));
    rig.set_goal(1, Goal::Position(MmCenti(100)));
    rig.set_goal(2, Goal::Position(MmCenti(-100)));
    rig.run(ms(3000));
    assert_eq!(rig.health(1), Health::Online);
    assert_eq!(rig.health(2), Health::Online);
    assert_eq!(rig.servo(1).position, 100);
    assert_eq!(rig.servo(2).position, -100);
    let c = rig.m.counters();
    assert_eq!(c.timeouts, 0);
    assert_eq!(
        c.echoes,
        rig.log.len() as u64,
        "every packet's echo skipped"
    );
    assert!(c.garbage_bytes >= 8 * (c.telemetry_replies), "{c:?}");
}

/// The bytes of servo `id`'s reply to a read of `length` registers from register 0 (the
/// identity read is 30), with its sum spoiled when `garbled`.
fn registers_reply(id: u8, length: usize, garbled: bool) -> Vec<u8> {
    let mut reply = ReturnPacket {
        id,
        flags: ReplyFlags(0),
        address: 0,
        data: vec![0; length],
    }
    .to_bytes();
    if garbled {
        let last = reply.len() - 1;
        reply[last] ^= 0x55;
    }
    reply
}

#[test]
fn a_corrupted_reply_is_counted_and_times_out() {
    let mut rig = Rig::with_ids(&[1]);
    let t0 = rig.t0;
    let _ = rig.m.poll_transmit(t0).unwrap();
    let reply = registers_reply(1, 30, true);
    // Its first half leaves the request waiting; the whole garbled reply ends it at once:
    // the servo has stopped talking, so the bus is free as after a clean reply.
    let (a, b) = reply.split_at(reply.len() / 2);
    rig.m.handle_input(a, t0 + ms(3));
    assert!(rig.m.reply_pending());
    rig.m.handle_input(b, t0 + ms(4));
    assert!(!rig.m.reply_pending());
    assert_eq!(rig.m.counters().bad_sums, 1);
    assert_eq!(rig.m.counters().timeouts, 1);
    assert!(
        rig.m.poll_transmit(t0 + ms(4)).is_some(),
        "the next request"
    );
}

#[test]
fn a_reply_garbled_in_its_length_frees_the_bus_once_as_many_bytes_as_a_reply_came() {
    let mut rig = Rig::with_ids(&[1]);
    let t0 = rig.t0;
    let _ = rig.m.poll_transmit(t0).unwrap();
    let mut reply = registers_reply(1, 30, false);
    // Length 30 read as 31: the decoder waits for one byte more than the servo sends.
    reply[5] = 31;
    let complete_at = rig.m.reply_complete_at().unwrap();
    let (a, b) = reply.split_at(reply.len() - 1);
    rig.m.handle_input(a, complete_at);
    assert!(
        rig.m.reply_pending(),
        "a byte of the reply is still to come"
    );
    rig.m.handle_input(b, complete_at);
    assert!(
        !rig.m.reply_pending(),
        "the servo has sent a whole reply's bytes"
    );
    assert_eq!(rig.m.counters().timeouts, 1);
    assert!(
        rig.m.poll_transmit(complete_at).is_some(),
        "the next request"
    );
}

#[test]
fn a_garbled_reply_from_another_servo_or_of_another_length_keeps_the_request_waiting() {
    let mut rig = Rig::with_ids(&[1, 2]);
    let t0 = rig.t0;
    let _ = rig.m.poll_transmit(t0).unwrap();
    rig.m
        .handle_input(&registers_reply(2, 30, true), t0 + ms(3));
    rig.m
        .handle_input(&registers_reply(1, 12, true), t0 + ms(3));
    assert!(rig.m.reply_pending(), "the awaited reply may still come");
    assert_eq!(rig.m.counters().bad_sums, 2);
    let deadline = rig.m.poll_timeout().unwrap();
    rig.m.handle_timeout(deadline);
    assert!(!rig.m.reply_pending());
    assert_eq!(rig.m.counters().timeouts, 1);
}

#[test]
fn a_reply_from_another_servo_is_not_taken_for_the_one_awaited() {
    let mut rig = Rig::with_ids(&[1]);
    let t0 = rig.t0;
    let _ = rig.m.poll_transmit(t0).unwrap();
    let mut other = FakeServo::new(7);
    let reply = other.handle(&[0xFA, 0xAF, 7, 0x03, 0, 0, 1, 0x05]).unwrap();
    rig.m.handle_input(&reply, t0 + ms(4));
    assert!(rig.m.reply_pending());
    assert_eq!(rig.m.counters().unexpected_replies, 1);
}

/// Servo 1's identity read on the wire, and the bytes of its reply with the header spoiled
/// (every byte is skipped as garbage).
fn identity_read_answered_with_a_garbled_header() -> (Rig, Vec<u8>) {
    let mut rig = Rig::with_ids(&[1]);
    let t0 = rig.t0;
    let _ = rig.m.poll_transmit(t0).unwrap();
    let mut reply = registers_reply(1, 30, false);
    reply[0] ^= 0x0F;
    (rig, reply)
}

#[test]
fn a_reply_garbled_in_its_header_frees_the_bus_a_few_byte_times_after_its_end() {
    let (mut rig, reply) = identity_read_answered_with_a_garbled_header();
    let complete_at = rig.m.reply_complete_at().unwrap();
    let allowance_ends = rig.m.poll_timeout().unwrap();
    rig.m.handle_input(&reply, complete_at);
    assert!(rig.m.reply_pending(), "the line is not yet known quiet");
    let frees = complete_at + rig.wire(QUIET_AFTER_GARBLED_BYTES) + rig.m.reply_lateness();
    assert_eq!(rig.m.poll_timeout(), Some(frees));
    assert!(frees < allowance_ends);
    rig.m.handle_timeout(frees);
    assert!(!rig.m.reply_pending());
    assert_eq!(rig.m.counters().timeouts, 1);
    assert!(rig.m.poll_transmit(frees).is_some(), "the next request");
}

#[test]
fn noise_before_a_reply_garbled_in_its_header_never_frees_the_bus_under_its_tail() {
    let (mut rig, reply) = identity_read_answered_with_a_garbled_header();
    let complete_at = rig.m.reply_complete_at().unwrap();
    // A byte of noise as the transceivers turn round, then the reply but its last byte: as
    // many bytes as a reply, read when the last one is still on the wire.
    rig.m
        .handle_input(&[0x00], complete_at - rig.wire(reply.len()));
    let (most, last) = reply.split_at(reply.len() - 1);
    rig.m.handle_input(most, complete_at);
    let tail_ends = complete_at + rig.wire(1);
    assert!(
        rig.m.poll_timeout().is_some_and(|t| t >= tail_ends),
        "the bus is held while the tail is on the wire"
    );
    // The tail comes: the bus is free a few byte times after it.
    rig.m.handle_input(last, tail_ends);
    assert!(rig.m.reply_pending());
    let frees = tail_ends + rig.wire(QUIET_AFTER_GARBLED_BYTES) + rig.m.reply_lateness();
    assert_eq!(rig.m.poll_timeout(), Some(frees));
    rig.m.handle_timeout(frees);
    assert!(!rig.m.reply_pending());
}

#[test]
fn bytes_read_before_the_request_left_the_wire_are_not_taken_for_the_reply() {
    let mut rig = Rig::with_ids(&[1]);
    rig.echo = false;
    let t0 = rig.t0;
    let request = rig.m.poll_transmit(t0).unwrap();
    let allowance_ends = rig.m.poll_timeout().unwrap();
    let complete_at = rig.m.reply_complete_at().unwrap();
    // A garbled echo of the request, read while the request was still on the wire, and a
    // reply's length of noise after it: too few bytes after the request to be a whole reply.
    let garbled_echo = vec![0x55; request.bytes.len()];
    rig.m.handle_input(&garbled_echo, t0);
    let mut reply = registers_reply(1, 30, false);
    reply[0] ^= 0x0F;
    let (most, _) = reply.split_at(reply.len() - request.bytes.len());
    rig.m.handle_input(most, complete_at);
    assert_eq!(
        rig.m.poll_timeout(),
        Some(allowance_ends),
        "the reply's bytes have not all come"
    );
}

#[test]
fn noise_before_a_clean_reply_that_comes_in_two_reads_leaves_the_reply_its_time() {
    let mut rig = Rig::with_ids(&[1]);
    let t0 = rig.t0;
    let _ = rig.m.poll_transmit(t0).unwrap();
    let reply = registers_reply(1, 30, false);
    let complete_at = rig.m.reply_complete_at().unwrap();
    // Eight bytes of noise, then the reply in two reads a USB adapter's millisecond apart:
    // after the first, as many bytes as a reply have come, but the decoder holds the reply
    // begun.
    rig.m.handle_input(
        &[0x00, 0xFF, 0x07, 0xFD, 0x11, 0xFA, 0x12, 0x34],
        t0 + ms(1),
    );
    let (first, rest) = reply.split_at(reply.len() - 8);
    rig.m.handle_input(first, complete_at);
    let second_read = complete_at + ms(1);
    assert!(
        rig.m.poll_timeout().is_some_and(|t| t > second_read),
        "the bus is held for the rest of the reply begun"
    );
    rig.m.handle_timeout(second_read);
    rig.m.handle_input(rest, second_read);
    assert!(!rig.m.reply_pending());
    assert_eq!(rig.m.counters().timeouts, 0, "the reply was taken");
}

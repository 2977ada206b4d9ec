//! A reply that is not the one awaited: a servo that answered after its allowance (the bus
//! master has moved on to the next request), or a reply begun when its allowance ended. Its
//! bytes never count as the awaited reply's, and while a reply's start sits in the decoder the
//! bus is not free before that reply can have ended: nothing is written over a servo talking.

use super::*;

/// Servos 1 and 2 started; servo 1's read timed out (no reply yet: it answers late) and the
/// request to servo 2 is on the wire. Returns the rig at that instant, servo 1's reply as it
/// will come, late, and servo 2's reply.
fn servo_2_awaited_while_servo_1_is_late() -> (Rig, Vec<u8>, Vec<u8>) {
    let mut rig = Rig::with_ids(&[1, 2]);
    let t0 = rig.t0;
    let first = rig.m.poll_transmit(t0).expect("servo 1's identity read");
    assert_eq!(first.kind, TxKind::Init(id(1)));
    let late = rig
        .servo(1)
        .handle(&first.bytes)
        .expect("a read has a reply");
    let deadline = rig.m.poll_timeout().unwrap();
    rig.m.handle_timeout(deadline);
    assert!(!rig.m.reply_pending(), "servo 1's read timed out");
    let second = rig.m.poll_transmit(deadline).expect("servo 2's read");
    assert_eq!(second.kind, TxKind::Init(id(2)));
    let awaited = rig
        .servo(2)
        .handle(&second.bytes)
        .expect("a read has a reply");
    rig.t = deadline;
    (rig, late, awaited)
}

#[test]
fn a_late_reply_read_alone_does_not_free_the_bus_before_the_awaited_one() {
    let (mut rig, late, reply) = servo_2_awaited_while_servo_1_is_late();
    let complete_at = rig.m.reply_complete_at().unwrap();
    let allowance_ends = rig.m.poll_timeout().unwrap();
    // Servo 1's whole reply, 3.5 ms late, read at the instant servo 2's could be whole: servo
    // 2's comes 1 ms later (an adapter holding it back), within its allowance.
    rig.m.handle_input(&late, complete_at);
    assert!(rig.m.reply_pending(), "servo 2's reply is still awaited");
    assert_eq!(
        rig.m.poll_timeout(),
        Some(allowance_ends),
        "another servo's bytes are not servo 2's"
    );
    assert!(rig.m.poll_transmit(complete_at).is_none());
    rig.m.handle_input(&reply, complete_at + ms(1));
    assert!(!rig.m.reply_pending(), "servo 2's reply taken");
    assert_eq!(rig.m.counters().timeouts, 1, "servo 1's only");
    assert_eq!(
        rig.m.counters().unexpected_replies,
        1,
        "servo 1's late reply"
    );
}

#[test]
fn a_late_reply_and_the_awaited_one_back_to_back_leave_the_awaited_one_its_tail() {
    let (mut rig, late, reply) = servo_2_awaited_while_servo_1_is_late();
    let complete_at = rig.m.reply_complete_at().unwrap();
    // One read holds servo 1's late reply and the first half of servo 2's: as many bytes as a
    // reply, and more, but servo 2's is only begun.
    let (head, tail) = reply.split_at(reply.len() / 2);
    rig.m
        .handle_input(&[late.clone(), head.to_vec()].concat(), complete_at);
    assert!(rig.m.reply_pending(), "servo 2's reply is begun");
    let tail_at = complete_at + rig.wire(tail.len());
    assert!(
        rig.m.poll_timeout().is_some_and(|t| t >= tail_at),
        "the bus is held while servo 2's tail is on the wire"
    );
    assert!(rig.m.poll_transmit(complete_at).is_none());
    rig.m.handle_input(tail, tail_at);
    assert!(!rig.m.reply_pending());
    assert_eq!(rig.m.counters().timeouts, 1, "servo 1's only");
}

#[test]
fn a_reply_begun_when_its_allowance_ends_holds_the_bus_until_it_can_have_ended() {
    let mut rig = Rig::with_ids(&[1, 2]);
    let t0 = rig.t0;
    let read = rig.m.poll_transmit(t0).unwrap();
    let reply = rig.servo(1).handle(&read.bytes).unwrap();
    let deadline = rig.m.poll_timeout().unwrap();
    // The servo answered late: its first ten bytes are in when the allowance ends.
    let (head, tail) = reply.split_at(10);
    rig.m.handle_input(head, deadline - us(10));
    rig.m.handle_timeout(deadline);
    assert!(!rig.m.reply_pending(), "the read timed out");
    assert_eq!(rig.m.counters().timeouts, 1);
    let tail_ends = deadline - us(10) + rig.wire(tail.len());
    assert!(
        rig.m.poll_transmit(deadline).is_none(),
        "nothing is written while the servo talks"
    );
    assert!(
        rig.m.poll_timeout().is_some_and(|t| t >= tail_ends),
        "the bus is held until the reply can have ended: {:?} before it",
        rig.m
            .poll_timeout()
            .map(|t| tail_ends.saturating_duration_since(t))
    );
    // The tail comes, a little late: the bus is free a few byte times after it.
    let tail_at = tail_ends + us(300);
    rig.m.handle_timeout(tail_ends - us(1));
    assert!(rig.m.poll_transmit(tail_ends - us(1)).is_none());
    rig.m.handle_input(tail, tail_at);
    assert_eq!(
        rig.m.poll_timeout(),
        Some(tail_at + rig.wire(QUIET_BYTES) + rig.m.reply_lateness()),
        "a few byte times after the tail's last byte"
    );
    let frees = rig.m.poll_timeout().unwrap();
    rig.m.handle_timeout(frees);
    assert!(rig.m.poll_transmit(frees).is_some(), "the next request");
}

/// How many byte times of quiet after the last byte of a reply that is not awaited free the
/// bus.
const QUIET_BYTES: usize = crate::bus::master::QUIET_AFTER_GARBLED_BYTES;

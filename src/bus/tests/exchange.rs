//! One exchange at a time on the half-duplex wire: nothing is written while a reply is pending
//! (whatever arrives, whenever: also as a property over random input), a reply's deadline is
//! the wire time of request and reply plus the return delay plus the turnaround allowance, and
//! a write later than planned moves that deadline instead of talking over the reply.

use super::*;

#[test]
fn nothing_is_transmitted_while_a_reply_is_pending() {
    let mut rig = Rig::with_ids(&[1, 2]);
    let t0 = rig.t0;
    let tx = rig.m.poll_transmit(t0).unwrap();
    assert!(tx.expects_reply);
    let deadline = rig.m.poll_timeout().unwrap();
    // New goals, time passing, unrelated bytes: still nothing until the reply or the deadline.
    rig.m
        .set_goal(id(2), Goal::Position(MmCenti(5)), t0 + us(10));
    for k in 0..50u32 {
        let t = t0 + (deadline - t0) * k / 50;
        rig.m.handle_input(&[0x00, 0x13], t);
        rig.m.handle_timeout(t);
        assert!(rig.m.poll_transmit(t).is_none(), "at {:?}", t - t0);
    }
    rig.m.handle_timeout(deadline - Duration::from_nanos(1));
    assert!(
        rig.m
            .poll_transmit(deadline - Duration::from_nanos(1))
            .is_none()
    );
    rig.m.handle_timeout(deadline);
    assert!(
        rig.m.poll_transmit(deadline).is_some(),
        "free after the timeout"
    );

    // Over a long run with every servo answering: each request's reply (or timeout) comes
    // before the next packet is written.
    let mut rig = Rig::online_with_force(&[1, 2, 3]);
    for k in 0..200 {
        rig.set_goal(1 + (k % 3) as u8, Goal::Position(MmCenti(k as i16)));
        rig.run(us(1700));
    }
    let c = rig.m.counters();
    let replies = c.telemetry_replies + c.other_requests + u64::from(rig.m.reply_pending());
    let requests = c.polls + c.motion_polls + c.other_requests;
    assert_eq!(replies, requests, "every request answered");
    assert_eq!(rig.m.counters().timeouts, 0);
    assert_eq!(rig.m.counters().unexpected_replies, 0);
}

#[test]
fn reply_timeout_is_wire_time_plus_return_delay_plus_turnaround() {
    let mut rig = Rig::with_ids(&[1]);
    let t0 = rig.t0;
    // Identity read before register 7 is known: 8-byte request, 38-byte reply, assumed delay.
    let expected = t0 + wire(8) + wire(38) + ms(5) + ms(2);
    let tx = rig.m.poll_transmit(t0).unwrap();
    assert_eq!(tx.wire_time, wire(8));
    assert_eq!(rig.m.poll_timeout(), Some(expected));

    // Once register 7 says 3 ms, a telemetry poll: 8 + 26 bytes + 3 ms + 2 ms.
    let mut rig = Rig::new(full_polls_only(&[1]));
    rig.servo(1).return_delay_ms = 3;
    rig.run(ms(100));
    assert_eq!(rig.health(1), Health::Online);
    rig.settle();
    rig.servo(1).present = false;
    let t = rig.t + us(7);
    rig.m.handle_timeout(t);
    let tx = rig.m.poll_transmit(t).unwrap();
    assert_eq!(tx.kind, TxKind::Poll(id(1)));
    assert_eq!(
        rig.m.poll_timeout(),
        Some(t + wire(8) + wire(26) + ms(3) + ms(2))
    );

    // A request queued behind a long packet counts from the end of that packet.
    let mut cfg = config(&[1, 2]);
    cfg.tick_gather = Duration::ZERO;
    let mut rig = Rig::online_with_force_on(cfg);
    rig.settle();
    let t = rig.t;
    rig.set_goal(1, Goal::Position(MmCenti(10)));
    let long = rig.m.poll_transmit(t).unwrap();
    assert_eq!(long.kind, TxKind::Command);
    let poll = rig.m.poll_transmit(t).unwrap();
    assert!(poll.expects_reply);
    let reply_len = match poll.kind {
        TxKind::Poll(_) => 26,
        TxKind::MotionPoll(_) => 16,
        _ => 20,
    };
    assert_eq!(
        rig.m.poll_timeout(),
        Some(t + long.wire_time + wire(8) + wire(reply_len) + ms(2))
    );
}

#[test]
fn a_write_later_than_planned_moves_the_reply_deadline_and_nothing_talks_over_the_reply() {
    let (mut rig, tx) = Rig::at_a_full_poll();
    let planned = rig.t;
    // The writing thread was preempted for 3 ms before the write.
    let written = planned + ms(3);
    rig.m.handle_written(written);
    // The reply comes after the request really left, then late by 1.5 ms of turnaround.
    let reply = rig.servo(1).handle(&tx.bytes).expect("an answer");
    let reply_end = written + wire(tx.bytes.len()) + ms(1) + us(500) + wire(reply.len());
    // Until the reply is in, nothing is written and no timeout is counted, whatever the time.
    let mut t = planned;
    while t < reply_end {
        rig.m.handle_timeout(t);
        assert!(
            rig.m.poll_transmit(t).is_none(),
            "talked over the reply at {:?}",
            t - planned
        );
        t += us(100);
    }
    assert_eq!(rig.m.counters().timeouts, 0);
    rig.m.handle_input(&reply, reply_end);
    assert!(!rig.m.reply_pending());
    assert_eq!(rig.m.counters().timeouts, 0);
    assert_eq!(rig.m.counters().telemetry_replies, rig.m.counters().polls);
}

mod properties {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(200))]

        /// Whatever arrives, whenever: no panic, and never a transmit while a reply is pending.
        #[test]
        fn any_bytes_goals_and_times_never_panic(
            steps in proptest::collection::vec(
                (0u8..4, proptest::collection::vec(any::<u8>(), 0..40), 0u64..5000, any::<i16>(), 1u8..4),
                1..80,
            )
        ) {
            let mut m = BusMaster::new(config(&[1, 2, 3]), Instant::now());
            let mut t = Instant::now();
            for (what, bytes, dt, pos, n) in steps {
                t += us(dt);
                match what {
                    0 => m.handle_input(&bytes, t),
                    1 => m.set_goal(id(n), Goal::Position(MmCenti(pos)), t),
                    2 => m.handle_timeout(t),
                    _ => {
                        let pending = m.reply_pending();
                        if let Some(tx) = m.poll_transmit(t) {
                            prop_assert!(!pending);
                            prop_assert!(!tx.bytes.is_empty());
                        }
                    }
                }
                let _ = m.poll_timeout();
                while m.poll_event().is_some() {}
                let _ = m.status();
            }
        }
    }
}

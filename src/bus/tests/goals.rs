//! Goals into long packets: a change of any goal sends one long packet with every servo's,
//! goals set meanwhile are coalesced and counted, clamped to the servo's limits, never queued
//! more than one frame ahead of the wire; the goal time of a soft start and of a goal sent
//! again; and a long packet lost on the line, noticed by the read-back of the goal register.

use super::*;

#[test]
fn a_goal_change_sends_one_long_packet_with_every_servo() {
    let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
    rig.set_goal(1, Goal::Position(MmCenti(100)));
    rig.set_goal(2, Goal::Position(MmCenti(-200)));
    rig.set_goal(3, Goal::Position(MmCenti(300)));
    rig.set_goal(4, Goal::Position(MmCenti(-400)));
    rig.run(ms(300));
    // Only servo 3 changes: the next bus slot is one long packet carrying all four.
    let from = rig.log.len();
    rig.set_goal(3, Goal::Position(MmCenti(333)));
    assert!(rig.m.reply_pending(), "a poll is in flight");
    rig.run(ms(10));
    let sent = rig.sent_since(from);
    let first = sent
        .iter()
        .position(|s| s.tx.kind == TxKind::Command)
        .unwrap();
    assert!(
        sent[..first].iter().all(|s| !s.tx.expects_reply),
        "the command takes the first free slot"
    );
    let commands = rig.commands_since(from);
    assert_eq!(commands.len(), 1, "one frame");
    let entries: Vec<(u8, i16)> = commands[0].iter().map(|e| (e.0, e.1)).collect();
    assert_eq!(entries, vec![(1, 100), (2, -200), (3, 333), (4, -400)]);
    assert_eq!(rig.servo(3).position, 333);
}

#[test]
fn goals_are_coalesced_and_counted() {
    let mut rig = Rig::online_with_force(&[1, 2]);
    rig.run(ms(1));
    assert!(rig.m.reply_pending());
    let before = *rig.m.counters();
    let from = rig.log.len();
    for k in 1..=5 {
        rig.set_goal(1, Goal::Position(MmCenti(k * 10)));
    }
    rig.set_goal(2, Goal::Position(MmCenti(0))); // unchanged
    rig.set_goal(9, Goal::Position(MmCenti(0))); // not on this bus
    rig.run(ms(5));
    let commands = rig.commands_since(from);
    assert_eq!(commands.len(), 1);
    assert_eq!(commands[0], vec![(1, 50, None), (2, 0, None)]);
    let c = rig.m.counters();
    assert_eq!(c.goals_received - before.goals_received, 6);
    assert_eq!(c.goals_superseded - before.goals_superseded, 4);
    assert_eq!(c.goals_sent - before.goals_sent, 1);
    assert_eq!(c.goals_unchanged - before.goals_unchanged, 1);
    assert_eq!(c.goals_unknown_id - before.goals_unknown_id, 1);
}

#[test]
fn goals_are_clamped_to_the_servo_limits() {
    let mut rig = Rig::with_ids(&[1]);
    rig.servo(1).plus = 1500;
    rig.run(ms(100));
    rig.set_goal(1, Goal::Position(MmCenti(i16::MAX)));
    rig.run(ms(3000));
    assert_eq!(rig.servo(1).goal_writes.last().unwrap().0, 1500);
    assert_eq!(
        rig.m.status().servo(id(1)).unwrap().goal,
        Some(MmCenti(1500))
    );
    // A goal given before the limits were read is clamped to them too.
    let mut rig = Rig::with_ids(&[1]);
    rig.servo(1).minus = -800;
    rig.set_goal(1, Goal::Position(MmCenti(-2400)));
    rig.run(ms(4000));
    assert_eq!(rig.servo(1).goal_writes.last().unwrap().0, -800);
    assert_eq!(rig.servo(1).position, -800);
}

#[test]
fn long_packets_never_queue_more_than_one_frame_ahead_of_the_wire() {
    let mut rig = Rig::online_with_force(&[1]);
    // Nothing to poll (the only servo is offline): goals every 100 µs, far faster than frames.
    rig.servo(1).present = false;
    rig.run(ms(500));
    assert_eq!(rig.health(1), Health::Offline);
    let from = rig.log.len();
    let start = rig.t;
    let mut queued_ahead = Vec::new();
    for k in 0..2000 {
        rig.set_goal(1, Goal::Position(MmCenti(k % 500)));
        let before = rig.wire_free;
        let n = rig.log.len();
        rig.run(us(100));
        if rig.log[n..].iter().any(|s| s.tx.kind == TxKind::Command) {
            queued_ahead.push(before.saturating_duration_since(rig.log[n].at));
        }
    }
    let frame = wire(8 + 3);
    let frames = rig.commands_since(from).len() as u32;
    let elapsed = rig.t - start;
    assert!(
        queued_ahead.iter().all(|q| *q <= wire(8 + 5)),
        "at most one frame queued: {:?}",
        queued_ahead.iter().max()
    );
    assert!(
        frames <= elapsed.div_duration_f64(frame).ceil() as u32 + 1,
        "{frames}"
    );
    assert!(frames > 100, "the wire is kept busy: {frames}");
}

#[test]
fn the_first_move_uses_a_soft_start_goal_time() {
    let mut rig = Rig::with_ids(&[1, 2]);
    rig.servo(1).position = -1000;
    rig.servo(1).stuck = true; // the rod lags, as a slow move would
    rig.servo(2).position = 500;
    rig.run(ms(100));
    let from = rig.log.len();
    rig.set_goal(1, Goal::Position(MmCenti(1000)));
    rig.set_goal(2, Goal::Position(MmCenti(500)));
    rig.run(ms(100));
    let commands = rig.commands_since(from);
    // 20 mm at 10 mm/s = 2 s. Servo 2 is already at its goal: force ON was all it needed.
    assert_eq!(commands, vec![vec![(1, 1000, Some(200))]]);
    assert_eq!(rig.servo(2).force, 1);
    assert_eq!(rig.servo(1).goal_writes, vec![(1000, Some(200))]);
    // A goal that changes during the soft start is approached at the soft speed too …
    rig.run(ms(900));
    let from = rig.log.len();
    rig.set_goal(1, Goal::Position(MmCenti(2000)));
    rig.run(ms(30));
    assert_eq!(
        rig.commands_since(from)[0][0],
        (1, 2000, Some(300)),
        "30 mm at 10 mm/s"
    );
    // … but does not make it last longer than the first move's 2 s: then full speed, and once
    // every goal-time register is zero the frames carry positions only.
    rig.run(ms(1100));
    rig.servo(1).stuck = false;
    let from = rig.log.len();
    rig.set_goal(1, Goal::Position(MmCenti(-2000)));
    rig.run(ms(30));
    rig.set_goal(1, Goal::Position(MmCenti(-1900)));
    rig.run(ms(30));
    let commands = rig.commands_since(from);
    assert_eq!(commands[0], vec![(1, -2000, Some(0)), (2, 500, Some(0))]);
    assert_eq!(commands[1], vec![(1, -1900, None), (2, 500, None)]);
}

#[test]
fn a_goal_sent_again_carries_the_time_left_of_its_move() {
    let mut cfg = config(&[1, 2]);
    cfg.servos[0].goal_time = Some(Ms10(100)); // 1 s
    cfg.soft_start_speed_mm_s = 0.0; // soft start off
    let mut rig = Rig::new(cfg);
    rig.run(ms(100));
    rig.set_goal(1, Goal::Position(MmCenti(0)));
    rig.set_goal(2, Goal::Position(MmCenti(0)));
    rig.run(ms(100));
    let from = rig.log.len();
    rig.set_goal(1, Goal::Position(MmCenti(800)));
    rig.run(ms(300));
    rig.set_goal(2, Goal::Position(MmCenti(50)));
    rig.run(ms(10));
    let commands = rig.commands_since(from);
    assert_eq!(commands.len(), 2);
    assert_eq!(commands[0][0], (1, 800, Some(100)));
    let (vid, pos, time) = commands[1][0];
    assert_eq!((vid, pos), (1, 800));
    let left = time.unwrap();
    assert!((69..=71).contains(&left), "about 0.7 s left: {left}");
    assert_eq!(commands[1][1], (2, 50, Some(0)));
}

#[test]
fn a_lost_long_packet_is_noticed_by_the_read_back() {
    let mut rig = Rig::online_with_force(&[1]);
    rig.set_goal(1, Goal::Position(MmCenti(700)));
    rig.run(ms(2000));
    // The servo's goal register differs from what was sent (a frame lost to noise).
    rig.servo(1).goal = 123;
    rig.servo(1).position = 123;
    rig.run(ms(1500));
    assert_eq!(rig.servo(1).goal, 700);
}

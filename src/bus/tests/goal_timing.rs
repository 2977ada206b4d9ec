//! When a goal's frame goes out against the polls: periodic goals find the bus free once the
//! rhythm is known, and the time left before them carries a position read; irregular goals wait
//! for the reply in flight and nothing else; an autopilot's ticks on two ports, on time,
//! jittery or sometimes late, never find a poll started after the tick began, and telemetry
//! keeps its rates. (The ticks as a real autopilot sends them, with holds and silences, are in
//! `ticks`.)

use super::*;

#[test]
fn periodic_goals_find_the_bus_free_and_the_time_left_is_read() {
    let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
    let period = ms(20);
    let mut delays = Vec::new();
    let mut position_reads = Vec::new();
    let polls_before = rig.m.counters().polls;
    let motion_before = rig.m.counters().motion_polls;
    let t_start = rig.t;
    for k in 0..100i16 {
        let at = rig.t;
        let goals: Vec<_> = (1..=4u8)
            .map(|n| (n, Goal::Position(MmCenti(k * 10 + i16::from(n)))))
            .collect();
        rig.message(&goals);
        let from = rig.log.len();
        rig.run(period);
        let sent = rig.sent_since(from);
        let command = sent
            .iter()
            .find(|s| s.tx.kind == TxKind::Command)
            .expect("a frame");
        if k >= 10 {
            delays.push(command.at.duration_since(at));
            position_reads.extend(
                sent.iter()
                    .filter(|s| matches!(s.tx.kind, TxKind::PositionPoll(_)))
                    .map(|s| s.tx.bytes.clone()),
            );
        }
    }
    assert_eq!(rig.m.goal_period(), Some(period));
    let c = *rig.m.counters();
    let polls = c.polls - polls_before;
    let motion_polls = c.motion_polls - motion_before;
    let seconds = rig.t.duration_since(t_start).as_secs_f64();
    // Once the rhythm is known, every frame leaves the moment its goals arrive: no poll or
    // position read holds the bus then.
    assert!(delays.iter().all(|d| *d == Duration::ZERO), "{delays:?}");
    // ... position and current are still read at more than 60 Hz per servo, temperature and
    // voltage at more than 10 Hz.
    let motion_hz = (polls + motion_polls) as f64 / seconds / 4.0;
    let full_hz = polls as f64 / seconds / 4.0;
    assert!(
        motion_hz > 60.0,
        "position and current at {motion_hz:.1} Hz per servo"
    );
    assert!(
        full_hz > 10.0,
        "temperature and voltage at {full_hz:.1} Hz per servo"
    );
    // Reads of position and current are registers 42–49.
    let motion_reads: Vec<_> = rig
        .log
        .iter()
        .filter(|s| matches!(s.tx.kind, TxKind::MotionPoll(_)))
        .collect();
    assert!(!motion_reads.is_empty());
    for s in motion_reads {
        assert_eq!(
            &s.tx.bytes[3..7],
            &[0x0F, 0x2A, 0x08, 0x00],
            "{:02X?}",
            s.tx.bytes
        );
    }
    // The time left before a goal, too short for any other poll, carries a read of registers
    // 42–43 alone when it fits (see the position-read test in `telemetry` for the period where
    // it does).
    for bytes in &position_reads {
        assert_eq!(&bytes[3..7], &[0x0F, 0x2A, 0x02, 0x00], "{bytes:02X?}");
    }
}

#[test]
fn a_goal_waits_for_the_reply_in_flight_and_nothing_else() {
    let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
    // Irregular arrivals (no rhythm to keep the bus free for): some goals find a poll in
    // flight, some an idle bus.
    let gaps = [
        7_300u64, 11_100, 2_900, 15_700, 5_300, 9_900, 3_700, 13_300, 6_100,
    ];
    let mut behind_a_reply = 0;
    for (k, gap) in gaps.iter().cycle().take(180).enumerate() {
        rig.run(us(*gap));
        let set_at = rig.t;
        let reply_end = if rig.m.reply_pending() {
            Some(
                rig.reply
                    .as_ref()
                    .map(|(end, _)| *end)
                    .expect("a reply on its way"),
            )
        } else {
            None
        };
        let from = rig.log.len();
        rig.set_goal(1 + (k % 4) as u8, Goal::Position(MmCenti(k as i16 * 7 + 1)));
        rig.run(ms(4));
        let frame_at = rig
            .sent_since(from)
            .iter()
            .find(|s| s.tx.kind == TxKind::Command)
            .expect("a frame")
            .at;
        // The frame is written the instant the reply in flight is complete, or at once.
        match reply_end {
            Some(end) => {
                behind_a_reply += 1;
                assert_eq!(
                    frame_at,
                    end,
                    "goal {k}: written {:?} after the reply",
                    frame_at - end
                );
            }
            None => assert_eq!(frame_at, set_at, "goal {k} on an idle bus"),
        }
    }
    assert!(
        behind_a_reply >= 60,
        "{behind_a_reply} of 180 goals behind a reply"
    );
}

/// Goals at `period` with the given arrival offsets (µs, may be negative) per tick, each tick
/// in `messages` messages `spacing` apart, each message carrying a new goal for `servos`.
/// Returns, per goal message after the first 20 ticks, how long its frame waited, and what the
/// bus carried when the message came.
fn run_autopilot(
    rig: &mut Rig,
    ticks: usize,
    offset_us: impl Fn(usize, usize) -> i64,
    messages: &[(&[u8], Duration)],
) -> Vec<(Duration, Option<TxKind>)> {
    let period = ms(20);
    let t0 = rig.t + ms(5);
    let mut arrivals: Vec<(Instant, usize, usize)> = Vec::new();
    for k in 0..ticks {
        for (m, (_, spacing)) in messages.iter().enumerate() {
            let base = t0 + period * k as u32 + *spacing;
            let off = offset_us(k, m);
            let at = if off >= 0 {
                base + us(off as u64)
            } else {
                base - us(off.unsigned_abs())
            };
            arrivals.push((at, k, m));
        }
    }
    arrivals.sort_by_key(|a| a.0);
    let mut messages_at = Vec::new();
    for (n, (at, k, m)) in arrivals.into_iter().enumerate() {
        let value = (n % 2000) as i16 + 1;
        rig.run(at.saturating_duration_since(rig.t));
        let in_flight = rig
            .m
            .reply_pending()
            .then(|| rig.log.last().map(|s| s.tx.kind))
            .flatten();
        let goals: Vec<_> = messages[m]
            .0
            .iter()
            .map(|&n| (n, Goal::Position(MmCenti(value))))
            .collect();
        rig.message(&goals);
        messages_at.push((rig.t, rig.log.len(), k, in_flight));
    }
    rig.run(period);
    // Each message's wait: until the first frame handed out at or after it.
    messages_at
        .into_iter()
        .filter(|(_, _, k, _)| *k >= 20)
        .map(|(at, from, _, in_flight)| {
            let frame = rig
                .sent_since(from)
                .iter()
                .find(|s| s.tx.kind == TxKind::Command)
                .expect("a frame after every message")
                .at;
            (frame - at, in_flight)
        })
        .collect()
}

const PORT0: &[u8] = &[1, 2, 3];
const PORT1: &[u8] = &[4];

#[test]
fn no_goal_of_a_tick_waits_behind_a_poll_started_after_the_tick_began() {
    // Ports 0 and 1 of each tick, 0.1 ms apart; a command 1.5 ms after port 0 in every tenth.
    let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
    let frames_before = rig.m.counters().command_frames;
    let waits = run_autopilot(&mut rig, 120, |_, _| 0, &[(PORT0, us(0)), (PORT1, us(100))]);
    let behind_poll: Vec<_> = waits.iter().filter(|w| w.1.is_some()).collect();
    assert!(behind_poll.is_empty(), "{behind_poll:?}");
    // One tick, one frame: port 0's goals wait the 0.1 ms for port 1's (known from the ticks
    // before), which leave with them at once, instead of 1.5 ms behind a frame of their own.
    let frames = rig.m.counters().command_frames - frames_before;
    assert!(frames <= 121, "{frames} frames for 120 ticks");
    for pair in waits.chunks(2) {
        assert_eq!(pair[0].0, us(100), "port 0: {pair:?}");
        assert_eq!(pair[1].0, Duration::ZERO, "port 1: {pair:?}");
    }
    let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
    let waits = run_autopilot(
        &mut rig,
        120,
        |_, _| 0,
        &[(PORT0, us(0)), (PORT1, us(100)), (&[2], us(1600))],
    );
    assert!(waits.iter().all(|w| w.1.is_none()), "{waits:?}");
}

/// Port 1's message, usually 0.1 ms behind port 0's, comes 0.2 ms later than that in every
/// tenth tick (its sender preempted between its two sends): the tick's goals still leave in
/// one frame, and port 0's wait no longer than for port 1's.
#[test]
fn a_tick_whose_second_message_is_a_little_late_still_leaves_in_one_frame() {
    let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
    let frames_before = rig.m.counters().command_frames;
    let late = |k: usize, m: usize| if m == 1 && k % 10 == 5 { 200 } else { 0 };
    let waits = run_autopilot(&mut rig, 120, late, &[(PORT0, us(0)), (PORT1, us(100))]);
    let frames = rig.m.counters().command_frames - frames_before;
    assert!(frames <= 121, "{frames} frames for 120 ticks");
    for pair in waits.chunks(2) {
        assert!(pair[0].0 <= us(300), "port 0: {pair:?}");
        assert_eq!(pair[1].0, Duration::ZERO, "port 1: {pair:?}");
    }
}

/// No goal message found a poll in flight when it came.
fn assert_no_goal_behind_a_poll(waits: &[(Duration, Option<TxKind>)]) {
    let behind: Vec<_> = waits.iter().filter(|w| w.1.is_some()).collect();
    assert!(
        behind.is_empty(),
        "{} of {}: {behind:?}",
        behind.len(),
        waits.len()
    );
}

#[test]
fn a_jittery_autopilot_finds_the_bus_free_and_telemetry_keeps_its_rates() {
    // The tick's send time jitters by ±1 ms; both ports go out together.
    let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
    let c0 = *rig.m.counters();
    let t0 = rig.t;
    let waits = run_autopilot(
        &mut rig,
        150,
        |k, _| uniform(k, 0, 1000),
        &[(PORT0, us(0)), (PORT1, us(100))],
    );
    assert_no_goal_behind_a_poll(&waits);
    let c = rig.m.counters();
    let seconds = (rig.t - t0).as_secs_f64();
    let motion_hz =
        ((c.polls + c.motion_polls) - (c0.polls + c0.motion_polls)) as f64 / seconds / 4.0;
    let full_hz = (c.polls - c0.polls) as f64 / seconds / 4.0;
    assert!(motion_hz >= 60.0, "{motion_hz:.1} Hz");
    assert!(full_hz >= 10.0, "{full_hz:.1} Hz");

    // One message in twenty is 3–8 ms late: the bus is still free when it comes.
    let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
    let late = |k: usize, m: usize| {
        if uniform(k, m + 7, 1000).rem_euclid(20) == 0 {
            3000 + uniform(k, m + 11, 2500) + 2500
        } else {
            0
        }
    };
    let waits = run_autopilot(&mut rig, 200, late, &[(PORT0, us(0)), (PORT1, us(100))]);
    let behind_full: Vec<_> = waits
        .iter()
        .filter(|w| matches!(w.1, Some(TxKind::Poll(_))))
        .collect();
    assert!(behind_full.is_empty(), "{behind_full:?}");
    assert_no_goal_behind_a_poll(&waits);
}

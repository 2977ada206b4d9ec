//! Conditions of a servo reported as events: a temperature error (no force ON tried while it
//! lasts, recovery after a power cycle), a temperature flag seen in a short reply (the next
//! poll reads the temperature, and the event waits for that read, or goes out after its wait
//! when the read never comes), and a stall (high current, far from the goal, not closing in,
//! for the configured time).

use super::*;

#[test]
fn a_temperature_error_is_reported_and_force_on_is_not_retried() {
    let mut rig = Rig::online_with_force_on(full_polls_only(&[1, 2]));
    rig.set_goal(1, Goal::Position(MmCenti(100)));
    rig.run(ms(50));
    // The servo overheats: error flag, force off, refuses force ON.
    rig.servo(1).flags = 0x80 | 0x20;
    rig.servo(1).force = 0;
    let ev_from = rig.events.len();
    // Learnt from the next reply of servo 1.
    rig.run(ms(20));
    let from = rig.log.len();
    for k in 0..100 {
        rig.set_goal(1, Goal::Position(MmCenti(200 + k)));
        rig.set_goal(2, Goal::Position(MmCenti(200 + k)));
        rig.run(ms(50));
    }
    let events = &rig.events[ev_from..];
    assert!(events.contains(&BusEvent::TemperatureError { id: id(1) }));
    assert!(events.contains(&BusEvent::TemperatureAlarm {
        id: id(1),
        on: true
    }));
    assert_eq!(rig.health(1), Health::TemperatureError);
    assert!(
        !rig.kinds_since(from).contains(&TxKind::Force(id(1))),
        "no force-ON attempts"
    );
    assert!(
        rig.commands_since(from)
            .iter()
            .all(|c| c.iter().all(|e| e.0 != 1))
    );
    assert!(
        rig.kinds_since(from).contains(&TxKind::Poll(id(1))),
        "still watched"
    );
    assert_eq!(rig.servo(2).position, 299, "the other servo keeps working");
    // Power-cycled and cool again: re-initialised, force ON, goal sent. The reply that shows
    // the restart already carries the new temperature, and the status has it at once.
    rig.servo(1).temperature = 31;
    rig.servo(1).power_cycle();
    let restart_seen = rig.events.len();
    while !rig.events[restart_seen..].contains(&BusEvent::ServoRestarted { id: id(1) }) {
        rig.run(ms(1));
    }
    let t = rig.m.status().servo(id(1)).unwrap().telemetry.unwrap();
    assert_eq!(
        t.present_temperature.0, 31,
        "the restart reply's reading is kept"
    );
    rig.run(ms(3000));
    assert!(
        rig.events[ev_from..].contains(&BusEvent::ServoRestarted { id: id(1) }),
        "{:?}",
        &rig.events[ev_from..]
    );
    assert_eq!(rig.health(1), Health::Online);
    assert_eq!(rig.servo(1).force, 1);
    assert_eq!(rig.servo(1).position, 299);
}

#[test]
fn a_stall_is_reported_after_the_configured_time_at_high_current() {
    let mut rig = Rig::online_with_force(&[1]);
    // Far from the goal but drawing little current: a slow move, not a stall.
    rig.servo(1).stuck = true;
    rig.set_goal(1, Goal::Position(MmCenti(1000)));
    rig.run(ms(3000));
    assert!(!rig.m.status().servo(id(1)).unwrap().stalled);
    // High current at the goal: working against a load, not a stall.
    rig.servo(1).stuck = false;
    rig.set_goal(1, Goal::Position(MmCenti(1200)));
    rig.servo(1).load = 300;
    rig.run(ms(3000));
    assert!(!rig.m.status().servo(id(1)).unwrap().stalled);
    // A heavy load: high current and far from the goal, but closing in: not a stall.
    rig.servo(1).stuck = true;
    rig.set_goal(1, Goal::Position(MmCenti(-1000)));
    for step in 1..=20 {
        rig.servo(1).position = 1200 - step * 100;
        rig.run(ms(50));
    }
    assert!(!rig.m.status().servo(id(1)).unwrap().stalled);
    rig.servo(1).position = -1000;
    rig.run(ms(50));
    // Rod blocked and high current: stalled once it lasts 500 ms, not before.
    rig.servo(1).stuck = true;
    rig.set_goal(1, Goal::Position(MmCenti(-500)));
    rig.run(ms(50));
    let started = rig.t;
    let ev_from = rig.events.len();
    rig.run(ms(440));
    assert!(!rig.events[ev_from..].contains(&BusEvent::Stalled {
        id: id(1),
        on: true
    }));
    rig.run(ms(100));
    assert!(
        rig.events[ev_from..].contains(&BusEvent::Stalled {
            id: id(1),
            on: true
        }),
        "stalled within {:?}",
        rig.t - started
    );
    assert!(rig.m.status().servo(id(1)).unwrap().stalled);
    // Freed: it follows, the stall clears.
    rig.servo(1).stuck = false;
    rig.servo(1).load = 20;
    rig.set_goal(1, Goal::Position(MmCenti(-400)));
    rig.run(ms(100));
    assert!(rig.events.contains(&BusEvent::Stalled {
        id: id(1),
        on: false
    }));
    assert!(!rig.m.status().servo(id(1)).unwrap().stalled);
}

#[test]
fn a_temperature_flag_seen_in_a_short_reply_makes_the_next_poll_read_the_temperature() {
    let mut rig = Rig::online_with_force(&[1]);
    rig.run(ms(100));
    rig.servo(1).temperature = 77;
    rig.servo(1).flags = 0x20;
    // Run until the alarm is out (it waits for the temperature read).
    let from = rig.log.len();
    while !rig.events.contains(&BusEvent::TemperatureAlarm {
        id: id(1),
        on: true,
    }) {
        rig.run(ms(1));
    }
    let reads: Vec<TxKind> = rig
        .kinds_since(from)
        .into_iter()
        .filter(|k| *k != TxKind::Command)
        .collect();
    // The first read saw the flag; a short one is followed by a full one at once.
    if reads.first() == Some(&TxKind::MotionPoll(id(1))) {
        assert_eq!(reads.get(1), Some(&TxKind::Poll(id(1))), "{reads:?}");
    }
    assert_eq!(
        rig.m
            .status()
            .servo(id(1))
            .unwrap()
            .telemetry
            .unwrap()
            .present_temperature
            .0,
        77
    );
}

/// A rig whose polls between two full ones are position-and-current reads for a second: a
/// flag that changes is seen first in a reply without the temperature.
fn rig_with_rare_full_reads() -> Rig {
    let mut cfg = config(&[1]);
    cfg.full_telemetry_interval = ms(1000);
    let mut rig = Rig::online_with_force_on(cfg);
    rig.run(ms(100));
    rig
}

/// The first poll after `from` in the log, and whether it is a short one.
fn first_read_is_short(rig: &Rig, from: usize) -> bool {
    rig.kinds_since(from)
        .into_iter()
        .find(|k| *k != TxKind::Command)
        .is_some_and(|k| k != TxKind::Poll(id(1)))
}

#[test]
fn a_temperature_event_from_a_short_reply_waits_for_the_temperature_read_after_it() {
    for alarm in [true, false] {
        let mut rig = rig_with_rare_full_reads();
        let read_before = rig.m.status().servo(id(1)).unwrap().telemetry_at.unwrap();
        // Heating up from 30 °C, unread: the flag arrives in a position-and-current reply.
        rig.servo(1).temperature = 86;
        rig.servo(1).flags = if alarm { 0x20 } else { 0x80 };
        let (from_log, from_events) = (rig.log.len(), rig.events.len());
        let wanted = |e: &BusEvent| {
            matches!(
                e,
                BusEvent::TemperatureAlarm { on: true, .. } | BusEvent::TemperatureError { .. }
            )
        };
        let mut seen = None;
        for _ in 0..200 {
            rig.run(us(100));
            if rig.events[from_events..].iter().any(wanted) {
                // What a reader of the status finds when the event comes out.
                seen = Some(rig.m.status());
                break;
            }
        }
        let status = seen.expect("the temperature event");
        assert!(
            first_read_is_short(&rig, from_log),
            "{:?}",
            rig.kinds_since(from_log)
        );
        let servo = status.servo(id(1)).unwrap();
        let t = servo.telemetry.unwrap();
        assert_eq!(t.present_temperature.0, 86, "alarm {alarm}");
        let read_at = servo.telemetry_at.unwrap();
        assert!(read_at > read_before);
        assert!(
            rig.t.saturating_duration_since(read_at) < ms(1),
            "alarm {alarm}: read {:?} before the event",
            rig.t.saturating_duration_since(read_at)
        );
    }
}

#[test]
fn a_temperature_event_whose_read_never_comes_goes_out_after_200_ms() {
    let mut rig = rig_with_rare_full_reads();
    rig.servo(1).temperature = 86;
    rig.servo(1).flags = 0x20;
    let (from, from_log) = (rig.events.len(), rig.log.len());
    // The flag arrives in a short reply, then the servo falls silent: no full read.
    let mut flagged_at = None;
    for _ in 0..200 {
        rig.run(us(100));
        if rig
            .m
            .status()
            .servo(id(1))
            .unwrap()
            .flags
            .temperature_alarm()
        {
            flagged_at = Some(rig.t);
            rig.servo(1).present = false;
            // A reply already on its way is lost too.
            rig.reply = None;
            break;
        }
    }
    let flagged_at = flagged_at.expect("the flag seen");
    assert!(
        first_read_is_short(&rig, from_log),
        "{:?}",
        rig.kinds_since(from_log)
    );
    let alarm = BusEvent::TemperatureAlarm {
        id: id(1),
        on: true,
    };
    rig.run(crate::bus::servo::TEMPERATURE_WAIT - ms(5));
    assert!(!rig.events[from..].contains(&alarm), "out before its wait");
    rig.run(ms(10));
    assert!(
        rig.events[from..].contains(&alarm),
        "{:?}",
        &rig.events[from..]
    );
    // Out before the servo is lost, with the reading from before the flag.
    let status = rig.m.status();
    let servo = status.servo(id(1)).unwrap();
    assert_eq!(servo.telemetry.unwrap().present_temperature.0, 30);
    assert!(servo.age.unwrap() > rig.t.saturating_duration_since(flagged_at));
}

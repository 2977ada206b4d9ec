//! A servo's share of bad replies over time ([`crate::bus::quality`]): garbled replies, however
//! many, never make a servo lost (silence does); from 20 % it is degraded, once, and "replies
//! ok" once the line is clean again; a share wandering about the threshold gives one
//! "degraded"; an unplugged servo is lost, not degraded, whether degraded before or not, and
//! comes back without its old state.

use super::*;

#[test]
fn a_servo_whose_replies_are_garbled_is_degraded_never_lost() {
    let mut rig = Rig::online_with_force(&[1, 2]);
    // Every reply of servo 1 has a bad sum: counted as missed, but the servo is answering.
    rig.servo(1).garble = true;
    let c0 = *rig.m.counters();
    let from = rig.events.len();
    rig.run(ms(1000));
    let c = rig.m.counters();
    assert!(
        c.bad_sums - c0.bad_sums >= 20,
        "{} bad sums",
        c.bad_sums - c0.bad_sums
    );
    assert!(!rig.events[from..].contains(&BusEvent::ServoLost { id: id(1) }));
    assert_ne!(rig.health(1), Health::Offline);
    assert!(rig.m.status().servo(id(1)).unwrap().timeouts >= 20);
}

#[test]
fn garbled_replies_at_10_20_30_and_60_percent_never_make_a_servo_lost_and_silence_does() {
    for share in [0.1, 0.2, 0.3, 0.6] {
        let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
        rig.servo(1).garble_share = share;
        let from = rig.events.len();
        let c0 = *rig.m.counters();
        let answered0 = rig.m.status().servo(id(1)).unwrap().answered;
        for k in 0..250i16 {
            for n in 1..=4u8 {
                rig.set_goal(n, Goal::Position(MmCenti(k * 4 + i16::from(n))));
            }
            rig.run(ms(20));
        }
        let lost: Vec<_> = rig.events[from..]
            .iter()
            .filter(|e| matches!(e, BusEvent::ServoLost { .. }))
            .collect();
        assert!(lost.is_empty(), "{share}: {lost:?}");
        assert_eq!(rig.health(1), Health::Online, "{share}");
        // Every garbled reply is counted, so the share of bad replies can be told.
        let bad = rig.m.counters().bad_sums - c0.bad_sums;
        let answered = rig.m.status().servo(id(1)).unwrap().answered - answered0;
        let seen = bad as f64 / (bad + answered) as f64;
        assert!((seen - share).abs() < 0.05, "{share}: {seen:.3} seen");
        // The servo keeps following its goals.
        assert_eq!(rig.servo(1).goal, 249 * 4 + 1, "{share}");
    }
    // Unplugged: silent, and lost once silent for `offline_after_silence`.
    let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
    rig.servo(1).present = false;
    let from = rig.events.len();
    rig.run(ms(500));
    assert!(
        rig.events[from..].contains(&BusEvent::ServoLost { id: id(1) }),
        "{:?}",
        &rig.events[from..]
    );
}

/// The reply-quality events of servo 1 (and any other servo's, which there must be none of).
fn quality_events(events: &[BusEvent]) -> Vec<BusEvent> {
    events
        .iter()
        .filter(|e| {
            matches!(
                e,
                BusEvent::RepliesDegraded { .. }
                    | BusEvent::RepliesOk { .. }
                    | BusEvent::ServoLost { .. }
                    | BusEvent::ServoBack { .. }
            )
        })
        .cloned()
        .collect()
}

/// Goals to every servo of a four-servo rig every 20 ms, for `d`.
fn run_with_goals(rig: &mut Rig, d: Duration) {
    let steps = d.as_millis() / 20;
    for k in 0..steps {
        for n in 1..=4u8 {
            rig.set_goal(
                n,
                Goal::Position(MmCenti((k % 500) as i16 * 4 + i16::from(n))),
            );
        }
        rig.run(ms(20));
    }
}

#[test]
fn garbled_replies_at_10_percent_leave_a_servo_online_and_at_20_30_60_percent_degrade_it_once() {
    for (share, degrades) in [(0.1, false), (0.2, true), (0.3, true), (0.6, true)] {
        let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
        rig.servo(1).garble_share = share;
        let from = rig.events.len();
        // Ten windows of garbled replies.
        run_with_goals(&mut rig, crate::bus::quality::WINDOW * 10);
        let events = quality_events(&rig.events[from..]);
        let status = rig.m.status();
        let degraded = status.servo(id(1)).unwrap().degraded;
        if !degrades {
            assert_eq!(events, vec![], "{share}");
            assert_eq!(degraded, None, "{share}");
        } else {
            // One "degraded", with the share in it; never "ok" while it lasts, never "lost".
            let [BusEvent::RepliesDegraded { id: servo, percent }] = events[..] else {
                panic!("{share}: {events:?}");
            };
            assert_eq!(servo, id(1), "{share}");
            let expected = (share * 100.0) as i32;
            assert!(
                (i32::from(percent) - expected).abs() <= 3,
                "{share}: {percent}%"
            );
            assert!(
                degraded.is_some_and(|p| (i32::from(p) - expected).abs() <= 3),
                "{share}: {degraded:?}"
            );
        }
        assert_eq!(rig.health(1), Health::Online, "{share}");
        for n in 2..=4 {
            assert_eq!(
                status.servo(id(n)).unwrap().degraded,
                None,
                "{share}: servo {n}"
            );
        }
        // The line is clean again: one "replies ok" (if it was degraded) within two windows.
        rig.servo(1).garble_share = 0.0;
        let from = rig.events.len();
        run_with_goals(&mut rig, crate::bus::quality::WINDOW * 2);
        let expected = if degrades {
            vec![BusEvent::RepliesOk { id: id(1) }]
        } else {
            vec![]
        };
        assert_eq!(quality_events(&rig.events[from..]), expected, "{share}");
        assert_eq!(rig.m.status().servo(id(1)).unwrap().degraded, None);
    }
}

#[test]
fn a_share_of_bad_replies_wandering_between_8_and_30_percent_gives_one_degraded() {
    let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
    let from = rig.events.len();
    // The share changes every 3 s, out of step with the windows, on both sides of 15 %.
    for share in [0.3, 0.12, 0.2, 0.08, 0.25, 0.12]
        .into_iter()
        .cycle()
        .take(20)
    {
        rig.servo(1).garble_share = share;
        run_with_goals(&mut rig, ms(3000));
    }
    let events = quality_events(&rig.events[from..]);
    assert!(
        matches!(events[..], [BusEvent::RepliesDegraded { .. }]),
        "{events:?}"
    );
    assert!(rig.m.status().servo(id(1)).unwrap().degraded.is_some());
}

#[test]
fn an_unplugged_servo_is_lost_not_degraded_and_back_when_plugged_in() {
    // A loose connector: 8 % of the replies garbled (not degraded), then none at all.
    // Unplugged at every 100 ms of a window: the silence before "lost" (300 ms, 15 % of a
    // window) falls at a window's end in some of these runs, and never counts as bad replies.
    for offset in (0..crate::bus::quality::WINDOW.as_millis() as u64).step_by(100) {
        let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
        rig.servo(1).garble_share = 0.08;
        run_with_goals(&mut rig, crate::bus::quality::WINDOW * 2 + ms(offset));
        let from = rig.events.len();
        rig.servo(1).present = false;
        run_with_goals(&mut rig, crate::bus::quality::WINDOW * 3);
        assert_eq!(
            quality_events(&rig.events[from..]),
            vec![BusEvent::ServoLost { id: id(1) }],
            "unplugged {offset} ms into a window"
        );
        assert_eq!(rig.health(1), Health::Offline);
        assert_eq!(rig.m.status().servo(id(1)).unwrap().degraded, None);
        let from = rig.events.len();
        rig.servo(1).present = true;
        rig.servo(1).garble_share = 0.0;
        run_with_goals(&mut rig, crate::bus::quality::WINDOW * 3);
        assert_eq!(
            quality_events(&rig.events[from..]),
            vec![BusEvent::ServoBack { id: id(1) }],
            "plugged in {offset} ms into a window"
        );
        assert_eq!(rig.health(1), Health::Online);
        assert_eq!(rig.m.status().servo(id(1)).unwrap().degraded, None);
    }
}

#[test]
fn a_degraded_servo_unplugged_is_lost_and_comes_back_without_its_old_state() {
    let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
    rig.servo(1).garble_share = 0.3;
    run_with_goals(&mut rig, crate::bus::quality::WINDOW * 3);
    assert!(rig.m.status().servo(id(1)).unwrap().degraded.is_some());
    let from = rig.events.len();
    rig.servo(1).present = false;
    run_with_goals(&mut rig, crate::bus::quality::WINDOW * 2);
    // "Lost" says more than a share of bad replies: the state goes without a word.
    assert_eq!(
        quality_events(&rig.events[from..]),
        vec![BusEvent::ServoLost { id: id(1) }]
    );
    assert_eq!(rig.m.status().servo(id(1)).unwrap().degraded, None);
    rig.servo(1).garble_share = 0.0;
    rig.servo(1).present = true;
    let from = rig.events.len();
    run_with_goals(&mut rig, crate::bus::quality::WINDOW * 3);
    assert_eq!(
        quality_events(&rig.events[from..]),
        vec![BusEvent::ServoBack { id: id(1) }]
    );
}

//! The servo's force: switched ON by the first position goal, before its long packet; hold,
//! OFF and brake goals (a held servo gets no entry, OFF and brake switch force, a position
//! after them switches it ON again with a soft start); a refused force ON retried with
//! back-off and reported once.

use super::*;

#[test]
fn first_goal_switches_force_on_before_the_long_packet() {
    let mut rig = Rig::with_ids(&[1]);
    rig.run(ms(100));
    rig.servo(1).position = 321;
    rig.run(ms(20));
    let from = rig.log.len();
    rig.set_goal(1, Goal::Position(MmCenti(400)));
    rig.run(ms(50));
    let kinds = rig.kinds_since(from);
    let force = kinds
        .iter()
        .position(|k| *k == TxKind::Force(id(1)))
        .unwrap();
    let command = kinds.iter().position(|k| *k == TxKind::Command).unwrap();
    assert!(force < command, "force ON first: {kinds:?}");
    // Force ON took the present position as goal; the first goal written is ours.
    assert_eq!(rig.servo(1).goal_writes.first().map(|w| w.0), Some(400));
    assert_eq!(rig.servo(1).position, 400);
    let st = rig.m.status();
    assert_eq!(st.servo(id(1)).unwrap().force, ForceState::On);
    assert_eq!(st.servo(id(1)).unwrap().goal, Some(MmCenti(400)));
}

#[test]
fn hold_sends_nothing_and_off_and_brake_switch_force() {
    let mut rig = Rig::online_with_force(&[1, 2]);
    rig.set_goal(1, Goal::Position(MmCenti(300)));
    rig.run(ms(20));
    let from = rig.log.len();
    rig.set_goal(1, Goal::Hold);
    rig.set_goal(2, Goal::Position(MmCenti(40)));
    rig.run(ms(20));
    let commands = rig.commands_since(from);
    assert_eq!(commands, vec![vec![(2, 40, None)]], "held servo left out");
    assert_eq!(rig.servo(1).position, 300);
    assert_eq!(rig.servo(1).force, 1);
    rig.set_goal(1, Goal::Off);
    rig.run(ms(20));
    assert_eq!(rig.servo(1).force, 0);
    assert_eq!(rig.m.status().servo(id(1)).unwrap().force, ForceState::Off);
    rig.set_goal(1, Goal::Brake);
    rig.run(ms(20));
    assert_eq!(rig.servo(1).force, 2);
    // Back to a position: force ON again, with a soft start.
    let from = rig.log.len();
    rig.set_goal(1, Goal::Position(MmCenti(500)));
    rig.run(ms(30));
    assert!(rig.kinds_since(from).contains(&TxKind::Force(id(1))));
    assert_eq!(rig.servo(1).force, 1);
    let commands = rig.commands_since(from);
    assert_eq!(commands[0][0], (1, 500, Some(20)), "2 mm at 10 mm/s");
}

#[test]
fn a_refused_force_on_is_retried_with_backoff() {
    let mut rig = Rig::with_ids(&[1]);
    rig.run(ms(100));
    rig.servo(1).refuse_force = true;
    let from = rig.log.len();
    rig.set_goal(1, Goal::Position(MmCenti(10)));
    rig.run(ms(4000));
    let tries: Vec<Instant> = rig
        .sent_since(from)
        .iter()
        .filter(|s| s.tx.kind == TxKind::Force(id(1)))
        .map(|s| s.at)
        .collect();
    let gaps: Vec<u128> = tries
        .windows(2)
        .map(|w| (w[1] - w[0]).as_millis())
        .collect();
    assert_eq!(tries.len(), 4, "at 0, 0.5, 1.5 and 3.5 s: {gaps:?}");
    for (gap, want) in gaps.iter().zip([500u128, 1000, 2000]) {
        assert!(*gap >= want && *gap <= want + 10, "{gaps:?}");
    }
    assert_eq!(
        rig.events
            .iter()
            .filter(|e| **e == BusEvent::ForceRefused { id: id(1) })
            .count(),
        1
    );
}

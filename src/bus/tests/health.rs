//! A servo's health over its missed replies: offline after enough timeouts and silence, then
//! probed with back-off; re-initialised (read again, force ON, its goal sent again) when it
//! answers again, or when a reply shows its force OFF after a restart no reply missed.

use super::*;

#[test]
fn a_servo_goes_offline_after_n_timeouts_and_is_probed_with_backoff() {
    let mut rig = Rig::online_with_force(&[1, 2]);
    rig.servo(2).present = false;
    let silent_from = rig.t;
    // Three missed replies are not enough: the servo must also have been silent for
    // `offline_after_silence`.
    while rig.m.status().servo(id(2)).unwrap().consecutive_timeouts < 3 {
        rig.run(ms(1));
    }
    assert_eq!(rig.health(2), Health::Online);
    assert!(!rig.events.contains(&BusEvent::ServoLost { id: id(2) }));
    while !rig.events.contains(&BusEvent::ServoLost { id: id(2) }) {
        rig.run(ms(1));
        assert!(
            rig.t - silent_from < ms(400),
            "not lost after 400 ms of silence"
        );
    }
    assert!(
        rig.t - silent_from >= ms(300),
        "lost after {:?}",
        rig.t - silent_from
    );
    assert_eq!(rig.health(2), Health::Offline);
    assert!(rig.m.status().servo(id(2)).unwrap().consecutive_timeouts >= 3);
    assert_eq!(
        rig.health(1),
        Health::Online,
        "the other servo is unaffected"
    );
    let from = rig.log.len();
    rig.run(ms(8000));
    let probes: Vec<Instant> = rig
        .sent_since(from)
        .iter()
        .filter(|s| s.tx.kind == TxKind::Probe(id(2)))
        .map(|s| s.at)
        .collect();
    let gaps: Vec<u128> = probes
        .windows(2)
        .map(|w| (w[1] - w[0]).as_millis())
        .collect();
    // 100 ms after going offline, then 200, 400, 800, 1600, 2000, 2000 … (each gap also
    // holds the probe's own timeout and at most one other poll).
    let expect = [200u128, 400, 800, 1600, 2000, 2000];
    assert!(gaps.len() >= expect.len(), "{gaps:?}");
    for (gap, want) in gaps.iter().zip(expect) {
        assert!(
            *gap >= want && *gap <= want + 20,
            "gaps {gaps:?}, expected {expect:?}"
        );
    }
    // Polls of the offline servo are probes only.
    assert!(
        !rig.kinds_since(from).contains(&TxKind::Poll(id(2))),
        "offline servo not polled"
    );
}

#[test]
fn a_servo_that_comes_back_is_reinitialised() {
    let mut rig = Rig::online_with_force(&[1, 2]);
    rig.set_goal(2, Goal::Position(MmCenti(500)));
    rig.run(ms(3000));
    assert_eq!(rig.servo(2).position, 500);
    rig.servo(2).present = false;
    rig.run(ms(500));
    assert_eq!(rig.health(2), Health::Offline);
    // Power-cycled while away: force OFF, goal 0.
    rig.servo(2).power_cycle();
    rig.servo(2).present = true;
    let from = rig.log.len();
    let ev_from = rig.events.len();
    rig.run(ms(2500));
    assert_eq!(rig.health(2), Health::Online);
    let events = &rig.events[ev_from..];
    assert!(events.contains(&BusEvent::ServoBack { id: id(2) }));
    assert!(events.contains(&BusEvent::ServoOnline { id: id(2) }));
    let kinds: Vec<TxKind> = rig
        .kinds_since(from)
        .into_iter()
        .filter(
            |k| matches!(k, TxKind::Probe(i) | TxKind::Init(i) | TxKind::Force(i) if *i == id(2)),
        )
        .collect();
    let probe = kinds
        .iter()
        .rposition(|k| *k == TxKind::Probe(id(2)))
        .unwrap();
    assert_eq!(
        &kinds[probe..],
        &[
            TxKind::Probe(id(2)),
            TxKind::Init(id(2)),
            TxKind::Force(id(2))
        ],
        "re-read then force ON again"
    );
    assert_eq!(rig.servo(2).force, 1);
    assert_eq!(rig.servo(2).goal, 500, "its goal is sent again");
}

#[test]
fn a_servo_found_force_off_is_reinitialised() {
    let mut rig = Rig::online_with_force(&[1]);
    rig.set_goal(1, Goal::Position(MmCenti(700)));
    rig.run(ms(2000));
    // A quick power cycle: no reply missed, but force is off and the goal is gone.
    rig.servo(1).power_cycle();
    rig.run(ms(1500));
    assert!(rig.events.contains(&BusEvent::ServoRestarted { id: id(1) }));
    assert_eq!(rig.servo(1).force, 1);
    assert_eq!(rig.servo(1).goal, 700);
}

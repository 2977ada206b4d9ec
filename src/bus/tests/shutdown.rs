//! Shutdown: the bus master waits for the pending reply, then writes its last packets as asked
//! (force OFF or brake for every servo, or the newest goals as they are) and nothing after.

use super::*;

#[test]
fn shutdown_waits_for_the_pending_reply_then_switches_force_off() {
    let mut rig = Rig::online_with_force(&[1, 2]);
    rig.run(ms(1));
    assert!(rig.m.reply_pending());
    rig.m.shutdown(ShutdownForce::Off);
    assert!(rig.m.poll_transmit(rig.t).is_none(), "reply still pending");
    assert!(!rig.m.is_shut_down());
    let from = rig.log.len();
    rig.run(ms(20));
    let kinds = rig.kinds_since(from);
    assert_eq!(
        kinds,
        vec![TxKind::Final(Some(id(1))), TxKind::Final(Some(id(2)))]
    );
    assert!(rig.m.is_shut_down());
    assert_eq!(rig.servo(1).force, 0);
    assert_eq!(rig.servo(2).force, 0);

    let mut rig = Rig::online_with_force(&[1, 2]);
    rig.run(ms(1));
    rig.set_goal(2, Goal::Position(MmCenti(-5)));
    rig.m.shutdown(ShutdownForce::AsIs);
    let from = rig.log.len();
    rig.run(ms(100));
    assert_eq!(
        rig.kinds_since(from),
        vec![TxKind::Command],
        "newest goals, then nothing"
    );
    assert_eq!(rig.servo(2).position, -5);
    assert_eq!(rig.servo(2).force, 1);

    let mut rig = Rig::online_with_force(&[1, 2]);
    rig.run(ms(1));
    rig.m.shutdown(ShutdownForce::Brake);
    let from = rig.log.len();
    rig.run(ms(20));
    assert_eq!(
        rig.kinds_since(from),
        vec![TxKind::Final(Some(id(1))), TxKind::Final(Some(id(2)))]
    );
    assert_eq!(rig.servo(1).force, 2);
    assert_eq!(rig.servo(2).force, 2);
}

//! The port lost and back, as the driver reports it: the pending reply is dropped (not counted
//! as a timeout), the events say so, and when the port is back the goals go out first.

use super::*;

#[test]
fn a_lost_port_drops_the_pending_reply_and_resends_goals_when_back() {
    let mut rig = Rig::online_with_force(&[1, 2]);
    rig.set_goal(1, Goal::Position(MmCenti(10)));
    rig.run(ms(10));
    assert!(rig.m.reply_pending());
    let t = rig.t;
    rig.m.handle_port_lost("read failed: EIO", t);
    rig.reply = None;
    assert!(!rig.m.reply_pending());
    assert!(!rig.m.status().port_open);
    assert_eq!(
        rig.m.poll_event(),
        Some(BusEvent::PortLost {
            reason: "read failed: EIO".into()
        })
    );
    let timeouts = rig.m.counters().timeouts;
    rig.t = t + ms(300);
    rig.m.handle_port_back(rig.t);
    rig.wire_free = rig.t;
    assert_eq!(rig.m.poll_event(), Some(BusEvent::PortBack));
    let from = rig.log.len();
    rig.run(ms(20));
    assert_eq!(
        rig.m.counters().timeouts,
        timeouts,
        "a lost port is not a timeout"
    );
    assert_eq!(rig.kinds_since(from)[0], TxKind::Command, "goals first");
    assert_eq!(
        rig.commands_since(from)[0],
        vec![(1, 10, None), (2, 0, None)]
    );
}

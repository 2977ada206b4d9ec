//! Commands to the bridge (DO_SET_SERVO, DO_SET_ACTUATOR, as COMMAND_LONG or COMMAND_INT,
//! addressed or broadcast), driven through the sans-IO core at exact instants.

mod mavlink_support;

use lj9da_bridge::bus::Goal;
use lj9da_bridge::protocol::MmCenti;
use mavlink::dialects::common::*;
use mavlink_support::{AP, acks, command_long, commands, header, messages, outputs, running};
use std::time::Instant;

#[test]
fn do_set_servo_addressed_to_the_bridge_moves_the_servo_and_is_acknowledged() {
    let t0 = Instant::now();
    let mut c = running(t0);
    messages(&mut c);
    let gcs = (255, 190);
    let set = |ch: f32, us: f32, to| {
        command_long(
            MavCmd::MAV_CMD_DO_SET_SERVO,
            [ch, us, 0.0, 0.0, 0.0, 0.0, 0.0],
            to,
        )
    };
    c.handle_message(0, &header(gcs), &set(9.0, 1568.0, (7, 140)), t0);
    assert_eq!(commands(&mut c), vec![(2, Goal::Position(MmCenti(200)))]);
    assert_eq!(
        acks(&messages(&mut c)),
        vec![(
            MavCmd::MAV_CMD_DO_SET_SERVO,
            MavResult::MAV_RESULT_ACCEPTED,
            255,
            190
        )]
    );
    // Not for us: ignored, no ACK.
    c.handle_message(0, &header(gcs), &set(9.0, 1600.0, (7, 1)), t0);
    assert!(commands(&mut c).is_empty());
    assert!(acks(&messages(&mut c)).is_empty());
    // A channel no servo listens to is denied.
    c.handle_message(0, &header(gcs), &set(5.0, 1600.0, (7, 140)), t0);
    assert_eq!(acks(&messages(&mut c))[0].1, MavResult::MAV_RESULT_DENIED);
    // The override holds while the autopilot's own value of the channel stays as it was ...
    c.handle_message(0, &header(AP), &outputs(0, &[(1, 1520)]), t0);
    assert!(commands(&mut c).is_empty());
    // ... and ends when the autopilot's output changes.
    c.handle_message(0, &header(AP), &outputs(0, &[(1, 1520), (9, 1544)]), t0);
    assert_eq!(commands(&mut c), vec![(2, Goal::Position(MmCenti(100)))]);
}

#[test]
fn do_set_actuator_moves_the_servo_of_that_actuator_and_nan_leaves_it() {
    let t0 = Instant::now();
    let mut c = running(t0);
    messages(&mut c);
    let gcs = (255, 190);
    let nan = f32::NAN;
    // Set 0: params 1–6 are actuators 1–6. The gear servo is actuator 2: +0.5 → +12.5 mm.
    let set = |p2: f32, index: f32| {
        command_long(
            MavCmd::MAV_CMD_DO_SET_ACTUATOR,
            [nan, p2, nan, nan, nan, nan, index],
            (7, 140),
        )
    };
    c.handle_message(0, &header(gcs), &set(0.5, 0.0), t0);
    assert_eq!(commands(&mut c), vec![(2, Goal::Position(MmCenti(1250)))]);
    assert_eq!(acks(&messages(&mut c))[0].1, MavResult::MAV_RESULT_ACCEPTED);
    // NaN for its parameter: left as it is, and no servo matched.
    c.handle_message(0, &header(gcs), &set(nan, 0.0), t0);
    assert!(commands(&mut c).is_empty());
    assert_eq!(acks(&messages(&mut c))[0].1, MavResult::MAV_RESULT_DENIED);
    // Set 1 is actuators 7–12: nobody there.
    c.handle_message(0, &header(gcs), &set(0.5, 1.0), t0);
    assert!(commands(&mut c).is_empty());
    assert_eq!(acks(&messages(&mut c))[0].1, MavResult::MAV_RESULT_DENIED);
}

#[test]
fn do_set_actuator_outside_minus_1_to_1_is_denied_and_moves_nothing() {
    let t0 = Instant::now();
    let mut c = running(t0);
    messages(&mut c);
    let gcs = (255, 190);
    let nan = f32::NAN;
    for value in [1.5, -1.01, f32::INFINITY, f32::NEG_INFINITY] {
        let set = command_long(
            MavCmd::MAV_CMD_DO_SET_ACTUATOR,
            [nan, value, nan, nan, nan, nan, 0.0],
            (7, 140),
        );
        c.handle_message(0, &header(gcs), &set, t0);
        assert!(
            commands(&mut c).is_empty(),
            "{value}: the servo neither moves nor holds"
        );
        assert_eq!(
            acks(&messages(&mut c)),
            vec![(
                MavCmd::MAV_CMD_DO_SET_ACTUATOR,
                MavResult::MAV_RESULT_DENIED,
                255,
                190
            )],
            "{value}"
        );
    }
    // A bad value for an actuator of no servo of ours denies the command too: it is one command.
    let set = command_long(
        MavCmd::MAV_CMD_DO_SET_ACTUATOR,
        [3.0, 0.5, nan, nan, nan, nan, 0.0],
        (7, 140),
    );
    c.handle_message(0, &header(gcs), &set, t0);
    assert!(commands(&mut c).is_empty());
    assert_eq!(acks(&messages(&mut c))[0].1, MavResult::MAV_RESULT_DENIED);
}

#[test]
fn do_set_servo_outside_the_servos_pwm_range_is_denied_and_moves_nothing() {
    let t0 = Instant::now();
    let mut c = running(t0);
    messages(&mut c);
    let gcs = (255, 190);
    // The gear on channel 9 has the default range 920–2120 µs.
    for us in [0.0, 900.0, 2121.0, 65535.0] {
        let set = command_long(
            MavCmd::MAV_CMD_DO_SET_SERVO,
            [9.0, us, 0.0, 0.0, 0.0, 0.0, 0.0],
            (7, 140),
        );
        c.handle_message(0, &header(gcs), &set, t0);
        assert!(commands(&mut c).is_empty(), "{us} µs");
        assert_eq!(
            acks(&messages(&mut c))[0].1,
            MavResult::MAV_RESULT_DENIED,
            "{us} µs"
        );
    }
    let set = command_long(
        MavCmd::MAV_CMD_DO_SET_SERVO,
        [9.0, 2120.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        (7, 140),
    );
    c.handle_message(0, &header(gcs), &set, t0);
    assert_eq!(commands(&mut c), vec![(2, Goal::Position(MmCenti(2500)))]);
    assert_eq!(acks(&messages(&mut c))[0].1, MavResult::MAV_RESULT_ACCEPTED);
}

fn command_int(
    command: MavCmd,
    params: [f32; 4],
    xyz: (i32, i32, f32),
    target: (u8, u8),
) -> MavMessage {
    MavMessage::COMMAND_INT(COMMAND_INT_DATA {
        param1: params[0],
        param2: params[1],
        param3: params[2],
        param4: params[3],
        x: xyz.0,
        y: xyz.1,
        z: xyz.2,
        command,
        target_system: target.0,
        target_component: target.1,
        ..Default::default()
    })
}

#[test]
fn command_int_addressed_to_the_bridge_is_carried_out_and_always_acknowledged() {
    let t0 = Instant::now();
    let mut c = running(t0);
    messages(&mut c);
    let gcs = (255, 190);
    let set = command_int(
        MavCmd::MAV_CMD_DO_SET_SERVO,
        [9.0, 1568.0, 0.0, 0.0],
        (0, 0, 0.0),
        (7, 140),
    );
    c.handle_message(0, &header(gcs), &set, t0);
    assert_eq!(commands(&mut c), vec![(2, Goal::Position(MmCenti(200)))]);
    assert_eq!(
        acks(&messages(&mut c)),
        vec![(
            MavCmd::MAV_CMD_DO_SET_SERVO,
            MavResult::MAV_RESULT_ACCEPTED,
            255,
            190
        )]
    );
    // DO_SET_ACTUATOR: actuators 5 and 6 travel in x and y × 1e7, INT32_MAX leaves one; the
    // gear is actuator 2 (param 2).
    let set = command_int(
        MavCmd::MAV_CMD_DO_SET_ACTUATOR,
        [f32::NAN, -0.5, f32::NAN, f32::NAN],
        (i32::MAX, i32::MAX, 0.0),
        (7, 140),
    );
    c.handle_message(0, &header(gcs), &set, t0);
    assert_eq!(commands(&mut c), vec![(2, Goal::Position(MmCenti(-1250)))]);
    assert_eq!(acks(&messages(&mut c))[0].1, MavResult::MAV_RESULT_ACCEPTED);
    // Any other command: answered UNSUPPORTED rather than left to time out.
    let other = command_int(
        MavCmd::MAV_CMD_DO_REPOSITION,
        [0.0; 4],
        (0, 0, 0.0),
        (7, 140),
    );
    c.handle_message(0, &header(gcs), &other, t0);
    assert_eq!(
        acks(&messages(&mut c)),
        vec![(
            MavCmd::MAV_CMD_DO_REPOSITION,
            MavResult::MAV_RESULT_UNSUPPORTED,
            255,
            190
        )]
    );
    // Addressed to the autopilot: not ours.
    let set = command_int(
        MavCmd::MAV_CMD_DO_SET_SERVO,
        [9.0, 1600.0, 0.0, 0.0],
        (0, 0, 0.0),
        (7, 1),
    );
    c.handle_message(0, &header(gcs), &set, t0);
    assert!(commands(&mut c).is_empty());
    assert!(acks(&messages(&mut c)).is_empty());
}

#[test]
fn a_broadcast_do_set_servo_is_left_to_the_autopilot_whose_output_the_bridge_follows() {
    let t0 = Instant::now();
    let mut c = running(t0);
    messages(&mut c);
    let gcs = (255, 190);
    for target in [(7, 0), (0, 0)] {
        let set = command_long(
            MavCmd::MAV_CMD_DO_SET_SERVO,
            [9.0, 1568.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            target,
        );
        c.handle_message(0, &header(gcs), &set, t0);
        assert!(
            commands(&mut c).is_empty(),
            "{target:?}: not acted on twice"
        );
        assert!(
            acks(&messages(&mut c)).is_empty(),
            "{target:?}: the autopilot answers"
        );
    }
    // The autopilot carries it out: its output carries the value, and the servo follows.
    c.handle_message(0, &header(AP), &outputs(0, &[(1, 1520), (9, 1568)]), t0);
    assert_eq!(commands(&mut c), vec![(2, Goal::Position(MmCenti(200)))]);
}

#[test]
fn a_broadcast_do_set_actuator_moves_the_servos_named_for_that_actuator() {
    let t0 = Instant::now();
    let mut c = running(t0);
    messages(&mut c);
    let gcs = (255, 190);
    let nan = f32::NAN;
    let set = |p2: f32, index: f32, target| {
        command_long(
            MavCmd::MAV_CMD_DO_SET_ACTUATOR,
            [nan, p2, nan, nan, nan, nan, index],
            target,
        )
    };
    c.handle_message(0, &header(gcs), &set(0.5, 0.0, (7, 0)), t0);
    assert_eq!(commands(&mut c), vec![(2, Goal::Position(MmCenti(1250)))]);
    assert_eq!(
        acks(&messages(&mut c)),
        vec![(
            MavCmd::MAV_CMD_DO_SET_ACTUATOR,
            MavResult::MAV_RESULT_ACCEPTED,
            255,
            190
        )]
    );
    // An actuator set with none of ours: silence, the autopilot's answer stands alone.
    c.handle_message(0, &header(gcs), &set(0.5, 1.0, (7, 0)), t0);
    assert!(commands(&mut c).is_empty());
    assert!(acks(&messages(&mut c)).is_empty());
    // Any other broadcast command is not the bridge's: no answer.
    let other = command_long(
        MavCmd::MAV_CMD_REQUEST_MESSAGE,
        [36.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        (7, 0),
    );
    c.handle_message(0, &header(gcs), &other, t0);
    assert!(acks(&messages(&mut c)).is_empty());
}

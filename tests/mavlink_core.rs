//! The bridge's MAVLink rules, driven through the sans-IO core at exact instants.

use lj9da_bridge::bus::Goal;
use lj9da_bridge::config::Config;
use lj9da_bridge::mavlink::outputs::servo_output_raw;
use lj9da_bridge::mavlink::{
    BridgeCore, BridgeEvent, Outgoing, ServoEvent, ServoReport, ServoState, TemperatureReading,
};
use lj9da_bridge::protocol::MmCenti;
use mavlink::MavHeader;
use mavlink::dialects::common::*;
use std::time::{Duration, Instant};

const MAPPING: &str = r#"
[mavlink]
connection = "udpin:0.0.0.0:14560"
failsafe_timeout_ms = 500
output_rate_hz = 50

[telemetry]
rate_hz = 5

[[bus]]
name = "wing"
port = "/dev/null"

[[servo]]
name = "aileron_left"
label = "ail_l"
bus = "wing"
id = 1
channel = 1
failsafe = "hold"

[[servo]]
name = "aileron_right"
label = "ail_r"
bus = "wing"
id = 2
channel = 18
reverse = true
failsafe = 5.0

[[servo]]
name = "gear"
bus = "wing"
id = 3
channel = 9
failsafe = "off"
actuator = 2
"#;

const AP: (u8, u8) = (7, 1);

fn core(t0: Instant) -> BridgeCore {
    BridgeCore::new(
        Config::parse(MAPPING, "test.toml").expect("test mapping is valid"),
        t0,
    )
}

fn header(from: (u8, u8)) -> MavHeader {
    MavHeader {
        system_id: u32::from(from.0),
        component_id: from.1,
        sequence: 0,
    }
}

fn autopilot_heartbeat() -> MavMessage {
    MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        mavtype: MavType::MAV_TYPE_FIXED_WING,
        autopilot: MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
        ..Default::default()
    })
}

fn outputs(port: u8, values: &[(usize, u16)]) -> MavMessage {
    let mut raw = [0u16; 16];
    for (i, v) in values {
        raw[*i - 1] = *v;
    }
    servo_output_raw(port, raw, 0)
}

fn commands(c: &mut BridgeCore) -> Vec<(usize, Goal)> {
    std::iter::from_fn(|| c.poll_command()).collect()
}

fn messages(c: &mut BridgeCore) -> Vec<Outgoing> {
    std::iter::from_fn(|| c.poll_message()).collect()
}

fn statustexts(out: &[Outgoing]) -> Vec<(MavSeverity, String)> {
    out.iter()
        .filter_map(|o| match &o.message {
            MavMessage::STATUSTEXT(s) => Some((s.severity, s.text.to_str().unwrap().to_string())),
            _ => None,
        })
        .collect()
}

/// A core that knows its autopilot and has had one output message.
fn running(t0: Instant) -> BridgeCore {
    let mut c = core(t0);
    c.handle_message(0, &header(AP), &autopilot_heartbeat(), t0);
    c.handle_message(0, &header(AP), &outputs(0, &[(1, 1520)]), t0);
    commands(&mut c);
    c
}

#[test]
fn the_autopilot_is_learned_from_its_heartbeat_and_strangers_are_ignored() {
    let t0 = Instant::now();
    let mut c = core(t0);
    // Outputs before any heartbeat: nobody is the autopilot yet.
    c.handle_message(0, &header(AP), &outputs(0, &[(1, 1544)]), t0);
    assert!(commands(&mut c).is_empty());
    // A GCS heartbeat does not make an autopilot.
    let gcs = MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        mavtype: MavType::MAV_TYPE_GCS,
        autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
        ..Default::default()
    });
    c.handle_message(0, &header((255, 190)), &gcs, t0);
    assert_eq!(c.autopilot(), None);
    c.handle_message(0, &header(AP), &autopilot_heartbeat(), t0);
    assert_eq!(c.autopilot(), Some(AP));
    assert_eq!(
        c.header().unwrap().system_id,
        7,
        "the bridge takes the vehicle's system id"
    );
    assert_eq!(
        c.header().unwrap().component_id,
        140,
        "MAV_COMP_ID_SERVO1 by default"
    );
    // Another system's outputs are not obeyed.
    c.handle_message(0, &header((8, 1)), &outputs(0, &[(1, 1544)]), t0);
    assert!(commands(&mut c).is_empty());
    c.handle_message(0, &header(AP), &outputs(0, &[(1, 1544)]), t0);
    assert_eq!(commands(&mut c)[0], (0, Goal::Position(MmCenti(100))));
}

#[test]
fn channels_17_to_32_arrive_on_port_1_and_9_to_16_in_the_extension_fields() {
    let t0 = Instant::now();
    let mut c = core(t0);
    c.handle_message(0, &header(AP), &autopilot_heartbeat(), t0);
    c.handle_message(0, &header(AP), &outputs(0, &[(1, 920), (9, 2120)]), t0);
    let got = commands(&mut c);
    assert!(got.contains(&(0, Goal::Position(MmCenti(-2500)))));
    assert!(got.contains(&(2, Goal::Position(MmCenti(2500)))));
    assert!(
        !got.iter().any(|(s, _)| *s == 1),
        "channel 18 is not in port 0"
    );
    // Channel 18 = port 1, servo 2; that servo is reversed.
    c.handle_message(0, &header(AP), &outputs(1, &[(2, 1544)]), t0);
    assert_eq!(commands(&mut c), vec![(1, Goal::Position(MmCenti(-100)))]);
}

#[test]
fn no_output_values_make_the_servo_hold() {
    let t0 = Instant::now();
    let mut c = running(t0);
    for us in [0, 65535, 919, 2121] {
        c.handle_message(0, &header(AP), &outputs(0, &[(1, 1600)]), t0);
        commands(&mut c);
        c.handle_message(0, &header(AP), &outputs(0, &[(1, us)]), t0);
        assert_eq!(commands(&mut c), vec![(0, Goal::Hold)], "{us} µs");
    }
}

#[test]
fn an_unchanged_goal_is_not_sent_again() {
    let t0 = Instant::now();
    let mut c = running(t0);
    c.handle_message(0, &header(AP), &outputs(0, &[(1, 1600)]), t0);
    assert_eq!(commands(&mut c).len(), 1);
    c.handle_message(0, &header(AP), &outputs(0, &[(1, 1600)]), t0);
    assert!(commands(&mut c).is_empty());
}

fn interval_requests(out: &[Outgoing]) -> Vec<(f32, f32, u8, u8)> {
    out.iter()
        .filter_map(|o| match &o.message {
            MavMessage::COMMAND_LONG(c) if c.command == MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL => {
                Some((c.param1, c.param2, c.target_system, c.target_component))
            }
            _ => None,
        })
        .collect()
}

#[test]
fn the_output_stream_is_requested_until_accepted_and_a_denied_rate_is_lowered() {
    let t0 = Instant::now();
    let mut c = core(t0);
    c.handle_message(0, &header(AP), &autopilot_heartbeat(), t0);
    c.handle_timeout(t0, &[]);
    let out = messages(&mut c);
    assert_eq!(
        interval_requests(&out),
        vec![(36.0, 20_000.0, 7, 1)],
        "50 Hz = 20 000 µs"
    );
    // No answer: asked again a second later, not before.
    c.handle_timeout(t0 + Duration::from_millis(999), &[]);
    assert!(interval_requests(&messages(&mut c)).is_empty());
    c.handle_timeout(t0 + Duration::from_secs(1), &[]);
    assert_eq!(interval_requests(&messages(&mut c)).len(), 1);
    // Denied (ArduPilot: above 0.8 × SCHED_LOOP_RATE): ask for 40 Hz and tell the user why.
    let ack = |result| {
        MavMessage::COMMAND_ACK(COMMAND_ACK_DATA {
            command: MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL,
            result,
            target_system: 7,
            target_component: 140,
            ..Default::default()
        })
    };
    c.handle_message(
        0,
        &header(AP),
        &ack(MavResult::MAV_RESULT_DENIED),
        t0 + Duration::from_secs(1),
    );
    assert_eq!(c.requested_rate_hz(), 40.0);
    assert!(c.take_notes().iter().any(|n| n.contains("SCHED_LOOP_RATE")));
    c.handle_timeout(t0 + Duration::from_millis(1001), &[]);
    assert_eq!(
        interval_requests(&messages(&mut c)),
        vec![(36.0, 25_000.0, 7, 1)]
    );
    c.handle_message(
        0,
        &header(AP),
        &ack(MavResult::MAV_RESULT_ACCEPTED),
        t0 + Duration::from_secs(1),
    );
    c.handle_timeout(t0 + Duration::from_secs(5), &[]);
    assert!(
        interval_requests(&messages(&mut c)).is_empty(),
        "accepted: no more requests"
    );
}

#[test]
fn a_stream_at_the_asked_rate_ends_the_requests_without_an_ack() {
    let t0 = Instant::now();
    let mut c = core(t0);
    c.handle_message(0, &header(AP), &autopilot_heartbeat(), t0);
    for i in 0..=120u64 {
        let t = t0 + Duration::from_millis(20 * i);
        c.handle_message(0, &header(AP), &outputs(0, &[(1, 1520)]), t);
        c.handle_timeout(t, &[]);
    }
    messages(&mut c);
    c.handle_timeout(t0 + Duration::from_millis(2500), &[]);
    assert!(interval_requests(&messages(&mut c)).is_empty());
}

#[test]
fn failsafe_is_entered_after_the_timeout_and_left_on_the_next_output() {
    let t0 = Instant::now();
    let mut c = running(t0);
    messages(&mut c);
    c.handle_timeout(t0 + Duration::from_millis(499), &[]);
    assert!(!c.in_failsafe());
    assert!(c.poll_timeout() <= t0 + Duration::from_millis(500));
    c.handle_timeout(t0 + Duration::from_millis(500), &[]);
    assert!(c.in_failsafe());
    let got = commands(&mut c);
    assert!(got.contains(&(0, Goal::Hold)));
    assert!(
        got.contains(&(1, Goal::Position(MmCenti(500)))),
        "failsafe position 5 mm"
    );
    assert!(got.contains(&(2, Goal::Off)));
    let texts = statustexts(&messages(&mut c));
    assert_eq!(
        texts,
        vec![(
            MavSeverity::MAV_SEVERITY_WARNING,
            "LJ9DA failsafe: no outputs for 500 ms".to_string()
        )]
    );
    // Staying in failsafe announces nothing more.
    c.handle_timeout(t0 + Duration::from_secs(3), &[]);
    assert!(statustexts(&messages(&mut c)).is_empty());
    c.handle_message(
        0,
        &header(AP),
        &outputs(0, &[(1, 1568)]),
        t0 + Duration::from_secs(4),
    );
    assert!(!c.in_failsafe());
    assert!(commands(&mut c).contains(&(0, Goal::Position(MmCenti(200)))));
    let texts = statustexts(&messages(&mut c));
    assert_eq!(
        texts,
        vec![(
            MavSeverity::MAV_SEVERITY_NOTICE,
            "LJ9DA failsafe cleared".to_string()
        )]
    );
}

fn command_long(command: MavCmd, params: [f32; 7], target: (u8, u8)) -> MavMessage {
    MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
        param1: params[0],
        param2: params[1],
        param3: params[2],
        param4: params[3],
        param5: params[4],
        param6: params[5],
        param7: params[6],
        command,
        target_system: target.0,
        target_component: target.1,
        confirmation: 0,
    })
}

fn acks(out: &[Outgoing]) -> Vec<(MavCmd, MavResult, u8, u8)> {
    out.iter()
        .filter_map(|o| match &o.message {
            MavMessage::COMMAND_ACK(a) => {
                Some((a.command, a.result, a.target_system, a.target_component))
            }
            _ => None,
        })
        .collect()
}

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
fn heartbeat_goes_out_once_a_second_with_the_worst_servo_state() {
    let t0 = Instant::now();
    let mut c = running(t0);
    let ok = ServoReport {
        state: Some(ServoState::Online),
        position_mm: Some(0.0),
        current_a: Some(0.07),
        temperature_c: Some(30.0),
        voltage_v: Some(12.0),
        ..Default::default()
    };
    let lost = ServoReport {
        state: Some(ServoState::Offline),
        ..Default::default()
    };
    let mut heartbeats = Vec::new();
    for ms in (0..=3000).step_by(10) {
        c.handle_timeout(t0 + Duration::from_millis(ms), &[ok, ok, lost]);
        for o in messages(&mut c) {
            if let MavMessage::HEARTBEAT(h) = o.message {
                heartbeats.push(h);
            }
        }
    }
    assert_eq!(heartbeats.len(), 4, "at 0, 1, 2 and 3 s");
    assert!(
        heartbeats
            .iter()
            .all(|h| h.mavtype == MavType::MAV_TYPE_SERVO
                && h.autopilot == MavAutopilot::MAV_AUTOPILOT_INVALID
                && h.system_status == MavState::MAV_STATE_EMERGENCY)
    );
}

#[test]
fn servo_telemetry_goes_out_at_the_configured_rate_with_named_values_and_esc_blocks() {
    let t0 = Instant::now();
    let mut c = running(t0);
    let r = ServoReport {
        state: Some(ServoState::Online),
        position_mm: Some(-12.02),
        current_a: Some(0.06),
        temperature_c: Some(45.0),
        voltage_v: Some(11.1),
        ..Default::default()
    };
    let mut named = Vec::new();
    let mut esc_status = 0;
    for ms in (0..1000).step_by(5) {
        c.handle_timeout(t0 + Duration::from_millis(ms), &[r, r, r]);
        for o in messages(&mut c) {
            match o.message {
                MavMessage::NAMED_VALUE_FLOAT(v) => {
                    named.push((v.name.to_str().unwrap().to_string(), v.value))
                }
                MavMessage::ESC_STATUS(_) => esc_status += 1,
                _ => {}
            }
        }
    }
    assert_eq!(esc_status, 5, "5 Hz × 1 block of four");
    assert_eq!(named.len(), 5 * 3 * 4);
    assert!(named.contains(&("ail_l_pos".to_string(), -12.02)));
    assert!(named.contains(&("gear_tmp".to_string(), 45.0)));
}

#[test]
fn events_become_one_statustext_each() {
    let t0 = Instant::now();
    let mut c = running(t0);
    messages(&mut c);
    c.event(
        BridgeEvent::Servo {
            servo: 0,
            event: ServoEvent::TemperatureAlarm {
                on: true,
                celsius: Some(76),
            },
        },
        t0,
    );
    c.event(
        BridgeEvent::Servo {
            servo: 0,
            event: ServoEvent::TemperatureError {
                last_read: Some(TemperatureReading {
                    celsius: 85,
                    age: Duration::from_millis(400),
                }),
            },
        },
        t0,
    );
    let texts = statustexts(&messages(&mut c));
    assert_eq!(
        texts,
        vec![
            (
                MavSeverity::MAV_SEVERITY_WARNING,
                "aileron_left: temperature alarm 76C".to_string()
            ),
            (
                MavSeverity::MAV_SEVERITY_CRITICAL,
                "aileron_left: overheat, force off; 85C 0.4s ago".to_string()
            ),
        ]
    );
}

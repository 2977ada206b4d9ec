//! The bridge's MAVLink rules, driven through the sans-IO core at exact instants.

mod mavlink_support;

use lj9da_bridge::bus::Goal;
use lj9da_bridge::config::Config;
use lj9da_bridge::mavlink::core::{NO_STATUS_AFTER, sys_status};
use lj9da_bridge::mavlink::{BridgeCore, Outgoing};
use lj9da_bridge::protocol::MmCenti;
use mavlink::MavHeader;
use mavlink::dialects::common::*;
use mavlink_support::{
    AP, MAPPING, acks, autopilot_heartbeat, command_long, commands, core, header, messages,
    outputs, running, running_on, statustexts,
};
use std::time::{Duration, Instant};

/// The links' readers drop every kind of message [`BridgeCore::handles`] leaves out (see
/// `mavlink::admission`): each of them, from the autopilot on its link, changes nothing the
/// core says or does.
#[test]
fn every_kind_the_readers_drop_is_one_the_core_ignores() {
    use mavlink::Message;
    let t0 = Instant::now();
    let mut c = running(t0);
    messages(&mut c);
    c.take_notes();
    c.take_output_ticks();
    let mut kinds = 0;
    for id in 0..=u32::from(u16::MAX) {
        let Some(message) = MavMessage::default_message_from_id(id) else {
            continue;
        };
        if BridgeCore::handles(&message) {
            continue;
        }
        kinds += 1;
        c.handle_message(0, &header(AP), &message, t0);
        assert_eq!(commands(&mut c), [], "{}", message.message_name());
        let out = messages(&mut c);
        assert!(
            out.is_empty(),
            "{}: {:?}",
            message.message_name(),
            out.first()
        );
        assert!(c.take_notes().is_empty(), "{}", message.message_name());
        assert!(
            c.take_output_ticks().is_empty(),
            "{}",
            message.message_name()
        );
        assert!(c.poll_param_set().is_none(), "{}", message.message_name());
    }
    assert!(kinds > 100, "{kinds} kinds tried");
}

#[test]
fn the_autopilots_heartbeat_is_relayed_to_the_ground_station_link_under_its_own_ids() {
    // QGroundControl creates a vehicle only from an autopilot's HEARTBEAT: the `gcs` link
    // must carry one, or it shows nothing of the bridge there.
    let t0 = Instant::now();
    let mapping = MAPPING.replace(
        "failsafe_timeout_ms = 500",
        "failsafe_timeout_ms = 500\ngcs = \"udpout:127.0.0.1:14550\"",
    );
    let mut c = BridgeCore::new(Config::parse(&mapping, "t.toml").unwrap(), t0);
    c.handle_message(0, &header(AP), &autopilot_heartbeat(), t0);
    let relayed: Vec<Outgoing> = messages(&mut c)
        .into_iter()
        .filter(|o| matches!(o.message, MavMessage::HEARTBEAT(_)))
        .collect();
    assert_eq!(
        relayed,
        vec![Outgoing {
            message: autopilot_heartbeat(),
            link: Some(1),
            sender: Some(header(AP)),
        }]
    );
    // Another system's heartbeat, or the autopilot's heard on the GCS link, is not relayed.
    c.handle_message(0, &header((9, 1)), &autopilot_heartbeat(), t0);
    c.handle_message(1, &header(AP), &autopilot_heartbeat(), t0);
    assert!(messages(&mut c).is_empty());
    // The bridge's own HEARTBEAT goes out under its own ids (sender None).
    c.handle_timeout(t0, &[]);
    let own = messages(&mut c)
        .into_iter()
        .find(|o| matches!(o.message, MavMessage::HEARTBEAT(_)))
        .unwrap();
    assert_eq!((own.link, own.sender), (None, None));
    // Without a `gcs` link nothing is relayed.
    let mut c = core(t0);
    c.handle_message(0, &header(AP), &autopilot_heartbeat(), t0);
    assert!(messages(&mut c).is_empty());
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

fn interval_ack(result: MavResult) -> MavMessage {
    MavMessage::COMMAND_ACK(COMMAND_ACK_DATA {
        command: MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL,
        result,
        target_system: 7,
        target_component: 140,
        ..Default::default()
    })
}

/// Drive a core that asks for its source and gets `result` to every request, for 10 s;
/// returns the requests sent, the notes and the STATUSTEXTs.
/// The requests sent, the notes and the STATUSTEXTs of [`answer_every_request`].
type Answered = (
    Vec<(f32, f32, u8, u8)>,
    Vec<String>,
    Vec<(MavSeverity, String)>,
);

fn answer_every_request(c: &mut BridgeCore, t0: Instant, result: MavResult) -> Answered {
    c.handle_message(0, &header(AP), &autopilot_heartbeat(), t0);
    c.handle_message(0, &header(AP), &sys_status(false), t0);
    let (mut requests, mut notes, mut texts) = (Vec::new(), Vec::new(), Vec::new());
    for ms in (0..10_000).step_by(100) {
        let t = t0 + Duration::from_millis(ms);
        c.handle_timeout(t, &[]);
        let out = messages(c);
        let asked = interval_requests(&out);
        texts.extend(statustexts(&out));
        for _ in &asked {
            c.handle_message(0, &header(AP), &interval_ack(result), t);
        }
        requests.extend(asked);
        notes.extend(c.take_notes());
        texts.extend(statustexts(&messages(c)));
    }
    (requests, notes, texts)
}

#[test]
fn a_refusal_that_is_not_about_the_rate_stops_the_requests_and_is_said_once() {
    for result in [
        MavResult::MAV_RESULT_UNSUPPORTED,
        MavResult::MAV_RESULT_FAILED,
    ] {
        let t0 = Instant::now();
        let mut c = core(t0);
        let (requests, notes, texts) = answer_every_request(&mut c, t0, result);
        assert_eq!(
            requests,
            vec![(36.0, 20_000.0, 7, 1)],
            "{result:?}: asked once"
        );
        assert_eq!(notes.len(), 1, "{result:?}: {notes:?}");
        assert!(
            notes[0].contains("does not provide SERVO_OUTPUT_RAW"),
            "{notes:?}"
        );
        assert!(!notes[0].contains("SCHED_LOOP_RATE"), "{notes:?}");
        assert_eq!(
            texts,
            vec![(
                MavSeverity::MAV_SEVERITY_ERROR,
                "LJ9DA: autopilot refuses SERVO_OUTPUT_RAW".to_string()
            )]
        );
        assert_eq!(
            c.requested_rate_hz(),
            50.0,
            "the rate was never the problem"
        );
    }
}

#[test]
fn denied_at_a_rate_no_ardupilot_refuses_means_the_message_is_not_provided() {
    // ArduPilot denies ACTUATOR_OUTPUT_STATUS (it has no such stream) with DENIED, as it does
    // a rate above 0.8 × SCHED_LOOP_RATE. Above 40 Hz a DENIED may be the rate: one step down
    // to 40 Hz. At 40 Hz no ArduPilot is too slow: the message is not provided.
    let t0 = Instant::now();
    let mut c = core(t0);
    let (requests, notes, texts) = answer_every_request(&mut c, t0, MavResult::MAV_RESULT_DENIED);
    assert_eq!(
        requests,
        vec![(36.0, 20_000.0, 7, 1), (36.0, 25_000.0, 7, 1)],
        "50 Hz, then 40 Hz, then no more"
    );
    assert_eq!(notes.len(), 2, "{notes:?}");
    assert!(notes[0].contains("SCHED_LOOP_RATE"), "{notes:?}");
    assert!(
        notes[1].contains("does not provide SERVO_OUTPUT_RAW"),
        "{notes:?}"
    );
    assert_eq!(texts.len(), 1, "{texts:?}");
}

#[test]
fn the_sched_loop_rate_advice_is_given_once_however_many_steps_down() {
    let t0 = Instant::now();
    let mapping = MAPPING.replace("output_rate_hz = 50", "output_rate_hz = 400");
    let mut c = BridgeCore::new(Config::parse(&mapping, "t.toml").unwrap(), t0);
    let (requests, notes, _) = answer_every_request(&mut c, t0, MavResult::MAV_RESULT_DENIED);
    let rates: Vec<f32> = requests.iter().map(|r| (1e6 / r.1).round()).collect();
    assert_eq!(rates, vec![400.0, 320.0, 240.0, 160.0, 80.0, 40.0]);
    let advice = notes
        .iter()
        .filter(|n| n.contains("SCHED_LOOP_RATE"))
        .count();
    assert_eq!(advice, 1, "{notes:?}");
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
    assert!(
        c.poll_timeout()
            .is_some_and(|t| t <= t0 + Duration::from_millis(500))
    );
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
    assert!(!c.servo_in_failsafe(0));
    assert!(
        c.servo_in_failsafe(1),
        "channel 18 is on port 1, which has not come back yet"
    );
    c.handle_message(
        0,
        &header(AP),
        &outputs(1, &[(2, 1520)]),
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

#[test]
fn failsafe_is_per_servo_kept_only_by_the_messages_that_carry_its_channel() {
    // PX4 streams SERVO_OUTPUT_RAW port 0 only: channels 1–16 arrive at 50 Hz, the aileron on
    // channel 18 never does. Port 0 must not keep the aileron's failsafe at bay.
    let t0 = Instant::now();
    let mut c = running(t0);
    messages(&mut c);
    let mut texts = Vec::new();
    let mut got = Vec::new();
    for i in 1..=200u64 {
        let t = t0 + Duration::from_millis(20 * i);
        c.handle_message(0, &header(AP), &outputs(0, &[(1, 1520)]), t);
        c.handle_timeout(t, &[]);
        got.extend(commands(&mut c));
        texts.extend(statustexts(&messages(&mut c)));
        if t < t0 + Duration::from_millis(500) {
            assert!(!c.in_failsafe(), "at {i}");
        }
    }
    assert!(c.servo_in_failsafe(1), "channel 18 missing for 4 s");
    assert!(!c.servo_in_failsafe(0) && !c.servo_in_failsafe(2));
    assert!(c.in_failsafe());
    assert_eq!(
        got,
        vec![(1, Goal::Position(MmCenti(500)))],
        "only the aileron on channel 18 takes its failsafe action (5 mm)"
    );
    assert_eq!(
        texts,
        vec![(
            MavSeverity::MAV_SEVERITY_WARNING,
            "aileron_right: failsafe, no ch18 for 500 ms".to_string()
        )],
        "announced once"
    );
    // Port 1 carries channel 18: the aileron follows it again, and the operator is told.
    let t = t0 + Duration::from_millis(4010);
    c.handle_message(0, &header(AP), &outputs(1, &[(2, 1544)]), t);
    assert!(!c.in_failsafe());
    assert_eq!(commands(&mut c), vec![(1, Goal::Position(MmCenti(-100)))]);
    assert_eq!(
        statustexts(&messages(&mut c)),
        vec![(
            MavSeverity::MAV_SEVERITY_NOTICE,
            "aileron_right: ch18 back, failsafe cleared".to_string()
        )]
    );
    // Port 1 stops again while port 0 goes on: failsafe again after the timeout.
    let mut t = t;
    for _ in 0..30 {
        t += Duration::from_millis(20);
        c.handle_message(0, &header(AP), &outputs(0, &[(1, 1520)]), t);
        c.handle_timeout(t, &[]);
    }
    assert!(c.servo_in_failsafe(1));
    assert_eq!(commands(&mut c), vec![(1, Goal::Position(MmCenti(500)))]);
}

/// Both ports at 50 Hz, port 1 `lag` after port 0 (PX4 sends its output drivers as separate
/// streams), for 2 s; then the whole stream stops. The texts said over the next second.
fn texts_when_a_two_port_stream_stops(lag: Duration) -> Vec<(MavSeverity, String)> {
    let t0 = Instant::now();
    let mut c = running(t0);
    let mut t = t0;
    for _ in 0..100 {
        t += Duration::from_millis(20);
        c.handle_message(0, &header(AP), &outputs(0, &[(1, 1520)]), t);
        c.handle_timeout(t, &[]);
        c.handle_message(0, &header(AP), &outputs(1, &[(2, 1520)]), t + lag);
        c.handle_timeout(t + lag, &[]);
    }
    messages(&mut c);
    let last = t + lag;
    let mut texts = Vec::new();
    while t < last + Duration::from_secs(1) {
        t += Duration::from_millis(1);
        c.handle_timeout(t, &[]);
        texts.extend(statustexts(&messages(&mut c)));
    }
    assert!(c.servo_in_failsafe(0) && c.servo_in_failsafe(1));
    texts
}

#[test]
fn a_stream_that_stops_is_one_text_when_its_ports_come_40_ms_apart() {
    let texts = texts_when_a_two_port_stream_stops(Duration::from_millis(40));
    assert_eq!(
        texts,
        vec![(
            MavSeverity::MAV_SEVERITY_WARNING,
            "LJ9DA failsafe: no outputs for 500 ms".to_string()
        )],
        "the stream's text alone: port 0's channel was not missing while the stream went on"
    );
}

#[test]
fn a_stream_that_stops_is_one_text_when_its_ports_come_microseconds_apart() {
    let texts = texts_when_a_two_port_stream_stops(Duration::from_micros(5));
    assert_eq!(
        texts,
        vec![(
            MavSeverity::MAV_SEVERITY_WARNING,
            "LJ9DA failsafe: no outputs for 500 ms".to_string()
        )]
    );
}

#[test]
fn after_the_streams_failsafe_a_channel_that_does_not_return_is_announced() {
    let t0 = Instant::now();
    let mut c = running(t0);
    c.handle_message(0, &header(AP), &outputs(1, &[(2, 1520)]), t0);
    commands(&mut c);
    messages(&mut c);
    c.handle_timeout(t0 + Duration::from_millis(500), &[]);
    assert!(c.servo_in_failsafe(1));
    messages(&mut c);
    // Only port 0 comes back: the aileron stays in failsafe and is announced once.
    let back = t0 + Duration::from_secs(2);
    c.handle_message(0, &header(AP), &outputs(0, &[(1, 1520)]), back);
    assert!(c.servo_in_failsafe(1) && !c.servo_in_failsafe(0));
    assert!(
        c.poll_timeout()
            .is_some_and(|t| t <= back + Duration::from_millis(500))
    );
    c.handle_message(
        0,
        &header(AP),
        &outputs(0, &[(1, 1520)]),
        back + Duration::from_millis(400),
    );
    c.handle_timeout(back + Duration::from_millis(500), &[]);
    assert!(c.servo_in_failsafe(1));
    // Said with the next message that comes without channel 18: the stream goes on without it.
    c.handle_message(
        0,
        &header(AP),
        &outputs(0, &[(1, 1520)]),
        back + Duration::from_millis(520),
    );
    let texts = statustexts(&messages(&mut c));
    assert!(
        texts.contains(&(
            MavSeverity::MAV_SEVERITY_WARNING,
            "aileron_right: failsafe, no ch18 for 500 ms".to_string()
        )),
        "{texts:?}"
    );
}

#[test]
fn a_command_ends_a_servos_failsafe_like_a_message_carrying_its_channel() {
    let t0 = Instant::now();
    let mut c = running(t0);
    let mut t = t0;
    for _ in 0..30 {
        t += Duration::from_millis(20);
        c.handle_message(0, &header(AP), &outputs(0, &[(1, 1520)]), t);
        c.handle_timeout(t, &[]);
    }
    assert!(c.servo_in_failsafe(1), "channel 18 missing");
    commands(&mut c);
    messages(&mut c);
    let set = command_long(
        MavCmd::MAV_CMD_DO_SET_SERVO,
        [18.0, 1568.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        (7, 140),
    );
    c.handle_message(0, &header((255, 190)), &set, t);
    assert!(!c.servo_in_failsafe(1));
    assert_eq!(commands(&mut c), vec![(1, Goal::Position(MmCenti(-200)))]);
    // The operator's command holds; the absence was announced already and is not again.
    for _ in 0..100 {
        t += Duration::from_millis(20);
        c.handle_message(0, &header(AP), &outputs(0, &[(1, 1520)]), t);
        c.handle_timeout(t, &[]);
    }
    assert!(commands(&mut c).is_empty());
    assert!(statustexts(&messages(&mut c)).is_empty());
}

#[test]
fn a_servo_driven_by_do_set_actuator_alone_has_no_channel_to_miss() {
    // The payload release is on channel 20, which this autopilot never outputs: it follows
    // DO_SET_ACTUATOR only. Port 0 running keeps it out of failsafe; the stream stopping does not.
    let mapping = format!(
        "{MAPPING}\n[[servo]]\nname = \"release\"\nbus = \"wing\"\nid = 4\nchannel = 20\nactuator = 1\nfailsafe = \"brake\"\n"
    );
    let t0 = Instant::now();
    let mut c = BridgeCore::new(Config::parse(&mapping, "t.toml").unwrap(), t0);
    c.handle_message(0, &header(AP), &autopilot_heartbeat(), t0);
    let mut t = t0;
    let mut texts = Vec::new();
    for _ in 0..100 {
        t += Duration::from_millis(20);
        c.handle_message(0, &header(AP), &outputs(0, &[(1, 1520)]), t);
        c.handle_timeout(t, &[]);
        texts.extend(statustexts(&messages(&mut c)));
    }
    assert!(!c.servo_in_failsafe(3));
    assert!(
        c.servo_in_failsafe(1),
        "the aileron on channel 18 is missed"
    );
    assert!(
        texts.iter().all(|(_, text)| !text.starts_with("release")),
        "{texts:?}"
    );
    let nan = f32::NAN;
    let set = command_long(
        MavCmd::MAV_CMD_DO_SET_ACTUATOR,
        [1.0, nan, nan, nan, nan, nan, 0.0],
        (7, 140),
    );
    commands(&mut c);
    c.handle_message(0, &header((255, 190)), &set, t);
    assert_eq!(commands(&mut c), vec![(3, Goal::Position(MmCenti(2500)))]);
    // No outputs at all: every servo, this one too, takes its failsafe action.
    c.handle_timeout(t + Duration::from_millis(500), &[]);
    assert!(c.servo_in_failsafe(3));
    assert!(commands(&mut c).contains(&(3, Goal::Brake)));
}

#[test]
fn a_core_without_an_autopilot_has_nothing_due_and_wakes_once_one_is_found() {
    // Before the autopilot's HEARTBEAT the bridge has no system ID to send with: nothing may
    // fall due, or the runtime would wake at once, again and again, and spin a core.
    let t0 = Instant::now();
    let mut c = core(t0);
    assert_eq!(c.poll_timeout(), None);
    c.handle_timeout(t0, &[]);
    assert!(messages(&mut c).is_empty());
    assert_eq!(c.poll_timeout(), None);
    // A ground station's message from another system changes nothing.
    c.handle_message(1, &header((255, 190)), &autopilot_heartbeat(), t0);
    let later = t0 + Duration::from_secs(3);
    c.handle_timeout(later, &[]);
    assert_eq!(c.poll_timeout(), None);
    // The autopilot appears: its heartbeat and stream request are due now.
    c.handle_message(0, &header(AP), &autopilot_heartbeat(), later);
    assert!(c.poll_timeout().is_some_and(|t| t <= later));
    c.handle_timeout(later, &[]);
    assert!(!messages(&mut c).is_empty());
    assert!(c.poll_timeout().is_some_and(|t| t > later));
}

#[test]
fn only_the_autopilots_link_moves_the_servos() {
    // The autopilot's outputs and output commands count on its link (0) alone: on the
    // ground-station link (1) the autopilot's ids are anyone's, e.g. its frames replayed.
    let t0 = Instant::now();
    let mut c = running(t0);
    messages(&mut c);
    commands(&mut c);
    c.handle_message(1, &header(AP), &outputs(0, &[(1, 1568)]), t0);
    assert!(commands(&mut c).is_empty(), "outputs on the GCS link");
    let gcs = (255, 190);
    let servo = command_long(
        MavCmd::MAV_CMD_DO_SET_SERVO,
        [9.0, 1568.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        (7, 140),
    );
    c.handle_message(1, &header(gcs), &servo, t0);
    assert!(commands(&mut c).is_empty(), "DO_SET_SERVO on the GCS link");
    assert_eq!(
        acks(&messages(&mut c)),
        vec![(
            MavCmd::MAV_CMD_DO_SET_SERVO,
            MavResult::MAV_RESULT_DENIED,
            255,
            190
        )]
    );
    let nan = f32::NAN;
    let actuator = |to| {
        command_long(
            MavCmd::MAV_CMD_DO_SET_ACTUATOR,
            [nan, 0.5, nan, nan, nan, nan, 0.0],
            to,
        )
    };
    c.handle_message(1, &header(gcs), &actuator((7, 140)), t0);
    assert!(
        commands(&mut c).is_empty(),
        "DO_SET_ACTUATOR on the GCS link"
    );
    assert_eq!(acks(&messages(&mut c))[0].1, MavResult::MAV_RESULT_DENIED);
    // Broadcast: ignored without an answer, as a broadcast the bridge does not carry out.
    c.handle_message(1, &header(gcs), &actuator((0, 0)), t0);
    assert!(commands(&mut c).is_empty());
    assert!(acks(&messages(&mut c)).is_empty());
    // The same from the autopilot's link moves the servos.
    c.handle_message(0, &header(gcs), &servo, t0);
    assert_eq!(commands(&mut c), vec![(2, Goal::Position(MmCenti(200)))]);
    c.handle_message(0, &header(AP), &outputs(0, &[(1, 1568)]), t0);
    assert!(!commands(&mut c).is_empty());
    // An autopilot is learned from its link only.
    let mut fresh = core(t0);
    fresh.handle_message(1, &header(AP), &autopilot_heartbeat(), t0);
    assert_eq!(fresh.autopilot(), None);
    fresh.handle_message(0, &header(AP), &autopilot_heartbeat(), t0);
    assert_eq!(fresh.autopilot(), Some(AP));
}

#[test]
fn the_relayed_heartbeat_keeps_the_autopilots_sequence_number() {
    let t0 = Instant::now();
    let mapping = MAPPING.replace(
        "failsafe_timeout_ms = 500",
        "failsafe_timeout_ms = 500\ngcs = \"udpout:127.0.0.1:14550\"",
    );
    let mut c = BridgeCore::new(Config::parse(&mapping, "t.toml").unwrap(), t0);
    for sequence in [17, 18] {
        let from = MavHeader {
            sequence,
            ..header(AP)
        };
        c.handle_message(0, &from, &autopilot_heartbeat(), t0);
        let relayed: Vec<_> = messages(&mut c)
            .into_iter()
            .filter_map(|o| o.sender)
            .collect();
        assert_eq!(relayed, vec![from]);
    }
}

/// SERVO_OUTPUT_RAW at `time_usec` carrying channel 1.
fn outputs_at(time_usec: u32) -> MavMessage {
    let mut raw = [0u16; 16];
    raw[0] = 1600;
    lj9da_bridge::mavlink::outputs::servo_output_raw(0, raw, time_usec)
}

#[test]
fn the_autopilots_clock_is_kept_for_the_record_once_a_second_and_never_from_a_zero() {
    let t0 = Instant::now();
    let mut c = running(t0);
    // The helper's outputs carry no time: nothing to keep.
    assert_eq!(c.poll_autopilot_clock(), None);
    c.handle_message(0, &header(AP), &outputs_at(5_000_000), t0);
    let first = c.poll_autopilot_clock().expect("the first clock at once");
    assert_eq!((first.time_usec, first.bits, first.at), (5_000_000, 32, t0));
    assert_eq!(c.poll_autopilot_clock(), None, "handed out once");
    // Within the period: kept back; the latest is handed out once the period has passed.
    for ms in [20u32, 500, 980] {
        let at = t0 + Duration::from_millis(ms.into());
        c.handle_message(0, &header(AP), &outputs_at(5_000_000 + ms * 1000), at);
        assert_eq!(c.poll_autopilot_clock(), None, "{ms} ms after the first");
    }
    let at = t0 + Duration::from_millis(1000);
    c.handle_message(0, &header(AP), &outputs_at(6_000_000), at);
    let second = c.poll_autopilot_clock().expect("a second later");
    assert_eq!((second.time_usec, second.at), (6_000_000, at));
    // A sender that fills in no time keeps none.
    let later = t0 + Duration::from_secs(3);
    c.handle_message(0, &header(AP), &outputs_at(0), later);
    assert_eq!(c.poll_autopilot_clock(), None);
}

/// The autopilot's PARAM_VALUE of BRD_SAFETY_MASK (ArduPilot sends integers as their value).
fn safety_mask(mask: u32) -> MavMessage {
    let mut id = [0u8; 16];
    id[..15].copy_from_slice(b"BRD_SAFETY_MASK");
    MavMessage::PARAM_VALUE(PARAM_VALUE_DATA {
        param_value: mask as f32,
        param_count: 900,
        param_index: 100,
        param_id: id.into(),
        param_type: MavParamType::MAV_PARAM_TYPE_INT32,
    })
}

fn positions(got: &[(usize, Goal)]) -> Vec<usize> {
    got.iter()
        .filter(|(_, g)| matches!(g, Goal::Position(_)))
        .map(|(s, _)| *s)
        .collect()
}

#[test]
fn ardupilots_safety_switch_holds_every_servo_off_its_safety_mask() {
    let t0 = Instant::now();
    let mut c = running(t0);
    messages(&mut c);
    c.handle_message(0, &header(AP), &sys_status(true), t0);
    let out = messages(&mut c);
    let asked = out.iter().any(|o| {
        matches!(&o.message, MavMessage::PARAM_REQUEST_READ(r)
            if r.param_id.to_str().unwrap() == "BRD_SAFETY_MASK"
                && (r.target_system, r.target_component) == AP
                && r.param_index == -1)
    });
    assert!(asked, "BRD_SAFETY_MASK asked of the autopilot: {out:?}");
    assert!(
        statustexts(&out)
            .iter()
            .any(|(_, t)| t == "LJ9DA: autopilot safety on, servos hold"),
        "{out:?}"
    );
    // Safety on, the mask not known yet: nothing moves, whatever the outputs say.
    c.handle_message(0, &header(AP), &outputs(0, &[(1, 1800), (9, 1100)]), t0);
    assert_eq!(positions(&commands(&mut c)), Vec::<usize>::new());
    // The mask lets output 9 (the gear) move with the safety on, not output 1.
    c.handle_message(0, &header(AP), &safety_mask(1 << 8), t0);
    c.handle_message(0, &header(AP), &outputs(0, &[(1, 1810), (9, 1110)]), t0);
    assert_eq!(positions(&commands(&mut c)), vec![2]);
    // Safety off (past the texts' flood guard): the autopilot's current outputs, all of them.
    let t1 = t0 + Duration::from_secs(5);
    c.handle_message(0, &header(AP), &sys_status(false), t1);
    assert!(
        statustexts(&messages(&mut c))
            .iter()
            .any(|(_, t)| t == "LJ9DA: autopilot safety off")
    );
    c.handle_message(0, &header(AP), &outputs(0, &[(1, 1810), (9, 1110)]), t1);
    assert_eq!(positions(&commands(&mut c)), vec![0]);
}

#[test]
fn the_safety_switch_is_only_the_ardupilot_autopilots_own() {
    let t0 = Instant::now();
    // A stranger's SYS_STATUS, or the autopilot's on another link: nothing is held.
    let mut c = running(t0);
    c.handle_message(0, &header((7, 190)), &sys_status(true), t0);
    c.handle_message(1, &header(AP), &sys_status(true), t0);
    c.handle_message(0, &header(AP), &outputs(0, &[(1, 1800)]), t0);
    assert_eq!(positions(&commands(&mut c)), vec![0]);
    // PX4 has no safety mask to read: its SYS_STATUS holds nothing back.
    let mut c = core(t0);
    let px4 = MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        mavtype: MavType::MAV_TYPE_FIXED_WING,
        autopilot: MavAutopilot::MAV_AUTOPILOT_PX4,
        ..Default::default()
    });
    c.handle_message(0, &header(AP), &px4, t0);
    c.handle_message(0, &header(AP), &sys_status(true), t0);
    c.handle_message(0, &header(AP), &outputs(0, &[(1, 1800)]), t0);
    assert_eq!(positions(&commands(&mut c)), vec![0]);
}

#[test]
fn the_safety_switch_holds_a_failsafe_position_and_do_set_servo_too() {
    let t0 = Instant::now();
    let mut c = running(t0);
    c.handle_message(0, &header(AP), &outputs(1, &[(2, 1600)]), t0);
    commands(&mut c);
    c.handle_message(0, &header(AP), &sys_status(true), t0);
    c.handle_message(0, &header(AP), &safety_mask(0), t0);
    // DO_SET_SERVO of output 1 from the autopilot's link: held.
    let set_servo = command_long(
        MavCmd::MAV_CMD_DO_SET_SERVO,
        [1.0, 1900.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        (AP.0, 140),
    );
    c.handle_message(0, &header(AP), &set_servo, t0);
    assert_eq!(positions(&commands(&mut c)), Vec::<usize>::new());
    // The stream stops: aileron_right's failsafe is a position (5 mm): held too.
    let later = t0 + Duration::from_millis(600);
    c.handle_timeout(later, &[]);
    let got = commands(&mut c);
    assert_eq!(positions(&got), Vec::<usize>::new(), "{got:?}");
}

#[test]
fn a_mapping_may_switch_the_servos_off_while_the_safety_is_on() {
    let t0 = Instant::now();
    let mapping = format!("{MAPPING}\n[bridge]\nwhile_safe = \"off\"\n");
    let mut c = running_on(&mapping, t0);
    c.handle_message(0, &header(AP), &sys_status(true), t0);
    c.handle_message(0, &header(AP), &safety_mask(1 << 8), t0);
    let out = messages(&mut c);
    assert!(
        statustexts(&out)
            .iter()
            .any(|(_, t)| t == "LJ9DA: autopilot safety on, servos off"),
        "{out:?}"
    );
    // Output 1 is off the mask: its servo is switched off, once, however the output moves;
    // output 9 is in it and moves.
    c.handle_message(0, &header(AP), &outputs(0, &[(1, 1800), (9, 1100)]), t0);
    c.handle_message(0, &header(AP), &outputs(0, &[(1, 1850), (9, 1100)]), t0);
    let got = commands(&mut c);
    let offs = got.iter().filter(|g| **g == (0, Goal::Off)).count();
    assert_eq!((offs, positions(&got)), (1, vec![2]), "{got:?}");
    // Safety off: the autopilot's output again (a move switches the force back on).
    let t1 = t0 + Duration::from_secs(5);
    c.handle_message(0, &header(AP), &sys_status(false), t1);
    c.handle_message(0, &header(AP), &outputs(0, &[(1, 1850), (9, 1100)]), t1);
    assert_eq!(positions(&commands(&mut c)), vec![0]);
}

#[test]
fn an_ardupilot_that_sends_no_sys_status_is_told_of_once() {
    let t0 = Instant::now();
    let warned = |c: &mut BridgeCore| {
        c.take_notes()
            .iter()
            .filter(|n| n.contains("no SYS_STATUS") && n.contains("MAVn_EXT_STAT"))
            .count()
    };
    let mut c = core(t0);
    c.handle_message(0, &header(AP), &autopilot_heartbeat(), t0);
    c.handle_message(0, &header(AP), &outputs(0, &[(1, 1520)]), t0);
    let just_before = t0 + NO_STATUS_AFTER - Duration::from_millis(1);
    c.handle_timeout(just_before, &[]);
    assert_eq!(warned(&mut c), 0);
    for s in [0, 1, 7] {
        c.handle_timeout(t0 + NO_STATUS_AFTER + Duration::from_secs(s), &[]);
    }
    assert_eq!(warned(&mut c), 1, "said once");
    // A SYS_STATUS in time, and nothing is said; PX4 sends none for this.
    let mut c = running(t0);
    c.handle_timeout(t0 + 3 * NO_STATUS_AFTER, &[]);
    assert_eq!(warned(&mut c), 0);
    let mut c = core(t0);
    let px4 = MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        mavtype: MavType::MAV_TYPE_FIXED_WING,
        autopilot: MavAutopilot::MAV_AUTOPILOT_PX4,
        ..Default::default()
    });
    c.handle_message(0, &header(AP), &px4, t0);
    c.handle_timeout(t0 + 3 * NO_STATUS_AFTER, &[]);
    assert_eq!(warned(&mut c), 0);
}

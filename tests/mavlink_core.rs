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

fn online(position_mm: f32) -> ServoReport {
    ServoReport {
        state: Some(ServoState::Online),
        position_mm: Some(position_mm),
        current_a: Some(0.06),
        temperature_c: Some(45.0),
        voltage_v: Some(11.1),
        ..Default::default()
    }
}

/// Every message the core sends in `seconds`, called every 5 ms with `report(ms)` for each of
/// its `servos`.
fn sent_for(
    c: &mut BridgeCore,
    t0: Instant,
    seconds: u64,
    servos: usize,
    report: impl Fn(u64) -> ServoReport,
) -> Vec<MavMessage> {
    c.handle_message(0, &header(AP), &autopilot_heartbeat(), t0);
    let mut out = Vec::new();
    for ms in (0..seconds * 1000).step_by(5) {
        let r = report(ms);
        c.handle_timeout(t0 + Duration::from_millis(ms), &vec![r; servos]);
        out.extend(messages(c).into_iter().map(|o| o.message));
    }
    out
}

fn named(out: &[MavMessage]) -> Vec<(String, f32)> {
    out.iter()
        .filter_map(|m| match m {
            MavMessage::NAMED_VALUE_FLOAT(v) => {
                Some((v.name.to_str().unwrap().to_string(), v.value))
            }
            _ => None,
        })
        .collect()
}

#[test]
fn named_values_go_out_when_they_change_and_are_refreshed_every_5_s() {
    let t0 = Instant::now();
    let mut c = running(t0);
    // rate_hz = 5: looked at every 200 ms. Only the left aileron's position changes.
    let out = sent_for(&mut c, t0, 10, 3, |ms| {
        online(-12.0 + (ms / 200) as f32 * 0.01)
    });
    let names = named(&out);
    let count = |name: &str| names.iter().filter(|(n, _)| n == name).count();
    assert_eq!(count("ail_l_pos"), 50, "changed at every look, 5 Hz × 10 s");
    assert_eq!(
        count("ail_l_tmp"),
        2,
        "unchanged: at 0 s and refreshed at 5 s"
    );
    assert_eq!(count("gear_vlt"), 2);
    assert!(names.contains(&("gear_tmp".to_string(), 45.0)));
}

#[test]
fn each_esc_carrier_has_its_own_rate_and_esc_info_defaults_to_1_hz() {
    let t0 = Instant::now();
    let mapping = MAPPING.replace("[telemetry]", "[telemetry]\nesc_status_hz = 2");
    let mut c = BridgeCore::new(Config::parse(&mapping, "t.toml").unwrap(), t0);
    let out = sent_for(&mut c, t0, 10, 3, |_| online(0.0));
    let info = out
        .iter()
        .filter(|m| matches!(m, MavMessage::ESC_INFO(_)))
        .count();
    let status = out
        .iter()
        .filter(|m| matches!(m, MavMessage::ESC_STATUS(_)))
        .count();
    assert_eq!(
        (info, status),
        (10, 20),
        "1 Hz and 2 Hz × 1 block of four, 10 s"
    );
}

#[test]
fn a_servo_going_offline_sends_esc_info_at_the_next_look_not_a_second_later() {
    let t0 = Instant::now();
    let mut c = running(t0);
    // rate_hz = 5: looks every 200 ms; ESC_INFO at 1 Hz.
    let out = sent_for(&mut c, t0, 2, 3, |_| online(0.0));
    let before = out
        .iter()
        .filter(|m| matches!(m, MavMessage::ESC_INFO(_)))
        .count();
    assert_eq!(before, 2, "1 Hz: at 0 and 1 s");
    let lost = ServoReport {
        state: Some(ServoState::Offline),
        ..Default::default()
    };
    // The second servo is lost at 2.1 s: the look then (due since 2.0 s) sends ESC_INFO,
    // whose own turn would be at 3 s.
    let reports = [online(0.0), lost, online(0.0)];
    c.handle_timeout(t0 + Duration::from_millis(2100), &reports);
    let info: Vec<u8> = messages(&mut c)
        .into_iter()
        .filter_map(|o| match o.message {
            MavMessage::ESC_INFO(i) => Some(i.info),
            _ => None,
        })
        .collect();
    assert_eq!(info, vec![0b101], "servo 2 offline, sent at once");
}

#[test]
fn esc_indexes_start_clear_of_the_motor_escs_unless_the_mapping_says() {
    let index = |mapping: &str| {
        let t0 = Instant::now();
        let mut c = BridgeCore::new(Config::parse(mapping, "t.toml").unwrap(), t0);
        let out = sent_for(&mut c, t0, 1, 3, |_| online(0.0));
        out.iter()
            .filter_map(|m| match m {
                MavMessage::ESC_INFO(i) => Some(("info", i.index)),
                MavMessage::ESC_STATUS(s) => Some(("status", s.index)),
                _ => None,
            })
            .collect::<Vec<_>>()
    };
    assert_eq!(index(MAPPING), vec![("info", 16), ("status", 16)]);
    let at_zero = MAPPING.replace("[telemetry]", "[telemetry]\nesc_index_base = 0");
    assert_eq!(index(&at_zero), vec![("info", 0), ("status", 0)]);
}

#[test]
fn the_mapping_chooses_the_named_quantities() {
    let mapping = MAPPING.replace(
        "[telemetry]",
        "[telemetry]\nnamed_values = [\"tmp\", \"pos\"]",
    );
    assert_eq!(
        names_sent_in_3_s(&mapping),
        [
            "ail_l_pos",
            "ail_l_tmp",
            "ail_r_pos",
            "ail_r_tmp",
            "gear_pos",
            "gear_tmp"
        ]
    );
}

#[test]
fn a_servo_with_a_list_of_its_own_sends_that_list_and_the_others_the_telemetry_list() {
    let mapping = MAPPING
        .replace("[telemetry]", "[telemetry]\nnamed_values = []")
        .replace(
            "label = \"ail_r\"",
            "label = \"ail_r\"\nnamed_values = [\"cur\", \"pos\"]",
        );
    assert_eq!(names_sent_in_3_s(&mapping), ["ail_r_cur", "ail_r_pos"]);
}

/// The NAMED_VALUE_FLOAT names a bridge with `mapping` sends in its first 3 s, servos online
/// and still (each value once: unchanged values are sent again only after 5 s), sorted.
fn names_sent_in_3_s(mapping: &str) -> Vec<String> {
    let t0 = Instant::now();
    let mut c = BridgeCore::new(Config::parse(mapping, "t.toml").unwrap(), t0);
    let mut names: Vec<String> = named(&sent_for(&mut c, t0, 1, 3, |_| online(0.0)))
        .into_iter()
        .map(|(n, _)| n)
        .collect();
    names.sort();
    names
}

/// Bytes on the wire of MAVLink 2 frames.
fn wire_bytes(out: &[MavMessage]) -> usize {
    let header = MavHeader::default();
    out.iter()
        .map(|m| {
            let mut buf = Vec::new();
            mavlink::write_v2_msg(&mut buf, header, m).unwrap();
            buf.len()
        })
        .sum()
}

#[test]
fn default_telemetry_of_four_moving_servos_fits_a_tenth_of_a_57600_baud_radio() {
    // 57 600 baud = 5 760 bytes/s, shared with all of the autopilot's own telemetry.
    let mapping = lj9da_bridge::config::SITL_DEFAULT_TOML;
    let t0 = Instant::now();
    let mut c = BridgeCore::new(Config::parse(mapping, "t.toml").unwrap(), t0);
    let servos = c_servos(mapping);
    // Worst case: every value changes all the time.
    let out = sent_for(&mut c, t0, 60, servos, |ms| ServoReport {
        current_a: Some(0.01 * (ms % 97) as f32),
        temperature_c: Some(40.0 + (ms % 13) as f32),
        voltage_v: Some(11.0 + 0.01 * (ms % 7) as f32),
        ..online(0.01 * (ms % 1000) as f32)
    });
    let per_s = wire_bytes(&out) / 60;
    println!("default telemetry, {servos} servos, every value changing: {per_s} bytes/s");
    assert!(per_s <= 576, "{per_s} bytes/s");
}

fn c_servos(mapping: &str) -> usize {
    Config::parse(mapping, "t.toml").unwrap().servos.len()
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
                reading: Some(TemperatureReading {
                    celsius: 76,
                    age: Duration::from_millis(20),
                }),
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
                "aileron_left: temperature alarm; 76C 0.0s ago".to_string()
            ),
            (
                MavSeverity::MAV_SEVERITY_CRITICAL,
                "aileron_left: overheat, force off; 85C 0.4s ago".to_string()
            ),
        ]
    );
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

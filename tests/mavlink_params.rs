//! The bridge as a MAVLink component, driven through the sans-IO core: parameters that take
//! effect at the next goal, refusals that keep the old value, and what it says it is.

use lj9da_bridge::bus::Goal;
use lj9da_bridge::config::Config;
use lj9da_bridge::config::edit::MappingFile;
use lj9da_bridge::mavlink::BridgeCore;
use lj9da_bridge::protocol::MmCenti;
use mavlink::MavHeader;
use mavlink::dialects::common::*;
use std::time::{Duration, Instant};

const MAPPING: &str = r#"
[mavlink]
connection = "udpin:0.0.0.0:14560"
system_id = 7

[[bus]]
name = "wing"
port = "/dev/null"

[[servo]]
name = "aileron_left"   # trimmed on the bench
bus = "wing"
id = 1
channel = 1

[[servo]]
name = "rudder"
bus = "wing"
id = 2
channel = 4
"#;

const GCS: (u8, u8) = (255, 190);
const AP: (u8, u8) = (7, 1);

fn header(from: (u8, u8)) -> MavHeader {
    MavHeader {
        system_id: u32::from(from.0),
        component_id: from.1,
        sequence: 0,
    }
}

struct Bench {
    core: BridgeCore,
    file: MappingFile,
    now: Instant,
}

impl Bench {
    fn new() -> Bench {
        let now = Instant::now();
        let cfg = Config::parse(MAPPING, "t.toml").unwrap();
        let mut core = BridgeCore::new(cfg, now);
        let hb = MavMessage::HEARTBEAT(HEARTBEAT_DATA {
            mavtype: MavType::MAV_TYPE_FIXED_WING,
            autopilot: MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
            ..Default::default()
        });
        core.handle_message(0, &header(AP), &hb, now);
        let mut bench = Bench {
            core,
            file: MappingFile::in_memory(MAPPING, "t.toml").unwrap(),
            now,
        };
        bench.drain();
        bench
    }

    fn send(&mut self, from: (u8, u8), msg: MavMessage) {
        self.now += Duration::from_millis(1);
        self.core.handle_message(1, &header(from), &msg, self.now);
        // What the runtime does with a change: the file decides.
        while let Some(set) = self.core.poll_param_set() {
            let result = self.file.apply(&set.edits).map_err(|e| e.reason());
            self.core.param_set_done(&set, result, self.now);
        }
    }

    fn drain(&mut self) -> (Vec<MavMessage>, Vec<(usize, Goal)>) {
        let mut messages = Vec::new();
        while let Some(out) = self.core.poll_message() {
            messages.push(out.message);
        }
        let mut goals = Vec::new();
        while let Some(g) = self.core.poll_command() {
            goals.push(g);
        }
        (messages, goals)
    }

    fn outputs(&mut self, servo1_us: u16) -> Vec<(usize, Goal)> {
        let msg = MavMessage::SERVO_OUTPUT_RAW(SERVO_OUTPUT_RAW_DATA {
            servo1_raw: servo1_us,
            servo4_raw: 1520,
            ..Default::default()
        });
        self.now += Duration::from_millis(20);
        self.core.handle_message(0, &header(AP), &msg, self.now);
        self.drain().1
    }

    /// Set a parameter: the messages sent and the goals given because of it.
    fn set(&mut self, name: &str, value: f32) -> (Vec<MavMessage>, Vec<(usize, Goal)>) {
        self.send(
            GCS,
            MavMessage::PARAM_SET(PARAM_SET_DATA {
                param_value: value,
                target_system: 7,
                target_component: 140,
                param_id: name.into(),
                param_type: MavParamType::MAV_PARAM_TYPE_REAL32,
            }),
        );
        self.drain()
    }
}

fn values(messages: &[MavMessage]) -> Vec<(String, f32)> {
    messages
        .iter()
        .filter_map(|m| match m {
            MavMessage::PARAM_VALUE(v) => Some((
                v.param_id
                    .to_str()
                    .unwrap_or("")
                    .trim_end_matches('\0')
                    .to_string(),
                v.param_value,
            )),
            _ => None,
        })
        .collect()
}

fn texts(messages: &[MavMessage]) -> Vec<String> {
    messages
        .iter()
        .filter_map(|m| match m {
            MavMessage::STATUSTEXT(t) => Some(t.text.to_str().unwrap_or("").to_string()),
            _ => None,
        })
        .collect()
}

#[test]
fn a_new_trim_moves_the_servo_at_once_and_the_next_goal_uses_it() {
    let mut b = Bench::new();
    // 1544 µs is +1.00 mm under the servo's own range.
    assert_eq!(
        b.outputs(1544),
        vec![
            (0, Goal::Position(MmCenti(100))),
            (1, Goal::Position(MmCenti(0)))
        ]
    );
    let (out, goals) = b.set("S1_PWM_TRIM", 1544.0);
    assert_eq!(values(&out), vec![("S1_PWM_TRIM".to_string(), 1544.0)]);
    assert!(texts(&out).is_empty(), "{out:?}");
    // The same autopilot value is now the trim: 0 mm, without waiting for a new message.
    assert_eq!(goals, vec![(0, Goal::Position(MmCenti(0)))]);
    // Above the new trim 576 µs span 25 mm: 24 µs is 1.04 mm.
    assert_eq!(b.outputs(1568), vec![(0, Goal::Position(MmCenti(104)))]);
    // The change was made in place, comment kept.
    assert!(
        b.file.text().contains("pwm_trim_us = 1544"),
        "{}",
        b.file.text()
    );
    assert!(b.file.text().contains("# trimmed on the bench"));
}

#[test]
fn a_reversed_servo_moves_at_once() {
    let mut b = Bench::new();
    b.outputs(1544);
    let (_, goals) = b.set("S1_REV", 1.0);
    assert_eq!(goals, vec![(0, Goal::Position(MmCenti(-100)))]);
}

#[test]
fn a_refused_value_answers_with_the_old_value_and_says_why_and_changes_nothing() {
    let mut b = Bench::new();
    b.outputs(1544);
    let (out, goals) = b.set("S1_PWM_TRIM", 3000.0);
    assert_eq!(values(&out), vec![("S1_PWM_TRIM".to_string(), 1520.0)]);
    let texts = texts(&out);
    assert_eq!(texts.len(), 1, "{texts:?}");
    assert!(texts[0].starts_with("S1_PWM_TRIM 3000: "), "{texts:?}");
    assert_eq!(b.file.text(), MAPPING);
    assert_eq!(goals, vec![]);
    assert_eq!(b.outputs(1568), vec![(0, Goal::Position(MmCenti(200)))]);
}

#[test]
fn a_new_channel_takes_over_at_once() {
    let mut b = Bench::new();
    b.outputs(1544);
    let (out, goals) = b.set("S1_CHAN", 4.0);
    assert_eq!(values(&out), vec![("S1_CHAN".to_string(), 4.0)]);
    // Channel 4 carries 1520 µs: servo 1 goes to 0 mm, and channel 1 no longer moves it.
    assert_eq!(goals, vec![(0, Goal::Position(MmCenti(0)))]);
    assert_eq!(b.outputs(1600), vec![]);
}

#[test]
fn setting_the_failsafe_action_to_a_position_also_sends_the_position() {
    let mut b = Bench::new();
    b.set("S2_FS_ACT", 3.0);
    let (out, _) = b.set("S2_FS_POS", -4.25);
    assert_eq!(values(&out), vec![("S2_FS_POS".to_string(), -4.25)]);
    let (out, _) = b.set("S2_FS_ACT", 0.0);
    assert_eq!(
        values(&out),
        vec![
            ("S2_FS_ACT".to_string(), 0.0),
            ("S2_FS_POS".to_string(), 0.0)
        ]
    );
}

#[test]
fn the_bridge_says_what_it_is_when_asked() {
    let mut b = Bench::new();
    let ask = |id: f32| {
        MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
            param1: id,
            command: MavCmd::MAV_CMD_REQUEST_MESSAGE,
            target_system: 7,
            target_component: 140,
            ..Default::default()
        })
    };
    b.send(GCS, ask(148.0));
    let (out, _) = b.drain();
    let [
        MavMessage::COMMAND_ACK(ack),
        MavMessage::AUTOPILOT_VERSION(v),
    ] = out.as_slice()
    else {
        panic!("{out:?}")
    };
    assert_eq!(ack.result, MavResult::MAV_RESULT_ACCEPTED);
    assert!(
        v.capabilities
            .contains(MavProtocolCapability::MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST)
    );
    assert!(
        !v.capabilities
            .contains(MavProtocolCapability::MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE)
    );
    assert!(
        v.capabilities
            .contains(MavProtocolCapability::MAV_PROTOCOL_CAPABILITY_MAVLINK2)
    );
    // major, minor, patch of the package, one byte each, then 255: an official release.
    let version = env!("CARGO_PKG_VERSION");
    let expected = version
        .split(['.', '-', '+'])
        .take(3)
        .fold(0u32, |v, part| (v << 8) | part.parse::<u32>().unwrap());
    assert_eq!(
        v.flight_sw_version,
        (expected << 8) | 255,
        "{:#010x} for {version}",
        v.flight_sw_version
    );

    b.send(GCS, ask(396.0));
    let (out, _) = b.drain();
    let [
        MavMessage::COMMAND_ACK(_),
        MavMessage::COMPONENT_INFORMATION_BASIC(info),
    ] = out.as_slice()
    else {
        panic!("{out:?}")
    };
    assert_eq!(info.vendor_name.to_str().unwrap(), "lj9da-bridge");
    assert_eq!(
        info.software_version.to_str().unwrap(),
        env!("CARGO_PKG_VERSION")
    );

    b.send(GCS, ask(33.0));
    let (out, _) = b.drain();
    let [MavMessage::COMMAND_ACK(ack)] = out.as_slice() else {
        panic!("{out:?}")
    };
    assert_eq!(ack.result, MavResult::MAV_RESULT_DENIED);
}

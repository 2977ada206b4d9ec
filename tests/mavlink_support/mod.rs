//! The sans-IO MAVLink core under test: its mapping (three servos on one bus), the autopilot's
//! messages in, and what the core says and commands out. Shared by `mavlink_core`,
//! `mavlink_commands` and `mavlink_telemetry`.
#![allow(dead_code)]

use lj9da_bridge::bus::Goal;
use lj9da_bridge::config::Config;
use lj9da_bridge::mavlink::core::sys_status;
use lj9da_bridge::mavlink::outputs::servo_output_raw;
use lj9da_bridge::mavlink::{BridgeCore, Outgoing};
use mavlink::MavHeader;
use mavlink::dialects::common::*;
use std::time::Instant;

pub const MAPPING: &str = r#"
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

pub const AP: (u8, u8) = (7, 1);

pub fn core(t0: Instant) -> BridgeCore {
    BridgeCore::new(
        Config::parse(MAPPING, "test.toml").expect("test mapping is valid"),
        t0,
    )
}

pub fn header(from: (u8, u8)) -> MavHeader {
    MavHeader {
        system_id: u32::from(from.0),
        component_id: from.1,
        sequence: 0,
    }
}

pub fn autopilot_heartbeat() -> MavMessage {
    MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        mavtype: MavType::MAV_TYPE_FIXED_WING,
        autopilot: MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
        ..Default::default()
    })
}

pub fn outputs(port: u8, values: &[(usize, u16)]) -> MavMessage {
    let mut raw = [0u16; 16];
    for (i, v) in values {
        raw[*i - 1] = *v;
    }
    servo_output_raw(port, raw, 0)
}

pub fn commands(c: &mut BridgeCore) -> Vec<(usize, Goal)> {
    std::iter::from_fn(|| c.poll_command()).collect()
}

pub fn messages(c: &mut BridgeCore) -> Vec<Outgoing> {
    std::iter::from_fn(|| c.poll_message()).collect()
}

pub fn statustexts(out: &[Outgoing]) -> Vec<(MavSeverity, String)> {
    out.iter()
        .filter_map(|o| match &o.message {
            MavMessage::STATUSTEXT(s) => Some((s.severity, s.text.to_str().unwrap().to_string())),
            _ => None,
        })
        .collect()
}

/// A core that knows its autopilot (ArduPilot, its safety switch off) and has had one output
/// message.
pub fn running(t0: Instant) -> BridgeCore {
    running_on(MAPPING, t0)
}

/// [`running`], on the mapping `text`.
pub fn running_on(text: &str, t0: Instant) -> BridgeCore {
    let mut c = BridgeCore::new(Config::parse(text, "test.toml").expect("valid"), t0);
    c.handle_message(0, &header(AP), &autopilot_heartbeat(), t0);
    c.handle_message(0, &header(AP), &sys_status(false), t0);
    c.handle_message(0, &header(AP), &outputs(0, &[(1, 1520)]), t0);
    commands(&mut c);
    c
}

pub fn command_long(command: MavCmd, params: [f32; 7], target: (u8, u8)) -> MavMessage {
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

pub fn acks(out: &[Outgoing]) -> Vec<(MavCmd, MavResult, u8, u8)> {
    out.iter()
        .filter_map(|o| match &o.message {
            MavMessage::COMMAND_ACK(a) => {
                Some((a.command, a.result, a.target_system, a.target_component))
            }
            _ => None,
        })
        .collect()
}

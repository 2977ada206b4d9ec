//! The DroneCAN layer against the `dronecan` package (PyPI), an implementation we did not
//! write: what the bridge encodes, `dronecan` decodes to the same values, and what `dronecan`
//! encodes, the bridge decodes. Frames cross as hex; the data types' ids and signatures are
//! `dronecan`'s own, compiled from the DSDL.

#[path = "common/python.rs"]
mod python;

use lj9da_bridge::dronecan::allocation::{self, ALLOCATION};
use lj9da_bridge::dronecan::messages::{
    self, ACTUATOR_STATUS, ARRAY_COMMAND, ActuatorStatus, Command, CommandType, DEVICE_TEMPERATURE,
    DataType, DeviceTemperature, GET_NODE_INFO, Health, Mode, NODE_STATUS, NodeInfo, NodeStatus,
};
use lj9da_bridge::dronecan::node::{Identity, Node};
use lj9da_bridge::dronecan::{CanFrame, CanId, Kind, Reassembler, Transfer};
use serde_json::{Value, json};
use std::io::Write;
use std::process::{Command as Process, Stdio};
use std::time::{Duration, Instant};

/// Reads one JSON request from stdin: `types` (names whose id and signature it prints),
/// `decode` (transfers as lists of [id, hex] frames, each decoded to its fields) and `encode`
/// (messages to put into frames).
const PEER: &str = r#"
import json, sys
import dronecan
from dronecan.transport import Frame, Transfer

def dtype(name):
    t = dronecan
    for part in name.split("."):
        t = getattr(t, part)
    return t

def fields(payload):
    name = dronecan.get_dronecan_data_type(payload).full_name
    if name == "uavcan.equipment.actuator.ArrayCommand":
        return [[c.actuator_id, c.command_type, c.command_value] for c in payload.commands]
    if name == "uavcan.equipment.actuator.Status":
        return [payload.actuator_id, payload.position, payload.force, payload.speed,
                payload.power_rating_pct]
    if name == "uavcan.protocol.NodeStatus":
        return status(payload)
    if name == "uavcan.equipment.device.Temperature":
        return [payload.device_id, payload.temperature, payload.error_flags]
    if name == "uavcan.protocol.dynamic_node_id.Allocation":
        return [payload.node_id, payload.first_part_of_unique_id, list(payload.unique_id)]
    if name == "uavcan.protocol.GetNodeInfo":
        s = payload.software_version
        h = payload.hardware_version
        return {"status": status(payload.status), "software": [s.major, s.minor,
                s.optional_field_flags, s.vcs_commit], "hardware": [h.major, h.minor],
                "unique_id": list(h.unique_id), "name": bytes(payload.name).decode()}
    raise ValueError(name)

def status(s):
    return [s.uptime_sec, s.health, s.mode, s.sub_mode, s.vendor_specific_status_code]

request = json.load(sys.stdin)
out = {"types": {}, "decoded": [], "encoded": []}
for name in request["types"]:
    t = dtype(name)
    out["types"][name] = [t.default_dtid, t.get_data_type_signature()]
for frames in request["decode"]:
    t = Transfer()
    t.from_frames([Frame(i, bytearray.fromhex(h)) for i, h in frames])
    out["decoded"].append({"source": t.source_node_id, "transfer_id": t.transfer_id,
                           "fields": fields(t.payload)})
a = dronecan.uavcan.equipment.actuator
array = a.ArrayCommand(commands=[a.Command(actuator_id=i + 1, command_type=i % 5,
                                           command_value=v)
                                 for i, v in enumerate([-1.0, -0.25, 0.0, 0.5, 1.0, 1520.0,
                                                        0.0125, 3.0])])
status_ = a.Status(actuator_id=4, position=-0.02, force=3.5, speed=0.125, power_rating_pct=55)
for payload, node in [(array, 10), (status_, 42)]:
    t = Transfer(payload=payload, source_node_id=node, transfer_id=17, transfer_priority=16)
    out["encoded"].append([[f.message_id, bytes(f.bytes).hex()] for f in t.to_frames()])
# A ground station's GetNodeInfo request from node 10 to node 42.
ask = Transfer(payload=dronecan.uavcan.protocol.GetNodeInfo.Request(), source_node_id=10,
               dest_node_id=42, service_not_message=True, request_not_response=True,
               transfer_id=23, transfer_priority=30)
out["encoded"].append([[f.message_id, bytes(f.bytes).hex()] for f in ask.to_frames()])
json.dump(out, sys.stdout)
"#;

fn frames_json(frames: &[CanFrame]) -> Value {
    frames
        .iter()
        .map(|f| json!([f.id(), hex(f.data())]))
        .collect()
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn unhex(text: &str) -> Vec<u8> {
    (0..text.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&text[i..i + 2], 16).unwrap())
        .collect()
}

fn message(source: u8, ty: DataType, transfer_id: u8, payload: Vec<u8>) -> Transfer {
    Transfer {
        id: CanId {
            priority: 16,
            kind: Kind::Message,
            data_type_id: ty.id,
            source,
            discriminator: 0,
        },
        transfer_id,
        payload,
    }
}

fn peer(request: Value) -> Value {
    let mut child = Process::new(python::dronecan_python())
        .args(["-c", PEER])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .expect("python with dronecan");
    child
        .stdin
        .take()
        .unwrap()
        .write_all(request.to_string().as_bytes())
        .unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success(), "the dronecan peer failed");
    serde_json::from_slice(&out.stdout).expect("the peer's JSON")
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-6 * b.abs().max(1.0)
}

#[test]
fn the_bridges_frames_and_dronecans_agree_both_ways() {
    let commands: Vec<Command> = [-1.0f32, -0.3, 0.0, 0.75, 1.0, 1900.0, 0.0125]
        .iter()
        .enumerate()
        .map(|(i, &value)| Command {
            actuator_id: i as u8 + 1,
            command_type: [
                CommandType::Unitless,
                CommandType::Position,
                CommandType::Pwm,
            ][i % 3],
            value,
        })
        .collect();
    let status = NodeStatus {
        uptime_sec: 123_456,
        health: Health::Warning,
        mode: Mode::Operational,
        sub_mode: 0,
        vendor_specific_status_code: 0x0105,
    };
    let info = NodeInfo {
        status,
        software_major: 0,
        software_minor: 1,
        vcs_commit: Some(0x8d7e_91a0),
        hardware_major: 0,
        hardware_minor: 0,
        unique_id: *b"lj9da-bridge-uid",
        name: "org.lj9da.bridge".into(),
    };
    let actuator = ActuatorStatus {
        actuator_id: 3,
        position: -0.0125,
        force: 0.0,
        speed: 0.25,
        power_rating_pct: 37,
    };
    let info_response = Transfer {
        id: CanId {
            priority: 30,
            kind: Kind::Response { destination: 10 },
            data_type_id: GET_NODE_INFO.id,
            source: 42,
            discriminator: 0,
        },
        transfer_id: 5,
        payload: messages::encode_node_info(&info),
    };
    // A node with no id asking for one: anonymous, its discriminator from the payload.
    let request = allocation::encode(&allocation::Allocation {
        node_id: 0,
        first_part_of_unique_id: true,
        unique_id: b"lj9da-".to_vec(),
    });
    let anonymous_request = Transfer {
        id: CanId {
            priority: 30,
            kind: Kind::Message,
            data_type_id: ALLOCATION.id,
            source: 0,
            discriminator: 0x1234,
        },
        transfer_id: 0,
        payload: request,
    };
    let sent = [
        (
            message(
                10,
                ARRAY_COMMAND,
                9,
                messages::encode_array_command(&commands[..1]),
            ),
            ARRAY_COMMAND,
        ),
        (
            message(
                10,
                ARRAY_COMMAND,
                31,
                messages::encode_array_command(&commands),
            ),
            ARRAY_COMMAND,
        ),
        (
            message(42, NODE_STATUS, 0, messages::encode_node_status(&status)),
            NODE_STATUS,
        ),
        (
            message(
                42,
                ACTUATOR_STATUS,
                7,
                messages::encode_actuator_status(&actuator),
            ),
            ACTUATOR_STATUS,
        ),
        (info_response, GET_NODE_INFO),
        (
            message(
                42,
                DEVICE_TEMPERATURE,
                12,
                messages::encode_device_temperature(&DeviceTemperature {
                    device_id: 5,
                    kelvin: 344.15,
                    error_flags: messages::TEMPERATURE_OVERHEATING,
                }),
            ),
            DEVICE_TEMPERATURE,
        ),
        (anonymous_request, ALLOCATION),
    ];
    let types = [
        ARRAY_COMMAND,
        ACTUATOR_STATUS,
        NODE_STATUS,
        GET_NODE_INFO,
        DEVICE_TEMPERATURE,
        ALLOCATION,
    ];
    let got = peer(json!({
        "types": types.iter().map(|t| t.name).collect::<Vec<_>>(),
        "decode": sent.iter().map(|(t, ty)| frames_json(&t.frames(ty.signature))).collect::<Vec<_>>(),
    }));

    // The ids and signatures are dronecan's.
    for t in types {
        assert_eq!(
            got["types"][t.name],
            json!([t.id, t.signature]),
            "{}",
            t.name
        );
    }
    // Each transfer decoded by dronecan to what was encoded.
    let decoded = got["decoded"].as_array().unwrap();
    for ((t, _), d) in sent.iter().zip(decoded) {
        assert_eq!(d["source"], json!(t.id.source));
        assert_eq!(d["transfer_id"], json!(t.transfer_id));
    }
    let one = decoded[0]["fields"].as_array().unwrap();
    let all = decoded[1]["fields"].as_array().unwrap();
    assert_eq!(one.len(), 1);
    assert_eq!(all.len(), commands.len());
    for (c, d) in commands.iter().zip(all) {
        let kind = match c.command_type {
            CommandType::Unitless => 0,
            CommandType::Position => 1,
            CommandType::Pwm => 4,
            other => panic!("{other:?}"),
        };
        assert_eq!(
            (d[0].as_u64(), d[1].as_u64()),
            (Some(u64::from(c.actuator_id)), Some(kind))
        );
        let half = f64::from(lj9da_bridge::dronecan::float16::to_f32(
            lj9da_bridge::dronecan::float16::from_f32(c.value),
        ));
        assert!(close(d[2].as_f64().unwrap(), half), "{c:?}: {d}");
    }
    assert_eq!(decoded[2]["fields"], json!([123_456, 1, 0, 0, 0x0105]));
    let s = decoded[3]["fields"].as_array().unwrap();
    assert_eq!((s[0].as_u64(), s[4].as_u64()), (Some(3), Some(37)));
    assert!(
        close(s[1].as_f64().unwrap(), -0.0125) || (s[1].as_f64().unwrap() + 0.0125).abs() < 1e-5
    );
    assert!(close(s[3].as_f64().unwrap(), 0.25));
    let i = &decoded[4]["fields"];
    assert_eq!(i["status"], json!([123_456, 1, 0, 0, 0x0105]));
    assert_eq!(i["software"], json!([0, 1, 1, 0x8d7e_91a0u32]));
    assert_eq!(i["unique_id"], json!(b"lj9da-bridge-uid".to_vec()));
    assert_eq!(i["name"], json!("org.lj9da.bridge"));
    let t = decoded[5]["fields"].as_array().unwrap();
    assert_eq!((t[0].as_u64(), t[2].as_u64()), (Some(5), Some(1)));
    let kelvin =
        lj9da_bridge::dronecan::float16::to_f32(lj9da_bridge::dronecan::float16::from_f32(344.15));
    assert!(close(t[1].as_f64().unwrap(), f64::from(kelvin)), "{t:?}");
    assert_eq!(
        decoded[6]["fields"],
        json!([0, true, b"lj9da-".to_vec()]),
        "the anonymous request"
    );

    // dronecan's own frames, put back together and decoded by the bridge.
    let t0 = Instant::now();
    let mut r = Reassembler::new();
    let mut transfers = Vec::new();
    for frames in got["encoded"].as_array().unwrap() {
        for f in frames.as_array().unwrap() {
            let frame = CanFrame::new(
                f[0].as_u64().unwrap() as u32,
                &unhex(f[1].as_str().unwrap()),
            )
            .unwrap();
            let signature = |id: &CanId| {
                [ARRAY_COMMAND, ACTUATOR_STATUS]
                    .into_iter()
                    .find(|t| t.id == id.data_type_id)
                    .map(|t| t.signature)
            };
            if let Some(t) = r
                .push(&frame, t0, signature)
                .expect("dronecan's frame taken")
            {
                transfers.push(t);
            }
        }
    }
    assert_eq!(transfers.len(), 2, "{transfers:?}");
    assert_eq!((transfers[0].id.source, transfers[0].transfer_id), (10, 17));
    let commands = messages::decode_array_command(&transfers[0].payload).unwrap();
    let values: Vec<(u8, CommandType, f32)> = commands
        .iter()
        .map(|c| (c.actuator_id, c.command_type, c.value))
        .collect();
    assert_eq!(
        values,
        vec![
            (1, CommandType::Unitless, -1.0),
            (2, CommandType::Position, -0.25),
            (3, CommandType::Force, 0.0),
            (4, CommandType::Speed, 0.5),
            (5, CommandType::Pwm, 1.0),
            (6, CommandType::Unitless, 1520.0),
            (7, CommandType::Position, 0.012_496_948),
            (8, CommandType::Force, 3.0),
        ]
    );
    let s = messages::decode_actuator_status(&transfers[1].payload).unwrap();
    assert_eq!((s.actuator_id, s.power_rating_pct), (4, 55));
    assert!(
        (s.position + 0.02).abs() < 1e-4 && s.force == 3.5 && s.speed == 0.125,
        "{s:?}"
    );
}

fn frames_of(encoded: &Value) -> Vec<CanFrame> {
    encoded
        .as_array()
        .unwrap()
        .iter()
        .map(|f| {
            CanFrame::new(
                f[0].as_u64().unwrap() as u32,
                &unhex(f[1].as_str().unwrap()),
            )
            .unwrap()
        })
        .collect()
}

#[test]
fn dronecan_commands_the_node_asks_who_it_is_and_hears_its_status() {
    let got = peer(json!({"types": [], "decode": []}));
    let encoded = got["encoded"].as_array().unwrap();
    let t0 = Instant::now();
    let mut node = Node::new(
        Identity {
            node_id: Some(42),
            name: "org.lj9da.bridge".into(),
            software_major: 0,
            software_minor: 1,
            vcs_commit: Some(0x1234_5678),
            unique_id: *b"0123456789abcdef",
        },
        t0,
    );
    node.set_health(Health::Warning, 0x0004);
    // dronecan's ArrayCommand from node 10: its eight commands.
    let received: Vec<_> = frames_of(&encoded[0])
        .iter()
        .filter_map(|f| node.handle_frame(f, t0))
        .collect();
    assert_eq!(received.len(), 1);
    assert_eq!(received[0].source, 10);
    assert_eq!(received[0].commands.len(), 8);
    // Its GetNodeInfo request: answered, then the NodeStatus that is due.
    for f in frames_of(&encoded[2]) {
        assert_eq!(node.handle_frame(&f, t0), None);
    }
    let response: Vec<CanFrame> = std::iter::from_fn(|| node.pop_frame()).collect();
    node.poll(t0 + Duration::from_millis(2_300));
    let status: Vec<CanFrame> = std::iter::from_fn(|| node.pop_frame()).collect();
    assert!(
        response.len() > 1 && !status.is_empty(),
        "{response:?} {status:?}"
    );
    let back = peer(json!({
        "types": [],
        "decode": [frames_json(&response), frames_json(&status)],
    }));
    let info = &back["decoded"][0];
    assert_eq!(
        (info["source"].as_u64(), info["transfer_id"].as_u64()),
        (Some(42), Some(23))
    );
    assert_eq!(info["fields"]["name"], json!("org.lj9da.bridge"));
    assert_eq!(
        info["fields"]["unique_id"],
        json!(b"0123456789abcdef".to_vec())
    );
    assert_eq!(info["fields"]["software"], json!([0, 1, 1, 0x1234_5678]));
    assert_eq!(info["fields"]["status"], json!([0, 1, 0, 0, 4]));
    assert_eq!(back["decoded"][1]["fields"], json!([2, 1, 0, 0, 4]));
}

//! The data types the bridge speaks, from the DroneCAN DSDL (`uavcan/equipment/actuator/`,
//! `uavcan/protocol/`), each with its default data type id and its signature.

use super::bits::{BitReader, BitWriter};
use super::float16;

/// A data type: its id and its signature (which seeds a multi-frame transfer's CRC).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DataType {
    pub name: &'static str,
    pub id: u16,
    pub signature: u64,
}

/// `uavcan.equipment.actuator.ArrayCommand`.
pub const ARRAY_COMMAND: DataType = DataType {
    name: "uavcan.equipment.actuator.ArrayCommand",
    id: 1010,
    signature: 0xD8A7_4862_38EC_3AF3,
};

/// `uavcan.equipment.actuator.Status`.
pub const ACTUATOR_STATUS: DataType = DataType {
    name: "uavcan.equipment.actuator.Status",
    id: 1011,
    signature: 0x5E9B_BA44_FAF1_EA04,
};

/// `uavcan.equipment.device.Temperature`.
pub const DEVICE_TEMPERATURE: DataType = DataType {
    name: "uavcan.equipment.device.Temperature",
    id: 1110,
    signature: 0x7026_1C28_A941_44C6,
};

/// `uavcan.protocol.NodeStatus`.
pub const NODE_STATUS: DataType = DataType {
    name: "uavcan.protocol.NodeStatus",
    id: 341,
    signature: 0x0F08_68D0_C1A7_C6F1,
};

/// `uavcan.protocol.GetNodeInfo` (a service).
pub const GET_NODE_INFO: DataType = DataType {
    name: "uavcan.protocol.GetNodeInfo",
    id: 1,
    signature: 0xEE46_8A81_21C4_6A9E,
};

/// What an actuator command's value means (`Command.command_type`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CommandType {
    /// −1 … +1.
    Unitless,
    /// Metres or radians.
    Position,
    /// Newtons or newton-metres.
    Force,
    /// Metres or radians per second.
    Speed,
    /// A pulse width in µs.
    Pwm,
    /// A type this version of the DSDL does not name.
    Other(u8),
}

impl CommandType {
    fn of(raw: u8) -> Self {
        match raw {
            0 => CommandType::Unitless,
            1 => CommandType::Position,
            2 => CommandType::Force,
            3 => CommandType::Speed,
            4 => CommandType::Pwm,
            n => CommandType::Other(n),
        }
    }

    fn raw(self) -> u8 {
        match self {
            CommandType::Unitless => 0,
            CommandType::Position => 1,
            CommandType::Force => 2,
            CommandType::Speed => 3,
            CommandType::Pwm => 4,
            CommandType::Other(n) => n,
        }
    }
}

/// One `uavcan.equipment.actuator.Command`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Command {
    pub actuator_id: u8,
    pub command_type: CommandType,
    /// As sent, a float16 widened.
    pub value: f32,
}

/// The most commands in one ArrayCommand.
pub const MAX_COMMANDS: usize = 15;

/// An ArrayCommand's commands. Its array is the message's last field, so its length is the
/// payload's (4 bytes a command): a payload that is not whole commands, or holds more than
/// [`MAX_COMMANDS`], is refused (`None`).
pub fn decode_array_command(payload: &[u8]) -> Option<Vec<Command>> {
    if !payload.len().is_multiple_of(4) || payload.len() / 4 > MAX_COMMANDS {
        return None;
    }
    let mut r = BitReader::new(payload);
    Some(
        (0..payload.len() / 4)
            .map(|_| Command {
                actuator_id: r.get(8) as u8,
                command_type: CommandType::of(r.get(8) as u8),
                value: float16::to_f32(r.get(16) as u16),
            })
            .collect(),
    )
}

/// The payload of an ArrayCommand of `commands` (at most [`MAX_COMMANDS`]).
pub fn encode_array_command(commands: &[Command]) -> Vec<u8> {
    let mut w = BitWriter::new();
    for c in commands.iter().take(MAX_COMMANDS) {
        w.put(u64::from(c.actuator_id), 8);
        w.put(u64::from(c.command_type.raw()), 8);
        w.put(u64::from(float16::from_f32(c.value)), 16);
    }
    w.finish()
}

/// `uavcan.equipment.actuator.Status`: one actuator's state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ActuatorStatus {
    pub actuator_id: u8,
    /// Metres (a linear actuator).
    pub position: f32,
    /// Newtons.
    pub force: f32,
    /// Metres per second.
    pub speed: f32,
    /// 0–100 % of its rated power; 127: unknown.
    pub power_rating_pct: u8,
}

/// `power_rating_pct` when it is not known.
pub const POWER_RATING_UNKNOWN: u8 = 127;

pub fn encode_actuator_status(s: &ActuatorStatus) -> Vec<u8> {
    let mut w = BitWriter::new();
    w.put(u64::from(s.actuator_id), 8);
    w.put(u64::from(float16::from_f32(s.position)), 16);
    w.put(u64::from(float16::from_f32(s.force)), 16);
    w.put(u64::from(float16::from_f32(s.speed)), 16);
    w.put(0, 1);
    w.put(u64::from(s.power_rating_pct.min(POWER_RATING_UNKNOWN)), 7);
    w.finish()
}

/// `uavcan.equipment.device.Temperature`: one device's temperature.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeviceTemperature {
    pub device_id: u16,
    /// Kelvin.
    pub kelvin: f32,
    /// [`TEMPERATURE_OVERHEATING`], [`TEMPERATURE_OVERCOOLING`].
    pub error_flags: u8,
}

/// `error_flags`: the device is over its temperature limit.
pub const TEMPERATURE_OVERHEATING: u8 = 1;
/// `error_flags`: the device is under its temperature limit.
pub const TEMPERATURE_OVERCOOLING: u8 = 2;

pub fn encode_device_temperature(t: &DeviceTemperature) -> Vec<u8> {
    let mut w = BitWriter::new();
    w.put(u64::from(t.device_id), 16);
    w.put(u64::from(float16::from_f32(t.kelvin)), 16);
    w.put(u64::from(t.error_flags), 8);
    w.finish()
}

pub fn decode_device_temperature(payload: &[u8]) -> Option<DeviceTemperature> {
    let mut r = BitReader::new(payload);
    let t = DeviceTemperature {
        device_id: r.get(16) as u16,
        kelvin: float16::to_f32(r.get(16) as u16),
        error_flags: r.get(8) as u8,
    };
    (!r.short()).then_some(t)
}

pub fn decode_actuator_status(payload: &[u8]) -> Option<ActuatorStatus> {
    let mut r = BitReader::new(payload);
    let s = ActuatorStatus {
        actuator_id: r.get(8) as u8,
        position: float16::to_f32(r.get(16) as u16),
        force: float16::to_f32(r.get(16) as u16),
        speed: float16::to_f32(r.get(16) as u16),
        power_rating_pct: {
            r.get(1);
            r.get(7) as u8
        },
    };
    (!r.short()).then_some(s)
}

/// `uavcan.protocol.NodeStatus.health`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Health {
    Ok = 0,
    Warning = 1,
    Error = 2,
    Critical = 3,
}

/// `uavcan.protocol.NodeStatus.mode`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    Operational = 0,
    Initialization = 1,
    Maintenance = 2,
    SoftwareUpdate = 3,
    Offline = 7,
}

/// `uavcan.protocol.NodeStatus`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NodeStatus {
    pub uptime_sec: u32,
    pub health: Health,
    pub mode: Mode,
    pub sub_mode: u8,
    pub vendor_specific_status_code: u16,
}

fn put_node_status(w: &mut BitWriter, s: &NodeStatus) {
    w.put(u64::from(s.uptime_sec), 32);
    w.put(s.health as u64, 2);
    w.put(s.mode as u64, 3);
    w.put(u64::from(s.sub_mode), 3);
    w.put(u64::from(s.vendor_specific_status_code), 16);
}

pub fn encode_node_status(s: &NodeStatus) -> Vec<u8> {
    let mut w = BitWriter::new();
    put_node_status(&mut w, s);
    w.finish()
}

/// `uavcan.protocol.GetNodeInfo`'s response: who the node is.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NodeInfo {
    pub status: NodeStatus,
    pub software_major: u8,
    pub software_minor: u8,
    /// The version control commit (`optional_field_flags` bit 0 says it is set), if known.
    pub vcs_commit: Option<u32>,
    pub hardware_major: u8,
    pub hardware_minor: u8,
    pub unique_id: [u8; 16],
    /// Reverse-domain, lower case, at most 80 bytes (longer is cut).
    pub name: String,
}

pub fn encode_node_info(info: &NodeInfo) -> Vec<u8> {
    let mut w = BitWriter::new();
    put_node_status(&mut w, &info.status);
    w.put(u64::from(info.software_major), 8);
    w.put(u64::from(info.software_minor), 8);
    w.put(u64::from(info.vcs_commit.is_some()), 8);
    w.put(u64::from(info.vcs_commit.unwrap_or(0)), 32);
    w.put(0, 64); // image_crc: not set (flag bit 1 clear)
    w.put(u64::from(info.hardware_major), 8);
    w.put(u64::from(info.hardware_minor), 8);
    w.put_bytes(&info.unique_id);
    w.put(0, 8); // certificate_of_authenticity: empty, its length first (not the last field)
    let name = info.name.as_bytes();
    w.put_bytes(&name[..name.len().min(80)]); // the last field: no length
    w.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn node_status_packs_health_mode_and_sub_mode_into_one_byte() {
        let bytes = encode_node_status(&NodeStatus {
            uptime_sec: 0x0102_0304,
            health: Health::Error,
            mode: Mode::Maintenance,
            sub_mode: 5,
            vendor_specific_status_code: 0xABCD,
        });
        assert_eq!(
            bytes,
            vec![0x04, 0x03, 0x02, 0x01, 0b10_010_101, 0xCD, 0xAB]
        );
    }

    #[test]
    fn an_array_command_is_whole_commands() {
        // ArduPlane's, as first seen on its bus: actuator 1, unitless, 0.0.
        let got = decode_array_command(&[1, 0, 0, 0, 2, 0, 0x00, 0x3C]).unwrap();
        assert_eq!(
            got,
            vec![
                Command {
                    actuator_id: 1,
                    command_type: CommandType::Unitless,
                    value: 0.0
                },
                Command {
                    actuator_id: 2,
                    command_type: CommandType::Unitless,
                    value: 1.0
                }
            ]
        );
        assert_eq!(
            encode_array_command(&got),
            vec![1, 0, 0, 0, 2, 0, 0x00, 0x3C]
        );
        assert_eq!(decode_array_command(&[1, 0, 0]), None);
        assert_eq!(decode_array_command(&[0; 64]), None);
    }

    #[test]
    fn a_device_temperature_is_five_bytes_in_kelvin() {
        let t = DeviceTemperature {
            device_id: 0x0102,
            kelvin: 273.15 + 26.0,
            error_flags: TEMPERATURE_OVERHEATING,
        };
        let bytes = encode_device_temperature(&t);
        assert_eq!(bytes.len(), 5);
        // Little-endian fields, as DSDL packs a whole-byte field.
        assert_eq!(&bytes[..2], &[0x02, 0x01]);
        assert_eq!(bytes[4], 1);
        let back = decode_device_temperature(&bytes).unwrap();
        assert_eq!(back.device_id, 0x0102);
        // float16 near 300 K: steps of 0.25 K.
        assert!((back.kelvin - 299.15).abs() <= 0.125, "{back:?}");
        assert_eq!(decode_device_temperature(&bytes[..4]), None);
    }

    #[test]
    fn an_actuator_status_is_eight_bytes() {
        let s = ActuatorStatus {
            actuator_id: 3,
            position: -0.0125,
            force: 12.5,
            speed: 0.0,
            power_rating_pct: 40,
        };
        let bytes = encode_actuator_status(&s);
        assert_eq!(bytes.len(), 8);
        assert_eq!(bytes[7], 40);
        let back = decode_actuator_status(&bytes).unwrap();
        assert_eq!(back.actuator_id, 3);
        assert!((back.position + 0.0125).abs() < 1e-5);
    }
}

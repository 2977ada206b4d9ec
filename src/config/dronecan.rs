//! The `[dronecan]` table: the bridge as a DroneCAN node, its servos as the autopilot's
//! actuators (`uavcan.equipment.actuator`).
//!
//! With the table the node runs: it answers GetNodeInfo, sends NodeStatus and each servo's
//! actuator Status. The servos take their goals from DroneCAN only when `[bridge] commands =
//! "dronecan"` says so (see [`super::bridge::CommandSource`]): one source commands them, never
//! both.

use super::error::{ConfigError, Scope};
use super::raw::{RawDroneCan, RawNodeId};
use super::servo::UnitlessLaw;
use std::fmt;

/// The multicast transport's interface number and groups: ArduPilot SITL's `CAN_P1_DRIVER`
/// interface 1 is group `239.65.82.0`, interface 2 `239.65.82.1`, …
pub const MULTICAST_INTERFACES: std::ops::RangeInclusive<u8> = 0..=9;

/// The node ids a node may take statically: 1–125 (126 and 127 are kept for tools, 0 is
/// "no id" in DroneCAN v0).
pub const NODE_IDS: std::ops::RangeInclusive<u8> = 1..=125;

/// How often each servo's actuator Status may be sent, in Hz.
pub const STATUS_HZ: std::ops::RangeInclusive<f64> = 1.0..=50.0;

/// Where the node's frames go.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CanInterface {
    /// A SocketCAN interface (`can0`): the bus on the aircraft.
    SocketCan(String),
    /// ArduPilot SITL's CAN over multicast UDP, interface n (group `239.65.82.n`, port
    /// 57732): the simulated bus, for tests on a computer without CAN.
    Multicast(u8),
}

impl fmt::Display for CanInterface {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CanInterface::SocketCan(name) => f.write_str(name),
            CanInterface::Multicast(n) => write!(f, "mcast:{n}"),
        }
    }
}

/// The node's id: set in the mapping, or asked of the bus's allocator.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NodeId {
    /// `node_id = 42`: 1–125.
    Static(u8),
    /// `node_id = "dynamic"`: dynamic node id allocation (ArduPilot runs an allocator on each
    /// DroneCAN driver); the node says nothing but its requests until it has one.
    Dynamic,
}

impl NodeId {
    /// The id, where the mapping sets it.
    pub fn fixed(self) -> Option<u8> {
        match self {
            NodeId::Static(n) => Some(n),
            NodeId::Dynamic => None,
        }
    }
}

impl fmt::Display for NodeId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            NodeId::Static(n) => write!(f, "{n}"),
            NodeId::Dynamic => f.write_str("dynamic"),
        }
    }
}

/// The `[dronecan]` table.
#[derive(Debug, Clone, PartialEq)]
pub struct DroneCanConfig {
    /// `interface = "can0"` or `"mcast:0"`.
    pub interface: CanInterface,
    /// The node's id: 1–125, or dynamic.
    pub node_id: NodeId,
    /// What an UNITLESS command means (default ArduPilot's pulse).
    pub unitless: UnitlessLaw,
    /// Each servo's actuator Status per second (default 10).
    pub status_hz: f64,
}

impl DroneCanConfig {
    pub(crate) fn from_raw(raw: &RawDroneCan, scope: &Scope<'_>) -> Result<Self, ConfigError> {
        let interface = interface(raw.interface.get_ref())
            .map_err(|r| scope.error_on(&raw.interface, "interface", r))?;
        let node_id = match raw.node_id.get_ref() {
            RawNodeId::Number(n) => u8::try_from(*n)
                .ok()
                .filter(|n| NODE_IDS.contains(n))
                .map(NodeId::Static)
                .ok_or_else(|| {
                    format!(
                        "{n} is outside 1–125 (0 is no id; 126 and 127 are kept for tools); give \
                         the bridge an id no other node on the bus has, or \"dynamic\""
                    )
                }),
            RawNodeId::Text(t) if t.trim().eq_ignore_ascii_case("dynamic") => Ok(NodeId::Dynamic),
            RawNodeId::Text(t) => Err(format!(
                "\"{t}\" is not a node id: a number 1–125, or \"dynamic\" to ask the bus's \
                 allocator (ArduPilot runs one)"
            )),
        }
        .map_err(|r| scope.error_on(&raw.node_id, "node_id", r))?;
        let unitless = match &raw.unitless {
            None => UnitlessLaw::default(),
            Some(v) => match v.get_ref().trim().to_ascii_lowercase().as_str() {
                "ardupilot" => UnitlessLaw::ArduPilotPulse,
                "normalized" | "normalised" => UnitlessLaw::Normalized,
                other => {
                    return Err(scope.error_on(
                        v,
                        "unitless",
                        format!(
                            "\"{other}\" is not a law for UNITLESS commands; use \"ardupilot\" \
                             (its pulse (p − 1000)/500 − 1, mapped as p µs) or \"normalized\" \
                             (−1 ↔ −25 mm, +1 ↔ +25 mm)"
                        ),
                    ));
                }
            },
        };
        let status_hz = match &raw.status_hz {
            None => 10.0,
            Some(hz) if STATUS_HZ.contains(hz.get_ref()) => *hz.get_ref(),
            Some(hz) => {
                return Err(scope.error_on(
                    hz,
                    "status_hz",
                    format!(
                        "{} Hz is outside 1–50 Hz (each servo's actuator Status per second)",
                        hz.get_ref()
                    ),
                ));
            }
        };
        Ok(DroneCanConfig {
            interface,
            node_id,
            unitless,
            status_hz,
        })
    }
}

/// `"can0"` (a SocketCAN interface's name) or `"mcast:N"`.
fn interface(text: &str) -> Result<CanInterface, String> {
    let text = text.trim();
    if let Some(n) = text.strip_prefix("mcast:") {
        return n
            .parse::<u8>()
            .ok()
            .filter(|n| MULTICAST_INTERFACES.contains(n))
            .map(CanInterface::Multicast)
            .ok_or_else(|| {
                format!(
                    "\"{text}\": the multicast interface is a number 0–9 (ArduPilot SITL's CAN \
                     interface 1 is \"mcast:0\")"
                )
            });
    }
    // IFNAMSIZ is 16 with the terminating zero.
    let valid = !text.is_empty()
        && text.len() <= 15
        && text
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.'));
    if valid {
        Ok(CanInterface::SocketCan(text.to_string()))
    } else {
        Err(format!(
            "\"{text}\" is not a network interface's name (at most 15 letters, digits, '_', '-' \
             or '.', e.g. \"can0\") nor \"mcast:N\""
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_interface_is_a_socketcan_name_or_a_multicast_number() {
        assert_eq!(
            interface("can0"),
            Ok(CanInterface::SocketCan("can0".into()))
        );
        assert_eq!(interface(" mcast:1 "), Ok(CanInterface::Multicast(1)));
        for bad in [
            "",
            "mcast:",
            "mcast:10",
            "mcast:-1",
            "/dev/can0",
            "can 0",
            "abcdefghijklmnop",
        ] {
            assert!(interface(bad).is_err(), "{bad:?} taken");
        }
        assert_eq!(CanInterface::Multicast(0).to_string(), "mcast:0");
    }

    const BASE: &str = "[mavlink]\nconnection = \"udpin:0.0.0.0:14560\"\n[[bus]]\nname = \"b\"\nport = \"p\"\n[[servo]]\nname = \"s\"\nbus = \"b\"\nid = 1\nchannel = 3\n";

    fn parse(extra: &str) -> Result<crate::config::Config, crate::config::ConfigError> {
        crate::config::Config::parse(&format!("{BASE}{extra}"), "t.toml")
    }

    #[test]
    fn the_table_takes_its_defaults_and_a_servo_its_channel_as_actuator_id() {
        let c = parse("[dronecan]\ninterface = \"can0\"\nnode_id = 42\n").unwrap();
        let d = c.dronecan.unwrap();
        assert_eq!(d.interface, CanInterface::SocketCan("can0".into()));
        assert_eq!(d.node_id, NodeId::Static(42));
        assert_eq!(d.unitless, UnitlessLaw::ArduPilotPulse);
        assert_eq!(d.status_hz, 10.0);
        assert_eq!(c.servos[0].dronecan_id, 3);
        assert_eq!(c.bridge.commands, crate::config::CommandSource::Mavlink);
        assert!(parse("").unwrap().dronecan.is_none());
        let dynamic = parse("[dronecan]\ninterface = \"can0\"\nnode_id = \"Dynamic\"\n").unwrap();
        assert_eq!(dynamic.dronecan.unwrap().node_id, NodeId::Dynamic);
    }

    #[test]
    fn dronecan_commands_need_the_table_and_bad_values_are_named() {
        let cases = [
            (
                "[bridge]\ncommands = \"dronecan\"\n",
                "commands",
                "needs a [dronecan] table",
            ),
            (
                "[bridge]\ncommands = \"both\"\n",
                "commands",
                "\"both\" is not a source",
            ),
            (
                "[dronecan]\ninterface = \"can0\"\nnode_id = 0\n",
                "node_id",
                "outside 1–125",
            ),
            (
                "[dronecan]\ninterface = \"can0\"\nnode_id = 126\n",
                "node_id",
                "outside 1–125",
            ),
            (
                "[dronecan]\ninterface = \"mcast:12\"\nnode_id = 9\n",
                "interface",
                "0–9",
            ),
            (
                "[dronecan]\ninterface = \"can0\"\nnode_id = 9\nunitless = \"x\"\n",
                "unitless",
                "\"x\"",
            ),
            (
                "[dronecan]\ninterface = \"can0\"\nnode_id = 9\nstatus_hz = 0.5\n",
                "status_hz",
                "1–50",
            ),
            ("[dronecan]\nnode_id = 9\n", "interface", "interface"),
            (
                "[dronecan]\ninterface = \"can0\"\nnode_id = \"auto\"\n",
                "node_id",
                "\"auto\" is not a node id",
            ),
            (
                "[dronecan]\ninterface = \"can0\"\nnode_id = 4.5\n",
                "node_id",
                "node_id",
            ),
        ];
        for (extra, key, reason) in cases {
            let e = parse(extra).expect_err(extra);
            assert_eq!(e.key(), Some(key), "{extra}: {e}");
            assert!(e.to_string().contains(reason), "{extra}: {e}");
        }
        let e = crate::config::Config::parse(
            &BASE.replace("channel = 3\n", "channel = 3\ndronecan_id = 256\n"),
            "t.toml",
        )
        .unwrap_err();
        assert_eq!(e.key(), Some("dronecan_id"), "{e}");
    }
}

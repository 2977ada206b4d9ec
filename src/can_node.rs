//! The bridge as a DroneCAN node, sans-IO: the [`crate::dronecan`] node with the servos behind
//! it. It is handed CAN frames, the servos' reports and the time, and hands back the
//! ArrayCommands received (for [`crate::mavlink::BridgeCore::handle_can_commands`]) and the
//! frames to send:
//!
//! - each servo's `uavcan.equipment.actuator.Status` at `[dronecan] status_hz`, under its
//!   `dronecan_id`: `position` the rod's measured position in metres, in the servo's own
//!   coordinates (as the flight record and NAMED_VALUE_FLOAT `pos` give it); `force` and
//!   `speed` unknown (NaN: the servo measures neither), `power_rating_pct` unknown (127). A
//!   servo with no position read yet sends nothing. ArduPilot logs each as a CSRV row whose
//!   `Pos` is the position in degrees (it reads it as an angle): mm = Pos × π / 180 × 1000.
//! - each servo's temperature as `uavcan.equipment.device.Temperature` once a second,
//!   `device_id` its `dronecan_id`, in kelvin, `error_flags` overheating while it is over its
//!   temperature alarm or limit. ArduPilot logs it (TEMP rows) for a temperature sensor of
//!   `TEMPn_TYPE` 6 (DroneCAN) whose `TEMPn_MSG_ID` is that id.
//! - NodeStatus once a second: health OK while every servo answers without alarm; WARNING while
//!   one is starting, stale, degraded, stalled or over its temperature alarm; ERROR while one
//!   is offline, in fault, or over its temperature limit. Its vendor-specific status code has
//!   bit n set for the mapping's servo n (from 0, the first 16) that is not OK.
//! - GetNodeInfo answered with the name [`NODE_NAME`], the bridge's version and this
//!   computer's unique id.

use crate::config::Config;
use crate::dronecan::frame::CanFrame;
use crate::dronecan::messages::{
    ActuatorStatus, DeviceTemperature, Health, POWER_RATING_UNKNOWN, TEMPERATURE_OVERHEATING,
};
use crate::dronecan::node::{Commands, Identity, Node, Refused, take_due};
use crate::mavlink::{ServoReport, ServoState};
use std::time::{Duration, Instant};

/// The node's name in GetNodeInfo.
pub const NODE_NAME: &str = "org.lj9da.bridge";

/// See the module docs.
#[derive(Debug)]
pub struct CanNode {
    node: Node,
    /// Each servo's `dronecan_id`, in mapping order.
    ids: Vec<u8>,
    period: Duration,
    next_status: Instant,
    next_temperature: Instant,
}

/// How often each servo's temperature goes out.
pub const TEMPERATURE_PERIOD: Duration = Duration::from_secs(1);

impl CanNode {
    /// The node of `cfg`'s `[dronecan]` table (`None` without one), started at `now`;
    /// `unique_id` is this computer's (see [`unique_id`]).
    pub fn new(cfg: &Config, unique_id: [u8; 16], now: Instant) -> Option<Self> {
        let d = cfg.dronecan.as_ref()?;
        let version = |i: usize| {
            env!("CARGO_PKG_VERSION")
                .split('.')
                .nth(i)
                .and_then(|n| n.parse().ok())
                .unwrap_or(0)
        };
        let identity = Identity {
            node_id: d.node_id.fixed(),
            name: NODE_NAME.to_string(),
            software_major: version(0),
            software_minor: version(1),
            vcs_commit: None,
            unique_id,
        };
        Some(CanNode {
            node: Node::new(identity, now),
            ids: cfg.servos.iter().map(|s| s.dronecan_id).collect(),
            period: Duration::from_secs_f64(1.0 / d.status_hz),
            next_status: now,
            next_temperature: now,
        })
    }

    /// The node's id: `None` while it asks the bus's allocator for one (`node_id = "dynamic"`).
    pub fn node_id(&self) -> Option<u8> {
        self.node.node_id()
    }

    /// A frame received at `now`: the ArrayCommand it completes, if any.
    pub fn handle_frame(&mut self, frame: &CanFrame, now: Instant) -> Option<Commands> {
        self.node.handle_frame(frame, now)
    }

    /// Time has come (see [`CanNode::poll_timeout`]): the servos' Status if due, the
    /// NodeStatus with the health `reports` (mapping order) give.
    pub fn handle_timeout(&mut self, now: Instant, reports: &[ServoReport]) {
        let (health, unwell) = health(reports);
        self.node.set_health(health, unwell);
        if take_due(&mut self.next_status, self.period, now) {
            for (id, r) in self.ids.iter().zip(reports) {
                let Some(mm) = r.position_mm else {
                    continue;
                };
                self.node.send_actuator_status(&ActuatorStatus {
                    actuator_id: *id,
                    position: mm / 1000.0,
                    force: f32::NAN,
                    speed: f32::NAN,
                    power_rating_pct: POWER_RATING_UNKNOWN,
                });
            }
        }
        if take_due(&mut self.next_temperature, TEMPERATURE_PERIOD, now) {
            for (id, r) in self.ids.iter().zip(reports) {
                let Some(celsius) = r.temperature_c else {
                    continue;
                };
                let hot = r.temperature_alarm || r.temperature_error;
                self.node.send_device_temperature(&DeviceTemperature {
                    device_id: u16::from(*id),
                    kelvin: celsius + 273.15,
                    error_flags: if hot { TEMPERATURE_OVERHEATING } else { 0 },
                });
            }
        }
        self.node.poll(now);
    }

    /// When [`CanNode::handle_timeout`] must next be called.
    pub fn poll_timeout(&self) -> Instant {
        self.next_status
            .min(self.next_temperature)
            .min(self.node.next_wake())
    }

    /// The next frame to send, oldest first.
    pub fn poll_frame(&mut self) -> Option<CanFrame> {
        self.node.pop_frame()
    }

    /// The frames received that made no transfer, by why.
    pub fn refused(&self) -> &Refused {
        self.node.refused()
    }
}

/// The node's health from the servos' reports, and the mask of the servos (bit n: servo n in
/// mapping order, the first 16) that are not OK.
pub fn health(reports: &[ServoReport]) -> (Health, u16) {
    let mut worst = Health::Ok;
    let mut unwell = 0u16;
    for (i, r) in reports.iter().enumerate() {
        let h = match r.state() {
            ServoState::Offline | ServoState::Fault => Health::Error,
            _ if r.temperature_error => Health::Error,
            ServoState::Starting | ServoState::Stale => Health::Warning,
            ServoState::Online if r.temperature_alarm || r.stalled || r.degraded.is_some() => {
                Health::Warning
            }
            ServoState::Online => Health::Ok,
        };
        if h != Health::Ok && i < 16 {
            unwell |= 1 << i;
        }
        if h as u8 > worst as u8 {
            worst = h;
        }
    }
    (worst, unwell)
}

/// A unique id from this computer's `/etc/machine-id` (its text, as read): the same on every
/// start, different on another computer; all zero without one (DroneCAN's "unknown").
pub fn unique_id(machine_id: Option<&str>) -> [u8; 16] {
    use sha2::{Digest, Sha256};
    let Some(text) = machine_id.map(str::trim).filter(|t| !t.is_empty()) else {
        return [0; 16];
    };
    let digest = Sha256::digest(format!("lj9da-bridge dronecan {text}").as_bytes());
    let mut id = [0; 16];
    id.copy_from_slice(&digest[..16]);
    id
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dronecan::frame::Kind;
    use crate::dronecan::messages::{self, ACTUATOR_STATUS, DEVICE_TEMPERATURE, NODE_STATUS};
    use crate::dronecan::transfer::Reassembler;

    fn cfg() -> Config {
        Config::parse(
            "[mavlink]\nconnection = \"udpin:0.0.0.0:14560\"\n[dronecan]\ninterface = \"mcast:0\"\nnode_id = 42\nstatus_hz = 20\n[[bus]]\nname = \"b\"\nport = \"p\"\n[[servo]]\nname = \"a\"\nbus = \"b\"\nid = 1\nchannel = 1\n[[servo]]\nname = \"e\"\nbus = \"b\"\nid = 2\nchannel = 2\ndronecan_id = 7\n",
            "t.toml",
        )
        .unwrap()
    }

    fn online(mm: f32) -> ServoReport {
        ServoReport {
            state: Some(ServoState::Online),
            position_mm: Some(mm),
            ..ServoReport::default()
        }
    }

    /// Every transfer of `ty` in the node's frames so far.
    fn sent(node: &mut CanNode, ty: messages::DataType, now: Instant) -> Vec<Vec<u8>> {
        let mut r = Reassembler::new();
        std::iter::from_fn(|| node.poll_frame())
            .filter_map(|f| {
                r.push(&f, now, |id| {
                    (id.kind == Kind::Message && id.data_type_id == ty.id).then_some(ty.signature)
                })
                .unwrap()
            })
            .map(|t| t.payload)
            .collect()
    }

    #[test]
    fn each_servo_with_a_position_says_it_under_its_id_at_the_tables_rate() {
        let t0 = Instant::now();
        let mut node = CanNode::new(&cfg(), [1; 16], t0).unwrap();
        let reports = [online(12.34), ServoReport::default()];
        node.handle_timeout(t0, &reports);
        let got: Vec<ActuatorStatus> = sent(&mut node, ACTUATOR_STATUS, t0)
            .iter()
            .map(|p| messages::decode_actuator_status(p).unwrap())
            .collect();
        assert_eq!(
            got.len(),
            1,
            "the servo with no reading sends nothing: {got:?}"
        );
        assert_eq!(got[0].actuator_id, 1);
        assert!((got[0].position - 0.01234).abs() < 2e-5, "{got:?}");
        assert!(got[0].force.is_nan() && got[0].speed.is_nan());
        assert_eq!(node.poll_timeout(), t0 + Duration::from_millis(50));
        node.handle_timeout(t0 + Duration::from_millis(49), &[online(1.0), online(2.0)]);
        assert!(
            sent(&mut node, ACTUATOR_STATUS, t0).is_empty(),
            "before 1/20 s"
        );
        node.handle_timeout(t0 + Duration::from_millis(50), &[online(1.0), online(2.0)]);
        let ids: Vec<u8> = sent(&mut node, ACTUATOR_STATUS, t0)
            .iter()
            .map(|p| messages::decode_actuator_status(p).unwrap().actuator_id)
            .collect();
        assert_eq!(ids, [1, 7]);
    }

    #[test]
    fn each_servo_says_its_temperature_once_a_second_in_kelvin() {
        let t0 = Instant::now();
        let mut node = CanNode::new(&cfg(), [1; 16], t0).unwrap();
        let warm = ServoReport {
            temperature_c: Some(26.0),
            ..online(0.0)
        };
        let hot = ServoReport {
            temperature_c: Some(71.0),
            temperature_alarm: true,
            ..online(0.0)
        };
        node.handle_timeout(t0, &[warm, hot]);
        let got: Vec<messages::DeviceTemperature> = sent(&mut node, DEVICE_TEMPERATURE, t0)
            .iter()
            .map(|p| messages::decode_device_temperature(p).unwrap())
            .collect();
        assert_eq!(got.len(), 2, "{got:?}");
        assert_eq!((got[0].device_id, got[0].error_flags), (1, 0));
        assert!((got[0].kelvin - 299.15).abs() <= 0.125, "{got:?}");
        assert_eq!((got[1].device_id, got[1].error_flags), (7, 1));
        node.handle_timeout(t0 + Duration::from_millis(999), &[warm, hot]);
        assert!(
            sent(&mut node, DEVICE_TEMPERATURE, t0).is_empty(),
            "before 1 s"
        );
        node.handle_timeout(t0 + TEMPERATURE_PERIOD, &[warm, ServoReport::default()]);
        assert_eq!(
            sent(&mut node, DEVICE_TEMPERATURE, t0).len(),
            1,
            "a servo with no reading says nothing"
        );
    }

    #[test]
    fn node_status_says_which_servos_are_unwell() {
        let off = ServoReport {
            state: Some(ServoState::Offline),
            ..ServoReport::default()
        };
        let hot = ServoReport {
            temperature_alarm: true,
            ..online(0.0)
        };
        assert_eq!(health(&[online(0.0), online(1.0)]), (Health::Ok, 0));
        assert_eq!(health(&[online(0.0), hot]), (Health::Warning, 0b10));
        assert_eq!(health(&[off, hot]), (Health::Error, 0b11));
        assert_eq!(health(&[ServoReport::default()]), (Health::Warning, 1));
        let t0 = Instant::now();
        let mut node = CanNode::new(&cfg(), [1; 16], t0).unwrap();
        node.handle_timeout(t0, &[online(0.0), off]);
        let status = sent(&mut node, NODE_STATUS, t0);
        assert_eq!(status.len(), 1);
        // uptime (4 bytes), health 2 bits | mode 3 | sub mode 3, vendor code.
        assert_eq!(status[0][4] >> 6, Health::Error as u8);
        assert_eq!(u16::from_le_bytes([status[0][5], status[0][6]]), 0b10);
    }

    #[test]
    fn the_unique_id_is_the_machines_and_zero_without_one() {
        let a = unique_id(Some("0123456789abcdef0123456789abcdef\n"));
        assert_eq!(a, unique_id(Some("0123456789abcdef0123456789abcdef")));
        assert_ne!(a, unique_id(Some("fedcba9876543210fedcba9876543210")));
        assert_ne!(a, [0; 16]);
        assert_eq!(unique_id(None), [0; 16]);
        assert_eq!(unique_id(Some(" \n")), [0; 16]);
    }
}

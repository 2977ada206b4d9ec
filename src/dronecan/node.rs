//! A DroneCAN node, sans-IO: it is handed frames and the time, and hands back the actuator
//! commands it received and the frames it has to send. It answers GetNodeInfo, sends its
//! NodeStatus once a second, numbers its transfers (one transfer id per data type, counting up
//! modulo 32), and broadcasts what it is given to say (an actuator's Status).
//!
//! What the commands mean for a servo, and what the node's health is, are the caller's: this
//! module knows no servo.

use super::allocation::{self, ALLOCATION, Allocatee};
use super::frame::{CanFrame, CanId, Kind};
use super::messages::{
    self, ACTUATOR_STATUS, ARRAY_COMMAND, ActuatorStatus, Command, DEVICE_TEMPERATURE, DataType,
    DeviceTemperature, GET_NODE_INFO, Health, Mode, NODE_STATUS, NodeInfo, NodeStatus,
};
use super::transfer::{Reassembler, Transfer, TransferError};
use std::collections::{HashMap, VecDeque};
use std::time::{Duration, Instant};

/// How often NodeStatus goes out: the specification's default, 1 Hz.
pub const NODE_STATUS_PERIOD: Duration = Duration::from_secs(1);

/// Priorities (0 highest): NodeStatus and services low, actuator status as the autopilot's own
/// actuator messages (medium, 16).
const PRIORITY_STATUS: u8 = 16;
const PRIORITY_LOW: u8 = 30;

/// Who the node is: what GetNodeInfo answers.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Identity {
    /// 1–127, or `None`: asked of an allocator on the bus (see [`super::allocation`]).
    pub node_id: Option<u8>,
    /// Reverse-domain name, e.g. `org.lj9da.bridge`.
    pub name: String,
    pub software_major: u8,
    pub software_minor: u8,
    pub vcs_commit: Option<u32>,
    /// The same on every start of this computer, different on another.
    pub unique_id: [u8; 16],
}

/// The frames received that did not make a transfer, counted by why.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Refused {
    pub identifier: u64,
    pub no_start: u64,
    pub out_of_order: u64,
    pub short_start: u64,
    pub crc: u64,
    pub too_long: u64,
    /// An ArrayCommand whose payload was not whole commands.
    pub malformed: u64,
}

impl Refused {
    fn count(&mut self, e: &TransferError) {
        let n = match e {
            TransferError::Identifier(_) => &mut self.identifier,
            TransferError::NoStart => &mut self.no_start,
            TransferError::OutOfOrder => &mut self.out_of_order,
            TransferError::ShortStart => &mut self.short_start,
            TransferError::Crc { .. } => &mut self.crc,
            TransferError::TooLong => &mut self.too_long,
        };
        *n += 1;
    }
}

/// ArrayCommand's commands as they came: from which node, when.
#[derive(Debug, Clone, PartialEq)]
pub struct Commands {
    pub source: u8,
    pub at: Instant,
    pub commands: Vec<Command>,
}

/// The node.
#[derive(Debug)]
pub struct Node {
    identity: Identity,
    /// The node's id: the identity's, or the allocator's once it has given one.
    id: Option<u8>,
    /// Asking for an id, until one is given.
    allocatee: Option<Allocatee>,
    started: Instant,
    next_status: Instant,
    health: Health,
    vendor_code: u16,
    reassembler: Reassembler,
    /// The next transfer id of each (kind, data type) this node sends.
    transfer_ids: HashMap<(Kind, u16), u8>,
    outgoing: VecDeque<CanFrame>,
    refused: Refused,
}

impl Node {
    /// A node started at `now`: its first NodeStatus is due at once.
    pub fn new(identity: Identity, now: Instant) -> Self {
        let allocatee = identity
            .node_id
            .is_none()
            .then(|| Allocatee::new(identity.unique_id, 0, 0, now));
        Node {
            id: identity.node_id,
            allocatee,
            identity,
            started: now,
            next_status: now,
            health: Health::Ok,
            vendor_code: 0,
            reassembler: Reassembler::new(),
            transfer_ids: HashMap::new(),
            outgoing: VecDeque::new(),
            refused: Refused::default(),
        }
    }

    /// The health and vendor-specific status code the next NodeStatus carries.
    pub fn set_health(&mut self, health: Health, vendor_code: u16) {
        self.health = health;
        self.vendor_code = vendor_code;
    }

    /// The frames received so far that made no transfer, by why.
    pub fn refused(&self) -> &Refused {
        &self.refused
    }

    /// The node's id: `None` while an allocator has not given one yet.
    pub fn node_id(&self) -> Option<u8> {
        self.id
    }

    /// A frame received at `now`: the ArrayCommand it completes, if any. A GetNodeInfo request
    /// to this node is answered (see [`Node::pop_frame`]); while the node asks for an id, the
    /// Allocation messages go to its [`Allocatee`]; other types are ignored.
    pub fn handle_frame(&mut self, frame: &CanFrame, now: Instant) -> Option<Commands> {
        let own = self.id;
        let allocating = self.allocatee.is_some();
        let wanted = |id: &CanId| match id.kind {
            Kind::Message if id.data_type_id == ARRAY_COMMAND.id && id.source != 0 => {
                Some(ARRAY_COMMAND.signature)
            }
            Kind::Message if allocating && id.data_type_id == ALLOCATION.id => {
                Some(ALLOCATION.signature)
            }
            Kind::Request { destination }
                if Some(destination) == own && id.data_type_id == GET_NODE_INFO.id =>
            {
                Some(GET_NODE_INFO.signature)
            }
            _ => None,
        };
        let transfer = match self.reassembler.push(frame, now, wanted) {
            Ok(Some(t)) => t,
            Ok(None) => return None,
            Err(e) => {
                self.refused.count(&e);
                return None;
            }
        };
        match transfer.id.kind {
            Kind::Message if transfer.id.data_type_id == ALLOCATION.id => {
                self.allocation(&transfer, now);
                None
            }
            Kind::Message => match messages::decode_array_command(&transfer.payload) {
                Some(commands) => Some(Commands {
                    source: transfer.id.source,
                    at: now,
                    commands,
                }),
                None => {
                    self.refused.malformed += 1;
                    None
                }
            },
            Kind::Request { .. } => {
                self.answer_node_info(&transfer, now);
                None
            }
            Kind::Response { .. } => None,
        }
    }

    fn allocation(&mut self, transfer: &Transfer, now: Instant) {
        let (Some(allocatee), Some(message)) = (
            self.allocatee.as_mut(),
            allocation::decode(&transfer.payload),
        ) else {
            return;
        };
        if let Some(id) = allocatee.handle(transfer.id.source, &message, now) {
            self.id = Some(id);
            self.allocatee = None;
            // Heard at once: the allocator (ArduPilot's) asks for its node info on its first
            // NodeStatus.
            self.next_status = now;
        }
    }

    fn status_at(&self, now: Instant) -> NodeStatus {
        let uptime = now.saturating_duration_since(self.started).as_secs();
        NodeStatus {
            uptime_sec: u32::try_from(uptime).unwrap_or(u32::MAX),
            health: self.health,
            mode: Mode::Operational,
            sub_mode: 0,
            vendor_specific_status_code: self.vendor_code,
        }
    }

    fn answer_node_info(&mut self, request: &Transfer, now: Instant) {
        let info = NodeInfo {
            status: self.status_at(now),
            software_major: self.identity.software_major,
            software_minor: self.identity.software_minor,
            vcs_commit: self.identity.vcs_commit,
            hardware_major: 0,
            hardware_minor: 0,
            unique_id: self.identity.unique_id,
            name: self.identity.name.clone(),
        };
        let Some(own) = self.id else {
            return;
        };
        let response = Transfer {
            id: CanId {
                priority: request.id.priority,
                kind: Kind::Response {
                    destination: request.id.source,
                },
                data_type_id: GET_NODE_INFO.id,
                source: own,
                discriminator: 0,
            },
            // A response carries its request's transfer id.
            transfer_id: request.transfer_id,
            payload: messages::encode_node_info(&info),
        };
        self.outgoing
            .extend(response.frames(GET_NODE_INFO.signature));
    }

    /// Broadcast `status`, an actuator's state.
    pub fn send_actuator_status(&mut self, status: &ActuatorStatus) {
        let payload = messages::encode_actuator_status(status);
        self.broadcast(ACTUATOR_STATUS, PRIORITY_STATUS, payload);
    }

    /// Broadcast `t`, a device's temperature.
    pub fn send_device_temperature(&mut self, t: &DeviceTemperature) {
        let payload = messages::encode_device_temperature(t);
        self.broadcast(DEVICE_TEMPERATURE, PRIORITY_LOW, payload);
    }

    /// A message from this node; dropped while it has no id (an anonymous node sends only its
    /// Allocation requests).
    fn broadcast(&mut self, ty: DataType, priority: u8, payload: Vec<u8>) {
        let Some(source) = self.id else {
            return;
        };
        self.send_message(ty, priority, source, payload);
    }

    fn send_message(&mut self, ty: DataType, priority: u8, source: u8, payload: Vec<u8>) {
        let next = self.transfer_ids.entry((Kind::Message, ty.id)).or_insert(0);
        // An anonymous frame's discriminator: from its payload's CRC, as libcanard makes it.
        let discriminator = if source == 0 {
            (super::crc::add(0xFFFF, &payload) >> 1) & 0x3FFF
        } else {
            0
        };
        let transfer = Transfer {
            id: CanId {
                priority,
                kind: Kind::Message,
                data_type_id: ty.id,
                source,
                discriminator,
            },
            transfer_id: *next,
            payload,
        };
        *next = (*next + 1) % 32;
        self.outgoing.extend(transfer.frames(ty.signature));
    }

    /// What is due at `now`: the NodeStatus once a second; while the node has no id, its
    /// Allocation requests instead.
    pub fn poll(&mut self, now: Instant) {
        if let Some(allocatee) = self.allocatee.as_mut() {
            if let Some(request) = allocatee.poll(now) {
                self.send_message(ALLOCATION, PRIORITY_LOW, 0, allocation::encode(&request));
            }
            return;
        }
        if !take_due(&mut self.next_status, NODE_STATUS_PERIOD, now) {
            return;
        }
        let payload = messages::encode_node_status(&self.status_at(now));
        self.broadcast(NODE_STATUS, PRIORITY_LOW, payload);
    }

    /// When [`Node::poll`] next has something to do.
    pub fn next_wake(&self) -> Instant {
        match &self.allocatee {
            Some(a) => a.next_wake().unwrap_or(self.next_status),
            None => self.next_status,
        }
    }

    /// The next frame to send, oldest first.
    pub fn pop_frame(&mut self) -> Option<CanFrame> {
        self.outgoing.pop_front()
    }
}

/// Whether something due at `*next` every `period` is due at `now`; if so `*next` moves on to
/// the first time after `now`. The period keeps its phase: a caller held up for several periods
/// does the thing once.
pub fn take_due(next: &mut Instant, period: Duration, now: Instant) -> bool {
    if now < *next {
        return false;
    }
    while *next <= now {
        *next += period;
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dronecan::messages::CommandType;

    fn identity() -> Identity {
        Identity {
            node_id: Some(42),
            name: "org.lj9da.bridge".into(),
            software_major: 0,
            software_minor: 1,
            vcs_commit: None,
            unique_id: [7; 16],
        }
    }

    fn drain(node: &mut Node) -> Vec<CanFrame> {
        std::iter::from_fn(|| node.pop_frame()).collect()
    }

    fn transfers(frames: &[CanFrame], now: Instant, ty: DataType) -> Vec<Transfer> {
        let mut r = Reassembler::new();
        frames
            .iter()
            .filter_map(|f| {
                r.push(f, now, |id| {
                    (id.data_type_id == ty.id).then_some(ty.signature)
                })
                .unwrap()
            })
            .collect()
    }

    #[test]
    fn node_status_goes_out_once_a_second_with_its_uptime_and_health() {
        let t0 = Instant::now();
        let mut node = Node::new(identity(), t0);
        node.poll(t0);
        node.set_health(Health::Error, 0x0002);
        node.poll(t0 + Duration::from_millis(999));
        node.poll(t0 + Duration::from_secs(1));
        // Held up for 3.5 s: one NodeStatus, the period's phase kept.
        node.poll(t0 + Duration::from_millis(4_500));
        assert_eq!(node.next_wake(), t0 + Duration::from_secs(5));
        let sent = transfers(&drain(&mut node), t0, NODE_STATUS);
        let got: Vec<(u8, u8, Vec<u8>)> = sent
            .iter()
            .map(|t| (t.id.source, t.transfer_id, t.payload.clone()))
            .collect();
        let status = |uptime, health, code| {
            messages::encode_node_status(&NodeStatus {
                uptime_sec: uptime,
                health,
                mode: Mode::Operational,
                sub_mode: 0,
                vendor_specific_status_code: code,
            })
        };
        assert_eq!(
            got,
            vec![
                (42, 0, status(0, Health::Ok, 0)),
                (42, 1, status(1, Health::Error, 2)),
                (42, 2, status(4, Health::Error, 2)),
            ]
        );
    }

    #[test]
    fn array_commands_come_out_and_get_node_info_is_answered_to_its_asker() {
        let t0 = Instant::now();
        let mut node = Node::new(identity(), t0);
        let commands = vec![
            Command {
                actuator_id: 1,
                command_type: CommandType::Unitless,
                value: 0.5,
            },
            Command {
                actuator_id: 2,
                command_type: CommandType::Pwm,
                value: 1500.0,
            },
        ];
        let from_autopilot = Transfer {
            id: CanId {
                priority: 16,
                kind: Kind::Message,
                data_type_id: ARRAY_COMMAND.id,
                source: 10,
                discriminator: 0,
            },
            transfer_id: 3,
            payload: messages::encode_array_command(&commands),
        };
        let mut got = None;
        for f in from_autopilot.frames(ARRAY_COMMAND.signature) {
            got = node.handle_frame(&f, t0).or(got);
        }
        assert_eq!(
            got,
            Some(Commands {
                source: 10,
                at: t0,
                commands
            })
        );
        // GetNodeInfo from node 10 to this node: answered to 10, with the request's transfer
        // id; one to another node is not ours.
        for destination in [42, 43] {
            let request = Transfer {
                id: CanId {
                    priority: 30,
                    kind: Kind::Request { destination },
                    data_type_id: GET_NODE_INFO.id,
                    source: 10,
                    discriminator: 0,
                },
                transfer_id: 21,
                payload: Vec::new(),
            };
            for f in request.frames(GET_NODE_INFO.signature) {
                assert_eq!(node.handle_frame(&f, t0), None);
            }
        }
        let frames = drain(&mut node);
        let mut r = Reassembler::new();
        let answers: Vec<Transfer> = frames
            .iter()
            .filter_map(|f| r.push(f, t0, |_| Some(GET_NODE_INFO.signature)).unwrap())
            .collect();
        assert_eq!(answers.len(), 1);
        assert_eq!(answers[0].id.kind, Kind::Response { destination: 10 });
        assert_eq!((answers[0].id.source, answers[0].transfer_id), (42, 21));
        // A garbled ArrayCommand is counted, not taken.
        let bad = Transfer {
            payload: vec![1, 0, 0],
            ..from_autopilot
        };
        for f in bad.frames(ARRAY_COMMAND.signature) {
            assert_eq!(node.handle_frame(&f, t0), None);
        }
        assert_eq!(node.refused().malformed, 1);
    }

    #[test]
    fn each_data_type_numbers_its_own_transfers_modulo_32() {
        let t0 = Instant::now();
        let mut node = Node::new(identity(), t0);
        let status = ActuatorStatus {
            actuator_id: 1,
            position: 0.0,
            force: 0.0,
            speed: 0.0,
            power_rating_pct: messages::POWER_RATING_UNKNOWN,
        };
        for _ in 0..33 {
            node.send_actuator_status(&status);
        }
        node.poll(t0);
        let frames = drain(&mut node);
        let ids: Vec<u8> = transfers(&frames, t0, ACTUATOR_STATUS)
            .iter()
            .map(|t| t.transfer_id)
            .collect();
        assert_eq!(ids.len(), 33);
        assert_eq!((ids[0], ids[31], ids[32]), (0, 31, 0));
        assert_eq!(transfers(&frames, t0, NODE_STATUS)[0].transfer_id, 0);
    }

    #[test]
    fn a_node_without_an_id_asks_for_one_and_says_nothing_else_until_given() {
        let t0 = Instant::now();
        let uid: [u8; 16] = std::array::from_fn(|i| 0x40 + i as u8);
        let mut node = Node::new(
            Identity {
                node_id: None,
                unique_id: uid,
                ..identity()
            },
            t0,
        );
        assert_eq!(node.node_id(), None);
        node.send_actuator_status(&ActuatorStatus {
            actuator_id: 1,
            position: 0.0,
            force: 0.0,
            speed: 0.0,
            power_rating_pct: 0,
        });
        node.poll(t0);
        assert!(
            drain(&mut node).is_empty(),
            "no NodeStatus, no Status, no request yet"
        );
        let mut at = node.next_wake();
        node.poll(at);
        let frames = drain(&mut node);
        assert_eq!(frames.len(), 1);
        let id = CanId::parse(frames[0].id()).unwrap();
        assert_eq!((id.source, id.kind, id.data_type_id), (0, Kind::Message, 1));
        assert_ne!(id.discriminator, 0);
        let request = allocation::decode(&frames[0].data()[..frames[0].data().len() - 1]).unwrap();
        assert!(request.first_part_of_unique_id);
        assert_eq!(request.unique_id, uid[..6]);

        // The allocator (ArduPilot's node 10) answers each stage with what it has so far; the
        // last answer, all 16 bytes, is a multi-frame transfer.
        let answer = |known: usize, node_id: u8, tid: u8| Transfer {
            id: CanId {
                priority: 30,
                kind: Kind::Message,
                data_type_id: ALLOCATION.id,
                source: 10,
                discriminator: 0,
            },
            transfer_id: tid,
            payload: allocation::encode(&allocation::Allocation {
                node_id,
                first_part_of_unique_id: false,
                unique_id: uid[..known].to_vec(),
            }),
        };
        for (tid, known) in [(0, 6), (1, 12)] {
            for f in answer(known, 0, tid).frames(ALLOCATION.signature) {
                assert_eq!(node.handle_frame(&f, at), None);
            }
            at = node.next_wake();
            node.poll(at);
            let frames = drain(&mut node);
            assert_eq!(frames.len(), 1, "the next stage");
            let r = allocation::decode(&frames[0].data()[..frames[0].data().len() - 1]).unwrap();
            assert!(!r.first_part_of_unique_id);
            assert_eq!(r.unique_id, uid[known..(known + 6).min(16)]);
        }
        for f in answer(16, 99, 2).frames(ALLOCATION.signature) {
            node.handle_frame(&f, at);
        }
        assert_eq!(node.node_id(), Some(99));
        assert_eq!(node.next_wake(), at, "its first NodeStatus at once");
        node.poll(at);
        let status = transfers(&drain(&mut node), at, NODE_STATUS);
        assert_eq!(status.len(), 1);
        assert_eq!(status[0].id.source, 99);
    }
}

//! DroneCAN beside ArduPlane SITL: a network namespace of the test's own, where SITL's
//! multicast CAN stays, and a listener on that bus that keeps every ArrayCommand and every
//! transfer of the bridge's node it hears.

use super::{Autopilot, block_after};
use lj9da_bridge::dronecan::allocation::{self, ALLOCATION, Allocation};
use lj9da_bridge::dronecan::frame::{CanId, Kind};
use lj9da_bridge::dronecan::messages::{self, ARRAY_COMMAND, Command};
use lj9da_bridge::dronecan::{mcast, transfer::Reassembler};
use std::net::UdpSocket;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Move the calling thread into a network namespace of its own (see
/// [`crate::common::netns`]); the test fails with one line where it cannot.
pub fn enter_network_namespace() {
    if let Err(why) = crate::common::netns::enter() {
        panic!("DroneCAN with ArduPlane SITL: {why}");
    }
}

/// The pages' ArduPlane: its MAVLink parameters (`docs/autopilot.md`), its DroneCAN parameters
/// (`docs/dronecan.md`) with `extra` lines after them, and the log kept on the ground; SERIAL1
/// sends to UDP `udp_port`. Returns the autopilot and its defaults.
pub fn arduplane_on_can(dir: &Path, extra: &str, udp_port: u16) -> (Autopilot, String) {
    let (binary, defaults) = super::arduplane().expect(
        "no ArduPlane SITL: set LJ9DA_ARDUPLANE to an arduplane program (plane.parm beside it)",
    );
    let parm = dir.join(format!("bridge-can{}.parm", extra.len()));
    std::fs::write(
        &parm,
        format!(
            "{}{}LOG_DISARMED 1\n{extra}",
            block_after("docs/autopilot.md", "<!-- sitl: ArduPlane parameters -->"),
            block_after(
                "docs/dronecan.md",
                "<!-- sitl: ArduPlane DroneCAN parameters -->"
            ),
        ),
    )
    .unwrap();
    let defaults = format!("{},{}", defaults.display(), parm.display());
    (
        Autopilot::arduplane(&binary, dir, &defaults, udp_port),
        defaults,
    )
}

/// A socket on SITL's CAN group, shared (SO_REUSEADDR) with ArduPlane's and the bridge's.
fn shared_multicast_socket() -> UdpSocket {
    use nix::sys::socket::{
        AddressFamily, IpMembershipRequest, SockFlag, SockType, SockaddrIn, bind, setsockopt,
        socket, sockopt,
    };
    use std::os::fd::AsRawFd;
    let fd = socket(
        AddressFamily::Inet,
        SockType::Datagram,
        SockFlag::SOCK_CLOEXEC,
        None,
    )
    .unwrap();
    setsockopt(&fd, sockopt::ReuseAddr, &true).unwrap();
    let group = std::net::SocketAddrV4::new(mcast::GROUP, mcast::PORT);
    bind(fd.as_raw_fd(), &SockaddrIn::from(group)).expect("the multicast port");
    setsockopt(
        &fd,
        sockopt::IpAddMembership,
        &IpMembershipRequest::new(mcast::GROUP, None),
    )
    .expect("the CAN group");
    UdpSocket::from(fd)
}

/// An ArrayCommand heard on the bus (from another node than the bridge's): when, its commands.
#[derive(Debug, Clone)]
pub struct Heard {
    pub at: Instant,
    pub commands: Vec<Command>,
}

#[derive(Default)]
struct State {
    commands: Vec<Heard>,
    /// Allocators' answers to dynamic node id requests: when, from which node, what.
    allocations: Vec<(Instant, u8, Allocation)>,
    /// Per data type, the transfers from `node` (the bridge's id) and when.
    from_node: Vec<(Instant, u16, Vec<u8>)>,
}

/// A listener on SITL's CAN interface 1 (group 239.65.82.0).
pub struct CanListener {
    state: Arc<Mutex<State>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl CanListener {
    /// Listen; the bridge's node is `node` (its transfers of the types in `types` are kept).
    pub fn start(node: u8, types: &'static [messages::DataType]) -> CanListener {
        let socket = shared_multicast_socket();
        socket
            .set_read_timeout(Some(Duration::from_millis(50)))
            .unwrap();
        let state = Arc::new(Mutex::new(State::default()));
        let stop = Arc::new(AtomicBool::new(false));
        let (s, st) = (state.clone(), stop.clone());
        let thread = std::thread::spawn(move || {
            let mut reassembler = Reassembler::new();
            let mut buf = [0u8; 128];
            while !st.load(Ordering::Relaxed) {
                let Ok(n) = socket.recv(&mut buf) else {
                    continue;
                };
                let at = Instant::now();
                let Ok(frame) = mcast::decode(&buf[..n]) else {
                    continue;
                };
                let wanted = |id: &CanId| {
                    if id.kind != Kind::Message {
                        return None;
                    }
                    if id.data_type_id == ARRAY_COMMAND.id && id.source != node {
                        return Some(ARRAY_COMMAND.signature);
                    }
                    if id.data_type_id == ALLOCATION.id && id.source != 0 {
                        return Some(ALLOCATION.signature);
                    }
                    types
                        .iter()
                        .find(|t| t.id == id.data_type_id && id.source == node)
                        .map(|t| t.signature)
                };
                let Ok(Some(t)) = reassembler.push(&frame, at, wanted) else {
                    continue;
                };
                let mut state = s.lock().unwrap();
                if t.id.data_type_id == ALLOCATION.id {
                    if let Some(a) = allocation::decode(&t.payload) {
                        state.allocations.push((at, t.id.source, a));
                    }
                } else if t.id.data_type_id == ARRAY_COMMAND.id {
                    if let Some(commands) = messages::decode_array_command(&t.payload) {
                        state.commands.push(Heard { at, commands });
                    }
                } else {
                    state.from_node.push((at, t.id.data_type_id, t.payload));
                }
            }
        });
        CanListener {
            state,
            stop,
            thread: Some(thread),
        }
    }

    /// The ArrayCommands heard since `since`.
    pub fn commands_since(&self, since: Instant) -> Vec<Heard> {
        let state = self.state.lock().unwrap();
        state
            .commands
            .iter()
            .filter(|h| h.at >= since)
            .cloned()
            .collect()
    }

    /// The allocators' answers heard so far: when, from which node, what.
    pub fn allocations(&self) -> Vec<(Instant, u8, Allocation)> {
        self.state.lock().unwrap().allocations.clone()
    }

    /// The bridge's transfers of data type `id` since `since`: when, payload.
    pub fn node_transfers_since(&self, id: u16, since: Instant) -> Vec<(Instant, Vec<u8>)> {
        let state = self.state.lock().unwrap();
        state
            .from_node
            .iter()
            .filter(|(at, ty, _)| *ty == id && *at >= since)
            .map(|(at, _, p)| (*at, p.clone()))
            .collect()
    }
}

impl Drop for CanListener {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

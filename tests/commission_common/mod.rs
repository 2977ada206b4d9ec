//! Helpers of the commissioning tests: a simulated bus on a real pseudo-terminal, a link to
//! it, and a record of the packets that reached the bus.
#![allow(dead_code)]

use lj9da_bridge::commission::Link;
use lj9da_bridge::protocol::{BaudRate, ReplyRequest, ServoId, ShortPacket};
use lj9da_sim::protocol::host_packet::ShortForm;
use lj9da_sim::{BusEvent, HostPacket, SimBus, SimConfig};
use std::path::Path;
use std::sync::mpsc::Receiver;
use std::time::{Duration, Instant};

/// A simulated bus with servos `ids`, all at 115 200 bit/s.
pub fn sim(ids: &[u8]) -> SimBus {
    SimBus::spawn_pty(SimConfig {
        ids: ids.to_vec(),
        baud: 115_200,
        ..SimConfig::default()
    })
    .expect("the simulated bus starts")
}

pub fn id(n: u8) -> ServoId {
    ServoId::new(n).expect("a valid test ID")
}

/// A link to `sim` at `baud`.
pub async fn link_at(sim: &SimBus, baud: BaudRate) -> Link {
    Link::open(sim.path(), baud).await.expect("the pty opens")
}

/// A link to `sim` at 115 200 bit/s.
pub async fn link(sim: &SimBus) -> Link {
    link_at(sim, BaudRate::B115200).await
}

/// Whether a host packet changes anything in a servo: a write with data, a special packet
/// (flash write, reboot, factory reset) or a long packet.
pub fn is_write(packet: &HostPacket) -> bool {
    match packet {
        HostPacket::Long(_) => true,
        HostPacket::Short(short) => match short.form() {
            ShortForm::Write { data, .. } => !data.is_empty(),
            ShortForm::Request { .. } => false,
            _ => true,
        },
    }
}

/// How long the end marker may take to reach the simulated bus: it is one 8-byte packet, about
/// 0.7 ms of wire time, so only a stalled machine gets near this; waiting longer would only hide
/// a hang.
const MARKER_DEADLINE: Duration = Duration::from_secs(10);

/// The packet that closes a window of observation: a request to ID 127 for no reply (flag 0,
/// count 0). No commissioning command sends it (scans ask for an ACK), and it is not a write.
fn end_marker() -> ShortPacket {
    ShortPacket::request(id(127), ReplyRequest::None)
}

/// Every host packet the bus saw since `events` was subscribed, up to an end marker sent now
/// through `link`. The simulator handles the line's bytes in order, so once the marker has
/// arrived every packet sent before it has too: nothing is missed however late the simulator's
/// thread runs, and "nothing written" is judged over a window that really ended.
pub async fn packets(events: &Receiver<BusEvent>, link: &mut Link) -> Vec<HostPacket> {
    link.send(&end_marker())
        .await
        .expect("the end marker is sent");
    packets_until_marker(events)
}

/// [`packets`] after a command run in another process: that process has exited and closed the
/// port, so the marker is sent through a descriptor of our own, at 115 200 bit/s.
///
/// Not through a [`Link`]: a link takes the port's exclusive lock, and a child process that
/// another test forks while the link is open shares the link's descriptor, lock included,
/// until the child's `exec` closes it. On a busy machine that can be long enough for the next
/// command to find the port locked.
pub fn packets_after_exit(events: &Receiver<BusEvent>, port: &Path) -> Vec<HostPacket> {
    use std::io::Write;
    use std::os::fd::AsFd;
    use std::os::unix::fs::OpenOptionsExt;
    let mut tty = std::fs::OpenOptions::new()
        .write(true)
        .custom_flags(libc::O_NOCTTY)
        .open(port)
        .expect("the port opens once the command has exited");
    lj9da_sim::runtime::pty::set_speed(tty.as_fd(), 115_200).expect("the port takes 115 200 bit/s");
    tty.write_all(&end_marker().to_bytes())
        .expect("the end marker is sent");
    drop(tty);
    packets_until_marker(events)
}

fn packets_until_marker(events: &Receiver<BusEvent>) -> Vec<HostPacket> {
    let marker = end_marker().to_bytes();
    let deadline = Instant::now() + MARKER_DEADLINE;
    let mut seen = Vec::new();
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        match events.recv_timeout(left) {
            Ok(BusEvent::Packet(p)) if p.bytes == marker => return seen,
            Ok(BusEvent::Packet(p)) => seen.push(p.packet),
            Ok(_) => {}
            Err(error) => panic!(
                "the end marker {marker:02X?} did not reach the simulated bus within \
                 {MARKER_DEADLINE:?} ({error}); packets seen before it: {seen:?}"
            ),
        }
    }
}

/// The writing packets among [`packets`].
pub async fn writes(events: &Receiver<BusEvent>, link: &mut Link) -> Vec<HostPacket> {
    packets(events, link)
        .await
        .into_iter()
        .filter(is_write)
        .collect()
}

/// The writing packets among [`packets_after_exit`].
pub fn writes_after_exit(events: &Receiver<BusEvent>, port: &Path) -> Vec<HostPacket> {
    packets_after_exit(events, port)
        .into_iter()
        .filter(is_write)
        .collect()
}

//! Helpers of the commissioning tests: a simulated bus on a real pseudo-terminal, a link to
//! it, and a record of the packets that reached the bus.
#![allow(dead_code)]

use lj9da_bridge::commission::Link;
use lj9da_bridge::protocol::{BaudRate, ServoId};
use lj9da_sim::protocol::host_packet::ShortForm;
use lj9da_sim::{BusEvent, HostPacket, SimBus, SimConfig};
use std::sync::mpsc::Receiver;
use std::time::Duration;

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

/// Every host packet the bus has seen since `events` was subscribed (after letting the bus
/// thread catch up).
pub fn packets(events: &Receiver<BusEvent>) -> Vec<HostPacket> {
    std::thread::sleep(Duration::from_millis(60));
    events
        .try_iter()
        .filter_map(|e| match e {
            BusEvent::Packet(p) => Some(p.packet),
            _ => None,
        })
        .collect()
}

/// The writing packets among [`packets`].
pub fn writes(events: &Receiver<BusEvent>) -> Vec<HostPacket> {
    packets(events).into_iter().filter(is_write).collect()
}

//! The simulator over real pseudo-terminals (and TCP): wire timing measured on the host side, a bit-rate
//! change end to end, the device disappearing and reappearing, event timestamps.

mod common;

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::os::fd::AsFd;
use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

use common::{HostPort, request, write};
use lj9da_sim::{BusEvent, ReturnPacket, SimBus, SimConfig};
use nix::poll::{PollFd, PollFlags, PollTimeout, poll};

const SET_BAUD_38400: [u8; 9] = [0xFA, 0xAF, 0x01, 0x00, 0x06, 0x01, 0x01, 0x04, 0x03];

fn exchange(port: &mut HostPort, packet: &[u8], expect: usize) -> Vec<u8> {
    port.send(packet);
    port.receive_bytes(expect, Duration::from_millis(500))
}

/// The tests of this file run one at a time: the timing test measures on the host side, and a loaded
/// machine (other pty tests, other builds) delays the host's reads.
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

fn serial() -> MutexGuard<'static, ()> {
    ONE_AT_A_TIME
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}

#[test]
fn a_26_byte_reply_at_115200_takes_its_wire_time() {
    let _serial = serial();
    let bus = SimBus::spawn_pty(SimConfig::default()).expect("spawn");
    let mut port = HostPort::open(&bus.path(), 115_200);
    let mut widest_spread = Duration::ZERO;
    for _ in 0..10 {
        let sent_at = port.send(&request(1, 0x09));
        let chunks = port.receive(26, Duration::from_secs(2));
        let bytes: Vec<u8> = chunks.iter().flat_map(|(_, bytes)| bytes.clone()).collect();
        assert!(ReturnPacket::parse(&bytes).is_some(), "{bytes:02X?}");
        let first = chunks.first().expect("first").0;
        let last = chunks.last().expect("last").0;
        // Physics, on every exchange: request 8 bytes + latency + reply 26 bytes ≥ 3.1 ms.
        assert!(
            last - sent_at >= Duration::from_micros(2_200),
            "{:?}",
            last - sent_at
        );
        widest_spread = widest_spread.max(last - first);
    }
    // The reply's bytes are paced over 25 byte times (2.17 ms). A late read on the host side can only make
    // one exchange look shorter, never longer, so the widest of ten shows the pacing.
    assert!(
        widest_spread >= Duration::from_micros(2_100),
        "{widest_spread:?}"
    );
}

#[test]
fn a_baud_change_works_end_to_end_when_the_host_follows() {
    let _serial = serial();
    let bus = SimBus::spawn_pty(SimConfig::default()).expect("spawn");
    let mut port = HostPort::open(&bus.path(), 115_200);
    assert_eq!(exchange(&mut port, &request(1, 0x01), 1), [0x07]);
    port.send(&SET_BAUD_38400);
    std::thread::sleep(Duration::from_millis(20));
    let at_old_rate = exchange(&mut port, &request(1, 0x09), 26);
    assert!(
        ReturnPacket::parse(&at_old_rate).is_none(),
        "understood at the old rate: {at_old_rate:02X?}"
    );
    drop(port);
    let mut port = HostPort::open(&bus.path(), 38_400);
    let reply = exchange(&mut port, &request(1, 0x09), 26);
    assert!(ReturnPacket::parse(&reply).is_some(), "{reply:02X?}");
    assert!(bus.handle().stats().baud_mismatches >= 1);
}

#[test]
fn the_host_can_close_and_reopen_the_port() {
    let _serial = serial();
    let bus = SimBus::spawn_pty(SimConfig::default()).expect("spawn");
    for _ in 0..3 {
        let mut port = HostPort::open(&bus.path(), 115_200);
        assert_eq!(exchange(&mut port, &request(1, 0x01), 1), [0x07]);
    }
}

#[test]
fn the_device_disappears_and_reappears_behind_a_stable_link() {
    let _serial = serial();
    let link = std::env::temp_dir().join(format!("lj9da-sim-test-{}", std::process::id()));
    let bus = SimBus::spawn_pty(SimConfig {
        link: Some(link.clone()),
        ..SimConfig::default()
    })
    .expect("spawn");
    assert_eq!(bus.path(), link);
    let handle = bus.handle();
    let mut port = HostPort::open(&link, 115_200);
    assert_eq!(exchange(&mut port, &request(1, 0x01), 1), [0x07]);

    handle.disconnect_port();
    let mut fds = [PollFd::new(port.file.as_fd(), PollFlags::POLLIN)];
    let _ = poll(&mut fds, PollTimeout::from(1000u16));
    let mut buffer = [0u8; 8];
    match port.file.read(&mut buffer) {
        Ok(0) => {}
        Err(error) => assert_ne!(error.kind(), std::io::ErrorKind::WouldBlock),
        Ok(n) => panic!("read {n} bytes from a vanished device"),
    }
    assert!(!link.exists(), "the link is gone while the device is gone");

    let new_path = handle.try_reconnect_port().expect("reconnect");
    assert_eq!(new_path, link);
    let mut port = HostPort::open(&link, 115_200);
    assert_eq!(exchange(&mut port, &request(1, 0x01), 1), [0x07]);
    drop(bus);
    assert!(!link.exists(), "shutdown removes the link");
}

#[test]
fn packet_events_carry_the_read_instant_of_the_first_byte() {
    let _serial = serial();
    let bus = SimBus::spawn_pty(SimConfig {
        ids: vec![1, 2],
        ..SimConfig::default()
    })
    .expect("spawn");
    let events = bus.handle().subscribe();
    let mut port = HostPort::open(&bus.path(), 115_200);
    let long =
        lj9da_sim::LongPacket::write(0x1E, &[(1, &[0x64, 0x00]), (2, &[0xF4, 0x01])]).encode();
    let before = Instant::now();
    port.send(&long);
    let packet = loop {
        match events
            .recv_timeout(Duration::from_secs(2))
            .expect("an event")
        {
            BusEvent::Packet(packet) => break packet,
            _ => continue,
        }
    };
    assert!(packet.first_byte_at >= before);
    assert!(packet.completed_at >= packet.first_byte_at + lj9da_sim::bus::byte_time(115_200) * 14);
    assert_eq!(packet.packet.goal_positions(), vec![(1, 100), (2, 500)]);
    assert_eq!(packet.host_baud, Some(115_200));
}

#[test]
fn handle_snapshots_follow_the_servo() {
    let _serial = serial();
    let bus = SimBus::spawn_pty(SimConfig::default()).expect("spawn");
    let handle = bus.handle();
    let mut port = HostPort::open(&bus.path(), 115_200);
    port.send(&write(1, 0x24, &[0x01]));
    port.send(&write(1, 0x1E, &500i16.to_le_bytes()));
    std::thread::sleep(Duration::from_millis(300));
    let servo = handle.snapshot(1).expect("servo 1");
    assert_eq!(servo.goal_mm, 5.0);
    assert_eq!(servo.position_mm, 5.0);
    assert!(handle.snapshot(9).is_none());
    assert_eq!(handle.stats().packets_rx, 2);
}

#[test]
fn echo_over_a_pty_returns_the_host_bytes() {
    let _serial = serial();
    let bus = SimBus::spawn_pty(SimConfig::default()).expect("spawn");
    bus.handle().set_echo(true);
    let mut port = HostPort::open(&bus.path(), 115_200);
    let packet = request(1, 0x01);
    let answer = exchange(&mut port, &packet, packet.len() + 1);
    assert_eq!(&answer[..packet.len()], packet.as_slice());
    assert_eq!(answer[packet.len()..], [0x07]);
}

#[test]
fn tcp_serves_one_client_at_a_time() {
    let _serial = serial();
    let bus = SimBus::spawn_tcp(SimConfig::default(), SocketAddr::from(([127, 0, 0, 1], 0)))
        .expect("spawn");
    let addr = bus.local_addr().expect("address");
    let mut client = TcpStream::connect(addr).expect("connect");
    client
        .set_read_timeout(Some(Duration::from_secs(2)))
        .expect("timeout");
    client.write_all(&request(1, 0x09)).expect("send");
    let mut reply = [0u8; 26];
    client.read_exact(&mut reply).expect("reply");
    assert!(ReturnPacket::parse(&reply).is_some());
    drop(client);
    let mut again = TcpStream::connect(addr).expect("reconnect");
    again
        .set_read_timeout(Some(Duration::from_secs(2)))
        .expect("timeout");
    again.write_all(&request(1, 0x01)).expect("send");
    let mut ack = [0u8; 1];
    again.read_exact(&mut ack).expect("ack");
    assert_eq!(ack, [0x07]);
}

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
    let config = SimConfig::default();
    let byte = lj9da_sim::bus::byte_time(115_200);
    // The request's 8 bytes reach the servo no sooner than 8 byte times after the host began to
    // write them; the servo answers after its processing latency; reply byte k (1-based) is
    // complete on the wire k byte times later. 8 + 26 bytes and 150 µs: the last byte ≥ 3.10 ms.
    let latency = config.processing_latency;
    let earliest = |k: u32| byte * (8 + k) + latency;
    let bus = SimBus::spawn_pty(config).expect("spawn");
    let mut port = HostPort::open(&bus.path(), 115_200);
    // The reply's bytes are paced over 25 byte times (2.17 ms) between the first and the last.
    // A host read that comes late gathers several bytes at once and makes one exchange look
    // shorter, never longer: the pacing shows in the widest spread seen. On a busy machine the
    // reads may be late several times in a row, so up to 50 exchanges are tried; an idle one
    // shows it in the first. A simulator that handed the reply over in one piece never would.
    // (Less 70 µs: each of the two instants is taken when the host's read() returns, which
    // can be tens of µs after the byte was handed over.)
    let paced = byte * 25 - Duration::from_micros(70);
    let mut widest_spread = Duration::ZERO;
    for _ in 0..50 {
        // Taken before the write: the simulator cannot have read the request any earlier.
        let before_write = Instant::now();
        port.send(&request(1, 0x09));
        let chunks = port.receive(26, Duration::from_secs(2));
        let bytes: Vec<u8> = chunks.iter().flat_map(|(_, bytes)| bytes.clone()).collect();
        assert!(ReturnPacket::parse(&bytes).is_some(), "{bytes:02X?}");
        // Physics, on every exchange and every byte: no byte arrives before its wire instant.
        // Lateness of either thread only makes bytes later, so a busy machine cannot fail this.
        let mut received = 0u32;
        for (read_at, chunk) in &chunks {
            received += chunk.len() as u32;
            assert!(
                *read_at - before_write >= earliest(received),
                "reply byte {received} read {:?} after the request was written, before its \
                 wire instant {:?}",
                *read_at - before_write,
                earliest(received)
            );
        }
        let first = chunks.first().expect("first").0;
        let last = chunks.last().expect("last").0;
        widest_spread = widest_spread.max(last - first);
        if widest_spread >= paced {
            break;
        }
    }
    assert!(
        widest_spread >= paced,
        "the reply never took its 25 byte times between first and last byte in 50 exchanges: \
         {widest_spread:?}"
    );
}

#[test]
fn a_baud_change_works_end_to_end_when_the_host_follows() {
    let _serial = serial();
    let bus = SimBus::spawn_pty(SimConfig::default()).expect("spawn");
    let mut port = HostPort::open(&bus.path(), 115_200);
    assert_eq!(exchange(&mut port, &request(1, 0x01), 1), [0x07]);
    // The simulator reads the line in order: the request right after the change comes to a
    // servo at the new rate, which does not understand it at the old one.
    port.send(&SET_BAUD_38400);
    port.send(&request(1, 0x09));
    let deadline = Instant::now() + Duration::from_secs(10);
    while bus.handle().stats().baud_mismatches == 0 {
        assert!(
            Instant::now() < deadline,
            "the request at the old rate was never refused for its rate"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    // The host follows on the same port (the simulator has read both packets above at the old
    // rate). The acknowledgement of a request at the new rate can only come after whatever the
    // request at the old rate brought: nothing must come before it.
    port.set_baud(38_400);
    port.send(&request(1, 0x01));
    let mut answer = Vec::new();
    while !answer.contains(&0x07) {
        let chunk = port.receive_bytes(1, deadline.saturating_duration_since(Instant::now()));
        assert!(
            !chunk.is_empty(),
            "no acknowledgement at the new rate: {answer:02X?}"
        );
        answer.extend(chunk);
    }
    assert_eq!(
        answer,
        [0x07],
        "bytes before the acknowledgement at the new rate"
    );
    drop(port);
    let mut port = HostPort::open(&bus.path(), 38_400);
    let reply = exchange(&mut port, &request(1, 0x09), 26);
    assert!(ReturnPacket::parse(&reply).is_some(), "{reply:02X?}");
    assert_eq!(bus.handle().stats().baud_mismatches, 1);
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
    // 5 mm at the rod's no-load speed at 12 V (≈ 85 mm/s) takes ≈ 60 ms. The snapshot is
    // watched until the servo has arrived instead of sleeping a guess; 10 s is far beyond any
    // stall of the simulator's thread, so only a servo that does not follow reaches it.
    let deadline = Instant::now() + Duration::from_secs(10);
    let servo = loop {
        let servo = handle.snapshot(1).expect("servo 1");
        if servo.position_mm == 5.0 || Instant::now() >= deadline {
            break servo;
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    assert_eq!(servo.goal_mm, 5.0);
    assert_eq!(servo.position_mm, 5.0, "{servo:?}");
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

//! UDP ports for the tests' links, taken from below the kernel's ephemeral range.
//!
//! A port found free by binding port 0 and closing the socket is free only until the next
//! socket bound to port 0: a ground station's, a bridge's `udpout`, a peer's, in a test running
//! beside. That one can take the same number before the bridge binds it, and the bridge then
//! fails to start. The kernel never hands out a port below its ephemeral range for port 0, so
//! a port from there stays free until its user binds it; each is handed out once per process.

use std::net::UdpSocket;
use std::sync::OnceLock;
use std::sync::atomic::{AtomicU32, Ordering};

/// What the bridge says when another program listens on its `udpin` port: one that took the
/// port between the test's check and the bridge's bind (another test run on the machine, or
/// a program of its own), named in the rest of the line. A test that meets it starts the
/// bridge again on another port.
#[allow(dead_code)]
pub const TAKEN: &str = "another program listens on UDP port";

/// The lowest port handed out.
const LOWEST: u32 = 10_000;

/// A UDP port on 127.0.0.1 that is free now and not handed out before in this process.
pub fn free_udp_port() -> u16 {
    static NEXT: AtomicU32 = AtomicU32::new(0);
    static START: OnceLock<u32> = OnceLock::new();
    let top = ephemeral_low();
    if top < LOWEST + 1_000 {
        // No room below the ephemeral range: the port-0 way, race and all.
        let socket = UdpSocket::bind("127.0.0.1:0").expect("a UDP socket");
        return socket.local_addr().expect("its address").port();
    }
    let span = top - LOWEST;
    // Test programs run one after another; a different start for each keeps a port that the
    // previous one's peers may still hold out of the way.
    let start = *START.get_or_init(|| std::process::id().wrapping_mul(2_654_435_761) % span);
    loop {
        let n = NEXT.fetch_add(1, Ordering::Relaxed);
        assert!(n < span, "no free UDP port left in {LOWEST}..{top}");
        let port = (LOWEST + (start + n) % span) as u16;
        if UdpSocket::bind(("127.0.0.1", port)).is_ok() {
            return port;
        }
    }
}

/// The first port of the kernel's ephemeral range (32768 when it cannot be read).
fn ephemeral_low() -> u32 {
    std::fs::read_to_string("/proc/sys/net/ipv4/ip_local_port_range")
        .ok()
        .and_then(|range| range.split_whitespace().next()?.parse().ok())
        .unwrap_or(32_768)
}

//! The floor of the e2e bench's goal latency on this machine: the least any program can do
//! between the sender's datagram and the simulated servos' pseudo-terminal.
//!
//! `lj9da-e2e-floor run --config FILE` reads the bench's mapping, blocks in `recv` on the
//! `udpin` address, and writes each SERVO_OUTPUT_RAW's goals (the mapping's PWM law) as one
//! long packet in the same thread, straight after the datagram arrives: one wake-up of its own,
//! no poll, no telemetry, no failsafe, no check of the frame's CRC. It is no bridge: it is what
//! the kernel's path costs (a UDP wake-up, a pty write, the simulator's wake-up), so that the
//! bench can tell that cost from a peer's own. Run it as `E2E_BRIDGE=…/lj9da-e2e-floor
//! E2E_WATCHDOG_MS=0 cargo bench --bench e2e`; it stops on SIGTERM as the bench asks.

use lj9da_bridge::config::Config;
use lj9da_bridge::protocol::{GoalEntry, LongPacket};
use nix::sys::termios::{SetArg, cfmakeraw, tcgetattr, tcsetattr};
use std::io::Write;
use std::net::UdpSocket;
use std::path::PathBuf;

/// SERVO_OUTPUT_RAW's message id and its full payload length (with the extensions).
const SERVO_OUTPUT_RAW: u32 = 36;
const PAYLOAD_LEN: usize = 37;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let config = match args.as_slice() {
        [_, run, flag, path] if run == "run" && flag == "--config" => PathBuf::from(path),
        _ => {
            eprintln!("usage: lj9da-e2e-floor run --config FILE");
            std::process::exit(2);
        }
    };
    let config = Config::load(&config).unwrap_or_else(|e| {
        eprintln!("{e}");
        std::process::exit(2);
    });
    let address = config
        .mavlink
        .connection
        .strip_prefix("udpin:")
        .expect("the bench's mapping listens with udpin:");
    let socket = UdpSocket::bind(address).expect("the udpin address");
    let bus = config.buses.first().expect("one bus");
    let mut port = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .open(&bus.port)
        .expect("the bus's port");
    let mut termios = tcgetattr(&port).expect("the port's termios");
    cfmakeraw(&mut termios);
    tcsetattr(&port, SetArg::TCSANOW, &termios).expect("raw mode");

    let mut datagram = [0u8; 2048];
    let mut packet = Vec::with_capacity(64);
    let mut goals = Vec::with_capacity(config.servos.len());
    loop {
        let Ok(n) = socket.recv(&mut datagram) else {
            continue;
        };
        let mut rest = &datagram[..n];
        while let Some((msgid, payload, after)) = next_frame(rest) {
            rest = after;
            if msgid != SERVO_OUTPUT_RAW {
                continue;
            }
            let mut p = [0u8; PAYLOAD_LEN];
            p[..payload.len().min(PAYLOAD_LEN)]
                .copy_from_slice(&payload[..payload.len().min(PAYLOAD_LEN)]);
            let message_port = p[20];
            goals.clear();
            for servo in &config.servos {
                let (slot_port, index) = servo.servo_output_raw_slot();
                if slot_port != message_port {
                    continue;
                }
                // servo1..8 at 4, servo9..16 after the port byte, at 21.
                let at = if index < 8 {
                    4 + 2 * index
                } else {
                    21 + 2 * (index - 8)
                };
                let us = u16::from_le_bytes([p[at], p[at + 1]]);
                if let Some(position) = servo.map_pwm(us) {
                    goals.push(GoalEntry {
                        id: servo.id,
                        position,
                        time: None,
                    });
                }
            }
            if let Ok(long) = LongPacket::goals(&goals) {
                packet.clear();
                long.encode_into(&mut packet);
                let _ = port.write_all(&packet);
            }
        }
    }
}

/// The first MAVLink 2 frame of `bytes`: its message id, payload and the bytes after it.
fn next_frame(bytes: &[u8]) -> Option<(u32, &[u8], &[u8])> {
    let start = bytes.iter().position(|&b| b == 0xFD)?;
    let frame = &bytes[start..];
    let len = usize::from(*frame.get(1)?);
    let signed = frame.get(2)? & 1 == 1;
    let total = 10 + len + 2 + if signed { 13 } else { 0 };
    if frame.len() < total {
        return None;
    }
    let msgid = u32::from_le_bytes([frame[7], frame[8], frame[9], 0]);
    Some((msgid, &frame[10..10 + len], &frame[total..]))
}

//! The bodies of the fuzz targets (`fuzz/fuzz_targets/*.rs`), kept in the library so that the
//! regression test (`tests/fuzz_regressions.rs`) replays every saved input through exactly the
//! same code as the fuzzer. Each function must return normally for any input; a panic is a
//! finding.

use crate::config::Config;
use crate::mavlink::BridgeCore;
use crate::protocol::{Decoder, Expect};
use mavlink::dialects::common::MavMessage;
use mavlink::{MavHeader, MavlinkVersion, Message};
use std::time::{Duration, Instant};

/// The protocol decoder fed `data` in chunks whose sizes come from the input itself, with and
/// without an ACK expected; everything must drain once the wait is given up.
pub fn protocol_decoder(data: &[u8]) {
    let Some((&first, rest)) = data.split_first() else {
        return;
    };
    let chunk = usize::from(first % 32) + 1;
    let mut d = Decoder::new();
    if first & 0x80 != 0 {
        d.expect(Expect::Ack);
    }
    for piece in rest.chunks(chunk) {
        d.push(piece);
        while d.poll().is_some() {}
    }
    d.abandon_partial();
    while d.poll().is_some() {}
    assert_eq!(
        d.buffered(),
        0,
        "the decoder must drain after abandon_partial"
    );
}

const FUZZ_MAPPING: &str = r#"
[mavlink]
connection = "udpin:127.0.0.1:14560"
[[bus]]
name = "a"
port = "/dev/null"
[[servo]]
name = "s1"
bus = "a"
id = 1
channel = 1
actuator = 1
[[servo]]
name = "s2"
bus = "a"
id = 2
channel = 17
reverse = true
failsafe = -3.5
"#;

/// MAVLink messages decoded from `data` and handed to the bridge's core, with the clock
/// advancing. Each message is `[selector, system id, component id, length, payload…]`: the
/// selector picks one of the messages the bridge acts on (or any id), and the payload goes
/// through the same `Message::parse` as a CRC-valid frame's payload, so the fuzzer reaches the
/// core without having to forge checksums. Every goal the core produces must lie inside the
/// servo's travel.
pub fn mavlink_input(data: &[u8]) {
    const IDS: [u32; 6] = [0, 36, 375, 76, 77, 253];
    let cfg = Config::parse(FUZZ_MAPPING, "fuzz").expect("fuzz mapping is valid");
    let travel: Vec<_> = cfg.servos.iter().map(|s| s.travel).collect();
    let t0 = Instant::now();
    let mut core = BridgeCore::new(cfg, t0);
    let mut now = t0;
    let mut rest = data;
    while let [selector, system, component, len, tail @ ..] = rest {
        let len = usize::from(*len).min(tail.len());
        let (payload, next) = tail.split_at(len);
        rest = next;
        let id = IDS[usize::from(selector % 6)];
        let version = if selector & 0x80 != 0 {
            MavlinkVersion::V1
        } else {
            MavlinkVersion::V2
        };
        let Ok(msg) = MavMessage::parse(version, id, payload) else {
            continue;
        };
        let header = MavHeader {
            system_id: u32::from(*system),
            component_id: *component,
            sequence: 0,
        };
        now += Duration::from_millis(u64::from(selector >> 3));
        core.handle_message(usize::from(selector & 1), &header, &msg, now);
        core.handle_timeout(now, &[]);
        while let Some((servo, goal)) = core.poll_command() {
            if let crate::bus::Goal::Position(p) = goal {
                assert!(
                    travel[servo].contains(p),
                    "goal {p} outside the travel of servo {servo}"
                );
            }
        }
        while core.poll_message().is_some() {}
    }
}

/// A mapping file: any text must give a config or an error, never a panic.
pub fn mapping_file(data: &[u8]) {
    let text = String::from_utf8_lossy(data);
    if let Ok(cfg) = Config::parse(&text, "fuzz.toml") {
        let _ = cfg.resolved_table();
        for s in &cfg.servos {
            for us in [0, 900, 1000, 1520, 2000, 2120, 65535] {
                if let Some(p) = s.map_pwm(us) {
                    assert!(s.travel.contains(p));
                }
            }
        }
    }
}

//! A flood on the autopilot's link, through the binary (`lj9da-bridge run`, real-time where
//! this machine grants it), with signing on: a stranger sends as fast as one process can, to
//! the port the autopilot uses, in turn valid signed HEARTBEATs of another system, frames with
//! a bad signature, and garbage. Meanwhile the autopilot (this test, signing its frames) streams
//! outputs at 50 Hz and listens for the bridge's HEARTBEATs. Each flood is judged against a
//! quiet spell of the same length before it:
//!
//! - the bridge's real-time threads take under 30 % of a core: the MAVLink loop's thread, which
//!   reads the links, is a real-time one while quiet (so that the autopilot's datagrams wait
//!   for no ordinary program), runs as a normal one while the flood lasts, and is a real-time
//!   one again after it (judged where this machine grants real-time scheduling, as it does to
//!   root; refused under `CI`, the test fails: a CI that cannot judge it must say so);
//! - the servos keep following: at least 90 % of the quiet spell's long packets;
//! - the autopilot keeps hearing the bridge: at least 80 % of the quiet spell's HEARTBEATs.

mod bus_support;
mod tempdir;

use bus_support::{sim_config, spawn_sim};
use lj9da_bridge::mavlink::signing::{Signed, Signing, SigningKey};
use lj9da_sim::BusEvent;
use lj9da_sim::protocol::host_packet::HostPacket;
use mavlink::dialects::common::{
    HEARTBEAT_DATA, MavAutopilot, MavMessage, MavModeFlag, MavState, MavType, SERVO_OUTPUT_RAW_DATA,
};
use mavlink::{MAVLinkMessageRaw, MavHeader, MavlinkReader};
use std::net::UdpSocket;
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};
use tempdir::TempDir;

const KEY: [u8; 32] = [0x5e; 32];
/// Each spell, quiet or flooded.
const SPELL: Duration = Duration::from_secs(5);

fn stamp() -> u64 {
    // MAVLink signing's timestamp: 10 µs units since 2015-01-01.
    let since_2015 = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap()
        .saturating_sub(Duration::from_secs(1_420_070_400));
    (since_2015.as_micros() / 10) as u64
}

/// Frames of one system, signed with [`KEY`].
struct Signer {
    signing: Signing,
    ids: (u8, u8),
    sequence: u8,
}

impl Signer {
    fn new(ids: (u8, u8)) -> Signer {
        Signer {
            signing: Signing::new(SigningKey::from_bytes(KEY), 1, None, stamp()).0,
            ids,
            sequence: 0,
        }
    }

    fn frame(&mut self, message: &MavMessage) -> Vec<u8> {
        let header = MavHeader {
            system_id: u32::from(self.ids.0),
            component_id: self.ids.1,
            sequence: self.sequence,
        };
        self.sequence = self.sequence.wrapping_add(1);
        match self.signing.sign(0, header, message, stamp()) {
            Signed::Frame(MAVLinkMessageRaw::V2(f), reserve) => {
                if let Some(r) = reserve {
                    self.signing.reservation_stored(r);
                }
                f.raw_bytes().to_vec()
            }
            _ => panic!("the test signs at once"),
        }
    }
}

fn heartbeat(mavtype: MavType) -> MavMessage {
    MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        custom_mode: 0,
        mavtype,
        autopilot: MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
        base_mode: MavModeFlag::empty(),
        system_status: MavState::MAV_STATE_ACTIVE,
        mavlink_version: 3,
    })
}

/// The autopilot: outputs at 50 Hz (channels 1 and 2 sweeping), a HEARTBEAT a second, all
/// signed; counts the bridge's HEARTBEATs it hears.
struct Autopilot {
    heartbeats: Arc<AtomicU64>,
    stop: Arc<AtomicBool>,
    threads: Vec<std::thread::JoinHandle<()>>,
}

impl Autopilot {
    fn start(port: u16) -> Autopilot {
        let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
        socket.connect(("127.0.0.1", port)).unwrap();
        socket
            .set_read_timeout(Some(Duration::from_millis(100)))
            .unwrap();
        let listener = socket.try_clone().unwrap();
        let heartbeats = Arc::new(AtomicU64::new(0));
        let stop = Arc::new(AtomicBool::new(false));
        let mut threads = Vec::new();
        {
            let (heartbeats, stop) = (heartbeats.clone(), stop.clone());
            threads.push(std::thread::spawn(move || {
                let mut buf = [0u8; 2048];
                while !stop.load(Ordering::Relaxed) {
                    let Ok(n) = listener.recv(&mut buf) else {
                        continue;
                    };
                    let mut reader = MavlinkReader::new(&buf[..n]);
                    while let Ok(raw) = reader.read_any_raw_message::<MavMessage>() {
                        if raw.component_id() == 140 && raw.message_id() == 0 {
                            heartbeats.fetch_add(1, Ordering::Relaxed);
                        }
                    }
                }
            }));
        }
        {
            let stop = stop.clone();
            threads.push(std::thread::spawn(move || {
                let mut signer = Signer::new((1, 1));
                let start = Instant::now();
                let mut next = start;
                let mut tick = 0u64;
                while !stop.load(Ordering::Relaxed) {
                    if tick.is_multiple_of(50) {
                        let _ =
                            socket.send(&signer.frame(&heartbeat(MavType::MAV_TYPE_FIXED_WING)));
                    }
                    // A triangle between 1100 and 1900 µs over 2 s: every tick a new goal.
                    let phase = (tick % 100) as i32;
                    let us = (1100 + 16 * (50 - (phase - 50).abs())) as u16;
                    let outputs = MavMessage::SERVO_OUTPUT_RAW(SERVO_OUTPUT_RAW_DATA {
                        time_usec: start.elapsed().as_micros() as u32,
                        servo1_raw: us,
                        servo2_raw: 3000 - us,
                        ..Default::default()
                    });
                    let _ = socket.send(&signer.frame(&outputs));
                    tick += 1;
                    next += Duration::from_millis(20);
                    std::thread::sleep(next.saturating_duration_since(Instant::now()));
                }
            }));
        }
        Autopilot {
            heartbeats,
            stop,
            threads,
        }
    }
}

impl Drop for Autopilot {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

/// What a flood sends.
#[derive(Clone, Copy, Debug)]
enum Flood {
    /// HEARTBEATs of system 9, signed with the key: frames the bridge accepts.
    ValidFrames,
    /// Signed HEARTBEATs whose signature is wrong.
    BadSignatures,
    /// Bytes that hold no frame.
    Garbage,
}

/// Send `flood` to `port` as fast as one thread can, for `spell`; returns datagrams sent.
fn flood(port: u16, flood: Flood, spell: Duration) -> u64 {
    let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
    socket.connect(("127.0.0.1", port)).unwrap();
    let mut signer = Signer::new((9, 1));
    let bad = {
        let mut frame = signer.frame(&heartbeat(MavType::MAV_TYPE_GCS));
        let last = frame.len() - 1;
        frame[last] ^= 0x55;
        frame
    };
    let garbage: Vec<u8> = (0..40u8).map(|i| i.wrapping_mul(37) | 1).collect();
    let start = Instant::now();
    let mut sent = 0u64;
    while start.elapsed() < spell {
        for _ in 0..64 {
            let bytes = match flood {
                Flood::ValidFrames => signer.frame(&heartbeat(MavType::MAV_TYPE_GCS)),
                Flood::BadSignatures => bad.clone(),
                Flood::Garbage => garbage.clone(),
            };
            if socket.send(&bytes).is_ok() {
                sent += 1;
            }
        }
    }
    sent
}

/// Each thread of `pid`: its id, its name, its scheduling policy and the CPU time (clock ticks)
/// it has used.
fn threads(pid: u32) -> Vec<(u32, String, u64, u64)> {
    let mut threads = Vec::new();
    let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) else {
        return threads;
    };
    for task in tasks.flatten() {
        let Ok(stat) = std::fs::read_to_string(task.path().join("stat")) else {
            continue;
        };
        let (Some(open), Some(close)) = (stat.find('('), stat.rfind(')')) else {
            continue;
        };
        // The fields after the name (which may hold spaces) begin with field 3.
        let after: Vec<&str> = stat[close + 2..].split_whitespace().collect();
        let field = |n: usize| after[n - 3].parse::<u64>().unwrap();
        threads.push((
            stat[..open].trim().parse().unwrap(),
            stat[open + 1..close].to_string(),
            field(41),
            field(14) + field(15),
        ));
    }
    threads
}

/// The scheduling policy of `pid`'s main thread, the MAVLink loop's (which reads the links).
fn loop_policy(pid: u32) -> Option<u64> {
    threads(pid).into_iter().find(|t| t.0 == pid).map(|t| t.2)
}

/// The CPU time (clock ticks) `pid`'s threads used while real-time ones, sampled every 10 ms
/// (a thread may change its policy: its time between two samples counts as real-time when it
/// was a real-time thread at either), until `stop`.
fn realtime_ticks_while(pid: u32, stop: &AtomicBool) -> u64 {
    let fifo = nix::libc::SCHED_FIFO as u64;
    let mut last: std::collections::HashMap<u32, (u64, u64)> = threads(pid)
        .into_iter()
        .map(|(tid, _, policy, ticks)| (tid, (policy, ticks)))
        .collect();
    let mut total = 0;
    while !stop.load(Ordering::Relaxed) {
        std::thread::sleep(Duration::from_millis(10));
        for (tid, _, policy, ticks) in threads(pid) {
            let (was, before) = last.insert(tid, (policy, ticks)).unwrap_or((policy, 0));
            if was == fifo || policy == fifo {
                total += ticks - before;
            }
        }
    }
    total
}
fn ticks_per_second() -> f64 {
    // SAFETY: sysconf only reads a value.
    (unsafe { nix::libc::sysconf(nix::libc::_SC_CLK_TCK) }) as f64
}

/// Long packets the simulated bus received, counted as they come.
fn count_long_packets(events: std::sync::mpsc::Receiver<BusEvent>) -> Arc<AtomicU64> {
    let count = Arc::new(AtomicU64::new(0));
    let counted = count.clone();
    std::thread::spawn(move || {
        for event in events {
            if let BusEvent::Packet(p) = event
                && matches!(p.packet, HostPacket::Long(_))
            {
                counted.fetch_add(1, Ordering::Relaxed);
            }
        }
    });
    count
}

/// What one spell saw.
#[derive(Debug, Clone, Copy)]
struct Spell {
    /// The loop's thread's policy as the spell ends.
    loop_policy: Option<u64>,
    realtime_share: f64,
    long_packets: u64,
    heartbeats: u64,
}

#[test]
fn a_flood_on_the_autopilots_link_holds_no_real_time_thread_and_moves_nothing_aside() {
    let dir = TempDir::new("link-flood");
    let sim = spawn_sim(sim_config(&[1, 2], 115_200));
    let long_packets = count_long_packets(sim.handle().subscribe());
    let port = {
        let udp = UdpSocket::bind("127.0.0.1:0").unwrap();
        udp.local_addr().unwrap().port()
    };
    let hex: String = KEY.iter().map(|b| format!("{b:02x}")).collect();
    let mapping = dir.path().join("bridge.toml");
    std::fs::write(
        &mapping,
        format!(
            r#"[mavlink]
connection = "udpin:127.0.0.1:{port}"
system_id = 1
output_rate_hz = 50
signing_key = "{hex}"
signing_timestamp_file = "{}"

[record]
enabled = false

[[bus]]
name = "wing"
port = "{}"
# The flood takes one of two cores: the judge is the goals, not the replies' timing.
turnaround_ms = 20

[[servo]]
name = "left"
bus = "wing"
id = 1
channel = 1

[[servo]]
name = "right"
bus = "wing"
id = 2
channel = 2
"#,
            dir.path().join("signing-timestamp").display(),
            sim.path().display(),
        ),
    )
    .unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_lj9da-bridge"))
        .args(["run", "--config"])
        .arg(&mapping)
        .env("RUST_LOG", "lj9da_bridge=warn")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("the bridge starts");
    let pid = child.id();
    let autopilot = Autopilot::start(port);
    // Until the goals flow.
    let deadline = Instant::now() + Duration::from_secs(20);
    while long_packets.load(Ordering::Relaxed) < 50 {
        assert!(Instant::now() < deadline, "no goals within 20 s");
        std::thread::sleep(Duration::from_millis(50));
    }
    let spell = |what: Option<Flood>| -> Spell {
        let (goals, beats) = (
            long_packets.load(Ordering::Relaxed),
            autopilot.heartbeats.load(Ordering::Relaxed),
        );
        let stop = Arc::new(AtomicBool::new(false));
        let sampler = {
            let stop = stop.clone();
            std::thread::spawn(move || realtime_ticks_while(pid, &stop))
        };
        let start = Instant::now();
        let sent = match what {
            Some(f) => flood(port, f, SPELL),
            None => {
                std::thread::sleep(SPELL);
                0
            }
        };
        let loop_policy = loop_policy(pid);
        stop.store(true, Ordering::Relaxed);
        let ticks = sampler.join().unwrap();
        let seconds = start.elapsed().as_secs_f64();
        let seen = Spell {
            loop_policy,
            realtime_share: ticks as f64 / ticks_per_second() / seconds,
            long_packets: long_packets.load(Ordering::Relaxed) - goals,
            heartbeats: autopilot.heartbeats.load(Ordering::Relaxed) - beats,
        };
        println!(
            "{what:?}: {sent} datagrams ({:.0}/s); {seen:?}",
            sent as f64 / seconds
        );
        seen
    };
    // Where real-time scheduling is refused the bridge has no real-time thread: the share is
    // 0 and says nothing; the test says so.
    let granted = std::thread::spawn(|| lj9da_realtime::request_fifo(1).is_ok())
        .join()
        .unwrap();
    if !granted {
        assert!(
            std::env::var_os("CI").is_none(),
            "real-time scheduling is refused here, so the real-time share cannot be judged; \
             CI must run this test where it is granted (as root)"
        );
        println!("real-time scheduling refused here: the real-time share is not judged");
    }
    let fifo = Some(nix::libc::SCHED_FIFO as u64);
    let mut failures = Vec::new();
    for what in [Flood::ValidFrames, Flood::BadSignatures, Flood::Garbage] {
        let quiet = spell(None);
        if granted && quiet.loop_policy != fifo {
            failures.push(format!(
                "before {what:?}: the loop's thread is not a real-time one ({:?})",
                quiet.loop_policy
            ));
        }
        let flooded = spell(Some(what));
        if granted && flooded.loop_policy == fifo {
            failures.push(format!(
                "{what:?}: the loop's thread is still a real-time one as the flood ends"
            ));
        }
        if flooded.realtime_share >= 0.30 {
            failures.push(format!(
                "{what:?}: the real-time threads took {:.0} % of a core",
                flooded.realtime_share * 100.0
            ));
        }
        if (flooded.long_packets as f64) < 0.9 * quiet.long_packets as f64 {
            failures.push(format!(
                "{what:?}: {} long packets, {} in the quiet spell",
                flooded.long_packets, quiet.long_packets
            ));
        }
        if (flooded.heartbeats as f64) < 0.8 * quiet.heartbeats as f64 {
            failures.push(format!(
                "{what:?}: the autopilot heard {} HEARTBEATs, {} in the quiet spell",
                flooded.heartbeats, quiet.heartbeats
            ));
        }
    }
    drop(autopilot);
    let _ = child.kill();
    let _ = child.wait();
    assert!(failures.is_empty(), "{failures:#?}");
}

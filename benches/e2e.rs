//! End-to-end benchmark: a MAVLink sender on UDP → the bridge process (`lj9da-bridge run`) →
//! simulated LJ9DA41s on pseudo-terminals at 115 200 bit/s.
//!
//! For 4 and 8 servos and outputs at 50 Hz and 400 Hz it prints:
//! - latency from a SERVO_OUTPUT_RAW datagram's send to the first byte of the long packet that
//!   carries its goal, as the simulated serial device saw it (p50, p99, max);
//! - the share of output messages whose goal reached the wire, with superseded goals (a newer
//!   message's goal went out first) counted apart, and goals lost;
//! - the telemetry rate per servo seen by a ground station (`<label>_pos` NAMED_VALUE_FLOAT);
//! - the bridge process's CPU time per second of run, and its peak resident memory.
//!
//! Every message gives servo 1 a goal that no other message in the window has, so each message
//! is matched to the packet that carried it. Run: `cargo bench --bench e2e` (`E2E_SECONDS=N`
//! sets the length of each case, default 6 s; `E2E_CASES=4x50,8x400` runs only those cases).

use lj9da_bridge::config::Config;
use lj9da_bridge::mavlink::outputs::servo_output_raw;
use lj9da_sim::{BusEvent, SimBus, SimConfig};
use mavlink::dialects::common::*;
use mavlink::{MavConnection, MavHeader};
use std::io::Write;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc::Receiver;
use std::time::{Duration, Instant};

struct Case {
    servos: usize,
    rate_hz: f64,
}

struct Outcome {
    sent: usize,
    on_wire: usize,
    superseded: usize,
    lost: usize,
    latencies_us: Vec<f64>,
    telemetry_hz: f64,
    cpu_percent: f64,
    peak_rss_kib: u64,
}

fn free_udp_port() -> u16 {
    std::net::UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

fn mapping(servos: usize, port: &str, ap: u16, gcs: u16) -> String {
    let mut s = format!(
        "[mavlink]\nconnection = \"udpin:127.0.0.1:{ap}\"\ngcs = \"udpout:127.0.0.1:{gcs}\"\nautopilot_system_id = 1\nfailsafe_timeout_ms = 2000\n\
         [telemetry]\nrate_hz = 20\n[bridge]\non_exit = \"hold\"\n[[bus]]\nname = \"b\"\nport = \"{port}\"\nbaud = 115200\n"
    );
    for i in 1..=servos {
        s += &format!("[[servo]]\nname = \"s{i}\"\nbus = \"b\"\nid = {i}\nchannel = {i}\n");
    }
    s
}

/// User + system CPU time of `pid` in seconds, and its peak resident set in KiB.
fn cpu_and_rss(pid: u32) -> (f64, u64) {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    let fields: Vec<&str> = stat
        .rsplit(')')
        .next()
        .unwrap_or("")
        .split_whitespace()
        .collect();
    let ticks: f64 = fields
        .get(11)
        .and_then(|u| u.parse::<f64>().ok())
        .unwrap_or(0.0)
        + fields
            .get(12)
            .and_then(|s| s.parse::<f64>().ok())
            .unwrap_or(0.0);
    let hz = 100.0; // USER_HZ on Linux
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    let rss = status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.split_whitespace().next()?.parse().ok())
        .unwrap_or(0);
    (ticks / hz, rss)
}

/// The PWM of servo `s` in message `i`: servo 1 walks through 800 distinct values.
fn pwm(s: usize, i: usize) -> u16 {
    if s == 1 {
        1120 + (i % 800) as u16
    } else {
        (1520.0 + 300.0 * ((i as f64) * 0.01 + s as f64).sin()) as u16
    }
}

fn run_case(case: &Case, seconds: f64) -> Outcome {
    let sim = SimBus::spawn_pty(SimConfig {
        ids: (1..=case.servos as u8).collect(),
        baud: 115_200,
        ..SimConfig::default()
    })
    .expect("simulated servos");
    let events: Receiver<BusEvent> = sim.handle().subscribe();
    let ap_port = free_udp_port();
    let gcs_port = free_udp_port();
    let dir = std::env::temp_dir().join(format!("lj9da-e2e-{}-{}", std::process::id(), ap_port));
    std::fs::create_dir_all(&dir).unwrap();
    let cfg_path = dir.join("bench.toml");
    let text = mapping(
        case.servos,
        &sim.path().display().to_string(),
        ap_port,
        gcs_port,
    );
    std::fs::write(&cfg_path, &text).unwrap();
    // The goal the bridge computes for servo 1, to match messages with packets.
    let servo1 = Config::parse(&text, "bench").expect("bench mapping").servos[0].clone();
    let goal_of = |us: u16| servo1.map_pwm(us).expect("bench PWM is in range").0;
    let mut bridge: Child = Command::new(env!("CARGO_BIN_EXE_lj9da-bridge"))
        .args(["run", "--config"])
        .arg(&cfg_path)
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("bridge process");
    let pid = bridge.id();

    let gcs = mavlink::connect::<MavMessage>(&format!("udpin:127.0.0.1:{gcs_port}")).unwrap();
    let gcs_thread = std::thread::spawn(move || {
        let mut pos = 0usize;
        let start = Instant::now();
        let mut first = None;
        while start.elapsed() < Duration::from_secs_f64(seconds + 4.0) {
            if let Ok((_, MavMessage::NAMED_VALUE_FLOAT(v))) = gcs.try_recv() {
                if v.name.to_str().unwrap_or("") == "s1_pos" {
                    first.get_or_insert_with(Instant::now);
                    pos += 1;
                }
            } else {
                std::thread::sleep(Duration::from_millis(2));
            }
        }
        (pos, first.map(|f| f.elapsed()))
    });

    let ap = mavlink::connect::<MavMessage>(&format!("udpout:127.0.0.1:{ap_port}")).unwrap();
    let header = MavHeader {
        system_id: 1,
        component_id: 1,
        sequence: 0,
    };
    let heartbeat = MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        mavtype: MavType::MAV_TYPE_FIXED_WING,
        autopilot: MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
        ..Default::default()
    });
    // Warm up: let every servo come online and take its first (soft-start) goal.
    let warm = Instant::now();
    while warm.elapsed() < Duration::from_secs(3) {
        let _ = ap.send(&header, &heartbeat);
        let _ = ap.send(&header, &outputs(case.servos, 0));
        std::thread::sleep(Duration::from_millis(50));
    }
    while events.try_recv().is_ok() {}
    let (cpu0, _) = cpu_and_rss(pid);
    let t_start = Instant::now();

    let period = Duration::from_secs_f64(1.0 / case.rate_hz);
    let n = (seconds * case.rate_hz) as usize;
    let mut sends = Vec::with_capacity(n);
    let mut next = Instant::now();
    for i in 1..=n {
        while Instant::now() < next {
            std::hint::spin_loop();
        }
        next += period;
        if i % (case.rate_hz as usize) == 0 {
            let _ = ap.send(&header, &heartbeat);
        }
        let msg = outputs(case.servos, i);
        let t = Instant::now();
        ap.send(&header, &msg).expect("send");
        sends.push((t, goal_of(pwm(1, i))));
    }
    std::thread::sleep(Duration::from_millis(300));
    let run_time = t_start.elapsed().as_secs_f64();
    let (cpu1, rss) = cpu_and_rss(pid);

    // Long packets seen by the simulated servos: (first byte instant, servo 1's goal).
    let mut packets = Vec::new();
    while let Ok(e) = events.try_recv() {
        if let BusEvent::Packet(p) = e
            && let Some((_, g)) = p
                .packet
                .goal_positions()
                .into_iter()
                .find(|(id, _)| *id == 1)
        {
            packets.push((p.first_byte_at, g));
        }
    }
    let mut latencies_us = Vec::new();
    // A message's goal is on the wire when a packet after its send carries it.
    let carried: Vec<Option<Instant>> = sends
        .iter()
        .map(|(t, goal)| {
            packets
                .iter()
                .find(|(at, g)| {
                    *at >= *t && *g == *goal && at.duration_since(*t) < Duration::from_secs(1)
                })
                .map(|(at, _)| *at)
        })
        .collect();
    // Not carried: superseded when a later message's goal reached the wire (the bus master
    // keeps only the newest goal per servo), lost when none did.
    let mut later_on_wire = false;
    let mut superseded_flags = vec![false; sends.len()];
    for k in (0..sends.len()).rev() {
        superseded_flags[k] = carried[k].is_none() && later_on_wire;
        later_on_wire |= carried[k].is_some();
    }
    let (mut on_wire, mut superseded, mut lost) = (0, 0, 0);
    for (k, (t, _)) in sends.iter().enumerate() {
        match carried[k] {
            Some(at) => {
                on_wire += 1;
                latencies_us.push(at.duration_since(*t).as_secs_f64() * 1e6);
            }
            None if superseded_flags[k] => superseded += 1,
            None => lost += 1,
        }
    }
    let _ = Command::new("kill")
        .args(["-TERM", &pid.to_string()])
        .status();
    let _ = bridge.wait();
    let (telemetry, since_first) = gcs_thread.join().unwrap();
    let telemetry_hz = since_first
        .map(|d| telemetry as f64 / d.as_secs_f64())
        .unwrap_or(0.0);
    sim.shutdown();
    let _ = std::fs::remove_dir_all(&dir);
    Outcome {
        sent: sends.len(),
        on_wire,
        superseded,
        lost,
        latencies_us,
        telemetry_hz,
        cpu_percent: (cpu1 - cpu0) / run_time * 100.0,
        peak_rss_kib: rss,
    }
}

fn outputs(servos: usize, i: usize) -> MavMessage {
    let mut raw = [0u16; 16];
    for (s, r) in raw.iter_mut().enumerate().take(servos) {
        *r = pwm(s + 1, i);
    }
    servo_output_raw(0, raw, 0)
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let i = ((sorted.len() - 1) as f64 * p).round() as usize;
    sorted[i]
}

fn main() {
    let seconds: f64 = std::env::var("E2E_SECONDS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(6.0);
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|c| {
            c.lines().find_map(|l| {
                l.strip_prefix("model name")
                    .map(|m| m.trim_start_matches([' ', '\t', ':']).to_string())
            })
        })
        .unwrap_or_else(|| "unknown CPU".into());
    let cores = std::thread::available_parallelism()
        .map(|n| n.get())
        .unwrap_or(0);
    println!(
        "end-to-end: UDP SERVO_OUTPUT_RAW → lj9da-bridge process → simulated LJ9DA41s on ptys, 115200 bit/s"
    );
    println!("machine: {cpu}, {cores} cores; {seconds} s per case");
    println!(
        "{:>6} {:>6} {:>6} {:>8} {:>10} {:>6} {:>9} {:>9} {:>9} {:>10} {:>8} {:>9}",
        "servos",
        "rate",
        "sent",
        "on wire",
        "superseded",
        "lost",
        "p50 µs",
        "p99 µs",
        "max µs",
        "telem Hz",
        "CPU %",
        "peak RSS"
    );
    for case in [
        Case {
            servos: 4,
            rate_hz: 50.0,
        },
        Case {
            servos: 4,
            rate_hz: 400.0,
        },
        Case {
            servos: 8,
            rate_hz: 50.0,
        },
        Case {
            servos: 8,
            rate_hz: 400.0,
        },
    ] {
        // `E2E_CASES=4x50,8x400` runs only those cases (e.g. while profiling one of them).
        if let Ok(only) = std::env::var("E2E_CASES")
            && !only
                .split(',')
                .any(|c| c.trim() == format!("{}x{}", case.servos, case.rate_hz))
        {
            continue;
        }
        let mut o = run_case(&case, seconds);
        o.latencies_us.sort_by(f64::total_cmp);
        println!(
            "{:>6} {:>6} {:>6} {:>7.1}% {:>10} {:>6} {:>9.0} {:>9.0} {:>9.0} {:>10.1} {:>8.2} {:>6} KiB",
            case.servos,
            case.rate_hz,
            o.sent,
            o.on_wire as f64 * 100.0 / o.sent.max(1) as f64,
            o.superseded,
            o.lost,
            percentile(&o.latencies_us, 0.5),
            percentile(&o.latencies_us, 0.99),
            o.latencies_us.last().copied().unwrap_or(f64::NAN),
            o.telemetry_hz,
            o.cpu_percent,
            o.peak_rss_kib
        );
        let _ = std::io::stdout().flush();
    }
    println!(
        "targets: p50 ≤ 200 µs, p99 ≤ 4 ms, no goal lost that was not superseded, CPU ≤ 2 % at 50 Hz × 4, peak RSS ≤ 16 MiB"
    );
}

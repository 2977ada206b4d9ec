//! End-to-end benchmark: a MAVLink sender on UDP → the bridge process (`lj9da-bridge run`) →
//! simulated LJ9DA41s on pseudo-terminals at 115 200 bit/s.
//!
//! Cases: 4 and 8 servos on port 0 at 50 Hz and 400 Hz; and 4 servos on two ports (channels 1–3
//! in SERVO_OUTPUT_RAW port 0, channel 17 in port 1, sent back to back as ArduPilot does) at
//! 50 Hz, from a steady autopilot, one whose ticks jitter by ±1 ms (uniform), and one that sends
//! 5 % of its messages 3–8 ms late; each two-port case quiet and beside two CPU hogs
//! (`E2E_HOGS=n` changes how many). For each it prints:
//! - latency from a SERVO_OUTPUT_RAW datagram's send to the first byte of the long packet that
//!   carries its goal, as the simulated serial device saw it (p50, p99, max), per port and for
//!   all goals;
//! - the share of output messages whose goal reached the wire, with superseded goals (a newer
//!   message's goal went out first) counted apart, and goals lost;
//! - the telemetry rate per servo seen by a ground station (`<label>_pos` NAMED_VALUE_FLOAT);
//! - the bridge process's CPU time per second of run, and its peak resident memory ("not
//!   measured" where /proc cannot be read);
//! - talk-overs (a packet written while a servo replied) and STATUSTEXTs of severity WARNING or
//!   worse heard by the ground station (none is true of healthy simulated servos).
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

#[derive(Clone, Copy, PartialEq)]
enum Jitter {
    None,
    /// Each tick sent up to 1 ms early or late (uniform).
    Uniform1Ms,
    /// One message in twenty sent 3–8 ms late.
    Late5Pct,
}

impl Jitter {
    fn name(self) -> &'static str {
        match self {
            Jitter::None => "steady",
            Jitter::Uniform1Ms => "±1ms",
            Jitter::Late5Pct => "5%late",
        }
    }
}

struct Case {
    servos: usize,
    rate_hz: f64,
    /// 1: every servo on port 0; 2: the last servo on channel 17 (port 1).
    ports: u8,
    jitter: Jitter,
    hogs: usize,
}

impl Case {
    fn name(&self) -> String {
        format!(
            "{}x{}{}{}",
            self.servos,
            self.rate_hz,
            if self.ports == 2 { "x2p" } else { "" },
            match self.jitter {
                Jitter::None => "",
                Jitter::Uniform1Ms => "j",
                Jitter::Late5Pct => "l",
            }
        )
    }
}

struct Outcome {
    sent: usize,
    on_wire: usize,
    superseded: usize,
    lost: usize,
    /// Per port: latencies of the goals that reached the wire.
    latencies_us: [Vec<f64>; 2],
    telemetry_hz: f64,
    /// `None` where /proc could not be read.
    cpu_percent: Option<f64>,
    peak_rss_kib: Option<u64>,
    collisions: usize,
    alarms: Vec<String>,
}

/// A small deterministic generator for the jittery autopilot.
struct XorShift(u64);

impl XorShift {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }

    /// Uniform in [0, 1).
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// `n` processes that keep a CPU busy, ended when dropped.
struct Hogs(Vec<Child>);

impl Hogs {
    fn start(n: usize) -> Hogs {
        Hogs(
            (0..n)
                .map(|_| {
                    Command::new("sh")
                        .args(["-c", "while :; do :; done"])
                        .spawn()
                        .expect("a CPU hog")
                })
                .collect(),
        )
    }
}

impl Drop for Hogs {
    fn drop(&mut self) {
        for h in &mut self.0 {
            let _ = h.kill();
            let _ = h.wait();
        }
    }
}

fn free_udp_port() -> u16 {
    std::net::UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

fn mapping(servos: usize, ports: u8, port: &str, ap: u16, gcs: u16) -> String {
    let mut s = format!(
        "[mavlink]\nconnection = \"udpin:127.0.0.1:{ap}\"\ngcs = \"udpout:127.0.0.1:{gcs}\"\nautopilot_system_id = 1\nfailsafe_timeout_ms = 2000\n\
         [telemetry]\nrate_hz = 20\n[bridge]\non_exit = \"hold\"\n[[bus]]\nname = \"b\"\nport = \"{port}\"\nbaud = 115200\n"
    );
    for i in 1..=servos {
        let channel = if ports == 2 && i == servos { 17 } else { i };
        s += &format!("[[servo]]\nname = \"s{i}\"\nbus = \"b\"\nid = {i}\nchannel = {channel}\n");
    }
    s
}

/// User + system CPU time of `pid` in seconds, and its peak resident set in KiB; each `None`
/// where /proc does not tell.
fn cpu_and_rss(pid: u32) -> (Option<f64>, Option<u64>) {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok();
    let cpu = stat.and_then(|stat| {
        let fields: Vec<String> = stat
            .rsplit(')')
            .next()?
            .split_whitespace()
            .map(str::to_string)
            .collect();
        let user: f64 = fields.get(11)?.parse().ok()?;
        let system: f64 = fields.get(12)?.parse().ok()?;
        Some((user + system) / 100.0) // USER_HZ on Linux
    });
    let rss = std::fs::read_to_string(format!("/proc/{pid}/status"))
        .ok()
        .and_then(|status| {
            status
                .lines()
                .find_map(|l| l.strip_prefix("VmHWM:"))
                .and_then(|v| v.split_whitespace().next()?.parse().ok())
        });
    (cpu, rss)
}

/// The PWM of servo `s` in message `i`: servo 1 (port 0) and the servo on port 1 walk through
/// 800 distinct values.
fn pwm(s: usize, i: usize, marked: usize) -> u16 {
    if s == 1 || s == marked {
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
        case.ports,
        &sim.path().display().to_string(),
        ap_port,
        gcs_port,
    );
    std::fs::write(&cfg_path, &text).unwrap();
    // The servo whose goals mark each port's messages: servo 1 on port 0; on port 1 the last.
    let marked = if case.ports == 2 { case.servos } else { 1 };
    let config = Config::parse(&text, "bench").expect("bench mapping");
    let markers = [config.servos[0].clone(), config.servos[marked - 1].clone()];
    let goal_of =
        |port: usize, us: u16| markers[port].map_pwm(us).expect("bench PWM is in range").0;
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
        let mut alarms = Vec::new();
        let start = Instant::now();
        let mut first = None;
        while start.elapsed() < Duration::from_secs_f64(seconds + 7.0) {
            match gcs.try_recv() {
                Ok((_, MavMessage::NAMED_VALUE_FLOAT(v))) => {
                    if v.name.to_str().unwrap_or("") == "s1_pos" {
                        first.get_or_insert_with(Instant::now);
                        pos += 1;
                    }
                }
                Ok((_, MavMessage::STATUSTEXT(t))) => {
                    if t.severity as u8 <= MavSeverity::MAV_SEVERITY_WARNING as u8 {
                        alarms.push(t.text.to_str().unwrap_or("?").to_string());
                    }
                }
                Ok(_) => {}
                Err(_) => std::thread::sleep(Duration::from_millis(2)),
            }
        }
        (pos, first.map(|f| f.elapsed()), alarms)
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
        for port in 0..case.ports {
            let _ = ap.send(&header, &outputs(case.servos, marked, port, 0));
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    while events.try_recv().is_ok() {}
    let (cpu0, _) = cpu_and_rss(pid);
    let t_start = Instant::now();

    // The schedule: (send instant, port, message number), in send order.
    let period = Duration::from_secs_f64(1.0 / case.rate_hz);
    let n = (seconds * case.rate_hz) as usize;
    let mut rng = XorShift(0x2545_F491_4F6C_DD1D);
    let t0 = Instant::now() + Duration::from_millis(20);
    let mut schedule = Vec::with_capacity(n * usize::from(case.ports));
    for i in 1..=n {
        let tick = t0 + period * i as u32;
        let tick = match case.jitter {
            Jitter::Uniform1Ms => {
                let offset = Duration::from_secs_f64(rng.unit() * 2e-3);
                tick + offset - Duration::from_millis(1)
            }
            _ => tick,
        };
        for port in 0..case.ports {
            let mut at = tick + Duration::from_micros(100) * u32::from(port);
            if case.jitter == Jitter::Late5Pct && rng.unit() < 0.05 {
                at += Duration::from_secs_f64(3e-3 + rng.unit() * 5e-3);
            }
            schedule.push((at, port, i));
        }
    }
    schedule.sort_by_key(|s| s.0);
    let mut sends: Vec<(Instant, usize, i16)> = Vec::with_capacity(schedule.len());
    for (k, (at, port, i)) in schedule.into_iter().enumerate() {
        while Instant::now() < at {
            std::hint::spin_loop();
        }
        if k % (case.rate_hz as usize) == 0 {
            let _ = ap.send(&header, &heartbeat);
        }
        let msg = outputs(case.servos, marked, port, i);
        let t = Instant::now();
        ap.send(&header, &msg).expect("send");
        let servo = if port == 0 { 1 } else { marked };
        sends.push((
            t,
            usize::from(port),
            goal_of(usize::from(port), pwm(servo, i, marked)),
        ));
    }
    std::thread::sleep(Duration::from_millis(300));
    let run_time = t_start.elapsed().as_secs_f64();
    let (cpu1, rss) = cpu_and_rss(pid);

    // Long packets seen by the simulated servos: (first byte instant, each marker's goal).
    let mut packets: [Vec<(Instant, i16)>; 2] = [Vec::new(), Vec::new()];
    let mut collisions = 0;
    while let Ok(e) = events.try_recv() {
        match e {
            BusEvent::Packet(p) => {
                let goals = p.packet.goal_positions();
                for (port, id) in [(0, 1u8), (1, marked as u8)] {
                    if let Some((_, g)) = goals.iter().find(|(i, _)| *i == id) {
                        packets[port].push((p.first_byte_at, *g));
                    }
                }
            }
            BusEvent::Collision { .. } => collisions += 1,
            _ => {}
        }
    }
    // A message's goal is on the wire when a packet after its send carries it.
    let carried: Vec<Option<Instant>> = sends
        .iter()
        .map(|(t, port, goal)| {
            packets[*port]
                .iter()
                .find(|(at, g)| {
                    *at >= *t && *g == *goal && at.duration_since(*t) < Duration::from_secs(1)
                })
                .map(|(at, _)| *at)
        })
        .collect();
    // Not carried: superseded when a later message's goal for the same port reached the wire
    // (the bus master keeps only the newest goal per servo), lost when none did.
    let mut later_on_wire = [false; 2];
    let mut superseded_flags = vec![false; sends.len()];
    for k in (0..sends.len()).rev() {
        let port = sends[k].1;
        superseded_flags[k] = carried[k].is_none() && later_on_wire[port];
        later_on_wire[port] |= carried[k].is_some();
    }
    let (mut on_wire, mut superseded, mut lost) = (0, 0, 0);
    let mut latencies_us = [Vec::new(), Vec::new()];
    for (k, (t, port, _)) in sends.iter().enumerate() {
        match carried[k] {
            Some(at) => {
                on_wire += 1;
                latencies_us[*port].push(at.duration_since(*t).as_secs_f64() * 1e6);
            }
            None if superseded_flags[k] => superseded += 1,
            None => lost += 1,
        }
    }
    let _ = Command::new("kill")
        .args(["-TERM", &pid.to_string()])
        .status();
    let _ = bridge.wait();
    let (telemetry, since_first, alarms) = gcs_thread.join().unwrap();
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
        cpu_percent: cpu0.zip(cpu1).map(|(a, b)| (b - a) / run_time * 100.0),
        peak_rss_kib: rss,
        collisions,
        alarms,
    }
}

/// SERVO_OUTPUT_RAW of message `i` for `port`: channels 1–16 (port 0) or 17–32 (port 1).
fn outputs(servos: usize, marked: usize, port: u8, i: usize) -> MavMessage {
    let mut raw = [0u16; 16];
    for s in 1..=servos {
        let on_port1 = marked != 1 && s == marked;
        if on_port1 == (port == 1) {
            let channel = if on_port1 { 0 } else { s - 1 };
            raw[channel] = pwm(s, i, marked);
        }
    }
    servo_output_raw(port, raw, 0)
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
    let hogs: usize = std::env::var("E2E_HOGS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(2);
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
        "{:<12} {:>6} {:>6} {:>8} {:>6} {:>5} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>6} {:>7} {:>8} {:>5} {:>6}",
        "case",
        "hogs",
        "sent",
        "on wire",
        "supsd",
        "lost",
        "p0 p50",
        "p0 p99",
        "p0 max",
        "p1 p50",
        "p1 p99",
        "all p99",
        "telem",
        "CPU %",
        "RSS KiB",
        "talk",
        "alarms"
    );
    let mut cases = Vec::new();
    for (servos, rate_hz) in [(4, 50.0), (4, 400.0), (8, 50.0), (8, 400.0)] {
        cases.push(Case {
            servos,
            rate_hz,
            ports: 1,
            jitter: Jitter::None,
            hogs: 0,
        });
    }
    for jitter in [Jitter::None, Jitter::Uniform1Ms, Jitter::Late5Pct] {
        for h in [0, hogs] {
            cases.push(Case {
                servos: 4,
                rate_hz: 50.0,
                ports: 2,
                jitter,
                hogs: h,
            });
        }
    }
    let us = |v: f64| {
        if v.is_nan() {
            "-".to_string()
        } else {
            format!("{v:.0}")
        }
    };
    for case in cases {
        // `E2E_CASES=4x50,4x50x2pj` runs only those cases (e.g. while profiling one of them).
        if let Ok(only) = std::env::var("E2E_CASES")
            && !only.split(',').any(|c| c.trim() == case.name())
        {
            continue;
        }
        let hogs = Hogs::start(case.hogs);
        let mut o = run_case(&case, seconds);
        drop(hogs);
        for l in &mut o.latencies_us {
            l.sort_by(f64::total_cmp);
        }
        let mut all: Vec<f64> = o.latencies_us.concat();
        all.sort_by(f64::total_cmp);
        let [p0, p1] = &o.latencies_us;
        println!(
            "{:<12} {:>6} {:>6} {:>7.1}% {:>6} {:>5} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>6.1} {:>7} {:>8} {:>5} {:>6}",
            format!("{} {}", case.name(), case.jitter.name()),
            case.hogs,
            o.sent,
            o.on_wire as f64 * 100.0 / o.sent.max(1) as f64,
            o.superseded,
            o.lost,
            us(percentile(p0, 0.5)),
            us(percentile(p0, 0.99)),
            us(p0.last().copied().unwrap_or(f64::NAN)),
            us(percentile(p1, 0.5)),
            us(percentile(p1, 0.99)),
            us(percentile(&all, 0.99)),
            o.telemetry_hz,
            o.cpu_percent
                .map_or("n/m".to_string(), |c| format!("{c:.2}")),
            o.peak_rss_kib.map_or("n/m".to_string(), |r| r.to_string()),
            o.collisions,
            o.alarms.len(),
        );
        for a in &o.alarms {
            println!("    alarm heard: {a}");
        }
        let _ = std::io::stdout().flush();
    }
    println!(
        "latencies in µs, from the autopilot's send to the first byte of the long packet; n/m: not measured (/proc unreadable)"
    );
    println!(
        "targets (4 servos, 50 Hz, two ports): quiet p0 p50 ≤ 150, p0 p99 ≤ 1500, p1 p50 ≤ 2000, all p99 ≤ 2500, CPU ≤ 1.5 %; two hogs p0 p50 ≤ 300, p0 p99 ≤ 4000, p1 p50 ≤ 3000, all p99 ≤ 4000; no talk-over, alarm or lost goal"
    );
}

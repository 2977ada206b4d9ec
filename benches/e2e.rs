//! End-to-end benchmark: a MAVLink sender on UDP → the bridge process (`lj9da-bridge run`) →
//! simulated LJ9DA41s on pseudo-terminals at 115 200 bit/s.
//!
//! Cases at 115 200 bit/s: 4 and 8 servos on port 0 at 50 Hz and 400 Hz, every message a new
//! goal; and 4 servos on two ports (channels 1–3 in SERVO_OUTPUT_RAW port 0, channel 17 in port 1, sent back to
//! back as ArduPilot does) at 50 Hz, each quiet and beside two CPU hogs (`E2E_HOGS=n` changes
//! how many), in these scenarios:
//! - `sweep` (steady), `±1ms` (ticks jitter uniformly), `5%late` (one message in twenty 3–8 ms
//!   late): every message changes its goals;
//! - `steps`: the outputs hold still and both ports step every 0.8 s, as a pilot's input after a
//!   steady spell (every message is still sent; only the steps are measured);
//! - `gap`: steps every 0.3 s; port 1 falls silent for 2.5 s after a third of the run;
//! - `rate`: steps every 0.3 s; for 3 s after a third of the run the stream slows to 12.5 Hz
//!   (ArduPilot during a parameter or log transfer), then comes back to 50 Hz;
//! - `garbled`: the sweep with a fifth of servo 1's replies corrupted;
//!
//! and the two-port sweep and steps at 460 800 bit/s (`@460k`), for the bridge's CPU at the
//! servo's fastest rate. `E2E_TELEMETRY=max` (or a number) sets the bus's `telemetry_hz`.
//!
//! For each it prints:
//! - latency from a SERVO_OUTPUT_RAW datagram's send to the first byte of the long packet that
//!   carries its goal, as the simulated serial device saw it (p50, p90, p99, max), per port and
//!   for all goals; in `gap` and `rate`, `settled` repeats port 0's p50/p90 for the steps sent
//!   at least 1 s after the disturbance began or ended;
//! - `behind`: the share of measured messages sent while a request was on the wire and its
//!   reply had not ended (the bus master's part of a latency, as against the process's);
//! - `polls`: position-and-current reads per servo per second, and `s1 ok`: servo 1's
//!   uncorrupted replies per second (compare `garbled` with `sweep` of the same run);
//! - the share of output messages whose goal reached the wire, with superseded goals (a newer
//!   message's goal went out first) counted apart, and goals lost;
//! - the telemetry rate per servo seen by a ground station (`<label>_pos` NAMED_VALUE_FLOAT);
//! - the bridge process's CPU time per second of run, and its peak resident memory ("not
//!   measured" where /proc cannot be read); the CPU split by thread (`main/bus/rest`: the
//!   MAVLink loop, the bus threads, the flight record's and the mapping file's writers) and
//!   the main and bus threads' wake-ups a second (`wk/s m/b`: voluntary context switches);
//! - talk-overs (a packet written while a servo replied; "(N sim)": of them, N where the
//!   simulator read a packet together with a request before it, i.e. its thread was not run for
//!   the reply allowance while the bridge timed the first out) and STATUSTEXTs of severity WARNING or
//!   worse heard by the ground station (none is true of healthy simulated servos).
//!
//! Every message gives servo 1 a goal that no other message in the window has, so each message
//! is matched to the packet that carried it. Run: `cargo bench --bench e2e` (`E2E_SECONDS=N`
//! sets the length of each case, default 6 s; `E2E_CASES=4x50,8x400` runs only those cases;
//! `E2E_BRIDGE=path` runs another build of the bridge, e.g. the code before a change;
//! `E2E_GCS_HZ` sets the ground station's NAMED_VALUE_FLOAT rate, `[telemetry] rate_hz`,
//! default 20 as in every earlier run of this bench; the bridge's own default is 1).

use lj9da_bridge::config::Config;
use lj9da_bridge::mavlink::outputs::servo_output_raw;
use lj9da_sim::protocol::host_packet::ShortForm;
use lj9da_sim::{BusEvent, Fault, HostPacket, SimBus, SimConfig};
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

/// What the autopilot's outputs do over a run.
#[derive(Clone, Copy, PartialEq)]
enum Scenario {
    /// Every message changes its goals.
    Sweep(Jitter),
    /// The outputs hold still; both ports step every 0.8 s.
    Steps,
    /// Steps every 0.3 s; port 1 silent for 2.5 s after a third of the run.
    PortGap,
    /// Steps every 0.3 s; 12.5 Hz for 3 s after a third of the run, then 50 Hz again.
    RateDrop,
    /// The steady sweep with a fifth of servo 1's replies corrupted.
    Garbled,
}

impl Scenario {
    fn name(self) -> &'static str {
        match self {
            Scenario::Sweep(j) => j.name(),
            Scenario::Steps => "steps",
            Scenario::PortGap => "gap",
            Scenario::RateDrop => "rate",
            Scenario::Garbled => "garbled",
        }
    }

    fn jitter(self) -> Jitter {
        match self {
            Scenario::Sweep(j) => j,
            _ => Jitter::None,
        }
    }

    /// Ticks between steps (`None`: every message changes).
    fn step_every(self) -> Option<usize> {
        match self {
            Scenario::Sweep(_) | Scenario::Garbled => None,
            Scenario::Steps => Some(40),
            Scenario::PortGap | Scenario::RateDrop => Some(15),
        }
    }

    /// Seconds the case runs at least (a disturbance and the time after it).
    fn min_seconds(self) -> f64 {
        match self {
            Scenario::PortGap | Scenario::RateDrop => 10.0,
            Scenario::Steps => 8.0,
            _ => 0.0,
        }
    }
}

struct Case {
    servos: usize,
    rate_hz: f64,
    /// The bus's bit rate.
    baud: u32,
    /// 1: every servo on port 0; 2: the last servo on channel 17 (port 1).
    ports: u8,
    scenario: Scenario,
    hogs: usize,
}

impl Case {
    fn name(&self) -> String {
        format!(
            "{}x{}{}{}{}",
            self.servos,
            self.rate_hz,
            if self.ports == 2 { "x2p" } else { "" },
            match self.scenario {
                Scenario::Sweep(Jitter::None) => "",
                Scenario::Sweep(Jitter::Uniform1Ms) => "j",
                Scenario::Sweep(Jitter::Late5Pct) => "l",
                Scenario::Steps => "s",
                Scenario::PortGap => "g",
                Scenario::RateDrop => "r",
                Scenario::Garbled => "c",
            },
            if self.baud == 115_200 { "" } else { "@460k" },
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
    /// Port 0's latencies of the steps sent at least 1 s after a disturbance began or ended
    /// (`gap`, `rate`).
    settled_us: Vec<f64>,
    /// Measured messages sent while a request was on the wire and its reply had not ended.
    behind: usize,
    /// Position-and-current reads per servo per second.
    polls_hz: f64,
    /// Servo 1's uncorrupted replies per second.
    servo1_ok_hz: f64,
    telemetry_hz: f64,
    /// `None` where /proc could not be read.
    cpu_percent: Option<f64>,
    /// Per part of the process (main thread, bus threads, the rest): CPU % of a core and
    /// wake-ups a second (see [`thread_split`]).
    threads: Option<[(f64, f64); 3]>,
    peak_rss_kib: Option<u64>,
    collisions: usize,
    /// Of them, those the simulator's starved thread caused (see `starved` in `run_case`).
    collisions_sim_starved: usize,
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

/// The bench's mapping. The failsafe timeout (3 s) outlasts the `gap` scenario's silent port
/// (2.5 s). `$E2E_TELEMETRY` (e.g. `50` or `"max"`) sets the bus's `telemetry_hz`; unset, the
/// bridge's default (and a build that predates the key still reads the file).
fn mapping(case: &Case, port: &str, ap: u16, gcs: u16) -> String {
    let (servos, ports, baud) = (case.servos, case.ports, case.baud);
    let telemetry = std::env::var("E2E_TELEMETRY")
        .map(|t| match t.parse::<f64>() {
            Ok(hz) => format!("telemetry_hz = {hz}\n"),
            Err(_) => format!("telemetry_hz = \"{t}\"\n"),
        })
        .unwrap_or_default();
    let gcs_hz = std::env::var("E2E_GCS_HZ").unwrap_or_else(|_| "20".into());
    let mut s = format!(
        "[mavlink]\nconnection = \"udpin:127.0.0.1:{ap}\"\ngcs = \"udpout:127.0.0.1:{gcs}\"\nautopilot_system_id = 1\nfailsafe_timeout_ms = 3000\n\
         [telemetry]\nrate_hz = {gcs_hz}\n[bridge]\non_exit = \"hold\"\n[[bus]]\nname = \"b\"\nport = \"{port}\"\nbaud = {baud}\n{telemetry}"
    );
    for i in 1..=servos {
        let channel = if ports == 2 && i == servos { 17 } else { i };
        s += &format!("[[servo]]\nname = \"s{i}\"\nbus = \"b\"\nid = {i}\nchannel = {channel}\n");
    }
    s
}

/// The bridge binary to run: `$E2E_BRIDGE` (another build, e.g. the code before a change, to
/// compare in the same hour), else this build's.
fn bridge_exe() -> std::ffi::OsString {
    std::env::var_os("E2E_BRIDGE").unwrap_or_else(|| env!("CARGO_BIN_EXE_lj9da-bridge").into())
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

/// Per thread of `pid`, CPU seconds (`schedstat`) and voluntary context switches (wake-ups), summed into the
/// main thread (the MAVLink loop), the bus threads (`bus <name>`) and
/// the rest (the flight record's writer and the mapping file's); `None` where /proc does not
/// tell.
fn thread_split(pid: u32) -> Option<[(f64, u64); 3]> {
    let mut split = [(0.0, 0u64); 3];
    for task in std::fs::read_dir(format!("/proc/{pid}/task"))
        .ok()?
        .flatten()
    {
        let dir = task.path();
        let comm = std::fs::read_to_string(dir.join("comm")).ok()?;
        // Time on a CPU in ns (the scheduler's own count: finer than stat's 10 ms ticks).
        let ran_ns: f64 = std::fs::read_to_string(dir.join("schedstat"))
            .ok()?
            .split_whitespace()
            .next()?
            .parse()
            .ok()?;
        let wakeups: u64 = std::fs::read_to_string(dir.join("status"))
            .ok()?
            .lines()
            .find_map(|l| l.strip_prefix("voluntary_ctxt_switches:"))?
            .trim()
            .parse()
            .ok()?;
        let k = if dir.file_name().and_then(|n| n.to_str()) == Some(&pid.to_string()) {
            0
        } else if comm.starts_with("bus ") {
            1
        } else {
            2
        };
        split[k].0 += ran_ns / 1e9;
        split[k].1 += wakeups;
    }
    Some(split)
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
        baud: case.baud,
        ..SimConfig::default()
    })
    .expect("simulated servos");
    let events: Receiver<BusEvent> = sim.handle().subscribe();
    let ap_port = free_udp_port();
    let gcs_port = free_udp_port();
    let dir = std::env::temp_dir().join(format!("lj9da-e2e-{}-{}", std::process::id(), ap_port));
    std::fs::create_dir_all(&dir).unwrap();
    let cfg_path = dir.join("bench.toml");
    let text = mapping(case, &sim.path().display().to_string(), ap_port, gcs_port);
    std::fs::write(&cfg_path, &text).unwrap();
    // The servo whose goals mark each port's messages: servo 1 on port 0; on port 1 the last.
    let marked = if case.ports == 2 { case.servos } else { 1 };
    let config = Config::parse(&text, "bench").expect("bench mapping");
    let markers = [config.servos[0].clone(), config.servos[marked - 1].clone()];
    let goal_of =
        |port: usize, us: u16| markers[port].map_pwm(us).expect("bench PWM is in range").0;
    let mut bridge: Child = Command::new(bridge_exe())
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
    if case.scenario == Scenario::Garbled {
        sim.handle()
            .inject(Some(1), Fault::CorruptReplies { probability: 0.2 });
    }
    while events.try_recv().is_ok() {}
    let (cpu0, _) = cpu_and_rss(pid);
    let split0 = thread_split(pid);
    let t_start = Instant::now();

    let schedule = schedule(case, seconds, Instant::now() + Duration::from_millis(20));
    let mut sends: Vec<Send> = Vec::with_capacity(schedule.len());
    for (k, m) in schedule.into_iter().enumerate() {
        while Instant::now() < m.at {
            std::hint::spin_loop();
        }
        if k % (case.rate_hz as usize) == 0 {
            let _ = ap.send(&header, &heartbeat);
        }
        let msg = outputs(case.servos, marked, m.port, m.value);
        let t = Instant::now();
        ap.send(&header, &msg).expect("send");
        if m.changed {
            let servo = if m.port == 0 { 1 } else { marked };
            sends.push(Send {
                at: t,
                port: usize::from(m.port),
                goal: goal_of(usize::from(m.port), pwm(servo, m.value, marked)),
                settled: m.settled,
            });
        }
    }
    std::thread::sleep(Duration::from_millis(300));
    let run_time = t_start.elapsed().as_secs_f64();
    let (cpu1, rss) = cpu_and_rss(pid);
    let split1 = thread_split(pid);

    // Long packets seen by the simulated servos: (first byte instant, each marker's goal);
    // requests on the wire: (first byte, end of the reply or of the request); reads of
    // position and current; servo 1's good replies.
    let mut packets: [Vec<(Instant, i16)>; 2] = [Vec::new(), Vec::new()];
    let mut collisions: Vec<Instant> = Vec::new();
    // Packets the simulator read in one go with a request before them: the bridge wrote the
    // later one only after the request had timed out, so the simulator's thread was not run for at
    // least the reply allowance (the bridge's thread, in the real-time class, was). The
    // simulator then puts both on its modelled line at once, and a reply to the first collides
    // with the second: a talk-over of the simulator's, not of the bridge's.
    let mut starved: Vec<(Instant, Instant)> = Vec::new();
    let mut last_request_read: Option<Instant> = None;
    let mut requests: Vec<(Instant, Instant)> = Vec::new();
    let mut open_request: Option<(Instant, Instant, u8)> = None;
    let (mut polls, mut servo1_ok) = (0usize, 0usize);
    // `E2E_TRACE=1`: the line's last events before each talk-over, µs before it.
    let trace = std::env::var_os("E2E_TRACE").is_some();
    let mut recent: std::collections::VecDeque<BusEvent> = std::collections::VecDeque::new();
    while let Ok(e) = events.try_recv() {
        if trace {
            if let BusEvent::Collision { at, id } = &e {
                eprintln!("talk-over with servo {id}; the line before it (µs before):");
                for before in &recent {
                    let when = match before {
                        BusEvent::Packet(p) => Some(p.first_byte_at),
                        BusEvent::Reply(r) => Some(r.first_byte_at),
                        BusEvent::HandedLate { at, .. } => Some(*at),
                        _ => None,
                    };
                    let ago = when.map_or(f64::NAN, |t| {
                        at.saturating_duration_since(t).as_secs_f64() * 1e6
                    });
                    eprintln!("  {ago:>8.0}  {before:?}");
                }
            }
            recent.push_back(e.clone());
            if recent.len() > 8 {
                recent.pop_front();
            }
        }
        match e {
            BusEvent::Packet(p) => {
                if last_request_read == Some(p.first_byte_at) {
                    match starved.last_mut() {
                        Some((at, end)) if *at == p.first_byte_at => *end = p.completed_at,
                        _ => starved.push((p.first_byte_at, p.completed_at)),
                    }
                }
                let expects_reply =
                    matches!(&p.packet, HostPacket::Short(short) if short.id != 0xFF);
                if expects_reply || last_request_read != Some(p.first_byte_at) {
                    last_request_read = expects_reply.then_some(p.first_byte_at);
                }
                if let Some((start, end, _)) = open_request.take() {
                    requests.push((start, end.min(p.first_byte_at)));
                }
                let goals = p.packet.goal_positions();
                for (port, id) in [(0, 1u8), (1, marked as u8)] {
                    if let Some((_, g)) = goals.iter().find(|(i, _)| *i == id) {
                        packets[port].push((p.first_byte_at, *g));
                    }
                }
                if let HostPacket::Short(short) = &p.packet {
                    // Registers 42–49 read by address, or 42–59 by reply request 09h.
                    let reads_position_and_current = match short.form() {
                        ShortForm::Request {
                            address,
                            length,
                            reply_code,
                        } => (address == 0x2A && length >= 8) || reply_code == 0x09,
                        // The bridge's full read: Count = 1 with no data (spec 4.1).
                        ShortForm::Write { reply_code, .. } => reply_code == 0x09,
                        _ => false,
                    };
                    if reads_position_and_current {
                        polls += 1;
                    }
                    if short.id != 0xFF {
                        open_request = Some((p.first_byte_at, p.completed_at, short.id));
                    }
                }
            }
            BusEvent::Reply(r) => {
                if let Some((start, _, id)) = open_request
                    && id == r.id
                {
                    requests.push((start, r.last_byte_at));
                    open_request = None;
                }
                if r.id == 1 && !r.corrupted {
                    servo1_ok += 1;
                }
            }
            BusEvent::Collision { at, .. } => collisions.push(at),
            _ => {}
        }
    }
    // A message's goal is on the wire when a packet after its send carries it.
    let carried: Vec<Option<Instant>> = sends
        .iter()
        .map(|m| {
            packets[m.port]
                .iter()
                .find(|(at, g)| {
                    *at >= m.at && *g == m.goal && at.duration_since(m.at) < Duration::from_secs(1)
                })
                .map(|(at, _)| *at)
        })
        .collect();
    // Not carried: superseded when a later message's goal for the same port reached the wire
    // (the bus master keeps only the newest goal per servo), lost when none did.
    let mut later_on_wire = [false; 2];
    let mut superseded_flags = vec![false; sends.len()];
    for k in (0..sends.len()).rev() {
        let port = sends[k].port;
        superseded_flags[k] = carried[k].is_none() && later_on_wire[port];
        later_on_wire[port] |= carried[k].is_some();
    }
    let behind = sends
        .iter()
        .filter(|m| {
            requests
                .iter()
                .any(|(start, end)| *start <= m.at && m.at < *end)
        })
        .count();
    let (mut on_wire, mut superseded, mut lost) = (0, 0, 0);
    let mut latencies_us = [Vec::new(), Vec::new()];
    let mut settled_us = Vec::new();
    for (k, m) in sends.iter().enumerate() {
        match carried[k] {
            Some(at) => {
                on_wire += 1;
                let us = at.duration_since(m.at).as_secs_f64() * 1e6;
                latencies_us[m.port].push(us);
                if m.settled && m.port == 0 {
                    settled_us.push(us);
                }
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
        settled_us,
        behind,
        polls_hz: polls as f64 / run_time / case.servos as f64,
        servo1_ok_hz: servo1_ok as f64 / run_time,
        telemetry_hz,
        cpu_percent: cpu0.zip(cpu1).map(|(a, b)| (b - a) / run_time * 100.0),
        threads: split0.zip(split1).map(|(a, b)| {
            let per = |k: usize| {
                (
                    (b[k].0 - a[k].0) / run_time * 100.0,
                    b[k].1.saturating_sub(a[k].1) as f64 / run_time,
                )
            };
            [per(0), per(1), per(2)]
        }),
        peak_rss_kib: rss,
        collisions: collisions.len(),
        collisions_sim_starved: collisions
            .iter()
            .filter(|at| {
                // Within the batch's modelled span, or the reply allowance after it.
                starved
                    .iter()
                    .any(|(from, to)| **at >= *from && **at <= *to + Duration::from_millis(20))
            })
            .count(),
        alarms,
    }
}

/// One output message of the autopilot.
struct Message {
    at: Instant,
    port: u8,
    /// Which values it carries (see [`pwm`]).
    value: usize,
    /// Its values differ from its port's message before it: its latency is measured.
    changed: bool,
    /// Sent at least 1 s after the scenario's disturbance began or ended.
    settled: bool,
}

/// A measured message as it was sent.
struct Send {
    at: Instant,
    port: usize,
    goal: i16,
    settled: bool,
}

/// The messages of `case` from `t0`, in send order.
fn schedule(case: &Case, seconds: f64, t0: Instant) -> Vec<Message> {
    let period = Duration::from_secs_f64(1.0 / case.rate_hz);
    let n = (seconds * case.rate_hz) as usize;
    let mut rng = XorShift(0x2545_F491_4F6C_DD1D);
    // The disturbance of `gap` and `rate`: from a third of the run, 2.5 s or 3 s long.
    let (from, until) = (n / 3, n / 3 + (case.rate_hz * 2.5) as usize);
    let until = if case.scenario == Scenario::RateDrop {
        n / 3 + (case.rate_hz * 3.0) as usize
    } else {
        until
    };
    let settle = case.rate_hz as usize;
    let mut out = Vec::with_capacity(n * usize::from(case.ports));
    for i in 1..=n {
        let disturbed = (from..until).contains(&i);
        if case.scenario == Scenario::RateDrop && disturbed && (i - from) % 4 != 0 {
            continue;
        }
        let tick = t0 + period * i as u32;
        let tick = match case.scenario.jitter() {
            Jitter::Uniform1Ms => {
                let offset = Duration::from_secs_f64(rng.unit() * 2e-3);
                tick + offset - Duration::from_millis(1)
            }
            _ => tick,
        };
        let (value, changed) = match case.scenario.step_every() {
            None => (i, true),
            Some(every) => (i / every, i % every == 0),
        };
        let settled = match case.scenario {
            Scenario::PortGap | Scenario::RateDrop => {
                (i >= from + settle && i < until) || i >= until + settle
            }
            _ => false,
        };
        for port in 0..case.ports {
            if case.scenario == Scenario::PortGap && port == 1 && disturbed {
                continue;
            }
            let mut at = tick + Duration::from_micros(100) * u32::from(port);
            if case.scenario.jitter() == Jitter::Late5Pct && rng.unit() < 0.05 {
                at += Duration::from_secs_f64(3e-3 + rng.unit() * 5e-3);
            }
            out.push(Message {
                at,
                port,
                value,
                changed,
                settled,
            });
        }
    }
    out.sort_by_key(|m| m.at);
    out
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
        "end-to-end: UDP SERVO_OUTPUT_RAW → lj9da-bridge process → simulated LJ9DA41s on ptys, 115200 bit/s (@460k: 460800)"
    );
    println!(
        "machine: {cpu}, {cores} cores; {seconds} s per case (at least 8–10 s for steps, gap, rate)"
    );
    println!("bridge: {}", bridge_exe().to_string_lossy());
    println!(
        "{:<16} {:>4} {:>5} {:>7} {:>5} {:>4} {:>6} {:>6} {:>6} {:>6} {:>6} {:>6} {:>7} {:>7} {:>7} {:>6} {:>6} {:>6} {:>6} {:>16} {:>9} {:>11} {:>6}",
        "case",
        "hogs",
        "sent",
        "on wire",
        "supsd",
        "lost",
        "p0 p50",
        "p0 p90",
        "p0 p99",
        "p0 max",
        "p1 p50",
        "allp99",
        "settled",
        "behind",
        "polls",
        "s1 ok",
        "telem",
        "CPU %",
        "RSS M",
        "main/bus/rest %",
        "wk/s m/b",
        "talk",
        "alarms"
    );
    let mut cases = Vec::new();
    for (servos, rate_hz) in [(4, 50.0), (4, 400.0), (8, 50.0), (8, 400.0)] {
        cases.push(Case {
            servos,
            rate_hz,
            baud: 115_200,
            ports: 1,
            scenario: Scenario::Sweep(Jitter::None),
            hogs: 0,
        });
    }
    for scenario in [
        Scenario::Sweep(Jitter::None),
        Scenario::Sweep(Jitter::Uniform1Ms),
        Scenario::Sweep(Jitter::Late5Pct),
        Scenario::Steps,
        Scenario::PortGap,
        Scenario::RateDrop,
        Scenario::Garbled,
    ] {
        for h in [0, hogs] {
            cases.push(Case {
                servos: 4,
                rate_hz: 50.0,
                baud: 115_200,
                ports: 2,
                scenario,
                hogs: h,
            });
        }
    }
    // The bridge's CPU at the servo's fastest rate.
    for scenario in [Scenario::Sweep(Jitter::None), Scenario::Steps] {
        for h in [0, hogs] {
            cases.push(Case {
                servos: 4,
                rate_hz: 50.0,
                baud: 460_800,
                ports: 2,
                scenario,
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
        let mut o = run_case(&case, seconds.max(case.scenario.min_seconds()));
        drop(hogs);
        for l in &mut o.latencies_us {
            l.sort_by(f64::total_cmp);
        }
        o.settled_us.sort_by(f64::total_cmp);
        let mut all: Vec<f64> = o.latencies_us.concat();
        all.sort_by(f64::total_cmp);
        let [p0, p1] = &o.latencies_us;
        let settled = if o.settled_us.is_empty() {
            "-".to_string()
        } else {
            format!(
                "{}/{}",
                us(percentile(&o.settled_us, 0.5)),
                us(percentile(&o.settled_us, 0.9))
            )
        };
        println!(
            "{:<16} {:>4} {:>5} {:>6.1}% {:>5} {:>4} {:>6} {:>6} {:>6} {:>6} {:>6} {:>6} {:>7} {:>6.1}% {:>7.1} {:>6.1} {:>6.1} {:>6} {:>6} {:>16} {:>9} {:>11} {:>6}",
            format!("{} {}", case.name(), case.scenario.name()),
            case.hogs,
            o.sent,
            o.on_wire as f64 * 100.0 / o.sent.max(1) as f64,
            o.superseded,
            o.lost,
            us(percentile(p0, 0.5)),
            us(percentile(p0, 0.9)),
            us(percentile(p0, 0.99)),
            us(p0.last().copied().unwrap_or(f64::NAN)),
            us(percentile(p1, 0.5)),
            us(percentile(&all, 0.99)),
            settled,
            o.behind as f64 * 100.0 / o.sent.max(1) as f64,
            o.polls_hz,
            o.servo1_ok_hz,
            o.telemetry_hz,
            o.cpu_percent
                .map_or("n/m".to_string(), |c| format!("{c:.2}")),
            o.peak_rss_kib
                .map_or("n/m".to_string(), |r| format!("{:.1}", r as f64 / 1024.0)),
            o.threads.map_or("n/m".to_string(), |t| format!(
                "{:.2}/{:.2}/{:.2}",
                t[0].0, t[1].0, t[2].0
            )),
            o.threads.map_or("n/m".to_string(), |t| format!(
                "{:.0}/{:.0}",
                t[0].1, t[1].1
            )),
            if o.collisions_sim_starved > 0 {
                format!("{} ({} sim)", o.collisions, o.collisions_sim_starved)
            } else {
                o.collisions.to_string()
            },
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
        "behind: measured messages sent while a request and its reply held the wire; polls: position-and-current reads per servo per second; s1 ok: servo 1's good replies per second; settled: port 0 p50/p90 of the steps 1 s or more after a disturbance began or ended"
    );
    println!(
        "targets (4 servos, 50 Hz, two ports): steps behind ≤ 10 % (20 % with hogs), p50/p90 ≤ 250/1000 µs (400/2000 with hogs); p1 p50 ≤ 400 (600); p0 p99 ≤ 1500 (3000), all p99 ≤ 2500 (4000); garbled s1 ok ≥ 70 % of the sweep's; polls ≥ 60 Hz (50); no talk-over, alarm or lost goal"
    );
}

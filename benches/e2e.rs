//! End-to-end benchmark: a MAVLink sender on UDP → the bridge process (`lj9da-bridge run`) →
//! simulated LJ9DA41s on pseudo-terminals at 115 200 bit/s.
//!
//! Each case also runs, right before or after the bridge (the order swapped from case to case,
//! so that both see the same minute of the machine), with a peer in the bridge's place: the
//! naive bridge, `../shared/peers/naive_bridge.py` beside the repository (`E2E_NAIVE=path`
//! names another), a pymavlink loop that writes every servo's goal on each SERVO_OUTPUT_RAW and
//! then polls one servo with a blocking read, as a normal process. It reads the same mapping
//! file and meets the same servos, sender and measures. Its Python is `$LJ9DA_PYTHON`, else the
//! tests' virtual environment with pymavlink under the target directory (made on first use,
//! from PyPI). Where the script or such a Python is missing, one line says so and the bridge
//! runs alone. `E2E_PEERS=bridge` (or `naive`) runs one of them.
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
//! and the two-port sweep and steps with no servo on port 1 (`x2pu`: most planes map channels
//! 1–16 while the autopilot still sends port 1), whose port 0 goals should not wait for it;
//!
//! and the two-port sweep and steps at 460 800 bit/s (`@460k`), for the bridge's CPU at the
//! servo's fastest rate. `E2E_TELEMETRY=max` (or a number) sets the bus's `telemetry_hz`;
//! `E2E_TURNAROUND_MS` its reply allowance (unset: the bridge's own 2 ms).
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
//! - on a second line: the machine's own stalls, as a probe thread per CPU that sleeps like the
//!   bus thread saw them (wake-ups more than 0.5 ms late; see [`Probe`]), with the CPU time the
//!   hypervisor stole meanwhile; idle spells (no request on the wire for more than three poll
//!   periods: a bus thread that did not run, or a tick it waited for that did not come) and
//!   how many no machine stall explains; port 0's and all goals' p99 without the goals that
//!   waited beside a machine stall; and in two-port cases the share of ticks (both messages
//!   sent within 0.5 ms) whose two goals left in one long packet, with port 1's goal's lag
//!   behind port 0's;
//! - talk-overs (a packet written while a servo replied; "(N sim)": of them, N where the
//!   simulator read a packet together with a request before it, i.e. its thread was not run for
//!   the reply allowance while the bridge timed the first out) and STATUSTEXTs of severity WARNING or
//!   worse heard by the ground station (none is true of healthy simulated servos);
//! - on a third line, the bridge's only: systemd's watchdog as the bench, in systemd's place,
//!   saw it. The bench binds a Unix datagram socket of its own and starts the bridge as
//!   systemd would (`NOTIFY_SOCKET`, `WATCHDOG_USEC` for `E2E_WATCHDOG_MS`, default 1000 ms,
//!   and `WATCHDOG_PID`, the bridge's own pid, through `sh -c 'export WATCHDOG_PID=$$; exec
//!   …'`); a thread at the sender's priority notes when each `READY=1` and `WATCHDOG=1` came,
//!   from the start to the stop (warm-up included). `watchdog T ms (pinged every P ms)`, P as the
//!   bridge says it (T/4 from `49107e8`, T/2 before): how
//!   many pings; the gaps from READY=1 (which arms systemd's timer) to the first ping and
//!   between consecutive pings, p50 and `longest` in ms (the longest is what `WatchdogSec=`
//!   must outlast), and READY to the first ping apart; how many gaps exceeded 1.5 periods: the
//!   bridge pings only when every bus thread has turned since its last look, so a gap is one
//!   period, or two where a look found a bus not turned (the bridge's "bus thread stuck" lines,
//!   which name the bus, are counted and repeated), or one and the loop's lateness; `late
//!   pings`: each gap more than 10 ms over the period, with when it ended (after READY=1, and
//!   on CLOCK_MONOTONIC as `E2E_TRACE_LATE` gives its goals). "NOT
//!   announced" where the bridge's log lacks its "systemd watchdog: …" line (a build without
//!   the watchdog, or a `WATCHDOG_PID` not its own). `E2E_WATCHDOG_MS=0`: no watchdog, the
//!   bridge started as before.
//!
//! The naive peer's lines carry its name after the case's, with `n/a` for what it has no figure
//! of: it sends its telemetry and STATUSTEXTs to the autopilot's address only (no ground
//! station hears them), and runs one thread. It has no failsafe; the bench measures none (the
//! `gap` case's silence is shorter than the bridge's failsafe timeout). After the two runs of
//! a case a table sets side by side the bridge's and the peer's port 0 p50 (in `steps`, `gap`
//! and `rate`: a step after the outputs held still), port 1's goals p50, all goals' p50 and
//! p99, the goals on the wire and the whole process's CPU, with the ratio peer/bridge (above
//! 1: the peer's figure is higher).
//!
//! The sender stands for the autopilot, another computer: it runs at a real-time priority
//! above the bridge's where granted, sleeps between sends and spins only for the last 0.5 ms.
//!
//! Every message gives servo 1 a goal that no other message in the window has, so each message
//! is matched to the packet that carried it. Run: `cargo bench --bench e2e` (`E2E_SECONDS=N`
//! sets the length of each case, default 6 s; `E2E_CASES=4x50,8x400` runs only those cases;
//! `E2E_BRIDGE=path` runs another build of the bridge, e.g. the code before a change;
//! `E2E_TRACE_LATE=1` lists every goal more than 1 ms late with its send on CLOCK_MONOTONIC,
//! to line it up with `perf sched record -k CLOCK_MONOTONIC -a`;
//! `E2E_GCS_HZ` sets the ground station's NAMED_VALUE_FLOAT rate, `[telemetry] rate_hz`,
//! default 20 as in every earlier run of this bench; the bridge's own default is 1).

#[path = "e2e/cases.rs"]
mod cases;
#[path = "e2e/machine.rs"]
mod machine;
#[path = "../tests/common/ports.rs"]
mod ports;
#[path = "../tests/common/python.rs"]
mod python;
#[path = "e2e/report.rs"]
mod report;
#[path = "e2e/watchdog.rs"]
mod watchdog;

use cases::{Case, Jitter, Scenario, Send, outputs, pwm, schedule};
use lj9da_bridge::config::Config;
use lj9da_sim::protocol::host_packet::ShortForm;
use lj9da_sim::{BusEvent, Fault, HostPacket, SimBus, SimConfig};
use machine::{Hogs, Probe, beside_stall, cpu_and_rss, steal_s, thread_split};
use mavlink::dialects::common::*;
use mavlink::{MavConnection, MavHeader};
use report::{clock_time, compare, report};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc::Receiver;
use std::time::{Duration, Instant};
use watchdog::{Listener, Pings};

/// The sender's real-time priority: above the bridge's bus threads and the simulator's.
const SENDER_PRIORITY: i32 = lj9da_bridge::bus::driver::REALTIME_PRIORITY + 10;

/// The sender spins for the last this-much before each send (see `run_case`): more than a
/// sleeping thread's usual lateness on an idle virtual machine.
const SEND_SPIN: Duration = Duration::from_micros(500);

/// The longest a process may take from its start to its first goal on the wire.
const WARM_UP_LIMIT: Duration = Duration::from_secs(60);

/// The process that runs between the autopilot and the simulated servos.
enum Peer {
    /// `lj9da-bridge run` (`$E2E_BRIDGE`, else this build's).
    Bridge,
    /// `naive_bridge.py run` (`../shared/peers/`: a pymavlink loop that writes every servo's
    /// goal on each SERVO_OUTPUT_RAW, then polls one servo with a blocking read), run by a
    /// Python with pymavlink.
    Naive { python: PathBuf, script: PathBuf },
}

impl Peer {
    fn name(&self) -> &'static str {
        match self {
            Peer::Bridge => "bridge",
            Peer::Naive { .. } => "naive",
        }
    }
}

/// The peers named by `$E2E_PEERS` (`bridge`, `naive`; default both). Where the naive peer's
/// script or a Python that runs it is missing, one line says so and the bridge runs alone.
fn peers() -> Vec<Peer> {
    let wanted = std::env::var("E2E_PEERS").unwrap_or_else(|_| "bridge,naive".into());
    let mut peers = Vec::new();
    for name in wanted.split(',').map(str::trim).filter(|n| !n.is_empty()) {
        match name {
            "bridge" => peers.push(Peer::Bridge),
            "naive" => match naive() {
                Ok(peer) => peers.push(peer),
                Err(why) => println!("naive peer not run: {why}"),
            },
            other => panic!("E2E_PEERS: unknown peer {other:?} (bridge, naive)"),
        }
    }
    if peers.is_empty() {
        peers.push(Peer::Bridge);
    }
    peers
}

/// The naive peer: its script (`$E2E_NAIVE`, else `../shared/peers/naive_bridge.py` beside the
/// repository) and a Python 3.11+ with pymavlink (`$LJ9DA_PYTHON`, else the tests' virtual
/// environment under the target directory, made on first use).
fn naive() -> Result<Peer, String> {
    let script = std::env::var_os("E2E_NAIVE").map_or_else(
        || Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/peers/naive_bridge.py"),
        PathBuf::from,
    );
    let Ok(script) = script.canonicalize() else {
        return Err(format!(
            "no {} (E2E_NAIVE=path names another); the bridge alone",
            script.display()
        ));
    };
    let python = std::panic::catch_unwind(python::python)
        .map_err(|_| "no Python with pymavlink (the panic above says why); the bridge alone")?;
    let runs = Command::new(&python)
        .args(["-c", "import tomllib, pymavlink.mavutil"])
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if !runs {
        return Err(format!(
            "{} lacks tomllib (Python 3.11+) or pymavlink; the bridge alone",
            python.display()
        ));
    }
    Ok(Peer::Naive { python, script })
}

/// Ask the process to end (SIGTERM: the bridge holds its servos, the naive peer ends its loop)
/// and wait; killed after 5 s.
fn stop(child: &mut Child) {
    let _ = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status();
    let asked = Instant::now();
    while asked.elapsed() < Duration::from_secs(5) {
        if let Ok(Some(_)) = child.try_wait() {
            return;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let _ = child.kill();
    let _ = child.wait();
}

struct Outcome {
    sent: usize,
    on_wire: usize,
    superseded: usize,
    lost: usize,
    /// Per port: latencies of the goals that reached the wire.
    latencies_us: [Vec<f64>; 2],
    /// The same, without the goals that waited beside a stall of the machine's (see [`Probe`]).
    unstalled_us: [Vec<f64>; 2],
    /// The probe's stalls: how many, and the longest (µs).
    stalls: usize,
    /// Time the hypervisor ran other guests instead of this machine's CPUs (`steal` in
    /// /proc/stat), in ms per second of run, summed over the CPUs (`None` where not told).
    steal_ms_per_s: Option<f64>,
    stall_max_us: f64,
    /// Spells of more than three poll periods with no request on the wire, and how many of
    /// them no stall of the machine's explains; `None` where the bus bunches its reads
    /// after each tick (at 460 800 bit/s four reads take 2.5 ms), so that every tick has one
    /// long gap by design.
    idle_spells: Option<(usize, usize)>,
    /// Ticks whose two ports' goals both reached the wire, and how many went in one packet.
    both_port_ticks: usize,
    one_packet_ticks: usize,
    /// Per such tick, how long after port 0's goal port 1's left (µs; 0 in one packet).
    port1_lag_us: Vec<f64>,
    /// Ticks left out of those: port 1's message sent more than 0.5 ms after port 0's.
    split_sends: usize,
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
    /// The watchdog's pings the bench heard as systemd (the bridge under `$E2E_WATCHDOG_MS`).
    watchdog: Option<Pings>,
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
    // The bus's reply allowance: unset, the bridge's own 2 ms. Builds before 3e30cc9 gave every
    // pseudo-terminal 20 ms whatever the mapping said; `E2E_TURNAROUND_MS=20` compares with them.
    let telemetry = match std::env::var("E2E_TURNAROUND_MS") {
        Ok(ms) => format!("{telemetry}turnaround_ms = {ms}\n"),
        Err(_) => telemetry,
    };
    let mut s = format!(
        "[mavlink]\nconnection = \"udpin:127.0.0.1:{ap}\"\ngcs = \"udpout:127.0.0.1:{gcs}\"\nautopilot_system_id = 1\nfailsafe_timeout_ms = 3000\n\
         [telemetry]\nrate_hz = {gcs_hz}\n[bridge]\non_exit = \"hold\"\n[[bus]]\nname = \"b\"\nport = \"{port}\"\nbaud = {baud}\n{telemetry}"
    );
    for i in 1..=servos {
        let channel = if ports == 2 && case.port1_mapped && i == servos {
            17
        } else {
            i
        };
        s += &format!("[[servo]]\nname = \"s{i}\"\nbus = \"b\"\nid = {i}\nchannel = {channel}\n");
    }
    s
}

/// The bridge binary to run: `$E2E_BRIDGE` (another build, e.g. the code before a change, to
/// compare in the same hour), else this build's.
fn bridge_exe() -> std::ffi::OsString {
    std::env::var_os("E2E_BRIDGE").unwrap_or_else(|| env!("CARGO_BIN_EXE_lj9da-bridge").into())
}

fn run_case(case: &Case, seconds: f64, peer: &Peer) -> Outcome {
    let sim = SimBus::spawn_pty(SimConfig {
        ids: (1..=case.servos as u8).collect(),
        baud: case.baud,
        ..SimConfig::default()
    })
    .expect("simulated servos");
    let events: Receiver<BusEvent> = sim.handle().subscribe();
    let ap_port = ports::free_udp_port();
    let gcs_port = ports::free_udp_port();
    let dir = std::env::temp_dir().join(format!("lj9da-e2e-{}-{}", std::process::id(), ap_port));
    std::fs::create_dir_all(&dir).unwrap();
    let cfg_path = dir.join("bench.toml");
    let text = mapping(case, &sim.path().display().to_string(), ap_port, gcs_port);
    std::fs::write(&cfg_path, &text).unwrap();
    // The servo whose goals mark each port's messages: servo 1 on port 0; on port 1 the last.
    let marked = if case.ports == 2 && case.port1_mapped {
        case.servos
    } else {
        1
    };
    let config = Config::parse(&text, "bench").expect("bench mapping");
    let markers = [config.servos[0].clone(), config.servos[marked - 1].clone()];
    let goal_of =
        |port: usize, us: u16| markers[port].map_pwm(us).expect("bench PWM is in range").0;
    // The bridge runs as systemd's child with a watchdog (`$E2E_WATCHDOG_MS`), the bench
    // playing systemd: its notify socket hears the pings.
    let mut systemd = match peer {
        Peer::Bridge => watchdog::timeout().map(|t| Listener::start(&dir, t)),
        Peer::Naive { .. } => None,
    };
    let mut command = match peer {
        Peer::Bridge => match &systemd {
            Some(listener) => listener.command(&dir, &bridge_exe()),
            None => {
                let mut c = Command::new(bridge_exe());
                c.env("RUST_LOG", "warn");
                c
            }
        },
        Peer::Naive { python, script } => {
            let mut c = Command::new(python);
            c.arg(script);
            c
        }
    };
    let mut bridge: Child = command
        .args(["run", "--config"])
        .arg(&cfg_path)
        .stdout(Stdio::null())
        .stderr(if systemd.is_some() {
            Stdio::piped()
        } else {
            Stdio::inherit()
        })
        .spawn()
        .unwrap_or_else(|e| panic!("{} process: {e}", peer.name()));
    // Under the watchdog's `sh -c … exec` this is the shell's pid, the bridge's once it has
    // exec'd (long before the warm-up ends).
    let pid = bridge.id();
    if let (Some(listener), Some(stderr)) = (systemd.as_mut(), bridge.stderr.take()) {
        listener.watch_log(stderr);
    }

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
    // Warm up: let every servo come online and take its first (soft-start) goal. At least 3 s,
    // and 1 s after servo 1's first goal reached the wire: the naive peer's Python takes a
    // second or more to start on a busy machine, and the run's sends must find it listening.
    let warm = Instant::now();
    let mut first_goal: Option<Instant> = None;
    while warm.elapsed() < Duration::from_secs(3)
        || first_goal.is_none_or(|at| at.elapsed() < Duration::from_secs(1))
    {
        assert!(
            warm.elapsed() < WARM_UP_LIMIT,
            "the {} process put no goal on the wire in {WARM_UP_LIMIT:?}",
            peer.name()
        );
        let _ = ap.send(&header, &heartbeat);
        for port in 0..case.ports {
            let _ = ap.send(&header, &outputs(case.servos, marked, port, 0));
        }
        std::thread::sleep(Duration::from_millis(50));
        while first_goal.is_none()
            && let Ok(e) = events.try_recv()
        {
            if let BusEvent::Packet(p) = e
                && p.packet.goal_positions().iter().any(|(id, _)| *id == 1)
            {
                first_goal = Some(Instant::now());
            }
        }
    }
    if case.scenario == Scenario::Garbled {
        sim.handle()
            .inject(Some(1), Fault::CorruptReplies { probability: 0.2 });
    }
    while events.try_recv().is_ok() {}
    let (cpu0, _) = cpu_and_rss(pid);
    let split0 = thread_split(pid);
    let t_start = Instant::now();
    let steal0 = steal_s();
    let probe = Probe::start();

    // The autopilot is another computer: its sends keep their time whatever the companion
    // computer runs. The sender asks for a real-time priority above the bridge's and the
    // simulator's (where granted; the send instants are measured either way).
    let _ = lj9da_realtime::request_fifo(SENDER_PRIORITY);
    let schedule = schedule(case, seconds, Instant::now() + Duration::from_millis(20));
    let mut sends: Vec<Send> = Vec::with_capacity(schedule.len());
    for (k, m) in schedule.into_iter().enumerate() {
        // Sleep to within SEND_SPIN of the send, then spin to it: the autopilot's sends are
        // timed to a few µs, and the sender does not keep a core busy between them (an
        // autopilot does not run on the companion computer; a sender that spun for the whole
        // period would be a CPU hog of the bench's own in every "quiet" case).
        if let Some(sleep) =
            m.at.checked_duration_since(Instant::now())
                .and_then(|left| left.checked_sub(SEND_SPIN))
        {
            std::thread::sleep(sleep);
        }
        while Instant::now() < m.at {
            std::hint::spin_loop();
        }
        if k % (case.rate_hz as usize) == 0 {
            let _ = ap.send(&header, &heartbeat);
        }
        let msg = outputs(case.servos, marked, m.port, m.value);
        let t = Instant::now();
        ap.send(&header, &msg).expect("send");
        // Port 1's messages are measured only where a servo is on it.
        if m.changed && (m.port == 0 || marked != 1) {
            let servo = if m.port == 0 { 1 } else { marked };
            sends.push(Send {
                at: t,
                port: usize::from(m.port),
                goal: goal_of(usize::from(m.port), pwm(servo, m.value, marked)),
                settled: m.settled,
                tick: m.tick,
            });
        }
    }
    std::thread::sleep(Duration::from_millis(300));
    let stalls = probe.stop();
    let run_time = t_start.elapsed().as_secs_f64();
    let steal_ms_per_s = steal0.zip(steal_s()).map(|(a, b)| (b - a) * 1e3 / run_time);
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
    let mut unstalled_us = [Vec::new(), Vec::new()];
    let mut settled_us = Vec::new();
    for (k, m) in sends.iter().enumerate() {
        match carried[k] {
            Some(at) => {
                on_wire += 1;
                let us = at.duration_since(m.at).as_secs_f64() * 1e6;
                latencies_us[m.port].push(us);
                if !beside_stall(&stalls, m.at, at) {
                    unstalled_us[m.port].push(us);
                }
                if m.settled && m.port == 0 {
                    settled_us.push(us);
                }
            }
            None if superseded_flags[k] => superseded += 1,
            None => lost += 1,
        }
    }
    // `E2E_TRACE_LATE=1`: every goal that left more than 1 ms after its message, with the
    // message's send on CLOCK_MONOTONIC (the clock of `perf sched record -k CLOCK_MONOTONIC`)
    // and the last request on the wire before it, to line the goal up with a trace.
    if std::env::var_os("E2E_TRACE_LATE").is_some() {
        let (now, mono) = (Instant::now(), monotonic_now());
        let mono_of = |t: Instant| mono - now.saturating_duration_since(t).as_secs_f64();
        for (k, m) in sends.iter().enumerate() {
            let Some(at) = carried[k] else { continue };
            let late = at.duration_since(m.at);
            if late > Duration::from_millis(1) {
                let last_request = requests.iter().rev().find(|(start, _)| *start <= m.at);
                eprintln!(
                    "late goal: sent {:.6} port {} on wire {:.0} µs later; last request began {:.0} µs before the send{}",
                    mono_of(m.at),
                    m.port,
                    late.as_secs_f64() * 1e6,
                    last_request.map_or(f64::NAN, |(s, _)| m.at.duration_since(*s).as_secs_f64()
                        * 1e6),
                    if beside_stall(&stalls, m.at, at) {
                        "; beside a machine stall"
                    } else {
                        ""
                    },
                );
            }
        }
    }
    // Ticks that carried both ports: one packet, or port 1 behind port 0 by how much.
    // Only ticks whose port 1 message was sent within 0.5 ms of port 0's count: a sender
    // held up between them is not one tick any more.
    let mut port0: std::collections::HashMap<usize, (Instant, Instant)> =
        std::collections::HashMap::new();
    for (k, m) in sends.iter().enumerate() {
        if m.port == 0
            && let Some(at) = carried[k]
        {
            port0.insert(m.tick, (m.at, at));
        }
    }
    let mut port1_lag_us = Vec::new();
    let mut split_sends = 0;
    for (k, m) in sends.iter().enumerate() {
        if m.port == 1
            && let (Some(at1), Some((sent0, at0))) = (carried[k], port0.get(&m.tick))
        {
            if m.at.saturating_duration_since(*sent0) > Duration::from_micros(500) {
                split_sends += 1;
                continue;
            }
            port1_lag_us.push(at1.saturating_duration_since(*at0).as_secs_f64() * 1e6);
        }
    }
    let one_packet_ticks = port1_lag_us.iter().filter(|lag| **lag == 0.0).count();
    // Spells with no request on the wire for more than three poll periods (the mean spacing of
    // position-and-current reads: 5 ms at 4 servos and 50 Hz).
    let spacing = Duration::from_secs_f64(run_time / polls.max(1) as f64);
    let spells: Vec<(Instant, Instant)> = requests
        .windows(2)
        .map(|w| (w[0].0, w[1].0))
        .filter(|(a, b)| b.saturating_duration_since(*a) > spacing * 3)
        .collect();
    let idle_unstalled = spells
        .iter()
        .filter(|(a, b)| !beside_stall(&stalls, *a, *b))
        .count();
    // Bunched: half the gaps between requests are under a third of the poll period.
    let mut gaps: Vec<Duration> = requests
        .windows(2)
        .map(|w| w[1].0.saturating_duration_since(w[0].0))
        .collect();
    gaps.sort();
    let bunched = gaps.get(gaps.len() / 2).is_some_and(|g| *g < spacing / 3);
    stop(&mut bridge);
    let watchdog = systemd.map(Listener::finish);
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
        unstalled_us,
        stalls: stalls.len(),
        steal_ms_per_s,
        stall_max_us: stalls
            .iter()
            .map(|(due, woke)| woke.duration_since(*due).as_secs_f64() * 1e6)
            .fold(0.0, f64::max),
        idle_spells: (!bunched).then_some((spells.len(), idle_unstalled)),
        both_port_ticks: port1_lag_us.len(),
        one_packet_ticks,
        port1_lag_us,
        split_sends,
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
        watchdog,
    }
}

/// CLOCK_MONOTONIC now, in seconds.
fn monotonic_now() -> f64 {
    nix::time::clock_gettime(nix::time::ClockId::CLOCK_MONOTONIC)
        .map_or(f64::NAN, |t| t.tv_sec() as f64 + t.tv_nsec() as f64 * 1e-9)
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
    match watchdog::timeout() {
        Some(t) => println!(
            "watchdog: the bench plays systemd, WATCHDOG_USEC for {} ms (E2E_WATCHDOG_MS; 0: none); the bridge says how often it pings",
            t.as_millis()
        ),
        None => println!("watchdog: none (E2E_WATCHDOG_MS=0)"),
    }
    let peers = peers();
    for peer in &peers {
        if let Peer::Naive { python, script } = peer {
            println!(
                "naive peer: {} {} (each case runs with it and the bridge, back to back)",
                python.display(),
                script.display()
            );
        }
    }
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
            port1_mapped: false,
            scenario: Scenario::Sweep(Jitter::None),
            hogs: 0,
        });
    }
    // Two ports, quiet and beside the hogs: at 115 200 bit/s every scenario, with the last
    // servo on port 1; port 1 sent but mapped to no servo (most planes), whose port 0 goals
    // wait for nothing; and at 460 800 bit/s, the bridge's CPU at the servo's fastest rate.
    let two_ports = [
        (
            115_200,
            true,
            &[
                Scenario::Sweep(Jitter::None),
                Scenario::Sweep(Jitter::Uniform1Ms),
                Scenario::Sweep(Jitter::Late5Pct),
                Scenario::Steps,
                Scenario::PortGap,
                Scenario::RateDrop,
                Scenario::Garbled,
            ][..],
        ),
        (
            115_200,
            false,
            &[Scenario::Sweep(Jitter::None), Scenario::Steps][..],
        ),
        (
            460_800,
            true,
            &[Scenario::Sweep(Jitter::None), Scenario::Steps][..],
        ),
    ];
    for (baud, port1_mapped, scenarios) in two_ports {
        for &scenario in scenarios {
            for h in [0, hogs] {
                cases.push(Case {
                    servos: 4,
                    rate_hz: 50.0,
                    baud,
                    ports: 2,
                    port1_mapped,
                    scenario,
                    hogs: h,
                });
            }
        }
    }
    // Each case runs once per peer, back to back, the order swapped from case to case: both
    // see the same minute of the machine.
    let mut selected = 0;
    for case in cases {
        // `E2E_CASES=4x50,4x50x2pj` runs only those cases (e.g. while profiling one of them).
        if let Ok(only) = std::env::var("E2E_CASES")
            && !only.split(',').any(|c| c.trim() == case.name())
        {
            continue;
        }
        let mut order: Vec<&Peer> = peers.iter().collect();
        if selected % 2 == 1 {
            order.reverse();
        }
        selected += 1;
        let started = clock_time();
        let mut figures = Vec::new();
        for peer in order {
            let hogs = Hogs::start(case.hogs);
            let o = run_case(&case, seconds.max(case.scenario.min_seconds()), peer);
            drop(hogs);
            figures.push((peer, report(&case, peer, o)));
        }
        compare(&case, &figures, &format!("{started}–{}", clock_time()));
        let _ = std::io::stdout().flush();
    }
    println!(
        "latencies in µs, from the autopilot's send to the first byte of the long packet; n/m: not measured (/proc unreadable)"
    );
    println!(
        "machine stalls: wake-ups of the bench's probe threads (one per CPU, sleeping 5 ms at a time like the bus thread) more than 0.5 ms late; idle spells: more than three poll periods with no request on the wire; two-port ticks: both ports' messages sent within 0.5 ms; beside no stall: goals whose wait no machine stall overlapped"
    );
    println!(
        "behind: measured messages sent while a request and its reply held the wire; polls: position-and-current reads per servo per second; s1 ok: servo 1's good replies per second; settled: port 0 p50/p90 of the steps 1 s or more after a disturbance began or ended"
    );
    if let Some(t) = watchdog::timeout() {
        println!(
            "watchdog: READY=1 and WATCHDOG=1 as the bench's notify socket received them (monotonic clock), the process's whole life; gaps from READY=1 to the first ping and between pings; a gap over 1.5 periods (the period as the bridge says it; {} ms timeout) is a look that found a bus not turned, or a late loop",
            t.as_millis()
        );
    }
    println!(
        "targets (4 servos, 50 Hz, two ports): steps behind ≤ 10 % (20 % with hogs), p50/p90 ≤ 250/1000 µs (400/2000 with hogs); p1 p50 ≤ 400 (600); p0 p99 ≤ 1500 (3000), all p99 ≤ 2500 (4000); garbled s1 ok ≥ 70 % of the sweep's; polls ≥ 60 Hz (50); no talk-over, alarm or lost goal"
    );
}

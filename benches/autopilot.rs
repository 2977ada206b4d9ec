//! From the stick to the servo with a real autopilot: ArduPlane SITL (`../shared/sitl`, or
//! `$LJ9DA_ARDUPLANE`) commanding the bridge over MAVLink, SERVO_OUTPUT_RAW at the rate it
//! grants, and over DroneCAN, ArrayCommand at `CAN_D1_UC_SRV_RT`, on SITL's multicast CAN.
//!
//! The bench runs in a network namespace of its own (root), where SITL's CAN group and its
//! fixed TCP port stay. Per case one ArduPlane, with the pages' parameters (`docs/autopilot.md`,
//! `docs/dronecan.md`) and the case's `SCHED_LOOP_RATE` and `CAN_D1_UC_SRV_RT`, in MANUAL; the
//! bench, as a ground station on TCP 5760 (system 255), steps the aileron stick with
//! RC_CHANNELS_OVERRIDE every 0.4–0.6 s (the interval drawn anew each time, so that steps do
//! not keep one phase to the autopilot's loop), resending the held stick every 100 ms. Beside it
//! two `lj9da-bridge run` processes, each with four simulated LJ9DA41s on a pseudo-terminal at
//! 115 200 bit/s and the shipped example's servos and channels: `mavlink`, commanded over
//! MAVLink through a UDP tap at the example's `output_rate_hz` 40 (what stock Plane grants);
//! `dronecan`, commanded over DroneCAN as node 42, its MAVLink link unused. Both follow the
//! same steps of the same autopilot.
//!
//! Per case and path it prints, over the steps that reached the wire:
//! - `msgs/s`: the autopilot's messages that carry the outputs (SERVO_OUTPUT_RAW at the tap,
//!   ArrayCommand at a listener on the CAN group), per second of run;
//! - `autopilot`: from the step's send to the first such message that carries it (the
//!   autopilot's loop, its stream or CAN thread, and the tap's or listener's thread);
//! - `bridge`: from that message to the first byte of the long packet that carries the step, as
//!   the simulated serial device saw it (the listener, a thread of the bench, may take the
//!   datagram after the bridge did: then this is a little under the bridge's true part);
//! - `total`: from the step's send to that first byte (p50, p90, max);
//! - `missed`: steps whose goal never reached the wire before the next step;
//! - the bridge process's CPU time per second of run, % of a core.
//!
//! Cases (`AUTOPILOT_BENCH_CASES`, default `50x100,100x100,200x200`): `LxR` is
//! `SCHED_LOOP_RATE` L, `CAN_D1_UC_SRV_RT` R. Each quiet, then beside two CPU hogs
//! (`AUTOPILOT_BENCH_HOGS=n`, `0` quiet only). `AUTOPILOT_BENCH_SECONDS` per run, default 30.
//! Run: `cargo bench --bench autopilot` (as root).

#[path = "../tests/autopilots/mod.rs"]
#[allow(dead_code)]
mod autopilots;
#[path = "../tests/common/mod.rs"]
#[allow(unused_imports)]
mod common;
#[path = "e2e/machine.rs"]
#[allow(dead_code)]
mod machine;

use autopilots::can::{CanListener, arduplane_on_can};
use autopilots::{Tap, fresh_dir};
use lj9da_sim::{BusEvent, HostPacket, SimBus, SimConfig};
use machine::{Hogs, cpu_and_rss};
use mavlink::dialects::common::*;
use mavlink::{MavConnection, MavHeader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU16, Ordering};
use std::sync::mpsc::Receiver;
use std::time::{Duration, Instant};

/// The node id of the bridge on DroneCAN (the page's).
const NODE_ID: u8 = 42;
/// The servo whose goals the bench follows: the left aileron, output 1, bus id 1.
const SERVO_ID: u8 = 1;
const CHANNEL: usize = 1;
/// The stick's two ends, in µs: each step crosses from one to the other.
const STICK: [u16; 2] = [1200, 1800];
/// A message carries a step when output 1 has moved this far from before the step (µs); a long
/// packet when its goal has moved this far (0.01 mm).
const OUTPUT_MOVED_US: f64 = 50.0;
const GOAL_MOVED: i32 = 200;

type Link = Arc<dyn MavConnection<MavMessage> + Send + Sync>;

/// The MAVLink connection to ArduPlane's SERIAL0 (TCP 5760) as ground station 255.
struct GroundStation {
    link: Link,
    manual: Arc<AtomicBool>,
    stick: Arc<AtomicU16>,
    stop: Arc<AtomicBool>,
    threads: Vec<std::thread::JoinHandle<()>>,
}

const GCS: MavHeader = MavHeader {
    system_id: 255,
    component_id: 190,
    sequence: 0,
};

fn rc_override(stick: u16) -> MavMessage {
    MavMessage::RC_CHANNELS_OVERRIDE(RC_CHANNELS_OVERRIDE_DATA {
        target_system: 1,
        target_component: 1,
        chan1_raw: stick,
        chan2_raw: 1500,
        chan4_raw: 1500,
        ..Default::default()
    })
}

impl GroundStation {
    fn connect() -> GroundStation {
        let deadline = Instant::now() + Duration::from_secs(60);
        let link = loop {
            match mavlink::connect::<MavMessage>("tcpout:127.0.0.1:5760") {
                Ok(link) => break Arc::new(link) as Link,
                Err(e) if Instant::now() < deadline => {
                    let _ = e;
                    std::thread::sleep(Duration::from_millis(200));
                }
                Err(e) => panic!("ArduPlane's TCP 5760: {e}"),
            }
        };
        let (manual, stick, stop) = (
            Arc::new(AtomicBool::new(false)),
            Arc::new(AtomicU16::new(STICK[0])),
            Arc::new(AtomicBool::new(false)),
        );
        let reader = {
            let (link, manual, stop) = (link.clone(), manual.clone(), stop.clone());
            std::thread::spawn(move || {
                while !stop.load(Ordering::Relaxed) {
                    match link.recv() {
                        Ok((h, MavMessage::HEARTBEAT(hb))) if h.system_id == 1 => {
                            // Plane's custom mode 0 is MANUAL.
                            manual.store(hb.custom_mode == 0, Ordering::Relaxed);
                        }
                        Ok(_) => {}
                        Err(_) => std::thread::sleep(Duration::from_millis(5)),
                    }
                }
            })
        };
        let sender = {
            let (link, manual, stick, stop) =
                (link.clone(), manual.clone(), stick.clone(), stop.clone());
            std::thread::spawn(move || {
                let mut tick = 0u32;
                while !stop.load(Ordering::Relaxed) {
                    if tick.is_multiple_of(10) {
                        let _ = link.send(
                            &GCS,
                            &MavMessage::HEARTBEAT(HEARTBEAT_DATA {
                                mavtype: MavType::MAV_TYPE_GCS,
                                autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
                                ..Default::default()
                            }),
                        );
                        if !manual.load(Ordering::Relaxed) {
                            let _ = link.send(
                                &GCS,
                                &MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
                                    target_system: 1,
                                    target_component: 1,
                                    command: MavCmd::MAV_CMD_DO_SET_MODE,
                                    param1: 1.0,
                                    param2: 0.0,
                                    ..Default::default()
                                }),
                            );
                        }
                    }
                    let _ = link.send(&GCS, &rc_override(stick.load(Ordering::Relaxed)));
                    tick += 1;
                    std::thread::sleep(Duration::from_millis(100));
                }
            })
        };
        GroundStation {
            link,
            manual,
            stick,
            stop,
            threads: vec![reader, sender],
        }
    }

    /// Move the stick to `to` now; returns when the message was written.
    fn step(&self, to: u16) -> Instant {
        self.stick.store(to, Ordering::Relaxed);
        self.link
            .send(&GCS, &rc_override(to))
            .expect("RC_CHANNELS_OVERRIDE to ArduPlane");
        Instant::now()
    }
}

impl Drop for GroundStation {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        // The reader is blocked in recv until ArduPlane (killed after this) closes the link.
        for t in self.threads.drain(..) {
            drop(t);
        }
    }
}

/// The shipped example's four servos on one bus, commanded over MAVLink or DroneCAN.
fn mapping(port: &Path, udp: u16, dronecan: bool) -> String {
    let mut s = format!(
        "[mavlink]\nconnection = \"udpin:127.0.0.1:{udp}\"\noutput_rate_hz = 40.0\nfailsafe_timeout_ms = 1000\n\
         [bridge]\non_exit = \"hold\"\ncommands = \"{}\"\n[[bus]]\nname = \"wing\"\nport = \"{}\"\nbaud = 115200\n",
        if dronecan { "dronecan" } else { "mavlink" },
        port.display()
    );
    for (id, channel) in [(1, 1), (2, 5), (3, 2), (4, 4)] {
        s += &format!(
            "[[servo]]\nname = \"s{id}\"\nbus = \"wing\"\nid = {id}\nchannel = {channel}\n"
        );
    }
    if dronecan {
        s += &format!("[dronecan]\ninterface = \"mcast:0\"\nnode_id = {NODE_ID}\n");
    }
    s
}

/// One bridge process and its simulated servos.
struct Bridge {
    name: &'static str,
    child: Child,
    events: Receiver<BusEvent>,
    _sim: SimBus,
    udp: u16,
}

impl Bridge {
    fn start(name: &'static str, dir: &Path, udp: u16, dronecan: bool) -> Bridge {
        let sim = SimBus::spawn_pty(SimConfig {
            ids: (1..=4).collect(),
            baud: 115_200,
            ..SimConfig::default()
        })
        .expect("simulated servos");
        let events = sim.handle().subscribe();
        let path = dir.join(format!("{name}.toml"));
        std::fs::write(&path, mapping(&sim.path(), udp, dronecan)).unwrap();
        let log = std::fs::File::create(dir.join(format!("{name}.log"))).unwrap();
        let child = Command::new(env!("CARGO_BIN_EXE_lj9da-bridge"))
            .args(["run", "--config"])
            .arg(&path)
            .env("RUST_LOG", "info")
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .expect("the bridge process");
        Bridge {
            name,
            child,
            events,
            _sim: sim,
            udp,
        }
    }

    /// The long packets so far: when their first byte came, servo 1's goal.
    fn goals(&self) -> Vec<(Instant, i32)> {
        self.events
            .try_iter()
            .filter_map(|e| match e {
                BusEvent::Packet(p) if matches!(p.packet, HostPacket::Long(_)) => p
                    .packet
                    .goal_positions()
                    .iter()
                    .find(|(id, _)| *id == SERVO_ID)
                    .map(|(_, g)| (p.first_byte_at, i32::from(*g))),
                _ => None,
            })
            .collect()
    }
}

impl Drop for Bridge {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// One path's figures over a run.
#[derive(Default)]
struct Followed {
    autopilot: Vec<f64>,
    bridge: Vec<f64>,
    total: Vec<f64>,
    missed: usize,
}

/// For each step (sent at `at`, the stick from the other end), the first message after it
/// whose output 1 has moved, and the first packet after it whose goal has moved; a step whose
/// packet does not come before the next step is missed.
fn follow(
    steps: &[Instant],
    end: Instant,
    messages: &[(Instant, f64)],
    goals: &[(Instant, i32)],
) -> Followed {
    let mut p = Followed::default();
    for (k, &at) in steps.iter().enumerate() {
        let next = steps.get(k + 1).copied().unwrap_or(end);
        let before_msg = messages.iter().rev().find(|m| m.0 < at).map(|m| m.1);
        let before_goal = goals.iter().rev().find(|g| g.0 < at).map(|g| g.1);
        let (Some(bm), Some(bg)) = (before_msg, before_goal) else {
            p.missed += 1;
            continue;
        };
        let msg = messages
            .iter()
            .find(|m| m.0 >= at && m.0 < next && (m.1 - bm).abs() > OUTPUT_MOVED_US);
        let goal = goals
            .iter()
            .find(|g| g.0 >= at && g.0 < next && (g.1 - bg).abs() > GOAL_MOVED);
        match (msg, goal) {
            (Some(m), Some(g)) => {
                let ms = |d: Duration| d.as_secs_f64() * 1e3;
                p.autopilot.push(ms(m.0 - at));
                // Negative where the listener took the datagram after the bridge's packet.
                p.bridge.push(
                    (g.0.saturating_duration_since(m.0).as_secs_f64()
                        - m.0.saturating_duration_since(g.0).as_secs_f64())
                        * 1e3,
                );
                p.total.push(ms(g.0 - at));
            }
            _ => p.missed += 1,
        }
    }
    p
}

fn quantiles(v: &[f64]) -> String {
    if v.is_empty() {
        return "-".into();
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let q = |f: f64| s[((s.len() - 1) as f64 * f).round() as usize];
    format!("{:.1}/{:.1}/{:.1}", q(0.5), q(0.9), s[s.len() - 1])
}

fn median(v: &[f64]) -> Option<f64> {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    s.get(s.len() / 2).copied()
}

/// Wait until `ready` holds, or panic with `what` after 60 s.
fn wait(what: &str, ready: impl Fn() -> bool) {
    let deadline = Instant::now() + Duration::from_secs(60);
    while !ready() {
        assert!(Instant::now() < deadline, "{what}: not within 60 s");
        std::thread::sleep(Duration::from_millis(100));
    }
}

fn run(loop_hz: u32, srv_rt: u32, hogs: usize, seconds: f64) {
    let dir = fresh_dir(&format!("bench-{loop_hz}x{srv_rt}-{hogs}"));
    let tap_port = common::free_udp_port();
    let tap = Tap::start(tap_port);
    let listener = CanListener::start(NODE_ID, &[]);
    let (ap, _) = arduplane_on_can(
        &dir,
        &format!("SCHED_LOOP_RATE {loop_hz}\nCAN_D1_UC_SRV_RT {srv_rt}\n"),
        tap_port,
    );
    tap.wait_for_autopilot(Duration::from_secs(60), || ap.console());
    let mavlink = Bridge::start("mavlink", &dir, common::free_udp_port(), false);
    tap.to_bridge(mavlink.udp);
    let dronecan = Bridge::start("dronecan", &dir, common::free_udp_port(), true);
    let gcs = GroundStation::connect();
    wait("ArduPlane in MANUAL", || gcs.manual.load(Ordering::Relaxed));
    // Both bridges follow the stick before the run.
    let mut early = [Vec::new(), Vec::new()];
    gcs.step(STICK[1]);
    let warm_from = Instant::now();
    let mut n = 0;
    while warm_from.elapsed() < Duration::from_secs(30) && n < 2 {
        std::thread::sleep(Duration::from_millis(200));
        early[0].extend(mavlink.goals());
        early[1].extend(dronecan.goals());
        n = early.iter().filter(|g| !g.is_empty()).count();
    }
    assert_eq!(
        n,
        2,
        "both bridges' servos moved after ArduPlane's stick (the logs in {})",
        dir.display()
    );
    gcs.step(STICK[0]);
    std::thread::sleep(Duration::from_secs(1));
    let _hogs = (hogs > 0).then(|| Hogs::start(hogs));
    std::thread::sleep(Duration::from_millis(300));

    let pids = [mavlink.child.id(), dronecan.child.id()];
    let cpu0 = pids.map(|p| cpu_and_rss(p).0);
    let from = Instant::now();
    // The goals so far stay: the last of them is the first step's "before".
    let mut goals = [early[0].clone(), early[1].clone()];
    goals[0].extend(mavlink.goals());
    goals[1].extend(dronecan.goals());
    let mut steps = Vec::new();
    let mut k = 1;
    let mut seed = u64::from(loop_hz * 1000 + srv_rt) ^ 0x9e37_79b9_7f4a_7c15;
    while from.elapsed().as_secs_f64() < seconds {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        let pause = 400 + seed % 200;
        std::thread::sleep(Duration::from_millis(pause));
        steps.push(gcs.step(STICK[k % 2]));
        k += 1;
        goals[0].extend(mavlink.goals());
        goals[1].extend(dronecan.goals());
    }
    std::thread::sleep(Duration::from_millis(500));
    let end = Instant::now();
    goals[0].extend(mavlink.goals());
    goals[1].extend(dronecan.goals());
    let cpu1 = pids.map(|p| cpu_and_rss(p).0);
    let run_s = (end - from).as_secs_f64();
    drop(_hogs);

    let outputs: Vec<(Instant, f64)> = tap
        .outputs_since(from - Duration::from_secs(1))
        .iter()
        .map(|t| (t.at, f64::from(t.outputs.servo1_raw)))
        .collect();
    let commands: Vec<(Instant, f64)> = listener
        .commands_since(from - Duration::from_secs(1))
        .iter()
        .filter_map(|h| {
            let c = h
                .commands
                .iter()
                .find(|c| usize::from(c.actuator_id) == CHANNEL)?;
            Some((h.at, f64::from(c.value)))
        })
        .collect();
    let rate =
        |m: &[(Instant, f64)]| m.iter().filter(|x| x.0 >= from && x.0 < end).count() as f64 / run_s;
    let paths = [
        (
            mavlink.name,
            follow(&steps, end, &outputs, &goals[0]),
            rate(&outputs),
        ),
        (
            dronecan.name,
            follow(&steps, end, &commands, &goals[1]),
            rate(&commands),
        ),
    ];
    println!(
        "\n{loop_hz}x{srv_rt} {} (SCHED_LOOP_RATE {loop_hz}, CAN_D1_UC_SRV_RT {srv_rt}, MAVLink asked 40 Hz): {} steps in {run_s:.0} s",
        if hogs > 0 {
            format!("beside {hogs} hogs")
        } else {
            "quiet".into()
        },
        steps.len()
    );
    println!(
        "{:<9} {:>7} {:>22} {:>22} {:>22} {:>7} {:>6}",
        "path",
        "msgs/s",
        "autopilot p50/p90/max",
        "bridge p50/p90/max",
        "total p50/p90/max ms",
        "missed",
        "CPU %"
    );
    for (i, (name, p, hz)) in paths.iter().enumerate() {
        let cpu = match (cpu0[i], cpu1[i]) {
            (Some(a), Some(b)) => format!("{:.2}", (b - a) / run_s * 100.0),
            _ => "n/a".into(),
        };
        println!(
            "{name:<9} {hz:>7.1} {:>22} {:>22} {:>22} {:>7} {cpu:>6}",
            quantiles(&p.autopilot),
            quantiles(&p.bridge),
            quantiles(&p.total),
            p.missed
        );
    }
    if let (Some(m), Some(c)) = (median(&paths[0].1.total), median(&paths[1].1.total)) {
        println!("dronecan / mavlink, total p50: {:.2}", c / m);
    }
    drop(gcs);
    drop(ap);
}

fn main() {
    if std::env::args().any(|a| a == "--list") {
        return;
    }
    if autopilots::arduplane().is_none() {
        println!(
            "autopilot bench NOT RUN: no ArduPlane SITL (../shared/sitl, or $LJ9DA_ARDUPLANE)"
        );
        return;
    }
    if let Err(why) = common::netns::enter() {
        println!("autopilot bench NOT RUN: {why}");
        return;
    }
    let seconds: f64 = std::env::var("AUTOPILOT_BENCH_SECONDS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(30.0);
    let hogs: usize = std::env::var("AUTOPILOT_BENCH_HOGS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(2);
    let cases =
        std::env::var("AUTOPILOT_BENCH_CASES").unwrap_or_else(|_| "50x100,100x100,200x200".into());
    for case in cases.split(',').map(str::trim).filter(|c| !c.is_empty()) {
        let (l, r) = case
            .split_once('x')
            .and_then(|(l, r)| Some((l.parse().ok()?, r.parse().ok()?)))
            .unwrap_or_else(|| {
                panic!("AUTOPILOT_BENCH_CASES: {case:?} is not LOOPxRATE, e.g. 50x100")
            });
        run(l, r, 0, seconds);
        if hogs > 0 {
            run(l, r, hogs, seconds);
        }
    }
}

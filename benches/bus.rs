//! Bus-master benchmark: the real tokio driver over a pseudo-terminal against the simulated
//! LJ9DA41 bus (which keeps wire time), at 115 200 and 460 800 bit/s with 1, 4 and 8 servos,
//! goals changing at 50 Hz and as fast as possible. Prints one table.
//!
//! Every number comes from the simulator's record of the line (host packets with the instant its
//! `read()` returned their first byte; replies with the instants their bytes were complete on the
//! wire), in the same process and on the same clock as the `Instant` taken just before each
//! `set_goal`:
//! - command frames/s, polls/s and pos/s: long packets, 42–59 requests and position-only reads
//!   (registers 42–43, bus time left before a goal too short for a poll) the line carried; reads
//!   of position and current (42–49) are in neither;
//! - telemetry Hz/servo: replies with position and current (42–49 or 42–59) per servo per
//!   second (the slowest servo's rate); the target line also gives the 42–59 rate alone;
//! - wire %: wire time of every host and reply byte over the elapsed time;
//! - limit %: the fraction of the wire-time limit of protocol spec section 8 that the bus master
//!   uses: time the line carries bytes, plus each servo's own turnaround between the end of a
//!   request and the start of its reply (section 8 counts it in a poll's cost); the rest is time
//!   the bus master left the line idle;
//! - →goal idle %: idle line time that ended with a goal frame (at 50 Hz, the line kept free for
//!   a goal that was expected); gap p50: the median idle gap after a reply's last byte, the
//!   host's reaction (the bus thread waking on that byte, the simulator waking on the request);
//! - latency: from `set_goal` to the first byte of the first long packet carrying that goal
//!   (goals replaced before reaching the wire are counted as superseded, not timed). A goal that
//!   arrives while a reply is awaited is "busy": its latency is compared with the time left
//!   until that reply's last byte reached the host ("excess" = latency − that time): its modelled
//!   wire instant, or later when the simulator's thread did not run in time (counted as
//!   "sim late"; a servo or adapter that is slow to answer holds the bus as long). Otherwise it
//!   is "idle". Each goal over the busy-bus bound is checked against the bus thread's late
//!   wake-ups and the simulator's late hand-overs during its wait. Neither sees a pseudo-
//!   terminal that is slow to pass bytes on (the kernel's tty work runs in a worker thread).
//!
//! Goals come as an autopilot message would bring them: every servo's goal in one
//! [`BusHandle::output_message`] call.
//!
//! Run: `cargo bench --bench bus` (about a minute and a half); `BUS_BENCH_FILTER=460800` runs
//! only the rows whose label contains the text; `BUS_BENCH_TRACE=1` prints the line around
//! each goal over the busy-bus bound.

#[path = "bus/table.rs"]
mod table;

use lj9da_bridge::bus::{
    BusConfig, BusHandle, ForceState, Goal, Health, ServoSetup, ShutdownForce, spawn_bus,
};
use lj9da_bridge::protocol::{BaudRate, MmCenti, ServoId};
use lj9da_sim::{BusEvent as SimEvent, HostPacket, SimBus, SimConfig};
use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use table::print_table;

const WARM_UP: Duration = Duration::from_millis(1000);
const WINDOW: Duration = Duration::from_millis(3000);
/// Period of the "as fast as possible" goal source: faster than any bus here can carry frames.
const MAX_RATE_PERIOD: Duration = Duration::from_micros(500);

#[derive(Clone, Copy)]
enum Rate {
    Hz50,
    Max,
}

#[derive(Clone, Copy)]
struct Scenario {
    baud: BaudRate,
    servos: u8,
    rate: Rate,
    /// Telemetry limited to one poll per servo per this interval: an idle bus.
    quiet_telemetry: Option<Duration>,
    /// Position and current read at this rate per servo (a mapping's `telemetry_hz`); `None`:
    /// as often as the bus allows.
    telemetry_hz: Option<f32>,
}

#[derive(Default)]
struct Row {
    label: String,
    frames_s: f64,
    polls_s: f64,
    /// Position-only reads (registers 42–43) per second.
    position_s: f64,
    /// Replies with position and current (registers 42–49 or 42–59) per servo per second,
    /// of the slowest servo.
    telemetry_hz_min: f64,
    /// Replies with temperature and voltage (registers 42–59), of the slowest servo.
    full_hz_min: f64,
    wire_fraction: f64,
    utilisation: f64,
    /// Idle line time that ended with a goal frame, as a fraction of the window.
    before_goals_fraction: f64,
    /// Idle gaps that began with the end of a reply (µs).
    gaps_us: Vec<f64>,
    latencies_us: Vec<f64>,
    idle_us: Vec<f64>,
    /// Duration of the `output_message` calls of idle goals (the write included).
    idle_call_us: Vec<f64>,
    busy_excess_us: Vec<f64>,
    /// Goals set while a request whose reply never came was in flight.
    behind_timeout: u64,
    goals_set: u64,
    goals_on_wire: u64,
    superseded: u64,
    timeouts: u64,
    collisions: u64,
    /// Writes of the simulator toward the host later than its wire model by > 200 µs.
    sim_late: u64,
    /// Wake-ups of the bus thread > 0.5 ms after the instant it slept until.
    late_wakeups: u64,
    /// CPU time the hypervisor gave to others during the window (all CPUs), if known.
    stolen_ms: Option<u64>,
    /// The bus thread's CPU time per transaction (request and reply, or long packet), µs.
    cpu_per_tx_us: f64,
    /// The bus thread's CPU time, % of one core.
    cpu_percent: f64,
    /// The bus thread's wake-ups (voluntary context switches) per transaction.
    wakeups_per_tx: f64,
    /// Busy goals over the bound while the bus thread was woken late.
    over_bus_late: u64,
    /// Busy goals over the bound while the simulator handed bytes over late (and the bus thread
    /// was not late).
    over_sim_late: u64,
}

struct GoalRecord {
    servo: u8,
    value: i16,
    at: Instant,
    /// How long the `output_message` call took (on an idle bus it includes writing the packet).
    call: Duration,
}

/// The bus thread's late wake-ups (the instant it logged one, and how late it was), collected
/// from its debug log by [`LateWakeupLog`].
static LATE_WAKEUPS: Mutex<Vec<(Instant, Duration)>> = Mutex::new(Vec::new());

/// A tracing layer that keeps the bus thread's "woke late" events in [`LATE_WAKEUPS`].
struct LateWakeupLog;

impl<S: tracing::Subscriber> tracing_subscriber::Layer<S> for LateWakeupLog {
    fn enabled(
        &self,
        metadata: &tracing::Metadata<'_>,
        _: tracing_subscriber::layer::Context<'_, S>,
    ) -> bool {
        metadata.target() == "lj9da_bridge::bus::driver"
    }

    fn on_event(&self, event: &tracing::Event<'_>, _: tracing_subscriber::layer::Context<'_, S>) {
        struct LateUs(Option<u64>);
        impl tracing::field::Visit for LateUs {
            fn record_u64(&mut self, field: &tracing::field::Field, value: u64) {
                if field.name() == "late_us" {
                    self.0 = Some(value);
                }
            }
            fn record_debug(&mut self, _: &tracing::field::Field, _: &dyn std::fmt::Debug) {}
        }
        let mut late = LateUs(None);
        event.record(&mut late);
        if let (Some(us), Ok(mut log)) = (late.0, LATE_WAKEUPS.lock()) {
            log.push((Instant::now(), Duration::from_micros(us)));
        }
    }
}

fn main() {
    {
        use tracing_subscriber::layer::SubscriberExt;
        let subscriber = tracing_subscriber::registry().with(LateWakeupLog);
        if tracing::subscriber::set_global_default(subscriber).is_err() {
            eprintln!("late wake-ups of the bus thread will not be attributed");
        }
    }
    let scenarios: Vec<Scenario> = [BaudRate::B115200, BaudRate::B460800]
        .into_iter()
        .flat_map(|baud| {
            [1u8, 4, 8].into_iter().flat_map(move |servos| {
                [Rate::Hz50, Rate::Max]
                    .into_iter()
                    .map(move |rate| Scenario {
                        baud,
                        servos,
                        rate,
                        quiet_telemetry: None,
                        telemetry_hz: None,
                    })
            })
        })
        .chain([BaudRate::B115200, BaudRate::B460800].map(|baud| Scenario {
            baud,
            servos: 4,
            rate: Rate::Hz50,
            quiet_telemetry: None,
            telemetry_hz: Some(50.0),
        }))
        .chain([BaudRate::B115200, BaudRate::B460800].map(|baud| Scenario {
            baud,
            servos: 4,
            rate: Rate::Hz50,
            quiet_telemetry: Some(Duration::from_secs(1)),
            telemetry_hz: None,
        }))
        .collect();

    let runtime = match tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("cannot start a tokio runtime: {e}");
            return;
        }
    };
    // `BUS_BENCH_FILTER=115200` runs only the rows whose label contains it.
    let filter = std::env::var("BUS_BENCH_FILTER").unwrap_or_default();
    let load_before = load_average();
    let wake_cost = sleep_wake_cost();
    // A first run, not reported: the first bus of a process pays for page faults and cold caches.
    let _ = runtime.block_on(run(Scenario {
        baud: BaudRate::B115200,
        servos: 1,
        rate: Rate::Hz50,
        quiet_telemetry: None,
        telemetry_hz: None,
    }));
    let mut rows = Vec::new();
    for s in scenarios.into_iter().filter(|s| label(s).contains(&filter)) {
        match runtime.block_on(run(s)) {
            Ok(row) => {
                eprintln!("done: {}", row.label);
                rows.push(row);
            }
            Err(e) => eprintln!("scenario failed: {e}"),
        }
    }
    print_table(&rows, &load_before, &load_average(), wake_cost);
}

/// The CPU time a thread is charged for one short sleep and its wake-up on this machine (the
/// mean over 400 sleeps of 1 ms, `getrusage(RUSAGE_THREAD)`): a read costs the bus thread at
/// least one such wake-up (for its reply), so this is the floor of its CPU per transaction.
fn sleep_wake_cost() -> Option<Duration> {
    const SLEEPS: u32 = 400;
    std::thread::spawn(|| {
        let cpu = || {
            // SAFETY: `usage` is a valid rusage for getrusage to fill; RUSAGE_THREAD is the caller.
            let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
            (unsafe { libc::getrusage(libc::RUSAGE_THREAD, &mut usage) } == 0).then(|| {
                let time = |t: libc::timeval| {
                    Duration::from_secs(u64::try_from(t.tv_sec).unwrap_or(0))
                        + Duration::from_micros(u64::try_from(t.tv_usec).unwrap_or(0))
                };
                time(usage.ru_utime) + time(usage.ru_stime)
            })
        };
        let before = cpu()?;
        for _ in 0..SLEEPS {
            std::thread::sleep(Duration::from_millis(1));
        }
        Some(cpu()?.saturating_sub(before) / SLEEPS)
    })
    .join()
    .ok()
    .flatten()
}

/// CPU time stolen by the hypervisor so far, all CPUs, in ms (`steal` of `/proc/stat`, in
/// USER_HZ = 100 ticks a second): a virtual CPU that is not run stalls every thread on it.
fn stolen_ms() -> Option<u64> {
    let stat = std::fs::read_to_string("/proc/stat").ok()?;
    let ticks: u64 = stat
        .lines()
        .next()?
        .split_whitespace()
        .nth(8)?
        .parse()
        .ok()?;
    Some(ticks * 10)
}

/// The 1-minute load average: the simulator runs in real time, so other work on the machine
/// shows in the numbers.
fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .ok()
        .and_then(|s| s.split_whitespace().next().map(str::to_string))
        .unwrap_or_else(|| "?".into())
}

fn label(s: &Scenario) -> String {
    format!(
        "{:>6} {} {}",
        s.baud.bits_per_second(),
        s.servos,
        match (s.rate, s.quiet_telemetry, s.telemetry_hz) {
            (_, Some(_), _) => "50 Hz, idle bus".to_string(),
            (_, None, Some(hz)) => format!("50 Hz, telem {hz}"),
            (Rate::Hz50, None, None) => "50 Hz".to_string(),
            (Rate::Max, None, None) => "max".to_string(),
        }
    )
}

fn id(n: u8) -> ServoId {
    ServoId::new(n).unwrap_or_else(|_| unreachable!("ids 1–8"))
}

/// The k-th goal of a servo: a triangle in ±2 mm, every value distinct from its neighbours and
/// unique within 800 goals, so a goal is recognised on the wire by its value.
fn goal_value(k: u64) -> i16 {
    let phase = (k % 800) as i16;
    if phase < 400 {
        phase - 200
    } else {
        600 - phase
    }
}

async fn run(s: Scenario) -> Result<Row, String> {
    let bps = s.baud.bits_per_second();
    let ids: Vec<u8> = (1..=s.servos).collect();
    let sim = SimBus::spawn_pty(SimConfig {
        ids: ids.clone(),
        baud: bps,
        ..SimConfig::default()
    })
    .map_err(|e| format!("simulated bus: {e}"))?;
    let mut cfg = BusConfig::new(
        "bench",
        s.baud,
        ids.iter()
            .map(|&n| ServoSetup::new(id(n), format!("s{n}")))
            .collect(),
    );
    if let Some(interval) = s.quiet_telemetry {
        cfg.telemetry_min_interval = interval;
        cfg.verify_interval = interval;
    }
    if let Some(hz) = s.telemetry_hz {
        cfg.telemetry_min_interval = Duration::from_secs_f32(1.0 / hz);
    }
    let bus = spawn_bus(cfg, sim.path());

    // Start-up: every servo online, force on at 0.
    wait(&bus, |st| {
        st.servos.iter().all(|s| s.health == Health::Online)
    })
    .await?;
    for &n in &ids {
        bus.set_goal(id(n), Goal::Position(MmCenti(goal_value(0))));
    }
    wait(&bus, |st| {
        st.servos.iter().all(|s| s.force == ForceState::On)
    })
    .await?;
    tokio::time::sleep(Duration::from_millis(200)).await;

    let events = sim.handle().subscribe();
    let stop = Arc::new(AtomicBool::new(false));
    let producer = {
        let bus = bus.clone();
        let stop = Arc::clone(&stop);
        let ids = ids.clone();
        let period = match s.rate {
            Rate::Hz50 => Duration::from_millis(20),
            Rate::Max => MAX_RATE_PERIOD,
        };
        std::thread::spawn(move || produce(&bus, &ids, period, &stop))
    };
    tokio::time::sleep(WARM_UP).await;
    let t0 = Instant::now();
    let status0 = bus.status();
    let c0 = status0.counters;
    let steal0 = stolen_ms();
    let stats0 = sim.handle().stats();
    tokio::time::sleep(WINDOW).await;
    let t1 = Instant::now();
    let status1 = bus.status();
    let c1 = status1.counters;
    let steal1 = stolen_ms();
    let stats1 = sim.handle().stats();
    stop.store(true, Ordering::SeqCst);
    let goals = producer
        .join()
        .map_err(|_| "goal producer panicked".to_string())?;
    tokio::time::sleep(Duration::from_millis(50)).await;
    bus.shutdown(ShutdownForce::AsIs).await;
    sim.shutdown();
    let events: Vec<SimEvent> = events.try_iter().collect();

    let secs = (t1 - t0).as_secs_f64();
    let byte_s = 10.0 / f64::from(bps);
    let mut row = Row {
        label: label(&s),
        ..Row::default()
    };
    let in_window = |t: Instant| t >= t0 && t < t1;

    // The line: host packets and replies in the window.
    let mut busy_wire_s = 0.0;
    let byte = Duration::from_secs_f64(byte_s);
    // Intervals the line is in use: host packets, replies, and each servo's turnaround.
    let mut in_use: Vec<(Instant, Instant, LineUse)> = Vec::new();
    let mut last_request_end: HashMap<u8, Instant> = HashMap::new();
    let mut telemetry_per_servo: HashMap<u8, u64> = HashMap::new();
    let mut full_per_servo: HashMap<u8, u64> = HashMap::new();
    let mut longs: Vec<(Instant, Vec<(u8, i16)>)> = Vec::new();
    // (request first byte, id) and (id, reply last byte) for busy/idle classification.
    let mut requests: Vec<(Instant, u8)> = Vec::new();
    let mut replies: Vec<(Instant, u8, Instant)> = Vec::new();
    // The simulator's late writes toward the host: (last byte due, handed over), by due instant.
    let mut handed_late: Vec<(Instant, Instant)> = events
        .iter()
        .filter_map(|e| match e {
            SimEvent::HandedLate { due, at, .. } => Some((*due, *at)),
            _ => None,
        })
        .collect();
    handed_late.sort();
    row.sim_late = handed_late.iter().filter(|(_, at)| in_window(*at)).count() as u64;
    // When a reply's last byte actually reached the host: later than on the modelled wire if the
    // simulator's thread was late with any of its bytes.
    let reply_reached_host = |first: Instant, last: Instant| {
        let from = handed_late.partition_point(|(due, _)| *due < first);
        handed_late[from..]
            .iter()
            .take_while(|(due, _)| *due <= last)
            .map(|(_, at)| *at)
            .fold(last, Instant::max)
    };
    for e in &events {
        match e {
            SimEvent::Packet(p) => {
                if in_window(p.first_byte_at) {
                    busy_wire_s += p.bytes.len() as f64 * byte_s;
                }
                let len = u32::try_from(p.bytes.len()).unwrap_or(u32::MAX);
                let start = p
                    .completed_at
                    .checked_sub(byte * len)
                    .unwrap_or(p.completed_at);
                let what = match p.packet {
                    HostPacket::Long(_) => LineUse::Goals,
                    HostPacket::Short(_) => LineUse::Other,
                };
                in_use.push((start, p.completed_at, what));
                match &p.packet {
                    HostPacket::Long(_) => {
                        if in_window(p.first_byte_at) {
                            row.frames_s += 1.0;
                        }
                        longs.push((p.first_byte_at, p.packet.goal_positions()));
                    }
                    HostPacket::Short(sp) => {
                        if sp.flag & 0x0F == 0x09 && in_window(p.first_byte_at) {
                            row.polls_s += 1.0;
                        }
                        if sp.flag & 0x0F == 0x0F
                            && sp.address == 0x2A
                            && sp.length == 2
                            && in_window(p.first_byte_at)
                        {
                            row.position_s += 1.0;
                        }
                        if sp.flag & 0x0F != 0 {
                            requests.push((p.first_byte_at, sp.id));
                            last_request_end.insert(sp.id, p.completed_at);
                        }
                    }
                }
            }
            SimEvent::Reply(r) => {
                replies.push((
                    r.first_byte_at,
                    r.id,
                    reply_reached_host(r.first_byte_at, r.last_byte_at),
                ));
                let start = r.first_byte_at.checked_sub(byte).unwrap_or(r.first_byte_at);
                in_use.push((start, r.last_byte_at, LineUse::Reply));
                if let Some(request_end) = last_request_end.remove(&r.id)
                    && request_end <= start
                {
                    in_use.push((request_end, start, LineUse::Other));
                }
                if in_window(r.first_byte_at) {
                    busy_wire_s += r.bytes.len() as f64 * byte_s;
                    if r.bytes.get(4) == Some(&0x2A) && matches!(r.bytes.len(), 16 | 26) {
                        *telemetry_per_servo.entry(r.id).or_default() += 1;
                    }
                    if r.bytes.get(4) == Some(&0x2A) && r.bytes.len() == 26 {
                        *full_per_servo.entry(r.id).or_default() += 1;
                    }
                }
            }
            _ => {}
        }
    }
    row.frames_s /= secs;
    row.polls_s /= secs;
    row.position_s /= secs;
    row.wire_fraction = busy_wire_s / secs;
    let line = line_within(&mut in_use, t0, t1);
    row.utilisation = line.in_use.as_secs_f64() / secs;
    row.before_goals_fraction = line.idle_before_goals.as_secs_f64() / secs;
    row.gaps_us = line
        .gaps_after_replies
        .iter()
        .map(|d| d.as_secs_f64() * 1e6)
        .collect();
    row.telemetry_hz_min = ids
        .iter()
        .map(|n| telemetry_per_servo.get(n).copied().unwrap_or(0) as f64 / secs)
        .fold(f64::INFINITY, f64::min);
    row.full_hz_min = ids
        .iter()
        .map(|n| full_per_servo.get(n).copied().unwrap_or(0) as f64 / secs)
        .fold(f64::INFINITY, f64::min);

    let late_wakeups: Vec<(Instant, Duration)> = LATE_WAKEUPS
        .lock()
        .map(|mut log| std::mem::take(&mut *log))
        .unwrap_or_default();

    let mut traced_at = None;

    // Latency: each goal set in the window to the first long packet carrying it.
    let mut by_servo_value: HashMap<(u8, i16), Vec<usize>> = HashMap::new();
    for (i, g) in goals.iter().enumerate() {
        by_servo_value
            .entry((g.servo, g.value))
            .or_default()
            .push(i);
    }
    let mut first_on_wire: Vec<Option<Instant>> = vec![None; goals.len()];
    for (at, entries) in &longs {
        for &(vid, value) in entries {
            let Some(candidates) = by_servo_value.get(&(vid, value)) else {
                continue;
            };
            // The newest goal with this value set before the packet's first byte.
            if let Some(&i) = candidates.iter().rev().find(|&&i| goals[i].at < *at)
                && first_on_wire[i].is_none()
            {
                first_on_wire[i] = Some(*at);
            }
        }
    }
    for (i, g) in goals.iter().enumerate() {
        if !in_window(g.at) {
            continue;
        }
        row.goals_set += 1;
        let Some(first) = first_on_wire[i] else {
            continue;
        };
        row.goals_on_wire += 1;
        let latency = first.saturating_duration_since(g.at);
        let us = latency.as_secs_f64() * 1e6;
        row.latencies_us.push(us);
        // Was a reply awaited when the goal was set? The newest request read before it, and
        // the end of its reply (a reply belongs to a request if it starts before the next one).
        let i = requests.partition_point(|(at, _)| *at <= g.at);
        let awaited = i.checked_sub(1).map(|i| {
            let (req_at, rid) = requests[i];
            let next = requests.get(i + 1).map(|r| r.0);
            let from = replies.partition_point(|(first, _, _)| *first <= req_at);
            let reply = replies[from..]
                .iter()
                .take_while(|(first, _, _)| next.is_none_or(|n| *first < n))
                .find(|(_, id, _)| *id == rid)
                .map(|(_, _, last)| *last);
            (req_at, reply)
        });
        match awaited {
            Some((_, Some(end))) if end > g.at => {
                let remaining = end.saturating_duration_since(g.at).as_secs_f64() * 1e6;
                row.busy_excess_us.push(us - remaining);
                if us - remaining > 500.0 {
                    let overlaps = |from: Instant, to: Instant| from < first && to > g.at;
                    if late_wakeups
                        .iter()
                        .any(|&(at, late)| overlaps(at.checked_sub(late).unwrap_or(at), at))
                    {
                        row.over_bus_late += 1;
                    } else if handed_late.iter().any(|&(due, at)| overlaps(due, at)) {
                        row.over_sim_late += 1;
                    }
                    // One trace per `output_message` call (its goals share the instants).
                    if std::env::var_os("BUS_BENCH_TRACE").is_some()
                        && traced_at.replace(g.at) != Some(g.at)
                    {
                        trace_goal(&events, &late_wakeups, g.at, first, us - remaining);
                    }
                }
            }
            Some((req_at, None)) if g.at < req_at + Duration::from_millis(20) => {
                row.behind_timeout += 1;
            }
            _ => {
                row.idle_us.push(us);
                row.idle_call_us.push(g.call.as_secs_f64() * 1e6);
            }
        }
    }
    row.superseded = c1.goals_superseded - c0.goals_superseded;
    row.timeouts = c1.timeouts - c0.timeouts;
    row.collisions = stats1.collisions - stats0.collisions;
    row.late_wakeups = c1.late_wakeups - c0.late_wakeups;
    let transactions = |c: &lj9da_bridge::bus::BusCounters| {
        c.polls + c.motion_polls + c.position_polls + c.other_requests + c.command_frames
    };
    let cpu = status1.thread.cpu.saturating_sub(status0.thread.cpu);
    let txs = (transactions(&c1) - transactions(&c0)).max(1) as f64;
    row.cpu_per_tx_us = cpu.as_secs_f64() * 1e6 / txs;
    row.wakeups_per_tx = status1
        .thread
        .wakeups
        .saturating_sub(status0.thread.wakeups) as f64
        / txs;
    row.cpu_percent = cpu.as_secs_f64() * 100.0 / (t1 - t0).as_secs_f64();
    row.stolen_ms = steal0.zip(steal1).map(|(a, b)| b.saturating_sub(a));
    Ok(row)
}

/// What a stretch of line time was used for.
#[derive(Clone, Copy, PartialEq, Eq)]
enum LineUse {
    /// A long packet (goal frame).
    Goals,
    /// A reply.
    Reply,
    /// A request, or a servo's turnaround between a request and its reply.
    Other,
}

/// Print the line around one goal over the busy-bus bound (`BUS_BENCH_TRACE=1`): µs from
/// the goal's `output_message` call.
fn trace_goal(
    events: &[SimEvent],
    late_wakeups: &[(Instant, Duration)],
    set_at: Instant,
    on_wire: Instant,
    excess_us: f64,
) {
    let rel = |t: Instant| {
        if t >= set_at {
            (t - set_at).as_secs_f64() * 1e6
        } else {
            -(set_at - t).as_secs_f64() * 1e6
        }
    };
    eprintln!(
        "slow goal: excess {excess_us:.0} µs, on the wire after {:.0} µs",
        rel(on_wire)
    );
    let from = set_at
        .checked_sub(Duration::from_millis(4))
        .unwrap_or(set_at);
    let shown = |at: Instant| at >= from && at <= on_wire + Duration::from_millis(1);
    let mut lines: Vec<(f64, String)> = late_wakeups
        .iter()
        .filter(|(at, _)| shown(*at))
        .map(|(at, late)| {
            (
                rel(*at),
                format!("bus thread ran, {} µs late", late.as_micros()),
            )
        })
        .collect();
    for e in events {
        let (at, what) = match e {
            SimEvent::Packet(p) => (
                p.first_byte_at,
                format!(
                    "host packet read by the simulator, {} bytes, complete {:.0}{}",
                    p.bytes.len(),
                    rel(p.completed_at),
                    if p.collided { " COLLIDED" } else { "" }
                ),
            ),
            SimEvent::Reply(r) => (
                r.first_byte_at,
                format!(
                    "reply from servo {}, {} bytes, last byte {:.0}",
                    r.id,
                    r.bytes.len(),
                    rel(r.last_byte_at)
                ),
            ),
            SimEvent::HandedLate { due, at, bytes } => (
                *due,
                format!(
                    "simulator late: {bytes} bytes handed over at {:.0}",
                    rel(*at)
                ),
            ),
            SimEvent::Collision { at, id } => (*at, format!("collision with servo {id}'s reply")),
            other => (set_at, format!("{other:?}")),
        };
        if shown(at) {
            lines.push((rel(at), what));
        }
    }
    lines.sort_by(|a, b| a.0.total_cmp(&b.0));
    for (t, l) in lines {
        eprintln!("  {t:>8.0} {l}");
    }
}

/// The line in `[t0, t1)`: the time it was in use, and its idle gaps.
struct LineTime {
    in_use: Duration,
    /// Idle time that ended with a goal frame.
    idle_before_goals: Duration,
    /// Each idle gap that began with the end of a reply: the host's reaction to it.
    gaps_after_replies: Vec<Duration>,
}

fn line_within(
    intervals: &mut [(Instant, Instant, LineUse)],
    t0: Instant,
    t1: Instant,
) -> LineTime {
    intervals.sort_by_key(|&(start, _, _)| start);
    let mut line = LineTime {
        in_use: Duration::ZERO,
        idle_before_goals: Duration::ZERO,
        gaps_after_replies: Vec::new(),
    };
    let mut covered_to = t0;
    let mut covered_by = None;
    for &(start, end, what) in intervals.iter() {
        if start > covered_to && start < t1 && covered_to > t0 {
            let gap = start - covered_to;
            if what == LineUse::Goals {
                line.idle_before_goals += gap;
            }
            if covered_by == Some(LineUse::Reply) {
                line.gaps_after_replies.push(gap);
            }
        }
        let start = start.max(covered_to);
        let end = end.min(t1);
        if end > start {
            line.in_use += end - start;
            covered_to = end;
            covered_by = Some(what);
        }
    }
    line
}

/// Set a new goal for every servo each `period`, until `stop`; returns what was set and when.
fn produce(bus: &BusHandle, ids: &[u8], period: Duration, stop: &AtomicBool) -> Vec<GoalRecord> {
    let mut out = Vec::new();
    let mut next = Instant::now();
    let mut k = 1u64;
    while !stop.load(Ordering::SeqCst) {
        // One autopilot message: every servo's goal in one call.
        let value = goal_value(k);
        let at = Instant::now();
        bus.output_message(ids.iter().map(|&n| (id(n), Goal::Position(MmCenti(value)))));
        let call = at.elapsed();
        for &n in ids {
            out.push(GoalRecord {
                servo: n,
                value,
                at,
                call,
            });
        }
        k += 1;
        next += period;
        let now = Instant::now();
        if next > now {
            std::thread::sleep(next - now);
        } else {
            next = now;
        }
    }
    out
}

async fn wait(
    bus: &BusHandle,
    done: impl Fn(&lj9da_bridge::bus::BusStatus) -> bool,
) -> Result<(), String> {
    let deadline = Instant::now() + Duration::from_secs(10);
    while Instant::now() < deadline {
        if done(&bus.status()) {
            return Ok(());
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    Err(format!("bus did not start: {:#?}", bus.status()))
}

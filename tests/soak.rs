//! Fault soak: the whole chain (simulated servos on a real pty behind a stable symlink, the
//! bridge in this process, the test playing the autopilot over UDP, a ground station) while
//! faults are injected in turn and together: corrupted and dropped replies, an echoing
//! adapter, a servo unplugged and back, a stalled rod, overheating, the autopilot stream
//! stopping and resuming, MAVLink garbage and a flood, the serial device disappearing and
//! reappearing, and several of them at once.
//!
//! Asserted after every fault: no panic anywhere in the process, every servo online again
//! within [`RECOVERY`] of the fault's end, every goal the autopilot sends afterwards reaching
//! its servo (a long packet the servo acted on, and its goal register), the fault announced
//! to the ground station with its exact STATUSTEXT and severity (and nothing worse than a
//! NOTICE that the fault does not explain), and, in a long soak, the process's memory flat.
//! How fast goals arrive and how much memory one round takes are reported, not checked: on a
//! shared machine they measure the load as much as the bridge.
//!
//! A missing STATUSTEXT, a servo not back or a goal not reaching its servo fails at once, with
//! the bridge's view and every STATUSTEXT heard. A wrong or late STATUSTEXT is logged as a
//! violation and the soak goes on, failing at its end with all of them.
//!
//! One round takes about two minutes. `LJ9DA_SOAK_ROUNDS=n` runs n rounds;
//! `LJ9DA_SOAK_SECONDS=s` keeps running rounds until s seconds have passed.

mod common;

use common::mapping::Mapping;
use common::peer::{self, Autopilot, AutopilotOptions};
use common::{Chain, ChainOptions, Heard};
use lj9da_bridge::bus::Health;
use lj9da_bridge::bus::quality;
use lj9da_bridge::runtime::BridgeView;
use lj9da_sim::fault::XorShift64;
use lj9da_sim::{BusEvent, Fault, FaultKind, Force, SimHandle};
use mavlink::dialects::common::*;
use mavlink::{MavHeader, MavlinkVersion};
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::Arc;
use std::sync::atomic::{AtomicI64, AtomicUsize, Ordering};
use std::sync::mpsc::Receiver;
use std::time::{Duration, Instant};
use tokio::sync::watch;

/// Four servos, the elevator's failsafe a position ([`ELEVATOR_FAILSAFE`]); outputs asked for
/// at 50 Hz and missed after 400 ms.
fn mapping() -> Mapping {
    Mapping::four_servos()
        .with(
            "[mavlink]",
            "failsafe_timeout_ms = 400\noutput_rate_hz = 50",
        )
        .with("[telemetry]", "rate_hz = 10")
        .with("[[bus]]", "baud = 115200")
        .servo_with("elevator", "failsafe = 22.0")
}

const NAMES: [&str; 4] = ["aileron_left", "aileron_right", "elevator", "rudder"];
/// The elevator's failsafe position, 0.01 mm (outside the ±15 mm the steps use).
const ELEVATOR_FAILSAFE: i16 = 2200;
/// What the garbage's unknown senders ask for, 0.01 mm: no servo may ever get it.
const FOREIGN_GOAL: i16 = 2000;

/// Every servo online again within this of its fault's end.
const RECOVERY: Duration = Duration::from_secs(8);
/// A goal not on the wire and in its servo within this is stuck, not slowed: a goal waits at
/// most for the transaction on the line, tens of ms even with a missed reply and a retry.
/// Measured beside two CPU hogs on two cores (`benches/README.md`, "The soak's bounds"): at
/// most 37 ms over a round's 81 steps, faults included. 2 s is 55 times that, room for an idle
/// virtual machine's stall; a bridge that no longer moves its servos passes no bound. How fast
/// goals arrive is the summary's report.
const STEP_LIMIT: Duration = Duration::from_secs(2);
const STEPS: usize = 3;
/// The bridge's flood guard holds a STATUSTEXT back this long after the last of its kind
/// (`STATUSTEXT_HOLD_OFF` in `src/mavlink/core.rs`).
const STATUSTEXT_HOLD_OFF: Duration = Duration::from_secs(3);

/// The latest a "degraded" may be heard after the reply faults were cleared: judged over the
/// window that still held faulty replies (it ends within one [`quality::WINDOW`] of the
/// clear), held back by the flood guard, plus 0.5 s for the bus thread and the UDP hop to the
/// ground station. 2 + 3 + 0.5 = 5.5 s.
const LAST_BAD_AFTER_CLEAR: Duration = Duration::from_millis(
    (quality::WINDOW.as_millis() + STATUSTEXT_HOLD_OFF.as_millis() + 500) as u64,
);

/// The growth of the process's resident memory allowed from after warm-up to the end, checked
/// only in a soak run long on purpose (`LJ9DA_SOAK_ROUNDS` above 1 or `LJ9DA_SOAK_SECONDS`):
/// over one round the allocator's and the test harness's own growth is as large as a leak.
const RSS_GROWTH_LIMIT_KIB: u64 = 8 * 1024;

/// The growth of the heap in use (bytes allocated and not freed, counted by [`Counting`])
/// allowed from after warm-up to the quiet end, checked in every run, CI's one round included.
/// Unlike the resident set it does not move with the allocator's arenas and caches, so one
/// round tells. Measured (`benches/README.md`, "The soak's bounds"): +154 KiB over a round,
/// most of it the test's ground station keeping what it heard. A leak of 160 bytes per output
/// message (about 3,200 in a round) passes it.
const HEAP_GROWTH_LIMIT: i64 = 512 * 1024;

/// The heap in use by the whole process, in bytes: every allocation counted in, every free out.
static HEAP_IN_USE: AtomicI64 = AtomicI64::new(0);

/// The system allocator, counting the heap in use.
struct Counting;

// SAFETY: every call is passed on to the system allocator unchanged; only a counter is added.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: the caller's contract, passed on.
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            HEAP_IN_USE.fetch_add(layout.size() as i64, Ordering::Relaxed);
        }
        p
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        // SAFETY: the caller's contract, passed on.
        let p = unsafe { System.alloc_zeroed(layout) };
        if !p.is_null() {
            HEAP_IN_USE.fetch_add(layout.size() as i64, Ordering::Relaxed);
        }
        p
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: the caller's contract, passed on.
        unsafe { System.dealloc(ptr, layout) };
        HEAP_IN_USE.fetch_sub(layout.size() as i64, Ordering::Relaxed);
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: the caller's contract, passed on.
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            HEAP_IN_USE.fetch_add(new_size as i64 - layout.size() as i64, Ordering::Relaxed);
        }
        p
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

const S: fn(u64) -> Duration = Duration::from_secs;
const MS: fn(u64) -> Duration = Duration::from_millis;

/// Panics anywhere in the process (bridge tasks, bus drivers, the simulator's thread).
static PANICS: AtomicUsize = AtomicUsize::new(0);

fn count_panics() {
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        PANICS.fetch_add(1, Ordering::SeqCst);
        default(info);
    }));
}

fn env_number(name: &str) -> Option<u64> {
    std::env::var(name).ok().and_then(|v| v.trim().parse().ok())
}

/// This process's resident set, KiB. The memory check needs it: a /proc that cannot be read
/// fails the soak here, rather than reading as 0 KiB and letting any growth pass.
fn rss_kib() -> u64 {
    const STATUS: &str = "/proc/self/status";
    let status = std::fs::read_to_string(STATUS).unwrap_or_else(|error| {
        panic!(
            "cannot read {STATUS} ({error}): the soak's memory-growth check cannot be made \
             (run it where /proc is mounted and readable)"
        )
    });
    status
        .lines()
        .find(|l| l.starts_with("VmRSS:"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| {
            panic!("no readable VmRSS line in {STATUS}: the memory-growth check cannot be made")
        })
}

/// The PWM value (µs) for a position (0.01 mm, whole mm) under the default 920/1520/2120 law.
fn pwm(centi: i16) -> u16 {
    (1520 + i32::from(centi) * 24 / 100) as u16
}

/// The goals (0.01 mm) of step `n`: whole millimetres within ±15, each servo's differing
/// from its goal of step `n - 1` by at least 7 mm.
fn goals_of(n: u32) -> [i16; 4] {
    std::array::from_fn(|i| (((n * 7 + i as u32 * 5) % 31) as i16 - 15) * 100)
}

fn all_online(view: &BridgeView) -> bool {
    view.servos.len() == 4 && view.servos.iter().all(|s| s.health == Health::Online)
}

fn healths(view: &BridgeView) -> Vec<Health> {
    view.servos.iter().map(|s| s.health).collect()
}

/// A STATUSTEXT without the " (+N)" the flood guard appends when it folded repeats.
fn base_text(text: &str) -> &str {
    if let Some(i) = text.rfind(" (+")
        && text.ends_with(')')
        && text[i + 3..text.len() - 1]
            .chars()
            .all(|c| c.is_ascii_digit())
    {
        return &text[..i];
    }
    text
}

/// The STATUSTEXTs heard at or after `since`, with their arrival.
fn texts_since(gcs: &Heard, since: Instant) -> Vec<(Instant, MavSeverity, String)> {
    gcs.since(since)
        .into_iter()
        .filter_map(|(t, _, m)| match m {
            MavMessage::STATUSTEXT(s) => Some((
                t,
                s.severity,
                s.text.to_str().unwrap_or("<not UTF-8>").to_string(),
            )),
            _ => None,
        })
        .collect()
}

fn short_severity(s: MavSeverity) -> &'static str {
    match s {
        MavSeverity::MAV_SEVERITY_EMERGENCY => "EMERGENCY",
        MavSeverity::MAV_SEVERITY_ALERT => "ALERT",
        MavSeverity::MAV_SEVERITY_CRITICAL => "CRITICAL",
        MavSeverity::MAV_SEVERITY_ERROR => "ERROR",
        MavSeverity::MAV_SEVERITY_WARNING => "WARNING",
        MavSeverity::MAV_SEVERITY_NOTICE => "NOTICE",
        MavSeverity::MAV_SEVERITY_INFO => "INFO",
        MavSeverity::MAV_SEVERITY_DEBUG => "DEBUG",
    }
}

fn is_number(s: &str) -> bool {
    let s = s.strip_prefix('-').unwrap_or(s);
    !s.is_empty() && s.chars().all(|c| c.is_ascii_digit())
}

/// "<name>: temperature alarm; NNC N.Ns ago" (the reading quoted with its age), or
/// "<name>: temperature alarm" when the bridge has no fresh reading.
fn temperature_alarm(name: &'static str) -> impl Fn(&str) -> bool {
    move |t| {
        t.strip_prefix(name)
            .and_then(|t| t.strip_prefix(": temperature alarm"))
            .is_some_and(|rest| rest.is_empty() || is_reading(rest))
    }
}

/// "; NNC N.Ns ago"
fn is_reading(t: &str) -> bool {
    t.strip_prefix("; ")
        .and_then(|r| r.strip_suffix("s ago"))
        .and_then(|r| r.split_once("C "))
        .is_some_and(|(c, age)| is_number(c) && age.parse::<f64>().is_ok())
}

/// "<name>: temperature ok NNC", or "<name>: temperature ok" when the bridge has no reading
/// taken after the event (e.g. right after a power cycle).
fn temperature_ok(name: &'static str) -> impl Fn(&str) -> bool {
    move |t| match t
        .strip_prefix(name)
        .and_then(|t| t.strip_prefix(": temperature ok"))
    {
        Some("") => true,
        Some(rest) => rest
            .strip_prefix(' ')
            .and_then(|t| t.strip_suffix('C'))
            .is_some_and(is_number),
        None => false,
    }
}

/// "<name>: overheat, force off", with the last temperature read and its age when it is
/// fresh: "<name>: overheat, force off; NNC N.Ns ago".
fn overheat(name: &'static str) -> impl Fn(&str) -> bool {
    move |t| {
        let Some(rest) = t
            .strip_prefix(name)
            .and_then(|t| t.strip_prefix(": overheat, force off"))
        else {
            return false;
        };
        rest.is_empty() || is_reading(rest)
    }
}

/// "<name>: degraded, N% replies bad", N above 15 (rounded, so 15 too).
fn degraded(name: &'static str) -> impl Fn(&str) -> bool {
    move |t| {
        t.strip_prefix(name)
            .and_then(|t| t.strip_prefix(": degraded, "))
            .and_then(|t| t.strip_suffix("% replies bad"))
            .is_some_and(|n| n.parse::<u8>().is_ok_and(|n| (15..=100).contains(&n)))
    }
}

fn exactly(expected: String) -> impl Fn(&str) -> bool {
    move |t| t == expected
}

/// [`expect_text`] for a STATUSTEXT that must read exactly `text`.
async fn expect_exact_text(
    chain: &Chain,
    since: Instant,
    severity: MavSeverity,
    text: &str,
    timeout: Duration,
) -> Duration {
    expect_text(chain, since, severity, text, timeout, exactly(text.into())).await
}

/// Wait until `cond` holds, at most `timeout`; on failure panic with `what`, the bridge's view
/// and every STATUSTEXT heard so far. Returns how long it took.
async fn wait_until(
    chain: &Chain,
    what: &str,
    timeout: Duration,
    mut cond: impl FnMut() -> bool,
) -> Duration {
    let start = Instant::now();
    loop {
        if cond() {
            return start.elapsed();
        }
        if start.elapsed() > timeout {
            let texts: Vec<String> = chain
                .gcs
                .statustexts()
                .into_iter()
                .map(|(s, t)| format!("{} {t}", short_severity(s)))
                .collect();
            panic!(
                "timed out after {timeout:?} waiting for {what}\nbridge view: {:#?}\nSTATUSTEXTs heard: {texts:#?}",
                *chain.view.borrow()
            );
        }
        tokio::time::sleep(MS(20)).await;
    }
}

/// Wait for a STATUSTEXT heard at or after `since` that `matches`, and check its severity.
/// Returns when it arrived, counted from `since`.
async fn expect_text(
    chain: &Chain,
    since: Instant,
    severity: MavSeverity,
    what: &str,
    timeout: Duration,
    matches: impl Fn(&str) -> bool,
) -> Duration {
    let find = || {
        texts_since(&chain.gcs, since)
            .into_iter()
            .find(|(_, _, t)| matches(base_text(t)))
    };
    wait_until(
        chain,
        &format!("STATUSTEXT {what:?}"),
        timeout.saturating_sub(since.elapsed()),
        || find().is_some(),
    )
    .await;
    let (at, sev, text) = find().expect("found above");
    assert_eq!(
        sev, severity,
        "STATUSTEXT {text:?} has severity {sev:?}, expected {severity:?}"
    );
    at.saturating_duration_since(since)
}

fn heartbeat(autopilot: MavAutopilot) -> MavMessage {
    MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        custom_mode: 0,
        mavtype: MavType::MAV_TYPE_FIXED_WING,
        autopilot,
        base_mode: MavModeFlag::empty(),
        system_status: MavState::MAV_STATE_ACTIVE,
        mavlink_version: 3,
    })
}

/// SERVO_OUTPUT_RAW with `goals` on channels 1 to 4.
fn outputs(goals: [i16; 4]) -> MavMessage {
    peer::outputs(&goals.map(pwm))
}

/// The autopilot, played by the test: HEARTBEAT at 1 Hz and SERVO_OUTPUT_RAW at 50 Hz (and at
/// once when the goals change) from system 1, component 1.
async fn autopilot(port: u16, goals: [i16; 4]) -> Autopilot {
    let options = AutopilotOptions {
        heartbeat: heartbeat(MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA),
        ..AutopilotOptions::default()
    };
    let mut ap = Autopilot::connect_with(port, options).await;
    ap.stream(50, outputs(goals));
    ap
}

/// What one phase did, for the log.
struct PhaseLog {
    name: String,
    start: Instant,
    duration: Duration,
    recovery: Option<Duration>,
    texts: Vec<(Instant, MavSeverity, String)>,
    notes: Vec<String>,
}

/// When each servo answered, as the bridge's view showed it (Online, Stale or Starting).
/// Reply quality is judged over windows of [`quality::WINDOW`], only for a servo polled at
/// both ends of one, so a faulty servo that goes lost and comes back makes its announcement
/// legitimately later.
#[derive(Clone, Default)]
struct AnswerLog(Arc<std::sync::Mutex<Vec<Answering>>>);

/// From `.0` on, whether each servo (in view order) answered.
type Answering = (Instant, Vec<bool>);

impl AnswerLog {
    fn watch(mut view: watch::Receiver<BridgeView>) -> AnswerLog {
        let log = AnswerLog::default();
        let writer = log.clone();
        tokio::spawn(async move {
            let mut last: Option<Vec<bool>> = None;
            loop {
                let answering: Vec<bool> = view
                    .borrow_and_update()
                    .servos
                    .iter()
                    .map(|s| matches!(s.health, Health::Online | Health::Stale | Health::Starting))
                    .collect();
                if last.as_ref() != Some(&answering) {
                    writer
                        .0
                        .lock()
                        .unwrap()
                        .push((Instant::now(), answering.clone()));
                    last = Some(answering);
                }
                if view.changed().await.is_err() {
                    break;
                }
            }
        });
        log
    }

    /// The spans within `[from, to]` during which any of the servos at `indices` did not
    /// answer.
    fn silent_spans(
        &self,
        indices: &[usize],
        from: Instant,
        to: Instant,
    ) -> Vec<(Instant, Instant)> {
        let log = self.0.lock().unwrap();
        let mut spans = Vec::new();
        let mut silent_since: Option<Instant> = None;
        for (at, answering) in log.iter() {
            let silent = indices
                .iter()
                .any(|&i| !answering.get(i).copied().unwrap_or(false));
            match (silent, silent_since) {
                (true, None) => silent_since = Some((*at).max(from)),
                (false, Some(since)) => {
                    if *at > from && since < to {
                        spans.push((since, (*at).min(to)));
                    }
                    silent_since = None;
                }
                _ => {}
            }
        }
        if let Some(since) = silent_since
            && since < to
        {
            spans.push((since, to));
        }
        spans
    }
}

struct Soak {
    chain: Chain,
    sim: SimHandle,
    ap: Autopilot,
    started: Instant,
    /// The step counter behind [`goals_of`].
    n: u32,
    goals: [i16; 4],
    log: Vec<PhaseLog>,
    rss: Vec<(String, u64)>,
    /// The heap in use at each of `rss`'s samples, bytes.
    heap: Vec<i64>,
    step_latencies: Vec<Duration>,
    round: u64,
    /// Wrong STATUSTEXTs: the soak goes on and fails at the end with all of them.
    violations: Vec<String>,
    answers: AnswerLog,
}

impl Soak {
    fn name_of(&self, phase: &str) -> String {
        format!("r{} {phase}", self.round)
    }

    /// Send the next goals and wait until each servo acted on a long packet carrying its goal
    /// and holds it in its goal register.
    async fn step(&mut self, bound: Duration) -> Duration {
        self.n += 1;
        let goals = goals_of(self.n);
        self.send_and_check(goals, bound, "step").await
    }

    async fn send_and_check(&mut self, goals: [i16; 4], bound: Duration, what: &str) -> Duration {
        let events = self.sim.subscribe();
        let start = Instant::now();
        self.goals = goals;
        self.ap.set(outputs(goals));
        let took = self.reached(&events, goals, start, bound, what).await;
        self.step_latencies.push(took);
        took
    }

    /// Wait until `goals` reached every servo (see [`Soak::step`]).
    async fn reached(
        &self,
        events: &Receiver<BusEvent>,
        goals: [i16; 4],
        start: Instant,
        bound: Duration,
        what: &str,
    ) -> Duration {
        let mut missing: Vec<(u8, i16)> = (1..=4u8).zip(goals).collect();
        loop {
            while let Ok(event) = events.try_recv() {
                if let BusEvent::Packet(p) = event
                    && p.packet.is_long()
                {
                    for (id, goal) in p.packet.goal_positions() {
                        if p.acted.contains(&id) {
                            missing.retain(|m| *m != (id, goal));
                        }
                    }
                }
            }
            let registers: Vec<i16> = (1..=4u8)
                .map(|id| {
                    self.sim
                        .snapshot(id)
                        .map_or(i16::MIN, |s| (s.goal_mm * 100.0).round() as i16)
                })
                .collect();
            if missing.is_empty() && registers == goals {
                return start.elapsed();
            }
            if start.elapsed() > bound {
                panic!(
                    "{what}: goals {goals:?} (0.01 mm) not on the servos within {bound:?}: no long packet \
                     acted on for (id, goal) {missing:?}; goal registers {registers:?}\nhealth: {:?}\n\
                     snapshots: {:#?}",
                    healths(&self.chain.view.borrow()),
                    self.sim.snapshots()
                );
            }
            tokio::time::sleep(MS(5)).await;
        }
    }

    async fn steps(&mut self, bound: Duration) {
        for _ in 0..STEPS {
            self.step(bound).await;
        }
    }

    /// Every servo online again; returns how long that took.
    async fn all_online(&self, what: &str) -> Duration {
        let view = self.chain.view.clone();
        wait_until(&self.chain, what, RECOVERY, || all_online(&view.borrow())).await
    }

    fn sample_rss(&mut self, label: String) {
        self.heap.push(HEAP_IN_USE.load(Ordering::Relaxed));
        self.rss.push((label, rss_kib()));
    }

    /// Close a phase: no panic so far, the bridge still running, nothing worse than a NOTICE
    /// heard that the phase does not explain; log it and sample the memory.
    fn finish(
        &mut self,
        name: String,
        start: Instant,
        recovery: Option<Duration>,
        explained: &[&dyn Fn(&str) -> bool],
        notes: Vec<String>,
    ) {
        assert_eq!(PANICS.load(Ordering::SeqCst), 0, "a panic during {name}");
        assert!(
            self.chain.bridge_running(),
            "the bridge stopped during {name}"
        );
        let texts = texts_since(&self.chain.gcs, start);
        let unexplained: Vec<_> = texts
            .iter()
            .filter(|(_, s, t)| {
                (*s as u32) <= MavSeverity::MAV_SEVERITY_WARNING as u32
                    && !explained.iter().any(|e| e(base_text(t)))
            })
            .map(|(_, s, t)| format!("{} {t}", short_severity(*s)))
            .collect();
        let log = PhaseLog {
            name: name.clone(),
            start,
            duration: start.elapsed(),
            recovery,
            texts,
            notes,
        };
        print_phase(&log, self.started);
        self.log.push(log);
        self.sample_rss(name.clone());
        if !unexplained.is_empty() {
            self.violation(format!(
                "{name}: STATUSTEXTs the fault does not explain: {unexplained:?}"
            ));
        }
    }

    /// A servo's reply faults (30 % of its requests bad, degraded above 15 %) are judged over
    /// windows of [`quality::WINDOW`] (2 s): announced within two of them (the first may hold
    /// only part of the fault, the second holds nothing else), plus 0.5 s for the bus thread
    /// and the UDP hop. A window counts only for a servo polled at both of its ends: every
    /// span in which the `faulty` servo (view index) did not answer delays the announcement by
    /// its own length and up to two windows (the one it ends and the one it starts), and is
    /// allowed for. Not a load allowance: the bridge's rule.
    fn detected_in_time(&mut self, name: &str, start: Instant, after: Duration, faulty: &[usize]) {
        let window = quality::WINDOW;
        let silent = self.answers.silent_spans(faulty, start, start + after);
        let allowed = window * 2
            + MS(500)
            + silent
                .iter()
                .map(|(from, to)| to.saturating_duration_since(*from) + window * 2)
                .sum::<Duration>();
        if after > allowed {
            let spans: Vec<String> = silent
                .iter()
                .map(|(from, to)| {
                    format!(
                        "{:.2}–{:.2} s",
                        from.saturating_duration_since(start).as_secs_f64(),
                        to.saturating_duration_since(start).as_secs_f64()
                    )
                })
                .collect();
            self.violation(format!(
                "{name}: 'degraded' only {:.2} s after the reply faults began (expected within \
                 {:.2} s: two windows and 0.5 s, plus the faulty servo's silent spans {spans:?} \
                 and two windows for each)",
                after.as_secs_f64(),
                allowed.as_secs_f64()
            ));
        }
    }

    /// A wrong STATUSTEXT: logged now, the soak fails at its end.
    fn violation(&mut self, what: String) {
        println!("[soak] VIOLATION: {what}");
        self.violations.push(what);
    }

    /// After reply faults of servo `servo` injected at `start` and cleared at `cleared`: no
    /// "replies ok" while they were on (its share of bad replies never fell below 5 % then),
    /// and, once any judgement made over a window that still held faulty replies can have been
    /// sent (a window, 2 s, plus the flood guard's hold-off, 3 s: a wait, not a bound), the
    /// last word is "replies ok", or "servo lost" (a lost servo's reply quality goes with it;
    /// "servo back" is checked apart). After the clear the servo recovers once: no "degraded"
    /// follows a "replies ok" (when a text arrives is the machine's; their order is the
    /// bridge's).
    async fn replies_recovered(
        &mut self,
        name: &str,
        servo: &'static str,
        start: Instant,
        cleared: Instant,
    ) -> Duration {
        let gcs = self.chain.gcs.clone();
        let ok = format!("{servo}: replies ok");
        let lost = format!("{servo}: servo lost");
        let is_degraded = degraded(servo);
        let last_word = || {
            texts_since(&gcs, start).into_iter().rfind(|(_, _, t)| {
                let t = base_text(t);
                is_degraded(t) || t == ok || t == lost
            })
        };
        wait_until(
            &self.chain,
            &format!("'{ok}' as the last word"),
            S(15),
            || {
                cleared.elapsed() >= LAST_BAD_AFTER_CLEAR
                    && last_word().is_some_and(|(_, s, t)| {
                        (s == MavSeverity::MAV_SEVERITY_INFO && t == ok) || t == lost
                    })
            },
        )
        .await;
        let texts = texts_since(&self.chain.gcs, start);
        for (at, _, text) in &texts {
            if base_text(text) == ok && *at < cleared {
                self.violation(format!(
                    "{name}: {text:?} heard {:.2} s into the phase, while the reply faults were still injected (cleared at {:.2} s)",
                    at.saturating_duration_since(start).as_secs_f64(),
                    cleared.saturating_duration_since(start).as_secs_f64()
                ));
            }
        }
        let mut recovered_at = None;
        for (at, _, text) in texts.iter().filter(|(at, _, _)| *at >= cleared) {
            let t = base_text(text);
            if t == ok {
                recovered_at.get_or_insert(*at);
            } else if let Some(ok_at) = recovered_at
                && is_degraded(t)
            {
                self.violation(format!(
                    "{name}: {text:?} heard {:.2} s after the reply faults were cleared, after \
                     'replies ok' at {:.2} s: degraded again with no fault",
                    at.saturating_duration_since(cleared).as_secs_f64(),
                    ok_at.saturating_duration_since(cleared).as_secs_f64()
                ));
            }
        }
        texts
            .iter()
            .find(|(at, _, t)| *at >= cleared && base_text(t) == ok)
            .map_or(Duration::ZERO, |(at, _, _)| {
                at.saturating_duration_since(cleared)
            })
    }

    // ----- the phases -----

    /// (1) Corrupted replies from servo 1 and dropped replies from servo 2.
    async fn reply_faults(&mut self) {
        let name = self.name_of("1 corrupted+dropped replies");
        let start = Instant::now();
        assert!(
            self.sim
                .inject(Some(1), Fault::CorruptReplies { probability: 0.3 })
        );
        assert!(
            self.sim
                .inject(Some(2), Fault::DropReplies { probability: 0.3 })
        );
        // The servos stay usable: goals reach them while their replies go bad.
        for _ in 0..STEPS {
            self.step(STEP_LIMIT).await;
        }
        // Servos 1 and 2 (view indices 0 and 1) are the ones with bad replies: each is
        // degraded, the other two are not.
        let mut bad = Vec::new();
        for (index, servo) in [(0, NAMES[0]), (1, NAMES[1])] {
            let after = expect_text(
                &self.chain,
                start,
                MavSeverity::MAV_SEVERITY_WARNING,
                &format!("{servo}: degraded, N% replies bad"),
                // Long enough for detected_in_time to judge a late announcement, not to hide it.
                S(40),
                degraded(servo),
            )
            .await;
            self.detected_in_time(&name, start, after, &[index]);
            bad.push(after);
        }
        let hold = S(5).saturating_sub(start.elapsed());
        tokio::time::sleep(hold).await;
        let stats = self.sim.stats();
        assert!(self.sim.clear(Some(1), FaultKind::CorruptReplies));
        assert!(self.sim.clear(Some(2), FaultKind::DropReplies));
        let cleared = Instant::now();
        let recovery = self
            .all_online("every servo online after the reply faults")
            .await;
        let mut ok = Vec::new();
        for servo in [NAMES[0], NAMES[1]] {
            ok.push(self.replies_recovered(&name, servo, start, cleared).await);
        }
        self.steps(STEP_LIMIT).await;
        let flapping = |t: &str| {
            [NAMES[0], NAMES[1]]
                .iter()
                .any(|n| t == format!("{n}: servo lost"))
        };
        self.finish(
            name,
            start,
            Some(recovery),
            &[&degraded(NAMES[0]), &degraded(NAMES[1]), &flapping],
            vec![
                format!("'degraded' after {bad:?}, 'replies ok' {ok:?} after clearing"),
                format!(
                    "sim: {} replies corrupted, {} dropped so far",
                    stats.replies_corrupted, stats.replies_dropped
                ),
            ],
        );
    }

    /// (2) An adapter that echoes every byte the bridge sends.
    async fn echo(&mut self) {
        let name = self.name_of("2 echoing adapter");
        let start = Instant::now();
        let echoes_before = self.sim.stats().echo_bytes;
        self.sim.set_echo(true);
        let mut worst = Health::Online;
        let mut n = 0;
        while start.elapsed() < S(5) {
            if n < STEPS {
                self.step(STEP_LIMIT).await;
                n += 1;
            }
            for h in healths(&self.chain.view.borrow()) {
                if h.severity() > worst.severity() {
                    worst = h;
                }
            }
            tokio::time::sleep(MS(20)).await;
        }
        self.sim.set_echo(false);
        let echoed = self.sim.stats().echo_bytes - echoes_before;
        assert!(echoed > 1000, "the adapter echoed only {echoed} bytes");
        assert!(
            worst != Health::Offline,
            "a servo went offline behind an echoing adapter"
        );
        let recovery = self.all_online("every servo online after the echo").await;
        self.steps(STEP_LIMIT).await;
        let lost = texts_since(&self.chain.gcs, start)
            .into_iter()
            .filter(|(_, _, t)| t.contains("servo lost"))
            .count();
        assert_eq!(lost, 0, "servo lost behind an echoing adapter");
        self.finish(
            name,
            start,
            Some(recovery),
            &[],
            vec![format!("{echoed} bytes echoed; worst health {worst:?}")],
        );
    }

    /// (3) Servo 2 unplugged for 3 s, then plugged back in.
    async fn unplug(&mut self) {
        let name = self.name_of("3 servo 2 unplugged");
        let start = Instant::now();
        assert!(self.sim.unplug(2));
        let view = self.chain.view.clone();
        let offline = wait_until(&self.chain, "servo 2 offline", S(5), || {
            view.borrow().servos[1].health == Health::Offline
        })
        .await;
        let lost = expect_exact_text(
            &self.chain,
            start,
            MavSeverity::MAV_SEVERITY_CRITICAL,
            "aileron_right: servo lost",
            S(5),
        )
        .await;
        tokio::time::sleep(S(3).saturating_sub(start.elapsed())).await;
        assert!(self.sim.plug(2));
        let plugged = Instant::now();
        let recovery = self
            .all_online("servo 2 online after being plugged in")
            .await;
        let back = expect_exact_text(
            &self.chain,
            plugged,
            MavSeverity::MAV_SEVERITY_NOTICE,
            "aileron_right: servo back",
            S(6),
        )
        .await;
        self.steps(STEP_LIMIT).await;
        let lost_text = |t: &str| t == "aileron_right: servo lost";
        self.finish(
            name,
            start,
            Some(recovery),
            &[&lost_text],
            vec![format!(
                "offline after {offline:?}, 'servo lost' after {lost:?}, 'servo back' {back:?} after plugging"
            )],
        );
    }

    /// (4) Servo 3's rod blocked while it is commanded to move, then freed.
    async fn stall(&mut self) {
        let name = self.name_of("4 servo 3 stalled");
        let start = Instant::now();
        assert!(self.sim.set_stalled(3, true));
        self.n += 1;
        let goals = goals_of(self.n);
        self.goals = goals;
        self.ap.set(outputs(goals));
        let stalled = expect_exact_text(
            &self.chain,
            start,
            MavSeverity::MAV_SEVERITY_ERROR,
            "elevator: stalled",
            S(4),
        )
        .await;
        // The view is refreshed at most every 50 ms: it may follow the STATUSTEXT a little.
        let view = self.chain.view.clone();
        wait_until(
            &self.chain,
            "the view showing the elevator stalled",
            S(1),
            || view.borrow().servos[2].report.stalled,
        )
        .await;
        tokio::time::sleep(S(1)).await;
        assert!(self.sim.set_stalled(3, false));
        let freed = Instant::now();
        let recovery = self.all_online("every servo online after the stall").await;
        let moving = expect_exact_text(
            &self.chain,
            freed,
            MavSeverity::MAV_SEVERITY_NOTICE,
            "elevator: moving again",
            S(6),
        )
        .await;
        // The freed rod reaches the goal it was blocked from.
        let sim = self.sim.clone();
        let goal = f32::from(goals[2]) / 100.0;
        let arrived = wait_until(&self.chain, "the freed elevator at its goal", S(3), || {
            sim.snapshot(3)
                .is_some_and(|s| (s.position_mm - goal).abs() < 0.1)
        })
        .await;
        self.steps(STEP_LIMIT).await;
        let stalled_text = |t: &str| t == "elevator: stalled";
        self.finish(
            name,
            start,
            Some(recovery),
            &[&stalled_text],
            vec![format!(
                "'stalled' after {stalled:?}, 'moving again' {moving:?} after freeing, at its goal {arrived:?} after"
            )],
        );
    }

    /// (5) Servo 4 overheats (alarm, then error and force off); cooled and power-cycled.
    async fn overheat(&mut self) {
        let name = self.name_of("5 servo 4 overheating");
        let start = Instant::now();
        assert!(self.sim.overheat(4));
        let alarm = expect_text(
            &self.chain,
            start,
            MavSeverity::MAV_SEVERITY_WARNING,
            "rudder: temperature alarm[; NNC N.Ns ago]",
            S(12),
            temperature_alarm("rudder"),
        )
        .await;
        let error = expect_text(
            &self.chain,
            start,
            MavSeverity::MAV_SEVERITY_CRITICAL,
            "rudder: overheat, force off[; NNC N.Ns ago]",
            S(15),
            overheat("rudder"),
        )
        .await;
        // The alarm flag is set at 75 °C (10 °C below the limit): a reading quoted with it
        // that is below 75 °C predates the flag, and then its age must say so (the bridge
        // waits up to 0.2 s for the temperature read after the flag).
        let alarm_text = texts_since(&self.chain.gcs, start)
            .into_iter()
            .find(|(_, _, t)| temperature_alarm("rudder")(base_text(t)))
            .map(|(_, _, t)| t)
            .unwrap_or_default();
        let quoted: Option<(i32, f64)> = base_text(&alarm_text)
            .strip_prefix("rudder: temperature alarm; ")
            .and_then(|r| r.strip_suffix("s ago"))
            .and_then(|r| r.split_once("C "))
            .and_then(|(c, age)| Some((c.parse().ok()?, age.parse().ok()?)));
        if quoted.is_some_and(|(c, age)| c < 75 && age < 0.2) {
            self.violation(format!(
                "{name}: {alarm_text:?} quotes a reading from before the alarm flag as fresh"
            ));
        }
        let view = self.chain.view.clone();
        wait_until(&self.chain, "the rudder in temperature error", S(3), || {
            view.borrow().servos[3].health == Health::TemperatureError
        })
        .await;
        let s4 = self.sim.snapshot(4).expect("servo 4");
        assert!(
            s4.error && s4.force == Force::Off,
            "servo 4 not latched off: {s4:?}"
        );
        tokio::time::sleep(MS(500)).await;
        // Cool it; the latched error needs a power cycle.
        assert!(self.sim.set_temperature(4, 30.0));
        assert!(self.sim.clear(Some(4), FaultKind::Overheat));
        assert!(self.sim.power_cycle(4));
        let cycled = Instant::now();
        let recovery = self
            .all_online("the rudder online after its power cycle")
            .await;
        let ok = expect_text(
            &self.chain,
            cycled,
            MavSeverity::MAV_SEVERITY_NOTICE,
            "rudder: temperature ok NNC",
            S(6),
            temperature_ok("rudder"),
        )
        .await;
        let ok_text = texts_since(&self.chain.gcs, cycled)
            .into_iter()
            .find(|(_, _, t)| temperature_ok("rudder")(base_text(t)))
            .map(|(_, _, t)| t)
            .unwrap_or_default();
        // The alarm is set 10 °C below the 85 °C limit: if "ok" quotes a temperature, it must be
        // below 75 °C (the servo was cooled to 30 °C); a stale reading must not be quoted.
        let quoted: Option<i32> = base_text(&ok_text)
            .strip_prefix("rudder: temperature ok ")
            .and_then(|t| t.strip_suffix('C'))
            .and_then(|t| t.parse().ok());
        if quoted.is_some_and(|c| c >= 75) {
            let now_c = self.sim.snapshot(4).map(|s| s.temperature_c);
            self.violation(format!(
                "{name}: {ok_text:?} quotes a temperature at or above the alarm threshold (75 C); the servo is at {now_c:?} C"
            ));
        }
        // Force on again after the next goal.
        self.steps(STEP_LIMIT).await;
        let s4 = self.sim.snapshot(4).expect("servo 4");
        assert_eq!(
            s4.force,
            Force::On,
            "the rudder's force after its power cycle"
        );
        let texts: [&dyn Fn(&str) -> bool; 3] = [
            &temperature_alarm("rudder"),
            &overheat("rudder"),
            // A request or two may go unanswered while it boots.
            &|t: &str| t == "rudder: servo lost",
        ];
        self.finish(
            name,
            start,
            Some(recovery),
            &texts,
            vec![format!(
                "alarm after {alarm:?}, overheat after {error:?}, {ok_text:?} {ok:?} after the power cycle"
            )],
        );
    }

    /// (6) The autopilot's output stream stops for 1.5 s, then resumes.
    async fn failsafe(&mut self) {
        let name = self.name_of("6 autopilot outputs stop");
        let start = Instant::now();
        self.ap.pause(true);
        let view = self.chain.view.clone();
        // The failsafe is due 400 ms (failsafe_timeout_ms) after the last output; 2 s leaves
        // 1.6 s for the bridge's tick and the view, far more than a busy machine takes. The
        // other 2 s waits of this phase are one long packet or one autopilot message away.
        let entered = wait_until(&self.chain, "failsafe", S(2), || view.borrow().failsafe).await;
        // The elevator takes its failsafe position.
        let sim = self.sim.clone();
        wait_until(
            &self.chain,
            "the elevator at its failsafe goal",
            S(2),
            || {
                sim.snapshot(3)
                    .is_some_and(|s| (s.goal_mm * 100.0).round() as i16 == ELEVATOR_FAILSAFE)
            },
        )
        .await;
        let text = expect_exact_text(
            &self.chain,
            start,
            MavSeverity::MAV_SEVERITY_WARNING,
            "LJ9DA failsafe: no outputs for 400 ms",
            S(3),
        )
        .await;
        tokio::time::sleep(MS(1500).saturating_sub(start.elapsed())).await;
        self.ap.pause(false);
        let resumed = Instant::now();
        let left = wait_until(&self.chain, "failsafe left", S(2), || {
            !view.borrow().failsafe
        })
        .await;
        let cleared = expect_exact_text(
            &self.chain,
            resumed,
            MavSeverity::MAV_SEVERITY_NOTICE,
            "LJ9DA failsafe cleared",
            S(5),
        )
        .await;
        // The autopilot's goals again, not the failsafe's.
        let goals = self.goals;
        let sim = self.sim.clone();
        wait_until(
            &self.chain,
            "the elevator back on the autopilot's goal",
            S(2),
            || {
                sim.snapshot(3)
                    .is_some_and(|s| (s.goal_mm * 100.0).round() as i16 == goals[2])
            },
        )
        .await;
        let recovery = self
            .all_online("every servo online after the failsafe")
            .await;
        self.steps(STEP_LIMIT).await;
        let failsafe_text = |t: &str| t == "LJ9DA failsafe: no outputs for 400 ms";
        self.finish(
            name,
            start,
            Some(left.max(recovery)),
            &[&failsafe_text],
            vec![format!(
                "failsafe after {entered:?} (text {text:?}), left {left:?} after resuming (text {cleared:?})"
            )],
        );
    }

    /// (7) MAVLink garbage to the bridge's port, then a flood of outputs.
    async fn garbage_and_flood(&mut self, rng: &mut XorShift64) {
        let name = self.name_of("7 MAVLink garbage + flood");
        let start = Instant::now();
        let port = self.chain.autopilot_port;
        let socket = tokio::net::UdpSocket::bind("127.0.0.1:0")
            .await
            .expect("garbage socket");
        let foreign = Instant::now();
        let events = self.sim.subscribe();
        let mut kinds = [0u32; 8];
        let mut datagrams = 0u32;
        // ~2 s of garbage, ~500 datagrams a second, while the real stream goes on.
        while foreign.elapsed() < S(2) {
            for _ in 0..10 {
                let kind = rng.below(kinds.len());
                kinds[kind] += 1;
                let datagram = garbage(kind, rng);
                let _ = socket.send_to(&datagram, ("127.0.0.1", port)).await;
                datagrams += 1;
            }
            tokio::time::sleep(MS(20)).await;
        }
        let garbage_end = Instant::now();
        // Nothing from the unknown senders or the broken frames reached a servo.
        tokio::time::sleep(MS(200)).await;
        let mut foreign_goals = Vec::new();
        while let Ok(event) = events.try_recv() {
            if let BusEvent::Packet(p) = event {
                foreign_goals.extend(
                    p.packet
                        .goal_positions()
                        .into_iter()
                        .filter(|(_, g)| *g == FOREIGN_GOAL),
                );
            }
        }
        drop(events);
        assert!(
            foreign_goals.is_empty(),
            "goals from unknown senders or broken frames reached the servos: {foreign_goals:?}"
        );
        let failsafe_texts: Vec<String> = texts_since(&self.chain.gcs, foreign)
            .into_iter()
            .filter(|(_, _, t)| t.contains("failsafe"))
            .map(|(_, _, t)| t)
            .collect();
        if self.chain.view.borrow().failsafe || !failsafe_texts.is_empty() {
            self.violation(format!(
                "{name}: failsafe while the real stream went on next to the garbage: {failsafe_texts:?}"
            ));
        }
        self.steps(STEP_LIMIT).await;

        // The flood: 5000 SERVO_OUTPUT_RAW in about a second, the last ones with the next goals.
        self.n += 1;
        let last = goals_of(self.n);
        let flood_events = self.sim.subscribe();
        let flood = Instant::now();
        self.goals = last;
        self.ap.set(outputs(last));
        let mut flood_sent = 0u32;
        for burst in 0..100 {
            for k in 0..50 {
                let goals = if burst == 99 && k >= 40 {
                    last
                } else {
                    std::array::from_fn(|_| (rng.below(31) as i16 - 15) * 100)
                };
                if self.ap.try_send(&outputs(goals)).await {
                    flood_sent += 1;
                }
            }
            tokio::time::sleep(MS(10)).await;
        }
        let flood_time = flood.elapsed();
        let settled = self
            .reached(
                &flood_events,
                last,
                flood,
                flood_time + S(1),
                "after the flood",
            )
            .await
            .saturating_sub(flood_time);
        drop(flood_events);
        self.steps(STEP_LIMIT).await;
        // The bridge's heartbeat went on at about 1 Hz through garbage and flood.
        tokio::time::sleep(MS(1200)).await;
        let window = start.elapsed();
        let beats: Vec<Instant> = self
            .chain
            .gcs
            .since(start)
            .into_iter()
            .filter(|(_, h, m)| h.component_id == 140 && matches!(m, MavMessage::HEARTBEAT(_)))
            .map(|(t, _, _)| t)
            .collect();
        let gaps: Vec<Duration> = beats.windows(2).map(|w| w[1] - w[0]).collect();
        let worst_gap = gaps.iter().max().copied().unwrap_or(window);
        let expected = window.as_secs_f64();
        assert!(
            (beats.len() as f64) >= expected - 1.5 && (beats.len() as f64) <= expected + 1.5,
            "{} bridge heartbeats in {window:?}",
            beats.len()
        );
        assert!(
            worst_gap < MS(1600),
            "the bridge's heartbeat stalled for {worst_gap:?}"
        );
        let recovery = self
            .all_online("every servo online after garbage and flood")
            .await;
        self.finish(
            name,
            start,
            Some(recovery),
            &[],
            vec![
                format!(
                    "{datagrams} garbage datagrams in {:?} (kinds {kinds:?}); no foreign goal reached a servo",
                    garbage_end - foreign
                ),
                format!(
                    "flood: {flood_sent} SERVO_OUTPUT_RAW in {flood_time:?}; its last goals on the servos {settled:?} after it ended"
                ),
                format!(
                    "{} bridge heartbeats in {window:?}, longest gap {worst_gap:?}",
                    beats.len()
                ),
            ],
        );
    }

    /// (8) The serial device disappears for 1 s and reappears.
    async fn port(&mut self) {
        let name = self.name_of("8 serial device gone");
        let start = Instant::now();
        let sim = self.sim.clone();
        tokio::task::spawn_blocking(move || sim.disconnect_port())
            .await
            .expect("disconnect");
        let lost = expect_exact_text(
            &self.chain,
            start,
            MavSeverity::MAV_SEVERITY_CRITICAL,
            "LJ9DA bus wing: port lost",
            S(3),
        )
        .await;
        tokio::time::sleep(S(1).saturating_sub(start.elapsed())).await;
        let sim = self.sim.clone();
        let path = tokio::task::spawn_blocking(move || sim.try_reconnect_port())
            .await
            .expect("reconnect")
            .expect("the simulated device reappears");
        let reconnected = Instant::now();
        let recovery = self
            .all_online("every servo online after the port came back")
            .await;
        let back = expect_exact_text(
            &self.chain,
            reconnected,
            MavSeverity::MAV_SEVERITY_NOTICE,
            "LJ9DA bus wing: port back",
            S(6),
        )
        .await;
        self.steps(STEP_LIMIT).await;
        let lost_text = |t: &str| t == "LJ9DA bus wing: port lost";
        self.finish(
            name,
            start,
            Some(recovery),
            &[&lost_text],
            vec![format!(
                "'port lost' after {lost:?}; device back at {} , 'port back' {back:?} after",
                path.display()
            )],
        );
    }

    /// (9) Corrupted replies from servo 1, servo 3 unplugged and an echoing adapter, together.
    async fn combined(&mut self) {
        let name = self.name_of("9 corruption + unplug + echo together");
        let start = Instant::now();
        assert!(
            self.sim
                .inject(Some(1), Fault::CorruptReplies { probability: 0.3 })
        );
        assert!(self.sim.unplug(3));
        self.sim.set_echo(true);
        let lost = expect_exact_text(
            &self.chain,
            start,
            MavSeverity::MAV_SEVERITY_CRITICAL,
            "elevator: servo lost",
            S(5),
        )
        .await;
        // Servo 1 (view index 0) is the one with bad replies; the unplugged elevator is lost,
        // not degraded.
        let bad = expect_text(
            &self.chain,
            start,
            MavSeverity::MAV_SEVERITY_WARNING,
            "aileron_left: degraded, N% replies bad",
            // Long enough for detected_in_time to judge a late announcement, not to hide it.
            S(40),
            degraded(NAMES[0]),
        )
        .await;
        self.detected_in_time(&name, start, bad, &[0]);
        tokio::time::sleep(S(5).saturating_sub(start.elapsed())).await;
        self.sim.clear_all();
        let cleared = Instant::now();
        let recovery = self
            .all_online("every servo online after the combined faults")
            .await;
        let back = expect_exact_text(
            &self.chain,
            cleared,
            MavSeverity::MAV_SEVERITY_NOTICE,
            "elevator: servo back",
            S(6),
        )
        .await;
        let ok = self
            .replies_recovered(&name, NAMES[0], start, cleared)
            .await;
        self.steps(STEP_LIMIT).await;
        let expected = |t: &str| t == "elevator: servo lost" || t == "aileron_left: servo lost";
        self.finish(
            name,
            start,
            Some(recovery),
            &[&expected, &degraded(NAMES[0])],
            vec![format!(
                "'servo lost' after {lost:?}, 'degraded' after {bad:?}; after clearing: 'servo back' {back:?}, 'replies ok' {ok:?}"
            )],
        );
    }
}

/// One datagram of garbage of kind `kind`: random bytes, fake MAVLink 2 and 1 headers, valid
/// frames from unknown systems or components, truncated and corrupted frames, mixtures.
fn garbage(kind: usize, rng: &mut XorShift64) -> Vec<u8> {
    let random = |rng: &mut XorShift64, n: usize| -> Vec<u8> {
        (0..n).map(|_| rng.next_u64() as u8).collect()
    };
    let frame = |version, system_id, component_id, msg: &MavMessage| {
        let mut out = Vec::new();
        mavlink::write_versioned_msg(
            &mut out,
            version,
            MavHeader {
                system_id,
                component_id,
                sequence: 0,
            },
            msg,
        )
        .expect("frame");
        out
    };
    let foreign = outputs([FOREIGN_GOAL; 4]);
    match kind {
        0 => {
            let n = 1 + rng.below(280);
            random(rng, n)
        }
        1 | 2 => {
            let mut d = vec![if kind == 1 { 0xFD } else { 0xFE }];
            let n = rng.below(300);
            d.extend(random(rng, n));
            d
        }
        3 => frame(MavlinkVersion::V2, 77, 1, &foreign),
        4 => {
            let mut d = frame(
                MavlinkVersion::V1,
                78,
                1,
                &heartbeat(MavAutopilot::MAV_AUTOPILOT_PX4),
            );
            d.extend(frame(MavlinkVersion::V1, 78, 1, &foreign));
            d
        }
        5 => {
            // The real autopilot's ids, the foreign goal: truncated, or one byte flipped.
            let mut d = frame(MavlinkVersion::V2, 1, 1, &foreign);
            if rng.below(2) == 0 {
                d.truncate(1 + rng.below(d.len() - 1));
            } else {
                let i = 1 + rng.below(d.len() - 1);
                d[i] ^= rng.nonzero_byte();
            }
            d
        }
        6 => frame(MavlinkVersion::V2, 1, 77, &foreign),
        _ => {
            let n = rng.below(40);
            let mut d = random(rng, n);
            d.extend(frame(MavlinkVersion::V2, 79, 1, &foreign));
            let n = rng.below(40);
            d.extend(random(rng, n));
            d
        }
    }
}

fn print_phase(log: &PhaseLog, started: Instant) {
    let recovery = log
        .recovery
        .map_or("-".to_string(), |r| format!("{:.2} s", r.as_secs_f64()));
    println!(
        "[soak] {:>6.1} s  {:<42} {:>5.1} s  back online {recovery}",
        (Instant::now() - started).as_secs_f64(),
        log.name,
        log.duration.as_secs_f64()
    );
    for (t, s, text) in &log.texts {
        println!(
            "[soak]            +{:>5.2} s {:<8} {text}",
            t.saturating_duration_since(log.start).as_secs_f64(),
            short_severity(*s)
        );
    }
    for note in &log.notes {
        println!("[soak]            {note}");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn fault_soak() {
    count_panics();
    let rounds = env_number("LJ9DA_SOAK_ROUNDS").unwrap_or(1).max(1);
    let seconds = env_number("LJ9DA_SOAK_SECONDS").map(S);
    let started = Instant::now();
    let chain = Chain::start_opts(
        mapping(),
        ChainOptions {
            autopilot: false,
            stable_links: true,
            // A long run must not hold every telemetry message: keep what is asserted on.
            gcs_keep: Some(|m| matches!(m, MavMessage::STATUSTEXT(_) | MavMessage::HEARTBEAT(_))),
            ..ChainOptions::default()
        },
    )
    .await;
    let sim = chain.sims[0].handle();
    assert!(
        sim.path().is_symlink(),
        "the bridge must open the stable symlink"
    );
    let ap = autopilot(chain.autopilot_port, goals_of(0)).await;
    let answers = AnswerLog::watch(chain.view.clone());
    let mut soak = Soak {
        chain,
        sim,
        ap,
        started,
        n: 0,
        goals: goals_of(0),
        log: Vec::new(),
        rss: Vec::new(),
        heap: Vec::new(),
        step_latencies: Vec::new(),
        round: 0,
        violations: Vec::new(),
        answers,
    };

    // Warm-up: every servo online, the bridge's heartbeat heard, goals reach the servos.
    let warm = Instant::now();
    let online = soak.all_online("every servo online at start").await;
    let view = soak.chain.view.clone();
    wait_until(
        &soak.chain,
        "the bridge obeying the autopilot",
        S(5),
        || view.borrow().autopilot == Some((1, 1)),
    )
    .await;
    soak.steps(S(5)).await;
    while warm.elapsed() < S(5) {
        soak.step(STEP_LIMIT).await;
        tokio::time::sleep(MS(300)).await;
    }
    soak.finish(
        "warm-up".into(),
        warm,
        Some(online),
        &[],
        vec![format!("all online {online:?} after start")],
    );

    let mut rng = XorShift64::new(0x50A4);
    loop {
        soak.round += 1;
        soak.reply_faults().await;
        soak.echo().await;
        soak.unplug().await;
        soak.stall().await;
        soak.overheat().await;
        soak.failsafe().await;
        soak.garbage_and_flood(&mut rng).await;
        soak.port().await;
        soak.combined().await;
        let more_rounds = soak.round < rounds;
        let more_time = seconds.is_some_and(|s| started.elapsed() < s);
        if !more_rounds && !more_time {
            break;
        }
    }
    // A quiet end: no fault, goals still followed, and no late warning from the faults gone.
    let quiet = Instant::now();
    while quiet.elapsed() < S(8) {
        soak.step(STEP_LIMIT).await;
        tokio::time::sleep(MS(300)).await;
    }
    let view = soak.chain.view.clone();
    assert!(all_online(&view.borrow()), "{:?}", healths(&view.borrow()));
    soak.finish("quiet end".into(), quiet, None, &[], vec![]);

    // The summary.
    let total = started.elapsed();
    let rss: Vec<String> = soak
        .rss
        .iter()
        .map(|(l, k)| format!("{l}: {:.1} MiB", *k as f64 / 1024.0))
        .collect();
    assert!(
        soak.rss.len() >= 2,
        "memory sampled {} time(s): the growth check needs a sample after warm-up and one at the end",
        soak.rss.len()
    );
    let first = soak.rss.first().map_or(0, |r| r.1);
    let last = soak.rss.last().map_or(0, |r| r.1);
    let peak = soak.rss.iter().map(|r| r.1).max().unwrap_or(0);
    let mut latencies = soak.step_latencies.clone();
    latencies.sort();
    let pct = |p: f64| latencies[((latencies.len() - 1) as f64 * p) as usize];
    println!("[soak] ---- summary ----");
    println!(
        "[soak] {} round(s), {} phases, {:.1} s in all",
        soak.round,
        soak.log.len(),
        total.as_secs_f64()
    );
    for log in &soak.log {
        println!(
            "[soak]   {:<42} {:>5.1} s  back online {}",
            log.name,
            log.duration.as_secs_f64(),
            log.recovery
                .map_or("-".into(), |r| format!("{:.2} s", r.as_secs_f64()))
        );
    }
    println!(
        "[soak] goals checked: {} steps, reached in median {:?}, p90 {:?}, max {:?} (a report: only a stuck goal, {STEP_LIMIT:?}, fails)",
        latencies.len(),
        pct(0.5),
        pct(0.9),
        pct(1.0)
    );
    println!(
        "[soak] autopilot sent {} outputs; ground station heard {} messages",
        soak.ap.sent(),
        soak.chain.gcs.count()
    );
    println!(
        "[soak] VmRSS of the test process (bridge + simulator + test harness), after warm-up and each phase:"
    );
    for r in &rss {
        println!("[soak]   {r}");
    }
    let long_run = rounds > 1 || seconds.is_some();
    println!(
        "[soak] VmRSS growth {:+.1} MiB (first {:.1}, last {:.1}, peak {:.1}; limit {} MiB, {})",
        (last as f64 - first as f64) / 1024.0,
        first as f64 / 1024.0,
        last as f64 / 1024.0,
        peak as f64 / 1024.0,
        RSS_GROWTH_LIMIT_KIB / 1024,
        if long_run {
            "checked"
        } else {
            "a report: checked only with LJ9DA_SOAK_ROUNDS > 1 or LJ9DA_SOAK_SECONDS"
        }
    );
    let heap_growth = soak.heap.last().unwrap() - soak.heap.first().unwrap();
    println!(
        "[soak] heap in use {:+.1} KiB from after warm-up to the end (first {:.1} MiB, peak {:.1} MiB; limit {} KiB, checked): {:?}",
        heap_growth as f64 / 1024.0,
        *soak.heap.first().unwrap() as f64 / 1048576.0,
        *soak.heap.iter().max().unwrap() as f64 / 1048576.0,
        HEAP_GROWTH_LIMIT / 1024,
        soak.heap.iter().map(|b| b / 1024).collect::<Vec<_>>()
    );
    assert!(
        heap_growth < HEAP_GROWTH_LIMIT,
        "the heap in use grew by {heap_growth} bytes from after warm-up to the end: {:?}",
        soak.heap
    );
    if long_run {
        assert!(
            last.saturating_sub(first) < RSS_GROWTH_LIMIT_KIB,
            "memory grew by {} KiB: {rss:?}",
            last.saturating_sub(first)
        );
    }
    assert_eq!(PANICS.load(Ordering::SeqCst), 0, "a panic during the soak");
    assert!(
        soak.violations.is_empty(),
        "{} wrong STATUSTEXT(s) during the soak:\n{}",
        soak.violations.len(),
        soak.violations.join("\n")
    );
    drop(soak.ap);
    soak.chain.stop().await;
}

//! The machine around the bridge: the probe threads that see its stalls, the CPU hogs, the time
//! the hypervisor stole; and what /proc tells of a process's CPU, memory and threads.

use std::process::{Child, Command};
use std::time::{Duration, Instant};

/// A wake-up of a [`Probe`] thread more than [`STALL`] after it was due: the machine did not
/// run a thread that asked to run then (the bridge's bus thread asks the same way).
const STALL: Duration = Duration::from_micros(500);
/// How long a probe thread sleeps at a time: a poll's spacing of the bus thread at 4 servos
/// and 50 Hz.
const PROBE_SLEEP: Duration = Duration::from_millis(5);

/// One thread of the bench's pinned to each CPU that sleeps like the bridge's bus thread
/// (SCHED_FIFO where allowed, 1 µs timer slack, [`PROBE_SLEEP`] at a time) and notes every
/// wake-up [`STALL`] late, as (due, woken). Its stalls are the machine's own (a virtual CPU the
/// host did not run, a CPU held by a thread above the probe's priority); a goal that waited
/// beside one is told apart from one the bridge alone delayed.
pub(super) struct Probe {
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    threads: Vec<std::thread::JoinHandle<Vec<(Instant, Instant)>>>,
}

impl Probe {
    pub(super) fn start() -> Probe {
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let cpus = std::thread::available_parallelism().map_or(1, |n| n.get());
        let threads = (0..cpus)
            .map(|cpu| {
                let stop = std::sync::Arc::clone(&stop);
                std::thread::spawn(move || {
                    pin_to_cpu(cpu);
                    let _ = nix::sys::prctl::set_timerslack(1_000);
                    let _ =
                        lj9da_realtime::request_fifo(lj9da_bridge::bus::driver::REALTIME_PRIORITY);
                    let mut stalls = Vec::new();
                    // Wake-ups on a fixed grid: a stall while the probe ran (between a wake-up
                    // and its next sleep) still makes the next wake-up late.
                    let mut due = Instant::now();
                    while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                        due += PROBE_SLEEP;
                        std::thread::sleep(due.saturating_duration_since(Instant::now()));
                        let woke = Instant::now();
                        if woke.saturating_duration_since(due) > STALL {
                            stalls.push((due, woke));
                            while due + PROBE_SLEEP <= woke {
                                due += PROBE_SLEEP;
                            }
                        }
                    }
                    stalls
                })
            })
            .collect();
        Probe { stop, threads }
    }

    /// Every CPU's stalls, by the instant they were due.
    pub(super) fn stop(self) -> Vec<(Instant, Instant)> {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        let mut all: Vec<(Instant, Instant)> = self
            .threads
            .into_iter()
            .flat_map(|t| t.join().unwrap_or_default())
            .collect();
        all.sort();
        all
    }
}

/// The machine's CPU time stolen by the hypervisor so far, in seconds (`None` where /proc/stat
/// does not tell).
pub(super) fn steal_s() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/stat").ok()?;
    let steal: f64 = stat
        .lines()
        .next()?
        .strip_prefix("cpu ")?
        .split_whitespace()
        .nth(7)?
        .parse()
        .ok()?;
    Some(steal / 100.0) // USER_HZ on Linux
}

/// Keep the calling thread on CPU `cpu` (left as it is where refused).
fn pin_to_cpu(cpu: usize) {
    use nix::libc;
    // SAFETY: a zeroed cpu_set_t is an empty set; CPU_SET writes within it for cpu < 1024;
    // sched_setaffinity only reads it.
    unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        libc::CPU_SET(cpu, &mut set);
        libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set);
    }
}

/// Whether a probe stall overlaps `from..=to`.
pub(super) fn beside_stall(stalls: &[(Instant, Instant)], from: Instant, to: Instant) -> bool {
    stalls.iter().any(|(due, woke)| *due <= to && *woke >= from)
}

/// `n` processes that keep a CPU busy, ended when dropped. Each in a session of its own, as
/// the programs beside a companion computer's bridge are (a camera's, a logger's, a shell's):
/// with the kernel's autogroups (`/proc/sys/kernel/sched_autogroup_enabled`) the scheduler
/// shares a CPU between sessions first, and hogs started in the bench's own session competed
/// with the bridge as its equals, a gentler load than the same loops started from a shell.
pub(super) struct Hogs(Vec<Child>);

impl Hogs {
    pub(super) fn start(n: usize) -> Hogs {
        use std::os::unix::process::CommandExt;
        Hogs(
            (0..n)
                .map(|_| {
                    let mut hog = Command::new("sh");
                    hog.args(["-c", "while :; do :; done"]);
                    // SAFETY: setsid is async-signal-safe and touches only the child.
                    unsafe {
                        hog.pre_exec(|| {
                            libc::setsid();
                            Ok(())
                        });
                    }
                    hog.spawn().expect("a CPU hog")
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

/// User + system CPU time of `pid` in seconds, and its peak resident set in KiB; each `None`
/// where /proc does not tell.
pub(super) fn cpu_and_rss(pid: u32) -> (Option<f64>, Option<u64>) {
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
pub(super) fn thread_split(pid: u32) -> Option<[(f64, u64); 3]> {
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

//! systemd's side of the bridge's watchdog, played by the bench: a notify socket of its own,
//! the bridge started as systemd starts it (`NOTIFY_SOCKET`, `WATCHDOG_USEC`, `WATCHDOG_PID`),
//! and the time each ping arrived. The longest gap between two pings is what `WatchdogSec=`
//! must outlast.

use std::io::{BufRead, BufReader};
use std::os::unix::net::UnixDatagram;
use std::path::Path;
use std::process::{ChildStderr, Command};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// A gap longer than the period by more than this is listed with when it ended: the loop's
/// usual lateness is about 1 ms a ping (its timer's resolution).
pub(super) const LATE: Duration = Duration::from_millis(10);

/// The watchdog timeout the bench asks of the bridge: `$E2E_WATCHDOG_MS`, default 1000 ms (the
/// bridge warns below 1 s, and says how often it pings: a quarter of it from `49107e8`, half
/// before); `0`: none, the bridge as before this measure (no `NOTIFY_SOCKET`).
pub(super) fn timeout() -> Option<Duration> {
    let ms: u64 = std::env::var("E2E_WATCHDOG_MS")
        .map(|s| {
            s.trim()
                .parse()
                .unwrap_or_else(|_| panic!("E2E_WATCHDOG_MS: not a number of ms: {s:?}"))
        })
        .unwrap_or(1000);
    (ms > 0).then(|| Duration::from_millis(ms))
}

/// What the notify socket heard: when `READY=1` came, and each `WATCHDOG=1`, by the monotonic
/// clock at its receipt (the reader runs at the sender's real-time priority where granted).
#[derive(Default)]
struct Heard {
    ready: Option<Instant>,
    pings: Vec<Instant>,
}

/// The bench's notify socket and its reader, and the watcher of the bridge's log (the line
/// that says the bridge saw the watchdog, and those that name a stuck bus thread).
pub(super) struct Listener {
    timeout: Duration,
    stop: Arc<AtomicBool>,
    socket: JoinHandle<Heard>,
    log: Option<JoinHandle<(Option<String>, Vec<String>)>>,
}

impl Listener {
    /// Bind `dir/notify` and read it on a thread of its own; have `command` (the bridge's)
    /// report there with a watchdog of `timeout`. `WATCHDOG_PID` must be the bridge's own pid
    /// (sd_notify checks it against getpid), which is not known before the spawn: the
    /// command becomes `sh -c 'export WATCHDOG_PID=$$; exec "$0" "$@"' bridge args…`, and the
    /// shell's pid is the bridge's once it has exec'd.
    pub(super) fn start(dir: &Path, timeout: Duration) -> Listener {
        let path = dir.join("notify");
        let socket = UnixDatagram::bind(&path).expect("the bench's notify socket");
        socket
            .set_read_timeout(Some(Duration::from_millis(50)))
            .unwrap();
        let stop = Arc::new(AtomicBool::new(false));
        let stopped = Arc::clone(&stop);
        let socket = std::thread::spawn(move || {
            let _ = lj9da_realtime::request_fifo(super::SENDER_PRIORITY);
            let mut heard = Heard::default();
            let mut buf = [0u8; 4096];
            while !stopped.load(Ordering::Relaxed) {
                let Ok(n) = socket.recv(&mut buf) else {
                    continue;
                };
                let at = Instant::now();
                for line in String::from_utf8_lossy(&buf[..n]).lines() {
                    match line {
                        "READY=1" => {
                            heard.ready.get_or_insert(at);
                        }
                        "WATCHDOG=1" => heard.pings.push(at),
                        _ => {}
                    }
                }
            }
            heard
        });
        Listener {
            timeout,
            stop,
            socket,
            log: None,
        }
    }

    /// The bridge's command, wrapped so that it reports to this listener as systemd's child.
    pub(super) fn command(&self, dir: &Path, bridge: &std::ffi::OsStr) -> Command {
        let mut c = Command::new("sh");
        c.args(["-c", r#"export WATCHDOG_PID=$$; exec "$0" "$@""#])
            .arg(bridge)
            .env("NOTIFY_SOCKET", dir.join("notify"))
            .env("WATCHDOG_USEC", self.timeout.as_micros().to_string())
            // The line that says the bridge took the watchdog (and its warning below 1 s).
            .env("RUST_LOG", "warn,lj9da_bridge::runtime::service=info");
        c
    }

    /// Read the bridge's log (its stderr, piped), passing every line on to the bench's.
    pub(super) fn watch_log(&mut self, stderr: ChildStderr) {
        self.log = Some(std::thread::spawn(move || {
            let (mut announced, mut stuck) = (None, Vec::new());
            for line in BufReader::new(stderr).lines() {
                let Ok(line) = line else { break };
                eprintln!("{line}");
                if line.contains("systemd watchdog:") {
                    announced.get_or_insert_with(|| line.clone());
                }
                if line.contains("bus thread stuck") {
                    stuck.push(line);
                }
            }
            (announced, stuck)
        }));
    }

    /// Stop reading (the bridge has ended, so its log too) and sum up the gaps.
    pub(super) fn finish(self) -> Pings {
        self.stop.store(true, Ordering::Relaxed);
        let heard = self.socket.join().unwrap_or_default();
        let (announced, stuck) = self.log.and_then(|l| l.join().ok()).unwrap_or_default();
        // The period as the bridge said it; a build that did not say it pinged every half.
        let period = announced
            .as_deref()
            .and_then(said_period)
            .unwrap_or(self.timeout / 2);
        // From READY=1 (it arms systemd's watchdog) to the first ping, then ping to ping.
        let marks: Vec<Instant> = heard.ready.into_iter().chain(heard.pings.clone()).collect();
        let mut gaps_ms: Vec<f64> = marks
            .windows(2)
            .map(|w| w[1].saturating_duration_since(w[0]).as_secs_f64() * 1e3)
            .collect();
        // Gaps more than LATE over the period, by when they ended: after READY=1, and on
        // CLOCK_MONOTONIC to line them up with `E2E_TRACE_LATE`'s goals.
        let (now, mono) = (Instant::now(), super::monotonic_now());
        let late: Vec<(f64, f64, f64)> = marks
            .windows(2)
            .filter(|w| w[1].saturating_duration_since(w[0]) > period + LATE)
            .map(|w| {
                (
                    w[1].saturating_duration_since(w[0]).as_secs_f64() * 1e3,
                    w[1].saturating_duration_since(marks[0]).as_secs_f64(),
                    mono - now.saturating_duration_since(w[1]).as_secs_f64(),
                )
            })
            .collect();
        let first_ms = heard
            .ready
            .and_then(|_| gaps_ms.first().copied())
            .unwrap_or(f64::NAN);
        let long = period.as_secs_f64() * 1e3 * 1.5;
        let over = gaps_ms.iter().filter(|g| **g > long).count();
        gaps_ms.sort_by(f64::total_cmp);
        Pings {
            timeout: self.timeout,
            period,
            ready: heard.ready.is_some(),
            pings: heard.pings.len(),
            first_ms,
            gap_p50_ms: gaps_ms.get(gaps_ms.len() / 2).copied().unwrap_or(f64::NAN),
            gap_max_ms: gaps_ms.last().copied().unwrap_or(f64::NAN),
            gaps: gaps_ms.len(),
            over_1_5: over,
            late,
            announced,
            stuck,
        }
    }
}

/// One run's pings (see [`Listener::finish`]).
pub(super) struct Pings {
    pub(super) timeout: Duration,
    /// Between two pings, as the bridge said it.
    pub(super) period: Duration,
    /// Whether `READY=1` came.
    pub(super) ready: bool,
    pub(super) pings: usize,
    /// From READY=1 to the first ping, ms.
    pub(super) first_ms: f64,
    /// Of the gaps from READY=1 on, ms.
    pub(super) gap_p50_ms: f64,
    pub(super) gap_max_ms: f64,
    pub(super) gaps: usize,
    /// Gaps longer than 1.5 periods: a look that found a bus not turned, or a late loop.
    pub(super) over_1_5: usize,
    /// The gaps more than [`LATE`] over the period: (ms, s after READY=1 at its end,
    /// CLOCK_MONOTONIC at its end).
    pub(super) late: Vec<(f64, f64, f64)>,
    /// The bridge's "systemd watchdog: …, pinged every …" line, if it said it.
    pub(super) announced: Option<String>,
    /// The bridge's "bus thread stuck" lines.
    pub(super) stuck: Vec<String>,
}

/// The period in the bridge's "systemd watchdog: 1s, pinged every 250ms" (a `Duration`'s
/// debug form: `250ms`, `1s`, `1.5s`, `750µs`).
fn said_period(line: &str) -> Option<Duration> {
    let text = line
        .split("pinged every ")
        .nth(1)?
        .split_whitespace()
        .next()?;
    let text = text.trim_end_matches(|c: char| !c.is_alphanumeric());
    let split = text.find(|c: char| !(c.is_ascii_digit() || c == '.'))?;
    let (number, unit) = text.split_at(split);
    let number: f64 = number.parse().ok()?;
    let scale = match unit {
        "s" => 1.0,
        "ms" => 1e-3,
        "µs" | "us" => 1e-6,
        "ns" => 1e-9,
        _ => return None,
    };
    Some(Duration::from_secs_f64(number * scale))
}

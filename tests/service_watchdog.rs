//! The bridge as a systemd service, through the binary: `lj9da-bridge run` under a
//! `NOTIFY_SOCKET` (a real Unix datagram socket of the test's, as systemd gives one) and a
//! `WATCHDOG_USEC`. It says READY=1 once its buses have tried their ports, then pings the
//! watchdog while every bus thread turns, a bus whose port is missing included; a bus thread
//! that hangs (the test-only fault switch) stops the pings, and the log names the bus. Where
//! real-time scheduling is granted, the MAVLink loop's thread and the bus threads run at
//! SCHED_FIFO, and no other thread does.

mod bus_support;
#[path = "common/ports.rs"]
mod ports;
mod tempdir;

use bus_support::*;
use std::io::{BufRead, BufReader};
use std::os::unix::net::UnixDatagram;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};
use tempdir::TempDir;

/// The watchdog timeout the tests ask for: pings every 250 ms.
const WATCHDOG: Duration = Duration::from_secs(1);

/// What came from the bridge, in the order the test took it, each with when.
#[derive(Debug)]
enum Said {
    /// A datagram on the notify socket.
    Notify(String),
    /// A line of its log.
    Log(String),
}

struct Service {
    child: Child,
    said: mpsc::Receiver<(Instant, Said)>,
    heard: Vec<(Instant, Said)>,
    _dir: TempDir,
    _sim: lj9da_sim::SimBus,
}

impl Service {
    /// `lj9da-bridge run` with bus "wing" on a simulated bus (servos 1 and 2) and bus "tail" on
    /// a port that does not exist, under a notify socket and a watchdog; `env`: more variables.
    fn start(tag: &str, env: &[(&str, &str)]) -> Self {
        loop {
            let mut service = Self::start_once(tag, env);
            // The bridge refuses a port another program took after the test found it free
            // (see `ports`): that program is named in the line; start again on another port.
            service.listen_until(PATIENCE, |h| {
                log_has(h, "MAVLink links set up").is_some() || log_has(h, ports::TAKEN).is_some()
            });
            match log_line(&service.heard, ports::TAKEN) {
                Some(line) => eprintln!("started again on another port: {line}"),
                None => return service,
            }
        }
    }

    fn start_once(tag: &str, env: &[(&str, &str)]) -> Self {
        let dir = TempDir::new(tag);
        let sim = spawn_sim(sim_config(&[1, 2], 115_200));
        let missing = dir.path().join("ttyUSB-missing");
        let mapping = dir.path().join("bridge.toml");
        let port = ports::free_udp_port();
        std::fs::write(
            &mapping,
            format!(
                r#"[mavlink]
connection = "udpin:127.0.0.1:{port}"
# The autopilot's id known beforehand: it is taken as the autopilot before it says anything.
system_id = 1

[record]
enabled = false

[[bus]]
name = "wing"
port = "{}"

[[bus]]
name = "tail"
port = "{}"

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

[[servo]]
name = "rudder"
bus = "tail"
id = 3
channel = 4
"#,
                sim.path().display(),
                missing.display()
            ),
        )
        .unwrap();
        let socket_path = dir.path().join("notify");
        let socket = UnixDatagram::bind(&socket_path).expect("a notify socket");
        let mut child = Command::new(env!("CARGO_BIN_EXE_lj9da-bridge"))
            .args(["run", "--config"])
            .arg(&mapping)
            .env("RUST_LOG", "lj9da_bridge=info")
            .env("NOTIFY_SOCKET", &socket_path)
            .env("WATCHDOG_USEC", WATCHDOG.as_micros().to_string())
            .envs(env.iter().copied())
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .expect("the bridge starts");
        let (tx, said) = mpsc::channel();
        let log_tx = tx.clone();
        let stderr = child.stderr.take().unwrap();
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                if log_tx.send((Instant::now(), Said::Log(line))).is_err() {
                    break;
                }
            }
        });
        std::thread::spawn(move || {
            let mut buf = [0u8; 4096];
            while let Ok(n) = socket.recv(&mut buf) {
                let text = String::from_utf8_lossy(&buf[..n]).into_owned();
                if tx.send((Instant::now(), Said::Notify(text))).is_err() {
                    break;
                }
            }
        });
        Service {
            child,
            said,
            heard: Vec::new(),
            _dir: dir,
            _sim: sim,
        }
    }

    /// Take what the bridge says until `done` holds for what came so far (then `true`) or
    /// until `within` has passed (`false`).
    fn listen_until(
        &mut self,
        within: Duration,
        done: impl Fn(&[(Instant, Said)]) -> bool,
    ) -> bool {
        let until = Instant::now() + within;
        while !done(&self.heard) {
            let left = until.saturating_duration_since(Instant::now());
            match self.said.recv_timeout(left) {
                Ok(said) => self.heard.push(said),
                Err(_) => return false,
            }
        }
        true
    }

    fn pings_after(&self, from: Instant) -> usize {
        self.heard
            .iter()
            .filter(|(at, s)| {
                *at > from && matches!(s, Said::Notify(t) if t.contains("WATCHDOG=1"))
            })
            .count()
    }

    fn transcript(&self) -> String {
        self.heard
            .iter()
            .map(|(_, s)| format!("{s:?}"))
            .collect::<Vec<_>>()
            .join("\n")
    }
}

impl Drop for Service {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn is_ready(said: &Said) -> bool {
    matches!(said, Said::Notify(t) if t.lines().any(|l| l == "READY=1"))
}

fn log_has(heard: &[(Instant, Said)], text: &str) -> Option<Instant> {
    heard
        .iter()
        .find(|(_, s)| matches!(s, Said::Log(l) if l.contains(text)))
        .map(|(at, _)| *at)
}

/// The first log line holding `text`.
fn log_line(heard: &[(Instant, Said)], text: &str) -> Option<String> {
    heard.iter().find_map(|(_, s)| match s {
        Said::Log(l) if l.contains(text) => Some(l.clone()),
        _ => None,
    })
}

#[test]
fn ready_once_the_buses_tried_their_ports_then_pings_while_every_bus_thread_turns() {
    let mut bridge = Service::start("service-ready", &[]);
    assert!(
        bridge.listen_until(PATIENCE, |h| h.iter().any(|(_, s)| is_ready(s))),
        "no READY=1:\n{}",
        bridge.transcript()
    );
    let (ready_at, ready) = bridge.heard.iter().find(|(_, s)| is_ready(s)).unwrap();
    let ready_at = *ready_at;
    // The status systemd shows: the simulated bus open, the missing port tried.
    let Said::Notify(ready) = ready else {
        unreachable!()
    };
    assert!(
        ready.contains("STATUS=3 servos, 1 of 2 buses open"),
        "{ready}\n{}",
        bridge.transcript()
    );
    // Nothing pinged before it was ready.
    let first_ping = bridge
        .heard
        .iter()
        .position(|(_, s)| matches!(s, Said::Notify(t) if t.contains("WATCHDOG=1")));
    let ready_pos = bridge.heard.iter().position(|(_, s)| is_ready(s)).unwrap();
    assert!(
        first_ping.is_none_or(|p| p >= ready_pos),
        "{}",
        bridge.transcript()
    );

    // Four watchdog timeouts: the missing port's back-off grows past a second meanwhile, and
    // its thread must still turn. Pings every 500 ms: about 8 of them.
    let window = 4 * WATCHDOG;
    bridge.listen_until(window, |_| false);
    let pings = bridge.pings_after(ready_at);
    assert!(
        pings >= 5,
        "{pings} pings in {window:?}:\n{}",
        bridge.transcript()
    );
    assert!(
        log_has(&bridge.heard, "no longer fed").is_none(),
        "{}",
        bridge.transcript()
    );
}

#[test]
fn a_bus_thread_that_hangs_stops_the_pings_and_is_named() {
    let mut bridge = Service::start("service-hang", &[("LJ9DA_TEST_HANG_BUS", "wing:1.5")]);
    let stuck = "bus thread stuck";
    assert!(
        bridge.listen_until(PATIENCE, |h| log_has(h, stuck).is_some()),
        "the stuck bus thread was not noticed:\n{}",
        bridge.transcript()
    );
    let transcript = bridge.transcript();
    // It pinged while the thread ran.
    let ready_at = bridge
        .heard
        .iter()
        .find(|(_, s)| is_ready(s))
        .map(|(at, _)| *at);
    let hung_at = log_has(&bridge.heard, "bus thread hangs now").expect("the switch's line");
    let ready_at = ready_at.unwrap_or_else(|| panic!("no READY=1:\n{transcript}"));
    assert!(
        bridge.heard.iter().any(|(at, s)| *at > ready_at
            && *at < hung_at
            && matches!(s, Said::Notify(t) if t.contains("WATCHDOG=1"))),
        "no ping before the hang:\n{transcript}"
    );
    // The line names the bus that hangs, not the one whose port is missing.
    let line = log_line(&bridge.heard, stuck).unwrap();
    assert!(line.contains("wing") && !line.contains("tail"), "{line}");

    // From the line on, no ping: the main loop looked (it logged the line) and keeps looking
    // every 500 ms; over three watchdog timeouts it must never find the hung thread turning.
    let told_at = log_has(&bridge.heard, stuck).unwrap();
    bridge.listen_until(3 * WATCHDOG, |_| false);
    // A ping already on its way when the line was written is no ping after it.
    let settle = told_at + Duration::from_millis(100);
    assert_eq!(bridge.pings_after(settle), 0, "{}", bridge.transcript());
    assert!(
        bridge.child.try_wait().unwrap().is_none(),
        "the bridge itself goes on (systemd kills it):\n{}",
        bridge.transcript()
    );
}

#[test]
fn a_start_that_a_bus_thread_holds_up_says_which_and_is_ready_without_pings() {
    // The wing's thread hangs at once after its first attempt at the port, before it counts
    // the turn: the start waits for it, says which bus it waited for, and is ready all the
    // same; with that thread stuck, the watchdog is never fed.
    let started = Instant::now();
    let mut bridge = Service::start("service-held", &[("LJ9DA_TEST_HANG_BUS", "wing:0")]);
    let wait = lj9da_bridge::runtime::service::READY_WAIT;
    let told = "has not tried its port";
    // The log line and the datagram come by two pipes: wait for both.
    assert!(
        bridge.listen_until(wait + PATIENCE, |h| {
            h.iter().any(|(_, s)| is_ready(s)) && log_has(h, told).is_some()
        }),
        "no READY=1, or the wait not told:\n{}",
        bridge.transcript()
    );
    let ready_at = bridge.heard.iter().find(|(_, s)| is_ready(s)).unwrap().0;
    assert!(
        ready_at >= started + wait,
        "ready {:?} after the start, before the wait was over:\n{}",
        ready_at - started,
        bridge.transcript()
    );
    let line = log_line(&bridge.heard, told).unwrap();
    assert!(line.contains("wing"), "{line}");
    bridge.listen_until(2 * WATCHDOG, |_| false);
    let pings = bridge
        .heard
        .iter()
        .filter(|(_, s)| matches!(s, Said::Notify(t) if t.contains("WATCHDOG=1")))
        .count();
    assert_eq!(pings, 0, "{}", bridge.transcript());
}

#[test]
fn a_bridge_that_hears_no_autopilot_says_so_and_where_it_listens() {
    let started = Instant::now();
    let mut bridge = Service::start("service-no-autopilot", &[]);
    let note = "no outputs heard from the autopilot for";
    assert!(
        bridge.listen_until(Duration::from_secs(10) + PATIENCE, |h| log_has(h, note)
            .is_some()),
        "nothing said of the missing autopilot:\n{}",
        bridge.transcript()
    );
    let told_at = log_has(&bridge.heard, note).unwrap();
    assert!(
        told_at >= started + Duration::from_secs(10),
        "{}",
        bridge.transcript()
    );
    let line = log_line(&bridge.heard, note).unwrap();
    assert!(line.contains("udpin:127.0.0.1:"), "{line}");
    assert!(
        line.contains("SERIALn_PROTOCOL")
            && line.contains("MAV_n_CONFIG")
            && line.contains("SER_<port>_PROTO on PX4 main"),
        "{line}"
    );
}

/// Each thread of process `pid`: its name, scheduling policy and real-time priority (fields 41
/// and 40 of proc_pid_stat(5)), the main thread first.
fn threads_of(pid: u32) -> Vec<(String, u32, u32)> {
    let mut tids: Vec<u32> = std::fs::read_dir(format!("/proc/{pid}/task"))
        .expect("the bridge's threads")
        .filter_map(|e| e.ok()?.file_name().to_str()?.parse().ok())
        .collect();
    tids.sort_by_key(|tid| *tid != pid);
    tids.into_iter()
        .filter_map(|tid| {
            let stat = std::fs::read_to_string(format!("/proc/{pid}/task/{tid}/stat")).ok()?;
            let name = stat[stat.find('(')? + 1..stat.rfind(')')?].to_string();
            // The fields after the name begin with field 3 (state).
            let after: Vec<&str> = stat[stat.rfind(')')? + 2..].split_whitespace().collect();
            Some((
                name,
                after[41 - 3].parse().ok()?,
                after[40 - 3].parse().ok()?,
            ))
        })
        .collect()
}

#[test]
fn the_mavlink_loop_and_the_bus_threads_run_real_time_and_nothing_else_does() {
    // Whether this machine grants real-time scheduling to the test (and so to the bridge).
    let granted = std::thread::spawn(|| lj9da_realtime::request_fifo(1).is_ok())
        .join()
        .unwrap();
    let mut bridge = Service::start("service-realtime", &[]);
    assert!(
        bridge.listen_until(PATIENCE, |h| h.iter().any(|(_, s)| is_ready(s))),
        "no READY=1:\n{}",
        bridge.transcript()
    );
    let threads = threads_of(bridge.child.id());
    let fifo = nix::libc::SCHED_FIFO as u32;
    let normal = nix::libc::SCHED_OTHER as u32;
    let (main, rest) = threads.split_first().expect("a main thread");
    let (buses, others): (Vec<_>, Vec<_>) = rest.iter().partition(|(n, ..)| n.starts_with("bus "));
    assert_eq!(buses.len(), 2, "{threads:?}");
    if granted {
        let (loop_priority, bus_priority) = (
            lj9da_bridge::runtime::LOOP_PRIORITY as u32,
            lj9da_bridge::bus::driver::REALTIME_PRIORITY as u32,
        );
        assert_eq!(
            (main.1, main.2),
            (fifo, loop_priority),
            "the MAVLink loop: {threads:?}"
        );
        for bus in &buses {
            assert_eq!((bus.1, bus.2), (fifo, bus_priority), "{threads:?}");
        }
        for other in &others {
            assert_eq!(other.1, normal, "{other:?} of {threads:?}");
        }
    } else {
        assert!(threads.iter().all(|t| t.1 == normal), "{threads:?}");
        assert!(
            log_has(&bridge.heard, "without real-time scheduling").is_some(),
            "{}",
            bridge.transcript()
        );
    }
}

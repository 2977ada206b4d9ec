//! A bus that asks for RS485 mode on a port whose driver refuses it (here a pseudo-terminal,
//! which has no RS485 mode, as a UART without it in its device tree) is not started: its port
//! is reported as not open, nothing is written on it, and the other buses run on. Through the
//! binary: the error at start names the bus, the port, the errno and what to check.

mod bus_support;
#[path = "common/ports.rs"]
mod ports;

use bus_support::*;
use lj9da_bridge::bus::spawn_bus;
use lj9da_bridge::protocol::BaudRate;
use lj9da_bridge::serial::rs485::Rs485Mode;
use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use nix::pty::{OpenptyResult, openpty};
use std::ffi::CString;
use std::fs::File;
use std::io::{BufRead, BufReader, Read};
use std::os::fd::{AsFd, AsRawFd, FromRawFd};
use std::os::unix::ffi::OsStrExt;
use std::path::Path;
use std::process::{Command, Stdio};

/// The closings of a file from now on, as the kernel tells them (inotify's `IN_CLOSE`): each
/// attempt of a bus to open its port ends with one when the port is refused.
struct Closings {
    inotify: File,
}

impl Closings {
    fn watch(path: &Path) -> Closings {
        // SAFETY: a plain system call; the descriptor it returns is owned by the `File` below.
        let fd = unsafe { libc::inotify_init1(libc::IN_CLOEXEC | libc::IN_NONBLOCK) };
        assert!(fd >= 0, "inotify: {}", std::io::Error::last_os_error());
        // SAFETY: `fd` is open and nothing else owns it.
        let inotify = unsafe { File::from_raw_fd(fd) };
        let name = CString::new(path.as_os_str().as_bytes()).expect("a path without NUL");
        // SAFETY: `name` is a NUL-terminated string that outlives the call.
        let watch = unsafe { libc::inotify_add_watch(fd, name.as_ptr(), libc::IN_CLOSE) };
        assert!(
            watch >= 0,
            "inotify on {}: {}",
            path.display(),
            std::io::Error::last_os_error()
        );
        Closings { inotify }
    }

    /// Block until `count` closings were seen; fail after [`PATIENCE`].
    fn wait(mut self, count: usize) {
        let deadline = std::time::Instant::now() + PATIENCE;
        let mut seen = 0;
        let mut buffer = [0u8; 4096];
        while seen < count {
            let left = deadline.saturating_duration_since(std::time::Instant::now());
            assert!(
                !left.is_zero(),
                "the port was closed {seen} times, not {count}"
            );
            let millis = u16::try_from(left.as_millis().max(1)).unwrap_or(u16::MAX);
            let mut fds = [PollFd::new(self.inotify.as_fd(), PollFlags::POLLIN)];
            let _ = poll(&mut fds, PollTimeout::from(millis));
            let n = match self.inotify.read(&mut buffer) {
                Ok(n) => n,
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => continue,
                Err(e) => panic!("inotify read: {e}"),
            };
            // Each event: wd (4 bytes), mask (4), cookie (4), name length (4), the name.
            let mut at = 0;
            while at + 16 <= n {
                let mask = u32::from_ne_bytes(buffer[at + 4..at + 8].try_into().unwrap());
                let name_len = u32::from_ne_bytes(buffer[at + 12..at + 16].try_into().unwrap());
                if mask & libc::IN_CLOSE != 0 {
                    seen += 1;
                }
                at += 16 + name_len as usize;
            }
        }
    }
}

/// A pseudo-terminal with no one on the other end, and its slave's path.
fn bare_pty() -> (OpenptyResult, std::path::PathBuf) {
    let pty = openpty(None, None).expect("a pseudo-terminal");
    let path = nix::unistd::ttyname(&pty.slave).expect("its name");
    (pty, path)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_refused_bus_stays_closed_and_silent_while_the_others_run() {
    let (refusing, refusing_path) = bare_pty();
    let mut wing = bus_config(&[1], BaudRate::B115200);
    wing.rs485 = Some(Rs485Mode::default());
    let refused = spawn_bus(wing.clone(), refusing_path.clone());

    let ids = [1, 2];
    let sim = spawn_sim(sim_config(&ids, 115_200));
    let running = spawn_bus(bus_config(&ids, BaudRate::B115200), sim.path());

    every_servo_online(&running).await;
    wait_status(
        &refused,
        "the refused bus reported with its port closed",
        |s| !s.port_open,
    )
    .await;
    // It keeps trying (a port may come back), but never opens nor writes a byte: seen after
    // two more attempts, each over once the bus has closed the port again.
    let closings = Closings::watch(&refusing_path);
    tokio::task::spawn_blocking(move || closings.wait(2))
        .await
        .expect("the watch of the port");
    let status = refused.status();
    assert!(!status.port_open, "{status:?}");
    assert_eq!(status.counters.bytes_sent, 0, "{status:?}");
    let flags = nix::fcntl::fcntl(refusing.master.as_raw_fd(), nix::fcntl::FcntlArg::F_GETFL)
        .expect("flags");
    nix::fcntl::fcntl(
        refusing.master.as_raw_fd(),
        nix::fcntl::FcntlArg::F_SETFL(
            nix::fcntl::OFlag::from_bits_retain(flags) | nix::fcntl::OFlag::O_NONBLOCK,
        ),
    )
    .expect("non-blocking");
    let mut master = File::from(refusing.master);
    let mut buf = [0u8; 64];
    match master.read(&mut buf) {
        Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {}
        other => panic!("the refused port was written to: {other:?}"),
    }
    assert!(running.status().port_open);

    // Without the RS485 request the same port opens: the refusal is what kept it closed.
    refused
        .shutdown(lj9da_bridge::bus::ShutdownForce::AsIs)
        .await;
    wing.rs485 = None;
    let plain = spawn_bus(wing, refusing_path.clone());
    wait_status(&plain, "the same port open with no RS485 mode asked", |s| {
        s.port_open
    })
    .await;
}

#[test]
fn the_bridge_says_at_start_which_bus_is_not_started_and_what_to_check() {
    let (_refusing, refusing_path) = bare_pty();
    let (_plain, plain_path) = bare_pty();
    let dir = std::env::temp_dir().join(format!("lj9da-rs485-run-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mapping = dir.join("hat.toml");
    // The bridge refuses a port another program took after the test found it free (see
    // `ports`), naming that program: it starts again on another port.
    let (mut child, seen, refusal, tail_open) = loop {
        std::fs::write(
            &mapping,
            format!(
                r#"[mavlink]
connection = "udpin:127.0.0.1:{}"

[record]
enabled = false

[[bus]]
name = "wing"
port = "{}"
rs485 = {{ rts_on_send = true }}

[[bus]]
name = "tail"
port = "{}"

[[servo]]
name = "aileron"
bus = "wing"
id = 1
channel = 1

[[servo]]
name = "rudder"
bus = "tail"
id = 2
channel = 4
"#,
                ports::free_udp_port(),
                refusing_path.display(),
                plain_path.display()
            ),
        )
        .unwrap();
        let mut child = Command::new(env!("CARGO_BIN_EXE_lj9da-bridge"))
            .args(["run", "--config"])
            .arg(&mapping)
            .env("RUST_LOG", "lj9da_bridge=info")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .expect("the bridge starts");
        let stderr = child.stderr.take().unwrap();
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        let mut seen = Vec::new();
        let mut refusal = None;
        let mut tail_open = false;
        let mut told_ground = false;
        let deadline = std::time::Instant::now() + PATIENCE;
        // The other bus's servo found silent comes some 300 ms after the ports were opened: by
        // then any second report of the wing's port would have been logged too.
        let mut tail_servo_lost = false;
        while refusal.is_none() || !tail_open || !told_ground || !tail_servo_lost {
            let left = deadline.saturating_duration_since(std::time::Instant::now());
            match rx.recv_timeout(left) {
                Ok(line) => {
                    if line.contains("not started") {
                        refusal = Some(line.clone());
                    }
                    if line.contains("servo 2 lost") {
                        tail_servo_lost = true;
                    }
                    // The STATUSTEXT to the ground station, as the MAVLink side logs it.
                    if line.contains("LJ9DA bus wing: port lost") {
                        told_ground = true;
                    }
                    if line.contains("serial port open")
                        && line.contains(&*plain_path.to_string_lossy())
                    {
                        tail_open = true;
                    }
                    seen.push(line);
                }
                Err(_) => break,
            }
        }
        if let Some(line) = seen.iter().find(|l| l.contains(ports::TAKEN)) {
            eprintln!("started again on another port: {line}");
            let _ = child.kill();
            let _ = child.wait();
            continue;
        }
        break (child, seen, refusal, tail_open);
    };
    let _ = child.kill();
    let _ = child.wait();
    let _ = std::fs::remove_dir_all(&dir);
    let log = seen.join("\n");
    let refusal = refusal.unwrap_or_else(|| panic!("no refusal in the log:\n{log}"));
    for part in [
        "ERROR",
        "bus \"wing\" not started",
        &*refusing_path.to_string_lossy(),
        "ENOTTY",
        "linux,rs485-enabled-at-boot-time",
        "automatic direction control",
    ] {
        assert!(refusal.contains(part), "{part:?} not in {refusal}");
    }
    assert!(tail_open, "the other bus did not open its port:\n{log}");
    // Said once, however often the port is tried again; told to the ground station once,
    // whether the bus gave up on the port before the MAVLink side listened or after.
    assert_eq!(log.matches("not started").count(), 1, "{log}");
    assert_eq!(log.matches("LJ9DA bus wing: port lost").count(), 1, "{log}");
}

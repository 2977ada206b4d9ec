//! Real autopilots for the tests: ArduPlane and PX4 SITL as separate processes, a UDP tap
//! between the autopilot and the bridge that keeps every SERVO_OUTPUT_RAW it passes on, and a
//! pymavlink ground station connected to the autopilot.
//!
//! Where the autopilots are: `$LJ9DA_ARDUPLANE` (the `arduplane` program; its SITL defaults
//! `plane.parm` beside it, or `$LJ9DA_ARDUPLANE_DEFAULTS`) and `$LJ9DA_PX4` (a folder with
//! `bin/px4` and `etc/`), else `../shared/sitl/` beside the repository.

pub mod can;

use crate::common::python::python;
use mavlink::MavlinkReader;
use mavlink::dialects::common::{MavMessage, SERVO_OUTPUT_RAW_DATA};
use std::io::{BufRead, BufReader, Write};
use std::net::{SocketAddr, UdpSocket};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// `../shared/sitl` beside the repository.
fn shared_sitl() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/sitl")
}

/// The `arduplane` SITL program and its defaults file, if there is one.
pub fn arduplane() -> Option<(PathBuf, PathBuf)> {
    let binary = std::env::var_os("LJ9DA_ARDUPLANE")
        .map(PathBuf::from)
        .unwrap_or_else(|| shared_sitl().join("ardupilot/arduplane"));
    let defaults = std::env::var_os("LJ9DA_ARDUPLANE_DEFAULTS")
        .map(PathBuf::from)
        .unwrap_or_else(|| binary.with_file_name("plane.parm"));
    (binary.is_file() && defaults.is_file()).then_some((binary, defaults))
}

/// The PX4 SITL folder (`bin/px4`, `etc/`), if there is one.
pub fn px4() -> Option<PathBuf> {
    let root = std::env::var_os("LJ9DA_PX4")
        .map(PathBuf::from)
        .unwrap_or_else(|| shared_sitl().join("px4"));
    (root.join("bin/px4").is_file() && root.join("etc").is_dir()).then_some(root)
}

/// A fresh folder under the target's temporary directory.
pub fn fresh_dir(name: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("autopilot-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("a folder for the autopilot");
    dir
}

/// The fenced block that follows `marker` in `page` (a file of the repository), as text.
pub fn block_after(page: &str, marker: &str) -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(page);
    let text = std::fs::read_to_string(&path).expect("the page reads");
    let after = text
        .split_once(marker)
        .unwrap_or_else(|| panic!("{page} has no `{marker}`"))
        .1;
    let body = after
        .split_once("```")
        .and_then(|(_, rest)| rest.split_once('\n'))
        .map(|(_, rest)| rest)
        .unwrap_or_else(|| panic!("no fenced block after `{marker}` in {page}"));
    let end = body
        .find("\n```")
        .unwrap_or_else(|| panic!("the block after `{marker}` in {page} is not closed"));
    body[..end + 1].to_string()
}

/// An autopilot process, killed when dropped.
pub struct Autopilot {
    child: Child,
    log: PathBuf,
}

impl Autopilot {
    /// ArduPlane in `dir` (its eeprom, logs), with `defaults` (comma-separated `.parm` files),
    /// SERIAL0 listening on TCP 5760 and SERIAL1 sending to UDP `udp_port`.
    pub fn arduplane(binary: &Path, dir: &Path, defaults: &str, udp_port: u16) -> Autopilot {
        let log = dir.join("arduplane.log");
        let child = Command::new(binary)
            .current_dir(dir)
            .args(["--model", "plane", "--speedup", "1", "-I0"])
            .args(["--home", "-35.363261,149.165230,584,353"])
            .args(["--defaults", defaults])
            .arg("--serial0=tcp:0")
            .arg(format!("--serial1=udpclient:127.0.0.1:{udp_port}"))
            .stdin(Stdio::null())
            .stdout(std::fs::File::create(&log).expect("the autopilot's log"))
            .stderr(Stdio::from(
                std::fs::File::options()
                    .append(true)
                    .open(&log)
                    .expect("the autopilot's log"),
            ))
            .spawn()
            .unwrap_or_else(|e| panic!("{} does not start: {e}", binary.display()));
        Autopilot { child, log }
    }

    /// PX4 SITL (SIH) as `model` in `dir`, with parameters `params` set at boot
    /// (`PX4_PARAM_<NAME>`); returns once its start-up script has returned.
    pub fn px4(root: &Path, model: &str, dir: &Path, params: &[(&str, &str)]) -> Autopilot {
        let bin = px4_bin(root);
        let log = dir.join("px4.log");
        let mut command = Command::new(bin.join("px4"));
        command
            .current_dir(dir)
            .env("PX4_SIM_MODEL", model)
            .env("PX4_SIMULATOR", "sihsim")
            .arg("-d")
            .arg("-w")
            .arg(dir)
            .arg(root.join("etc"))
            .stdin(Stdio::null())
            .stdout(std::fs::File::create(&log).expect("the autopilot's log"))
            .stderr(Stdio::null());
        for (name, value) in params {
            command.env(format!("PX4_PARAM_{name}"), value);
        }
        let child = command.spawn().expect("px4 starts");
        let ap = Autopilot { child, log };
        let deadline = Instant::now() + Duration::from_secs(60);
        loop {
            let text = std::fs::read_to_string(&ap.log).unwrap_or_default();
            if text.contains("Startup script returned successfully") {
                return ap;
            }
            assert!(
                !text.contains("Startup script returned with return value"),
                "PX4's start-up script failed:\n{text}"
            );
            assert!(
                Instant::now() < deadline,
                "PX4 did not start within 60 s:\n{text}"
            );
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// Kill it at once (SIGKILL), as a crash would, and wait for it.
    pub fn kill(mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    /// What it wrote to its console.
    pub fn console(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }
}

impl Drop for Autopilot {
    fn drop(&mut self) {
        // SIGTERM first: PX4 then removes its server's lock for the next instance 0.
        let _ = nix::sys::signal::kill(
            nix::unistd::Pid::from_raw(self.child.id() as i32),
            nix::sys::signal::Signal::SIGTERM,
        );
        let deadline = Instant::now() + Duration::from_secs(5);
        while Instant::now() < deadline {
            if let Ok(Some(_)) = self.child.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// PX4's `bin` with its `px4-*` module links (a copy that made them plain files breaks its
/// start-up): made once under the target directory.
fn px4_bin(root: &Path) -> PathBuf {
    let made = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("px4-bin");
    let source = root.join("bin");
    let stamp = std::fs::metadata(source.join("px4"))
        .and_then(|m| m.modified())
        .expect("bin/px4");
    if std::fs::metadata(made.join("px4"))
        .and_then(|m| m.modified())
        .is_ok_and(|t| t >= stamp)
    {
        return made;
    }
    let part = made.with_extension("part");
    let _ = std::fs::remove_dir_all(&part);
    std::fs::create_dir_all(&part).expect("px4-bin");
    for entry in std::fs::read_dir(&source).expect("PX4's bin") {
        let name = entry.expect("an entry").file_name();
        let name = name.to_string_lossy();
        if name.starts_with("px4-") && name != "px4-alias.sh" {
            std::os::unix::fs::symlink("px4", part.join(&*name)).expect("a module link");
        } else {
            std::fs::copy(source.join(&*name), part.join(&*name)).expect("copy");
        }
    }
    let _ = std::fs::remove_dir_all(&made);
    std::fs::rename(&part, &made).expect("px4-bin in place");
    made
}

/// One SERVO_OUTPUT_RAW passed from the autopilot to the bridge, and when.
#[derive(Clone, Debug)]
pub struct Tapped {
    pub at: Instant,
    pub outputs: SERVO_OUTPUT_RAW_DATA,
}

/// What the tap saw.
#[derive(Default)]
struct TapState {
    bridge: Option<SocketAddr>,
    /// The bridge's datagrams are dropped, not passed on: to the autopilot, a bridge killed.
    bridge_silenced: bool,
    autopilot: Option<SocketAddr>,
    outputs: Vec<Tapped>,
    /// When the last datagram from the autopilot came.
    last_from_autopilot: Option<Instant>,
    /// Datagrams whose first frame is MAVLink 2 with a signature: (from the autopilot, from
    /// the bridge), and all datagrams the same way.
    signed: (u64, u64),
    datagrams: (u64, u64),
    /// `datagrams` and `signed` as they were just before the autopilot's first signed
    /// datagram: the count of a signed link starts there.
    before_first_signed: Option<((u64, u64), (u64, u64))>,
}

/// Whether a datagram's first frame is a signed MAVLink 2 frame (incompat_flags bit 0).
fn signed(datagram: &[u8]) -> bool {
    datagram.first() == Some(&0xFD) && datagram.get(2).is_some_and(|f| f & 1 != 0)
}

/// A UDP tap on the autopilot's link: the autopilot sends to `port`, the tap passes every
/// datagram on to the bridge's `udpin` port, and the bridge's datagrams back to the autopilot's
/// address. It keeps every SERVO_OUTPUT_RAW it passed on.
pub struct Tap {
    pub port: u16,
    state: Arc<Mutex<TapState>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl Tap {
    pub fn start(port: u16) -> Tap {
        let socket = UdpSocket::bind(("127.0.0.1", port))
            .unwrap_or_else(|e| panic!("UDP port {port} for the tap: {e}"));
        socket
            .set_read_timeout(Some(Duration::from_millis(50)))
            .unwrap();
        let state = Arc::new(Mutex::new(TapState::default()));
        let stop = Arc::new(AtomicBool::new(false));
        let (s, st) = (state.clone(), stop.clone());
        let thread = std::thread::spawn(move || {
            let mut buf = [0u8; 65536];
            while !st.load(Ordering::Relaxed) {
                let Ok((n, from)) = socket.recv_from(&mut buf) else {
                    continue;
                };
                let at = Instant::now();
                let datagram = &buf[..n];
                let mut state = s.lock().unwrap();
                if Some(from) == state.bridge {
                    state.datagrams.1 += 1;
                    state.signed.1 += u64::from(signed(datagram));
                    if state.bridge_silenced {
                        continue;
                    }
                    if let Some(to) = state.autopilot {
                        let _ = socket.send_to(datagram, to);
                    }
                    continue;
                }
                state.autopilot = Some(from);
                state.last_from_autopilot = Some(at);
                if signed(datagram) && state.before_first_signed.is_none() {
                    state.before_first_signed = Some((
                        (state.datagrams.0, state.signed.0),
                        (state.datagrams.1, state.signed.1),
                    ));
                }
                state.datagrams.0 += 1;
                state.signed.0 += u64::from(signed(datagram));
                let mut reader = MavlinkReader::new(datagram);
                while let Ok((_, msg)) = reader.read_any_message::<MavMessage>() {
                    if let MavMessage::SERVO_OUTPUT_RAW(outputs) = msg {
                        state.outputs.push(Tapped { at, outputs });
                    }
                }
                if let Some(to) = state.bridge {
                    let _ = socket.send_to(datagram, to);
                }
            }
        });
        Tap {
            port,
            state,
            stop,
            thread: Some(thread),
        }
    }

    /// Pass the autopilot's datagrams to the bridge's `udpin` port from now on.
    pub fn to_bridge(&self, port: u16) {
        self.state.lock().unwrap().bridge = Some(SocketAddr::from(([127, 0, 0, 1], port)));
    }

    /// From now on the bridge's datagrams no longer reach the autopilot, as if the bridge had
    /// been killed, its computer's power cut or its cable pulled: no last word.
    pub fn silence_bridge(&self) {
        self.state.lock().unwrap().bridge_silenced = true;
    }

    /// Every SERVO_OUTPUT_RAW passed on since `since`.
    pub fn outputs_since(&self, since: Instant) -> Vec<Tapped> {
        let state = self.state.lock().unwrap();
        state
            .outputs
            .iter()
            .filter(|t| t.at >= since)
            .cloned()
            .collect()
    }

    /// Every SERVO_OUTPUT_RAW passed on.
    pub fn outputs(&self) -> Vec<Tapped> {
        self.state.lock().unwrap().outputs.clone()
    }

    /// Datagrams passed on since the autopilot's first signed one (that one included), and how
    /// many of them were signed: `((from the autopilot, signed), (from the bridge, signed))`; `None` while the autopilot has signed
    /// nothing. Signing begins whenever the autopilot takes its key, so a count from any other
    /// moment races with it.
    pub fn datagrams_since_first_signed(&self) -> Option<((u64, u64), (u64, u64))> {
        let state = self.state.lock().unwrap();
        let ((ap_all, ap_signed), (br_all, br_signed)) = state.before_first_signed?;
        Some((
            (state.datagrams.0 - ap_all, state.signed.0 - ap_signed),
            (state.datagrams.1 - br_all, state.signed.1 - br_signed),
        ))
    }

    /// When the autopilot's last datagram came.
    pub fn last_from_autopilot(&self) -> Option<Instant> {
        self.state.lock().unwrap().last_from_autopilot
    }

    /// Wait until the autopilot has sent something (it is up), or panic after `timeout`.
    pub fn wait_for_autopilot(&self, timeout: Duration, console: impl Fn() -> String) {
        let deadline = Instant::now() + timeout;
        while self.last_from_autopilot().is_none() {
            assert!(
                Instant::now() < deadline,
                "the autopilot sent nothing to UDP {} in {timeout:?}; its console:\n{}",
                self.port,
                console()
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }
}

impl Drop for Tap {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// A message the ground station heard, as pymavlink decoded it.
pub type GcsMessage = serde_json::Value;

/// A pymavlink ground station on `address` (`tests/autopilots/gcs.py`).
pub struct GroundStation {
    child: Mutex<Child>,
    stdin: ChildStdin,
    heard: Arc<Mutex<Vec<GcsMessage>>>,
}

impl GroundStation {
    pub fn connect(address: &str) -> GroundStation {
        let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/autopilots/gcs.py");
        let mut child = Command::new(python())
            .arg(script)
            .arg(address)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("the pymavlink ground station starts");
        let stdin = child.stdin.take().unwrap();
        let stdout = child.stdout.take().unwrap();
        let heard = Arc::new(Mutex::new(Vec::new()));
        let h = heard.clone();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines() {
                let Ok(line) = line else { break };
                if let Ok(v) = serde_json::from_str::<GcsMessage>(&line) {
                    h.lock().unwrap().push(v);
                }
            }
        });
        let gcs = GroundStation {
            child: Mutex::new(child),
            stdin,
            heard,
        };
        gcs.wait_for("the ground station's start", Duration::from_secs(30), |m| {
            m["msg"] == "READY"
        });
        gcs
    }

    /// Send `message` (pymavlink's name, e.g. `COMMAND_LONG`) with `fields`.
    pub fn send(&mut self, message: &str, fields: serde_json::Value) {
        self.command(serde_json::json!({"send": message, "fields": fields}));
    }

    /// Send a raw command line to the script (see `gcs.py`).
    pub fn command(&mut self, command: serde_json::Value) {
        writeln!(self.stdin, "{command}").expect("the ground station takes a command");
        self.stdin.flush().unwrap();
    }

    /// How many messages heard so far (a mark for [`GroundStation::heard_after`]).
    pub fn mark(&self) -> usize {
        self.heard.lock().unwrap().len()
    }

    /// The messages heard after `mark`.
    pub fn heard_after(&self, mark: usize) -> Vec<GcsMessage> {
        self.heard.lock().unwrap()[mark..].to_vec()
    }

    /// Wait until a message that `pred` accepts has been heard, and return it; panic after
    /// `timeout` naming `what`.
    pub fn wait_for(
        &self,
        what: &str,
        timeout: Duration,
        pred: impl Fn(&GcsMessage) -> bool,
    ) -> GcsMessage {
        self.wait_for_after(0, what, timeout, pred)
    }

    /// As [`GroundStation::wait_for`], among the messages heard after `mark`.
    pub fn wait_for_after(
        &self,
        mark: usize,
        what: &str,
        timeout: Duration,
        pred: impl Fn(&GcsMessage) -> bool,
    ) -> GcsMessage {
        let deadline = Instant::now() + timeout;
        loop {
            if let Some(m) = self.heard.lock().unwrap()[mark..].iter().find(|m| pred(m)) {
                return m.clone();
            }
            if let Ok(Some(status)) = self.child.lock().unwrap().try_wait() {
                panic!("the ground station ended ({status}) before it heard {what}");
            }
            assert!(
                Instant::now() < deadline,
                "the ground station did not hear {what} in {timeout:?}; it heard {} messages, the \
                 last ones: {:?}",
                self.mark(),
                self.heard_after(self.mark().saturating_sub(8))
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

impl Drop for GroundStation {
    fn drop(&mut self) {
        let child = self.child.get_mut().unwrap();
        let _ = child.kill();
        let _ = child.wait();
    }
}

/// Whether `m` came from system `sys`, component `comp`.
pub fn from(m: &GcsMessage, sys: u8, comp: u8) -> bool {
    m["src"] == serde_json::json!([sys, comp])
}

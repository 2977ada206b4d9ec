//! MAVLink 2 signing against a third-party implementation: pymavlink with `setup_signing`, over
//! real UDP sockets, plays the autopilot and the ground station of a bridge whose mapping has a
//! signing key (simulated servos on pseudo-terminals behind it).
//!
//! - A signed autopilot's outputs move the servos, and it accepts the bridge's signed messages.
//! - An unsigned autopilot, and one signing with another key, move nothing: every message is
//!   dropped and counted per reason in the bridge's view, and neither hears the bridge on its
//!   `udpin` link (which answers only where an accepted frame came from).
//! - A signed ground station sees the bridge's HEARTBEAT and telemetry, verified by pymavlink,
//!   and its commands are answered; one with another key sees nothing from the bridge and its
//!   commands are dropped; an unsigned one hears the bridge but its commands are dropped too.
//! - A mapping's `signing_passphrase` is the key MAVProxy's `signing setup` derives.
//! - A restart with the clock behind the stored timestamp reservation signs above it.
//!
//! The Python environment: `$LJ9DA_PYTHON` if set, else a virtual environment made once, under a
//! lock, in the target directory with `pip install pymavlink` (see `common/python.rs`).

mod common;

use common::mapping::Mapping;
use common::python::python;
use common::{Chain, ChainOptions, free_udp_port};
use lj9da_bridge::runtime::BridgeView;
use std::collections::HashMap;
use std::io::{BufRead, BufReader, Read};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

const KEY_HEX: &str = "5e1f0a2b3c4d5e6f708192a3b4c5d6e7f8091a2b3c4d5e6f708192a3b4c5d6e7";
const OTHER_KEY_HEX: &str = "0000000000000000000000000000000000000000000000000000000000000001";
const PASSPHRASE: &str = "flaps and ailerons";

/// What the autopilot script's 1900 µs on channel 1 means with the default PWM range (920/1520/2120
/// µs ↔ −25/0/+25 mm): +15.83 mm.
const COMMANDED_MM: f64 = 25.0 * (1900.0 - 1520.0) / 600.0;

/// A mapping signed with `signing` (a `signing_*` line), its timestamp file under the target's
/// temporary folder. The vehicle's system id is set, so that the bridge sends its HEARTBEAT
/// before it has accepted one from the autopilot.
fn mapping(signing: &str, name: &str) -> (String, PathBuf) {
    let ts = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!(
        "signing-{name}-{}.signing-timestamp",
        std::process::id()
    ));
    let _ = std::fs::remove_file(&ts);
    let mavlink = format!(
        "system_id = 1\noutput_rate_hz = 20\n{signing}\nsigning_timestamp_file = \"{}\"",
        ts.display()
    );
    let text = Mapping::aileron_and_rudder()
        .with("[mavlink]", &mavlink)
        .with("[telemetry]", "rate_hz = 10")
        .to_string();
    (text, ts)
}

fn keyed(name: &str) -> (String, PathBuf) {
    mapping(&format!("signing_key = \"{KEY_HEX}\""), name)
}

/// A pymavlink peer, running until [`Peer::stop`] closes its standard input (or the test ends
/// and drops it), so that a test waits for what it needs, not for a fixed run.
struct Peer {
    what: String,
    child: Child,
    /// Everything it printed so far, and the counts of its latest `progress` line.
    stdout: Arc<Mutex<(String, HashMap<String, u64>)>>,
    stderr: Arc<Mutex<String>>,
    readers: Vec<std::thread::JoinHandle<()>>,
}

impl Peer {
    /// Start the pymavlink `script` with `args`; its first argument after the port is the most
    /// seconds it may run (a bound for a test that hangs, never reached by one that passes).
    async fn start(script: &'static str, args: Vec<String>, what: &str) -> Peer {
        let python = tokio::task::spawn_blocking(python).await.unwrap();
        let mut child = Command::new(&python)
            .arg("-c")
            .arg(script)
            .args(&args)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap_or_else(|e| panic!("pymavlink {what} did not run: {e}"));
        let stdout = Arc::new(Mutex::new((String::new(), HashMap::new())));
        let stderr = Arc::new(Mutex::new(String::new()));
        let out = child.stdout.take().unwrap();
        let seen = stdout.clone();
        let mut err = child.stderr.take().unwrap();
        let said = stderr.clone();
        let readers = vec![
            std::thread::spawn(move || {
                for line in BufReader::new(out).lines().map_while(Result::ok) {
                    let mut seen = seen.lock().unwrap();
                    if let Some(counts) = line.strip_prefix("progress ") {
                        seen.1 = counts
                            .split_whitespace()
                            .filter_map(|kv| kv.split_once('='))
                            .filter_map(|(k, v)| Some((k.to_string(), v.parse().ok()?)))
                            .collect();
                    }
                    seen.0.push_str(&line);
                    seen.0.push('\n');
                }
            }),
            std::thread::spawn(move || {
                let mut text = String::new();
                let _ = err.read_to_string(&mut text);
                *said.lock().unwrap() = text;
            }),
        ];
        Peer {
            what: what.to_string(),
            child,
            stdout,
            stderr,
            readers,
        }
    }

    /// The count `name` of the peer's latest progress line (0 before it said any).
    fn count(&self, name: &str) -> u64 {
        self.stdout
            .lock()
            .unwrap()
            .1
            .get(name)
            .copied()
            .unwrap_or(0)
    }

    /// Wait (up to `timeout`, `what` in the failure) until `pred` holds of the peer and the
    /// bridge's view.
    async fn wait(
        &self,
        chain: &Chain,
        what: &str,
        timeout: Duration,
        pred: impl Fn(&Peer, &BridgeView) -> bool,
    ) {
        let deadline = Instant::now() + timeout;
        while !pred(self, &chain.view.borrow()) {
            if Instant::now() >= deadline {
                // Copied first: a panic holding the locks would poison them for the readers.
                let said = self.stdout.lock().unwrap().0.clone();
                let err = self.stderr.lock().unwrap().clone();
                panic!(
                    "timed out after {timeout:?} waiting for {what}: {} said:\n{said}{err}; {:#?}",
                    self.what,
                    *chain.view.borrow()
                );
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }

    /// Tell the peer to stop (its standard input closes), and return what it printed.
    async fn stop(mut self) -> String {
        drop(self.child.stdin.take());
        let what = self.what.clone();
        let status = tokio::time::timeout(
            Duration::from_secs(10),
            tokio::task::spawn_blocking(move || {
                let status = self.child.wait();
                for reader in self.readers {
                    let _ = reader.join();
                }
                (status, self.stdout, self.stderr)
            }),
        )
        .await
        .unwrap_or_else(|_| panic!("pymavlink {what} did not stop in 10 s"))
        .unwrap();
        let (status, stdout, stderr) = status;
        let status = status.unwrap();
        assert!(
            status.success(),
            "{what} failed: {}",
            stderr.lock().unwrap()
        );
        stdout.lock().unwrap().0.clone()
    }
}

/// The most seconds a peer may run: a bound for a hung test only.
const PEER_LIMIT: &str = "120";

/// The value after `name` on the line starting with it.
fn value(stdout: &str, name: &str) -> u64 {
    stdout
        .lines()
        .find_map(|l| l.strip_prefix(&format!("{name} ")))
        .and_then(|v| v.trim().parse().ok())
        .unwrap_or_else(|| panic!("no {name} in {stdout}"))
}

/// Sets up signing the way MAVProxy does: the key from hex (`key <hex>`), from a passphrase
/// (`passphrase <text>`, MAVProxy's `passphrase_to_key`), or none (`none`); unsigned messages are
/// refused (`allow_unsigned_callback` returning False).
const SIGNING_SETUP: &str = r#"
import hashlib, os, sys, threading, time
os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil

def setup(m, form, secret):
    if form == "none":
        return
    if form == "passphrase":
        # MAVProxy's passphrase_to_key (modules/mavproxy_signing.py).
        key = hashlib.sha256(secret.encode("ascii")).digest()
    else:
        key = bytes.fromhex(secret)
    m.setup_signing(key, sign_outgoing=True, allow_unsigned_callback=lambda *args: False)

# The test stops the script by closing its standard input.
stopped = threading.Event()
def watch_stdin():
    sys.stdin.read()
    stopped.set()
threading.Thread(target=watch_stdin, daemon=True).start()

def running(end):
    return not stopped.is_set() and time.time() < end

# What the test waits for: the counts, on a line of their own whenever one changes.
said = {}
def progress(**counts):
    if counts != said:
        said.clear()
        said.update(counts)
        print("progress", *(f"{k}={v}" for k, v in counts.items()), flush=True)

def stats(m):
    s = m.mav.signing
    print("goodsig", s.goodsig_count)
    print("badsig", s.badsig_count)
    print("reject", s.reject_count)
"#;

/// An autopilot (system 1, component 1) on the bridge's `udpin`: HEARTBEAT at 2 Hz and
/// SERVO_OUTPUT_RAW at 20 Hz with channel 1 at 1900 µs until stopped; it counts the bridge's
/// HEARTBEATs that its signing check let through.
const AUTOPILOT: &str = r#"
port, seconds, form, secret = int(sys.argv[1]), float(sys.argv[2]), sys.argv[3], sys.argv[4]
m = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", dialect="common", source_system=1, source_component=1)
setup(m, form, secret)
mav = mavutil.mavlink
bridge_heartbeats, sent = 0, 0
end, next_hb = time.time() + seconds, 0.0
while running(end):
    now = time.time()
    if now >= next_hb:
        m.mav.heartbeat_send(mav.MAV_TYPE_FIXED_WING, mav.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, mav.MAV_STATE_ACTIVE)
        next_hb = now + 0.5
    m.mav.servo_output_raw_send(int(now * 1e6) & 0xFFFFFFFF, 0, 1900, 1500, 1500, 1500, 0, 0, 0, 0)
    sent += 1
    deadline = now + 0.05
    while True:
        left = deadline - time.time()
        if left <= 0:
            break
        msg = m.recv_match(blocking=True, timeout=left)
        if msg is not None and msg.get_type() == "HEARTBEAT" and msg.get_srcComponent() == 140:
            bridge_heartbeats += 1
    progress(bridge_heartbeats=bridge_heartbeats, goodsig=m.mav.signing.goodsig_count, badsig=m.mav.signing.badsig_count)
print("sent", sent)
print("bridge_heartbeats", bridge_heartbeats)
# The latest signature timestamp accepted from the bridge (pymavlink keeps one per stream).
stamps = [t for (link, system, component), t in m.mav.signing.stream_timestamps.items() if component == 140]
print("bridge_timestamp", max(stamps) if stamps else 0)
stats(m)
"#;

/// A ground station on the bridge's `gcs` output: it waits for the bridge's HEARTBEAT, sends it
/// MAV_CMD_DO_SET_SERVO until acknowledged, and counts what it accepted, until stopped.
const GROUND_STATION: &str = r#"
port, seconds, form, secret = int(sys.argv[1]), float(sys.argv[2]), sys.argv[3], sys.argv[4]
m = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", dialect="common", source_system=255, source_component=190)
setup(m, form, secret)
mav = mavutil.mavlink
heartbeats, names, acks, commands = 0, set(), 0, 0
end, next_command = time.time() + seconds, 0.0
while running(end):
    progress(heartbeats=heartbeats, named_values=len(names), commands=commands, acks=acks, badsig=m.mav.signing.badsig_count)
    msg = m.recv_match(blocking=True, timeout=0.1)
    now = time.time()
    # The bridge's address is known once anything arrived, accepted or not.
    if getattr(m, "clients", None) or getattr(m, "last_address", None) is not None:
        if now >= next_command and acks == 0:
            m.mav.command_long_send(1, 140, mav.MAV_CMD_DO_SET_SERVO, 0, 1, 1600, 0, 0, 0, 0, 0)
            commands += 1
            next_command = now + 0.5
    if msg is None or msg.get_type() == "BAD_DATA" or msg.get_srcComponent() != 140:
        continue
    t = msg.get_type()
    if t == "HEARTBEAT":
        heartbeats += 1
    elif t == "NAMED_VALUE_FLOAT":
        names.add(msg.name)
    elif t == "COMMAND_ACK" and msg.command == mav.MAV_CMD_DO_SET_SERVO:
        acks += 1
print("heartbeats", heartbeats)
print("named_values", len(names))
print("commands", commands)
print("acks", acks)
stats(m)
"#;

fn script(body: &'static str) -> &'static str {
    Box::leak(format!("{SIGNING_SETUP}{body}").into_boxed_str())
}

/// The test playing the autopilot through pymavlink beside `chain`, signing as `form`/`secret`
/// say.
async fn autopilot(chain: &Chain, form: &str, secret: &str) -> Peer {
    let args = vec![
        chain.autopilot_port.to_string(),
        PEER_LIMIT.into(),
        form.to_string(),
        secret.to_string(),
    ];
    Peer::start(script(AUTOPILOT), args, "autopilot").await
}

/// The bridge with the test playing the autopilot for `seconds` (what it refuses is counted
/// over that span); returns the script's output and the bridge's view at the end.
async fn autopilot_run(
    mapping: &str,
    seconds: u64,
    form: &str,
    secret: &str,
) -> (String, BridgeView, Chain) {
    let chain = Chain::start_opts(mapping, ChainOptions::default()).await;
    let peer = autopilot(&chain, form, secret).await;
    tokio::time::sleep(Duration::from_secs(seconds)).await;
    let stdout = peer.stop().await;
    let view = chain.view.borrow().clone();
    (stdout, view, chain)
}

/// The bridge with the test playing the autopilot until one of its outputs set a goal and it
/// accepted a HEARTBEAT of the bridge (up to 30 s, `what` in the failure); returns the script's
/// output and the chain.
async fn obeyed_autopilot_run(
    mapping: &str,
    form: &str,
    secret: &str,
    what: &str,
) -> (String, Chain) {
    let chain = Chain::start_opts(mapping, ChainOptions::default()).await;
    let peer = autopilot(&chain, form, secret).await;
    peer.wait(&chain, what, Duration::from_secs(30), |p, v| {
        commanded(v) && p.count("bridge_heartbeats") >= 1
    })
    .await;
    (peer.stop().await, chain)
}

/// No servo was given a goal (none is, before the first accepted output).
fn no_goal(view: &BridgeView) -> bool {
    view.servos.iter().all(|s| s.goal_mm.is_none()) && !commanded(view)
}

fn commanded(view: &BridgeView) -> bool {
    view.servos
        .iter()
        .any(|s| s.goal_mm.is_some_and(|g| (g - COMMANDED_MM).abs() < 0.3))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_signed_autopilot_moves_the_servos_and_verifies_the_bridge() {
    let (text, ts) = keyed("signed-autopilot");
    let (stdout, chain) =
        obeyed_autopilot_run(&text, "key", KEY_HEX, "the signed outputs to set a goal").await;
    let view = chain.view.borrow().clone();
    assert_eq!(view.autopilot, Some((1, 1)), "{view:?}");
    assert_eq!(view.signing_drops.len(), 2, "{view:?}");
    assert_eq!(view.signing_drops[0].total(), 0, "{view:?}");
    // pymavlink accepted the bridge's HEARTBEATs with their signatures, and refused nothing.
    assert!(value(&stdout, "bridge_heartbeats") >= 1, "{stdout}");
    assert!(value(&stdout, "goodsig") >= 1, "{stdout}");
    assert_eq!(value(&stdout, "badsig"), 0, "{stdout}");
    assert_eq!(value(&stdout, "reject"), 0, "{stdout}");
    chain.stop().await;
    let reserved: u64 = std::fs::read_to_string(&ts)
        .expect("the timestamp file is written")
        .trim()
        .parse()
        .unwrap();
    assert!(reserved > lj9da_bridge::mavlink::signing::now());
    let _ = std::fs::remove_file(ts);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_unsigned_autopilot_moves_nothing_and_is_counted() {
    let (text, ts) = keyed("unsigned-autopilot");
    let (stdout, _, chain) = autopilot_run(&text, 3, "none", "-").await;
    let sent = value(&stdout, "sent");
    assert!(sent >= 10, "{stdout}");
    // The outputs and heartbeats are counted (at least half of them: UDP on a busy machine, and
    // the first datagrams may come before the bridge listens).
    chain
        .wait_view("the drops to be counted", Duration::from_secs(10), |v| {
            v.signing_drops
                .first()
                .is_some_and(|d| d.unsigned >= sent / 2)
        })
        .await;
    let view = chain.view.borrow().clone();
    assert!(no_goal(&view), "an unsigned output moved a servo: {view:?}");
    let d = view.signing_drops[0];
    assert_eq!((d.bad_signature, d.old_timestamp), (0, 0), "{d:?}");
    // Nor does it hear the bridge: a `udpin` link answers only where an accepted frame came
    // from.
    assert_eq!(value(&stdout, "bridge_heartbeats"), 0, "{stdout}");
    chain.stop().await;
    let _ = std::fs::remove_file(ts);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_autopilot_with_another_key_moves_nothing_and_is_counted() {
    let (text, ts) = keyed("wrong-key-autopilot");
    let (stdout, _, chain) = autopilot_run(&text, 3, "key", OTHER_KEY_HEX).await;
    let sent = value(&stdout, "sent");
    chain
        .wait_view("the drops to be counted", Duration::from_secs(10), |v| {
            v.signing_drops
                .first()
                .is_some_and(|d| d.bad_signature >= sent / 2)
        })
        .await;
    let view = chain.view.borrow().clone();
    assert!(
        no_goal(&view),
        "a wrongly signed output moved a servo: {view:?}"
    );
    assert_eq!(view.signing_drops[0].unsigned, 0, "{view:?}");
    // Nor does it hear the bridge: a `udpin` link answers only where an accepted frame came
    // from.
    assert_eq!(value(&stdout, "bridge_heartbeats"), 0, "{stdout}");
    assert_eq!(value(&stdout, "badsig"), 0, "{stdout}");
    chain.stop().await;
    let _ = std::fs::remove_file(ts);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_passphrase_is_the_key_mavproxy_derives() {
    let (text, ts) = mapping(
        &format!("signing_passphrase = \"{PASSPHRASE}\""),
        "passphrase",
    );
    let (stdout, chain) = obeyed_autopilot_run(
        &text,
        "passphrase",
        PASSPHRASE,
        "outputs signed with the passphrase's key",
    )
    .await;
    assert!(value(&stdout, "bridge_heartbeats") >= 1, "{stdout}");
    assert_eq!(value(&stdout, "badsig"), 0, "{stdout}");
    assert_eq!(chain.view.borrow().signing_drops[0].total(), 0);
    chain.stop().await;
    let _ = std::fs::remove_file(ts);
}

/// The bridge with the simulated autopilot (signing with the mapping's key, as `sitl` runs it)
/// and pymavlink as the ground station until `done` holds of it and the bridge's view (up to
/// 30 s, `what` in the failure).
async fn ground_station_run(
    form: &str,
    secret: &str,
    name: &str,
    what: &str,
    done: impl Fn(&Peer, &BridgeView) -> bool,
) -> (String, BridgeView) {
    let (text, ts) = keyed(name);
    let port = free_udp_port();
    let chain = Chain::start_with(&text, true, Some(port)).await;
    let args = vec![
        port.to_string(),
        PEER_LIMIT.into(),
        form.to_string(),
        secret.to_string(),
    ];
    let peer = Peer::start(script(GROUND_STATION), args, "ground station").await;
    peer.wait(&chain, what, Duration::from_secs(30), done).await;
    let stdout = peer.stop().await;
    // The simulated autopilot signs with the mapping's key: its outputs are obeyed.
    chain
        .wait_view(
            "the simulated autopilot's outputs",
            Duration::from_secs(20),
            |v| v.autopilot == Some((1, 1)) && v.servos.iter().all(|s| s.goal_mm.is_some()),
        )
        .await;
    assert_eq!(chain.view.borrow().signing_drops[0].total(), 0);
    let view = chain.view.borrow().clone();
    chain.stop().await;
    let _ = std::fs::remove_file(ts);
    (stdout, view)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_signed_ground_station_verifies_the_telemetry_and_is_answered() {
    let (stdout, view) = ground_station_run(
        "key",
        KEY_HEX,
        "signed-gcs",
        "heartbeats, telemetry and an answer",
        |p, _| p.count("heartbeats") >= 2 && p.count("named_values") >= 4 && p.count("acks") >= 1,
    )
    .await;
    assert!(value(&stdout, "heartbeats") >= 2, "{stdout}");
    assert!(value(&stdout, "named_values") >= 4, "{stdout}");
    assert!(value(&stdout, "acks") >= 1, "{stdout}");
    assert_eq!(value(&stdout, "badsig"), 0, "{stdout}");
    assert_eq!(value(&stdout, "reject"), 0, "{stdout}");
    assert_eq!(view.signing_drops[1].total(), 0, "{view:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_ground_station_with_another_key_sees_nothing_and_is_not_answered() {
    // Done once the bridge's messages were refused and a command of the ground station was
    // dropped: nothing it refused can be accepted later.
    let (stdout, view) = ground_station_run(
        "key",
        OTHER_KEY_HEX,
        "wrong-key-gcs",
        "messages refused both ways",
        |p, v| p.count("badsig") >= 2 && v.signing_drops[1].bad_signature >= 1,
    )
    .await;
    assert_eq!(value(&stdout, "heartbeats"), 0, "{stdout}");
    assert_eq!(value(&stdout, "named_values"), 0, "{stdout}");
    assert_eq!(value(&stdout, "acks"), 0, "{stdout}");
    // The bridge's messages did arrive: pymavlink refused them.
    assert!(value(&stdout, "badsig") >= 2, "{stdout}");
    // And the bridge dropped the ground station's commands.
    assert!(value(&stdout, "commands") >= 1, "{stdout}");
    assert!(view.signing_drops[1].bad_signature >= 1, "{view:?}");
}

/// A restart whose clock is behind the timestamps the previous run reserved (a companion
/// computer without a real-time clock): the bridge still signs above the reservation, and a
/// signed autopilot, which takes the bridge's newer timestamps as its own, is obeyed.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_restart_behind_the_stored_timestamp_signs_above_it() {
    let (text, ts) = keyed("restart");
    // Ahead of the clock, but not so far that the autopilot's first frames, stamped by the
    // clock, are more than a minute behind the bridge's floor (reservation − 30 s): on a
    // `udpin` link the autopilot hears the bridge, and catches up with its timestamps, only
    // once one of its frames is accepted.
    let ahead = lj9da_bridge::mavlink::signing::now() + 45 * 100_000;
    std::fs::write(&ts, format!("{ahead}\n")).unwrap();
    let (stdout, chain) =
        obeyed_autopilot_run(&text, "key", KEY_HEX, "the signed outputs to set a goal").await;
    assert!(value(&stdout, "bridge_timestamp") >= ahead, "{stdout}");
    assert_eq!(value(&stdout, "badsig"), 0, "{stdout}");
    chain.stop().await;
    let reserved: u64 = std::fs::read_to_string(&ts)
        .unwrap()
        .trim()
        .parse()
        .unwrap();
    assert!(reserved > ahead);
    let _ = std::fs::remove_file(ts);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_unsigned_ground_station_hears_the_bridge_but_is_not_answered() {
    // Done once two commands were sent and dropped: a dropped command is never answered.
    let (stdout, view) = ground_station_run(
        "none",
        "-",
        "unsigned-gcs",
        "heartbeats heard and two commands dropped",
        |p, v| p.count("heartbeats") >= 2 && v.signing_drops[1].unsigned >= 2,
    )
    .await;
    // Without a key pymavlink does not check signatures: it hears the bridge.
    assert!(value(&stdout, "heartbeats") >= 2, "{stdout}");
    // Its commands are dropped as unsigned, never answered.
    assert!(value(&stdout, "commands") >= 2, "{stdout}");
    assert_eq!(value(&stdout, "acks"), 0, "{stdout}");
    assert!(view.signing_drops[1].unsigned >= 1, "{view:?}");
}

/// A ground station on the bridge's `gcs` output that sets `S1_PWM_TRIM` to 1500 (again every
/// 0.5 s until a PARAM_VALUE says so) and counts the PARAM_VALUEs it hears, until stopped.
const PARAM_SETTER: &str = r#"
port, seconds, form, secret = int(sys.argv[1]), float(sys.argv[2]), sys.argv[3], sys.argv[4]
m = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", dialect="common", source_system=255, source_component=190)
setup(m, form, secret)
mav = mavutil.mavlink
sets, values, trim = 0, 0, None
end, next_set = time.time() + seconds, 0.0
while running(end):
    progress(sets=sets, param_values=values, trim=int(trim) if trim is not None else 0)
    msg = m.recv_match(blocking=True, timeout=0.1)
    now = time.time()
    if getattr(m, "clients", None) or getattr(m, "last_address", None) is not None:
        if now >= next_set and trim != 1500.0:
            m.mav.param_set_send(1, 140, b"S1_PWM_TRIM", 1500.0, mav.MAV_PARAM_TYPE_REAL32)
            sets += 1
            next_set = now + 0.5
    if msg is None or msg.get_type() != "PARAM_VALUE" or msg.get_srcComponent() != 140:
        continue
    values += 1
    if msg.param_id == "S1_PWM_TRIM":
        trim = msg.param_value
print("sets", sets)
print("param_values", values)
print("trim", int(trim) if trim is not None else 0)
"#;

/// The bridge, its mapping in a file, the simulated autopilot signing with the mapping's key,
/// and pymavlink setting a parameter as the ground station until `done` holds of it and the
/// bridge's view (up to 30 s, `what` in the failure); returns the script's output, the bridge's
/// view and the mapping file as it is after the run.
async fn param_setter_run(
    form: &str,
    secret: &str,
    name: &str,
    what: &str,
    done: impl Fn(&Peer, &BridgeView) -> bool,
) -> (String, BridgeView, String) {
    let (text, ts) = keyed(name);
    let file = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("signing-{name}-{}.toml", std::process::id()));
    std::fs::write(&file, &text).unwrap();
    let port = free_udp_port();
    let opts = ChainOptions {
        autopilot: true,
        gcs_port: Some(port),
        mapping_file: Some(file.clone()),
        ..ChainOptions::default()
    };
    let chain = Chain::start_opts(&text, opts).await;
    let args = vec![
        port.to_string(),
        PEER_LIMIT.into(),
        form.to_string(),
        secret.to_string(),
    ];
    let peer = Peer::start(script(PARAM_SETTER), args, "parameter setter").await;
    peer.wait(&chain, what, Duration::from_secs(30), done).await;
    let stdout = peer.stop().await;
    let view = chain.view.borrow().clone();
    chain.stop().await;
    let saved = std::fs::read_to_string(&file).unwrap();
    let _ = std::fs::remove_file(&file);
    let _ = std::fs::remove_file(ts);
    (stdout, view, saved)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_signed_ground_station_sets_a_parameter_and_the_file_keeps_it() {
    let (stdout, view, saved) =
        param_setter_run("key", KEY_HEX, "signed-param", "the new trim", |p, _| {
            p.count("trim") == 1500
        })
        .await;
    assert_eq!(value(&stdout, "trim"), 1500, "{stdout}");
    assert!(saved.contains("pwm_trim_us = 1500"), "{saved}");
    assert_eq!(view.signing_drops[1].total(), 0, "{view:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_parameter_set_from_an_unsigned_sender_is_refused_and_nothing_is_written() {
    // Done once two sets were dropped: a dropped set never reaches the parameters.
    let (stdout, view, saved) =
        param_setter_run("none", "-", "unsigned-param", "two sets dropped", |p, v| {
            p.count("sets") >= 2 && v.signing_drops[1].unsigned >= 2
        })
        .await;
    assert!(value(&stdout, "sets") >= 2, "{stdout}");
    // Not one PARAM_VALUE: the set never reached the parameters.
    assert_eq!(value(&stdout, "param_values"), 0, "{stdout}");
    assert!(!saved.contains("pwm_trim_us"), "{saved}");
    assert!(view.signing_drops[1].unsigned >= 1, "{view:?}");
}

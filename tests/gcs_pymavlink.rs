//! A third-party ground station: pymavlink (from PyPI) listens where the bridge serves its
//! telemetry and must see the bridge's heartbeat and every servo's NAMED_VALUE_FLOAT, decoded
//! by its own MAVLink implementation. (ESC_INFO and ESC_STATUS are marked work-in-progress in
//! common.xml and pymavlink's generated dialects leave them out, so they are checked with the
//! `mavlink` crate's decoder in `bridge_chain.rs` instead.)
//!
//! The Python environment: `$LJ9DA_PYTHON` if set, else a virtual environment made once, under a
//! lock, in the target directory with `pip install pymavlink` (see `common/python.rs`).

mod common;

use common::mapping::Mapping;
use common::python::python;
use common::{Chain, ChainOptions, free_udp_port};
use std::fmt::Display;
use std::path::PathBuf;
use std::process::Command;
use std::time::Duration;

/// The left aileron and the rudder; outputs asked for at 40 Hz, telemetry at 10 Hz.
fn mapping() -> Mapping {
    Mapping::aileron_and_rudder()
        .with("[mavlink]", "output_rate_hz = 40")
        .with("[telemetry]", "rate_hz = 10")
}

const LISTENER: &str = r#"
import os, sys, time
os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil
port, seconds = int(sys.argv[1]), float(sys.argv[2])
m = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", dialect="common")
heartbeats, names = set(), set()
end = time.time() + seconds
while time.time() < end:
    msg = m.recv_match(blocking=True, timeout=0.2)
    if msg is None or msg.get_srcComponent() != 140:
        continue
    t = msg.get_type()
    if t == "HEARTBEAT":
        servo = msg.type == mavutil.mavlink.MAV_TYPE_SERVO
        invalid = msg.autopilot == mavutil.mavlink.MAV_AUTOPILOT_INVALID
        heartbeats.add((msg.get_srcSystem(), "servo" if servo else msg.type, "invalid" if invalid else msg.autopilot))
    elif t == "NAMED_VALUE_FLOAT":
        names.add(msg.name)
for h in sorted(heartbeats):
    print("heartbeat", *h)
print("names", *sorted(names))
"#;

/// Start the chain with its ground-station link on a free UDP port, run the pymavlink `script`
/// against that port for `seconds`, stop the chain, and return what the script printed
/// (`what` names the script in failures).
async fn run_beside_the_chain(script: &'static str, seconds: &'static str, what: &str) -> String {
    run_beside(mapping(), None, script, seconds, what).await
}

/// As [`run_beside_the_chain`], for `mapping`; with `file` (holding `mapping`) the bridge saves
/// parameter changes there.
async fn run_beside(
    mapping: impl Display,
    file: Option<PathBuf>,
    script: &'static str,
    seconds: &'static str,
    what: &str,
) -> String {
    let python = tokio::task::spawn_blocking(python).await.unwrap();
    let port = free_udp_port();
    let opts = ChainOptions {
        autopilot: true,
        gcs_port: Some(port),
        mapping_file: file,
        ..ChainOptions::default()
    };
    let chain = Chain::start_opts(mapping, opts).await;
    let run = tokio::task::spawn_blocking(move || {
        Command::new(&python)
            .args(["-c", script, &port.to_string(), seconds])
            .output()
    });
    let out = tokio::time::timeout(Duration::from_secs(60), run)
        .await
        .unwrap_or_else(|_| panic!("pymavlink {what} did not finish in 60 s"))
        .unwrap()
        .unwrap_or_else(|e| panic!("pymavlink {what} did not run: {e}"));
    chain.stop().await;
    assert!(
        out.status.success(),
        "{what} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pymavlink_sees_the_bridge_heartbeat_and_servo_telemetry() {
    let stdout = run_beside_the_chain(LISTENER, "6", "listener").await;
    // The vehicle's system id 1, MAV_TYPE_SERVO, MAV_AUTOPILOT_INVALID as pymavlink names them.
    assert!(
        stdout.lines().any(|l| l == "heartbeat 1 servo invalid"),
        "{stdout}"
    );
    let names = stdout
        .lines()
        .find(|l| l.starts_with("names"))
        .unwrap_or("");
    for name in [
        "ail_l_pos",
        "ail_l_cur",
        "ail_l_tmp",
        "ail_l_vlt",
        "rudder_pos",
        "rudder_vlt",
    ] {
        assert!(
            names.split_whitespace().any(|n| n == name),
            "{name} missing: {stdout}"
        );
    }
}

const VEHICLE_LISTENER: &str = r#"
import os, sys, time
os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil
port, seconds = int(sys.argv[1]), float(sys.argv[2])
m = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", dialect="common")
seen = set()
end = time.time() + seconds
while time.time() < end:
    msg = m.recv_match(type="HEARTBEAT", blocking=True, timeout=0.2)
    if msg is None:
        continue
    invalid = msg.autopilot == mavutil.mavlink.MAV_AUTOPILOT_INVALID
    seen.add((msg.get_srcSystem(), msg.get_srcComponent(), "invalid" if invalid else "autopilot"))
for s in sorted(seen):
    print("heartbeat", *s)
"#;

/// QGroundControl creates a vehicle only from the HEARTBEAT of an autopilot (component 1,
/// autopilot field not INVALID): the ground-station link carries the autopilot's, relayed, as
/// well as the bridge's own.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_ground_station_link_carries_an_autopilot_heartbeat_for_qgroundcontrol() {
    let stdout = run_beside_the_chain(VEHICLE_LISTENER, "4", "listener").await;
    assert!(
        stdout.lines().any(|l| l == "heartbeat 1 1 autopilot"),
        "no autopilot heartbeat on the GCS link: {stdout}"
    );
    assert!(
        stdout.lines().any(|l| l == "heartbeat 1 140 invalid"),
        "{stdout}"
    );
}

const COMMAND_SENDER: &str = r#"
import os, sys, time
os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil
port, seconds = int(sys.argv[1]), float(sys.argv[2])
m = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", dialect="common", source_system=255, source_component=190)
end = time.time() + seconds
# The bridge's address is learned from its first message.
while time.time() < end:
    msg = m.recv_match(type="HEARTBEAT", blocking=True, timeout=0.2)
    if msg is not None and msg.get_srcComponent() == 140:
        break
mav = mavutil.mavlink
tests = [
    (mav.MAV_CMD_DO_SET_SERVO, (1, 1600, 0, 0), 0),
    (mav.MAV_CMD_DO_REPOSITION, (0, 0, 0, 0), 0),
]
for command, params, frame in tests:
    answer = None
    for attempt in range(5):
        m.mav.command_int_send(1, 140, frame, command, 0, 0, *params, 0, 0, 0.0)
        ack = m.recv_match(type="COMMAND_ACK", blocking=True, timeout=1.0)
        if ack is not None and ack.command == command:
            answer = ack.result
            break
    print("ack", command, answer)
"#;

/// A ground station sends COMMAND_INT to the bridge and gets a COMMAND_ACK for each, so it
/// neither retries nor times out.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn command_int_to_the_bridge_is_answered() {
    let stdout = run_beside_the_chain(COMMAND_SENDER, "10", "sender").await;
    // MAV_CMD_DO_SET_SERVO (183) DENIED (2): on the ground-station link nothing moves the
    // servos, and the answer says so; MAV_CMD_DO_REPOSITION (192) UNSUPPORTED (3).
    assert!(stdout.lines().any(|l| l == "ack 183 2"), "{stdout}");
    assert!(stdout.lines().any(|l| l == "ack 192 3"), "{stdout}");
}

const PARAM_CLIENT: &str = r#"
import math, os, sys, time
os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil
port, seconds = int(sys.argv[1]), float(sys.argv[2])
m = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", dialect="common", source_system=255, source_component=190)
mav = mavutil.mavlink
end = time.time() + seconds
while time.time() < end:
    msg = m.recv_match(type="HEARTBEAT", blocking=True, timeout=0.2)
    if msg is not None and msg.get_srcComponent() == 140:
        break

def values_until(quiet, stop=lambda v: False):
    got = []
    last = time.time()
    while time.time() - last < quiet and time.time() < end:
        msg = m.recv_match(type=["PARAM_VALUE", "STATUSTEXT"], blocking=True, timeout=0.1)
        if msg is None or msg.get_srcComponent() != 140:
            continue
        last = time.time()
        got.append(msg)
        if msg.get_type() == "PARAM_VALUE" and stop(msg):
            break
    return got

# QGroundControl's way: every component at once.
m.mav.param_request_list_send(1, 0)
listed = [v for v in values_until(1.5) if v.get_type() == "PARAM_VALUE"]
count = listed[0].param_count if listed else 0
print("list", count, len(listed), len({v.param_index for v in listed}))
print("types", sorted({v.param_type for v in listed}))
byname = {v.param_id: v.param_value for v in listed}
print("value", "S1_PWM_TRIM", byname.get("S1_PWM_TRIM"))
print("value", "BRG_FS_MS", byname.get("BRG_FS_MS"))
print("value", "S2_ID", byname.get("S2_ID"))

# MAVProxy's `param fetch NAME`, aimed at the component.
m.mav.param_request_read_send(1, 140, b"S2_CHAN", -1)
got = values_until(1.0, lambda v: v.param_id == "S2_CHAN")
print("read", [(v.param_id, v.param_value) for v in got if v.get_type() == "PARAM_VALUE"])

def answered(name, text):
    """The set is answered: the PARAM_VALUE of `name` is in (unless it names no parameter),
    and the STATUSTEXT saying why, when `text` says one comes."""
    def done(got):
        value = any(v.get_type() == "PARAM_VALUE" and v.param_id == name for v in got)
        said = any(v.get_type() == "STATUSTEXT" and (v.text.startswith(name) or "no parameter" in v.text) for v in got)
        return (value or text == "only") and (said or not text)
    return done

def set_param(name, value, ptype, text):
    m.mav.param_set_send(1, 140, name.encode(), value, ptype)
    # An accepted set is answered once the mapping file is saved (two fsyncs): no quiet time
    # stands for that, so wait for the answer itself, up to a deadline.
    done = answered(name, text)
    got = []
    deadline = min(time.time() + 10, end)
    while time.time() < deadline and not done(got):
        msg = m.recv_match(type=["PARAM_VALUE", "STATUSTEXT"], blocking=True, timeout=0.1)
        if msg is not None and msg.get_srcComponent() == 140:
            got.append(msg)
    if not done(got):
        print("unanswered", name, value)
    vals = [(v.param_id, v.param_value) for v in got if v.get_type() == "PARAM_VALUE"]
    texts = [v.text for v in got if v.get_type() == "STATUSTEXT" and v.text.startswith(name)]
    texts += [v.text for v in got if v.get_type() == "STATUSTEXT" and "no parameter" in v.text]
    return vals, texts

# The last field: whether a STATUSTEXT says why ("only": nothing but the text).
for name, value, ptype, text in [
    ("S1_PWM_TRIM", 1500.0, mav.MAV_PARAM_TYPE_REAL32, False),
    ("S1_PWM_TRIM", 3000.0, mav.MAV_PARAM_TYPE_REAL32, True),
    ("S1_PWM_TRIM", float("nan"), mav.MAV_PARAM_TYPE_REAL32, True),
    ("S1_PWM_TRIM", 1490.0, mav.MAV_PARAM_TYPE_INT32, True),
    ("S2_ID", 9.0, mav.MAV_PARAM_TYPE_REAL32, True),
    ("NO_SUCH_PARAM", 1.0, mav.MAV_PARAM_TYPE_REAL32, "only"),
]:
    vals, texts = set_param(name, value, ptype, text)
    print("set", name, value, ptype, vals, texts)

# A flood of list requests: the bridge answers, at most one pass queued per link, and lives.
for _ in range(300):
    m.mav.param_request_list_send(1, 140)
flood = [v for v in values_until(1.5) if v.get_type() == "PARAM_VALUE"]
print("flood values", len(flood))
print("flood indexes", len({v.param_index for v in flood}))
alive = None
t = time.time()
while time.time() - t < 3 and alive is None:
    msg = m.recv_match(type="HEARTBEAT", blocking=True, timeout=0.2)
    if msg is not None and msg.get_srcComponent() == 140:
        alive = True
print("alive", alive)
"#;

const PARAM_MAPPING: &str = r#"
# An airframe whose trims are set from the ground station.
[mavlink]
connection = "udpin:127.0.0.1:14560"

[[bus]]
name = "wing"
port = "sim"
turnaround_ms = 20

[[servo]]
name = "aileron_left"
bus = "wing"
id = 1
channel = 1
pwm_trim_us = 1520   # bench trim

[[servo]]
name = "rudder"
bus = "wing"
id = 2
channel = 4
"#;

/// pymavlink as the ground station: the whole list (as QGroundControl asks for it), a read
/// by name (as MAVProxy's `param fetch`), a set that is saved into the mapping file with its
/// comments, and refusals (out of range, NaN, wrong type, read-only, unknown name) that
/// answer with the old value or a STATUSTEXT and write nothing; a flood of requests is
/// answered without growing the queue.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_ground_station_reads_and_sets_parameters_and_the_file_keeps_them() {
    let path = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("params-{}.toml", std::process::id()));
    std::fs::write(&path, PARAM_MAPPING).unwrap();
    let stdout = run_beside(
        PARAM_MAPPING,
        Some(path.clone()),
        PARAM_CLIENT,
        "25",
        "parameter client",
    )
    .await;
    let line = |prefix: &str| {
        stdout
            .lines()
            .find(|l| l.starts_with(prefix))
            .unwrap_or_else(|| panic!("no {prefix:?} in {stdout}"))
            .to_string()
    };
    // 5 bridge parameters and 14 per servo; every index once; all REAL32 (9).
    assert_eq!(line("list "), "list 33 33 33", "{stdout}");
    assert_eq!(line("types "), "types [9]", "{stdout}");
    assert_eq!(line("value S1_PWM_TRIM"), "value S1_PWM_TRIM 1520.0");
    assert_eq!(line("value BRG_FS_MS"), "value BRG_FS_MS 500.0");
    assert_eq!(line("value S2_ID"), "value S2_ID 2.0");
    assert_eq!(line("read "), "read [('S2_CHAN', 4.0)]", "{stdout}");
    assert!(!stdout.contains("unanswered"), "{stdout}");
    assert_eq!(
        line("set S1_PWM_TRIM 1500.0"),
        "set S1_PWM_TRIM 1500.0 9 [('S1_PWM_TRIM', 1500.0)] []"
    );
    let refused = line("set S1_PWM_TRIM 3000.0");
    assert!(
        refused
            .starts_with("set S1_PWM_TRIM 3000.0 9 [('S1_PWM_TRIM', 1500.0)] ['S1_PWM_TRIM 3000: "),
        "{refused}"
    );
    assert_eq!(
        line("set S1_PWM_TRIM nan"),
        "set S1_PWM_TRIM nan 9 [('S1_PWM_TRIM', 1500.0)] ['S1_PWM_TRIM NaN: not a number']"
    );
    assert_eq!(
        line("set S1_PWM_TRIM 1490.0 6"),
        "set S1_PWM_TRIM 1490.0 6 [('S1_PWM_TRIM', 1500.0)] ['S1_PWM_TRIM 1490: type 6 not REAL32']"
    );
    assert_eq!(
        line("set S2_ID"),
        "set S2_ID 9.0 9 [('S2_ID', 2.0)] ['S2_ID 9: read-only']"
    );
    assert_eq!(
        line("set NO_SUCH_PARAM"),
        "set NO_SUCH_PARAM 1.0 9 [] ['no parameter NO_SUCH_PARAM']"
    );
    // Every value at least once; far fewer than a list per request (300 × 33): a value waiting
    // for its link is not queued again.
    assert_eq!(line("flood indexes"), "flood indexes 33", "{stdout}");
    let flood: usize = line("flood values ")[13..].parse().unwrap_or(0);
    assert!((33..330).contains(&flood), "{stdout}");
    assert_eq!(line("alive "), "alive True");

    // Saved in place, comments kept; what `check` and a restart read.
    let saved = std::fs::read_to_string(&path).unwrap();
    assert_eq!(
        saved,
        PARAM_MAPPING.replace(
            "pwm_trim_us = 1520   # bench",
            "pwm_trim_us = 1500   # bench"
        )
    );
    let cfg = lj9da_bridge::config::Config::load(&path).unwrap();
    assert_eq!(cfg.servos[0].pwm.trim_us, 1500);
    let _ = std::fs::remove_file(&path);
}

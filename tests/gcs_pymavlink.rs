//! A third-party ground station: pymavlink (from PyPI) listens where the bridge serves its
//! telemetry and must see the bridge's heartbeat and every servo's NAMED_VALUE_FLOAT, decoded
//! by its own MAVLink implementation. (ESC_INFO and ESC_STATUS are marked work-in-progress in
//! common.xml and pymavlink's generated dialects leave them out, so they are checked with the
//! `mavlink` crate's decoder in `bridge_chain.rs` instead.)
//!
//! The Python environment: `$LJ9DA_PYTHON` if set (`.ci/run` sets it), else a virtual
//! environment made once under the target directory with `pip install pymavlink`.

mod common;

use common::{Chain, free_udp_port};
use std::path::PathBuf;
use std::process::Command;
use std::time::Duration;

const MAPPING: &str = r#"
[mavlink]
connection = "udpin:127.0.0.1:14560"
output_rate_hz = 40

[telemetry]
rate_hz = 10

[[bus]]
name = "wing"
port = "sim"
turnaround_ms = 20

[[servo]]
name = "aileron_left"
label = "ail_l"
bus = "wing"
id = 1
channel = 1

[[servo]]
name = "rudder"
bus = "wing"
id = 2
channel = 4
"#;

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

fn python() -> PathBuf {
    if let Some(p) = std::env::var_os("LJ9DA_PYTHON") {
        return PathBuf::from(p);
    }
    let venv = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("pymavlink-venv");
    let python = venv.join("bin/python");
    let ready = python.exists()
        && Command::new(&python)
            .args(["-c", "import pymavlink"])
            .status()
            .is_ok_and(|s| s.success());
    if !ready {
        let made = Command::new("python3")
            .args(["-m", "venv"])
            .arg(&venv)
            .status();
        assert!(
            made.is_ok_and(|s| s.success()),
            "python3 -m venv failed: install Python 3 with venv"
        );
        let pip = Command::new(venv.join("bin/pip"))
            .args(["install", "--quiet", "pymavlink"])
            .status();
        assert!(
            pip.is_ok_and(|s| s.success()),
            "pip install pymavlink failed (needs PyPI)"
        );
    }
    python
}

/// Start the chain with its ground-station link on a free UDP port, run the pymavlink `script`
/// against that port for `seconds`, stop the chain, and return what the script printed
/// (`what` names the script in failures).
async fn run_beside_the_chain(script: &'static str, seconds: &'static str, what: &str) -> String {
    let python = tokio::task::spawn_blocking(python).await.unwrap();
    let port = free_udp_port();
    let chain = Chain::start_with(MAPPING, true, Some(port)).await;
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
    // MAV_CMD_DO_SET_SERVO (183) ACCEPTED (0); MAV_CMD_DO_REPOSITION (192) UNSUPPORTED (3).
    assert!(stdout.lines().any(|l| l == "ack 183 0"), "{stdout}");
    assert!(stdout.lines().any(|l| l == "ack 192 3"), "{stdout}");
}

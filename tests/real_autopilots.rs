//! The bridge against real autopilots: ArduPlane and PX4 SITL (their own flight code, built from
//! their sources), configured only as `docs/autopilot.md` tells a user — the parameter lines and
//! mapping blocks are read from the page — with the project's simulated servos on pseudo-terminals
//! and pymavlink as the ground station, connected to the autopilot, not to the bridge.
//!
//! Each test needs its autopilot (see `autopilots/mod.rs` for where they are looked for) and
//! uses its fixed ports (ArduPlane: TCP 5760, UDP 14560; PX4: UDP 14540, 14550), so the tests
//! are ignored by `cargo test --workspace` and run one at a time by `.ci/autopilots`:
//!
//! ```sh
//! cargo test --test real_autopilots -- --ignored --test-threads=1
//! ```

mod autopilots;
mod common;

use autopilots::can::{CanListener, Heard, arduplane_on_can};
use autopilots::{Autopilot, GcsMessage, GroundStation, Tap, Tapped, block_after, fresh_dir};
use common::{Chain, ChainOptions};
use lj9da_bridge::config::Config;
use lj9da_bridge::config::servo::ServoConfig;
use lj9da_bridge::dronecan::messages::{
    ACTUATOR_STATUS, Command, CommandType, NODE_STATUS, decode_actuator_status,
};
use lj9da_bridge::mavlink::rate;
use lj9da_sim::BusEvent;
use lj9da_sim::protocol::host_packet::HostPacket;
use serde_json::json;
use sha2::{Digest, Sha256};
use std::sync::mpsc::Receiver;
use std::sync::{Arc, Mutex, OnceLock};
use std::time::{Duration, Instant};

const PAGE: &str = "docs/autopilot.md";
const SECS: fn(u64) -> Duration = Duration::from_secs;

/// What the bridge logs, kept for the checks of its lines (installed once per process).
fn bridge_log() -> Arc<Mutex<Vec<u8>>> {
    static LOG: OnceLock<Arc<Mutex<Vec<u8>>>> = OnceLock::new();
    LOG.get_or_init(|| {
        let log = Arc::new(Mutex::new(Vec::new()));
        let writer = log.clone();
        tracing_subscriber::fmt()
            .with_ansi(false)
            .with_writer(move || LogWriter(writer.clone()))
            .init();
        log
    })
    .clone()
}

struct LogWriter(Arc<Mutex<Vec<u8>>>);

impl std::io::Write for LogWriter {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.lock().unwrap().extend_from_slice(buf);
        std::io::stderr().write_all(buf)?;
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// The log's lines that contain `needle`.
fn log_lines_with(log: &Mutex<Vec<u8>>, needle: &str) -> Vec<String> {
    String::from_utf8_lossy(&log.lock().unwrap())
        .lines()
        .filter(|l| l.contains(needle))
        .map(str::to_string)
        .collect()
}

/// The position, in 0.01 mm, that a servo's PWM law, reverse and travel give for `us`: the
/// mapping file's rule, worked out here on its own. `None`: no output (the servo holds).
fn expected_goal(servo: &ServoConfig, us: u16) -> Option<i16> {
    let (min, trim, max) = (servo.pwm.min_us, servo.pwm.trim_us, servo.pwm.max_us);
    if us == 0 || us == u16::MAX || us < min || us > max {
        return None;
    }
    let offset = f64::from(us) - f64::from(trim);
    let span = if offset >= 0.0 {
        f64::from(max - trim)
    } else {
        f64::from(trim - min)
    };
    let mut centi = (offset * 2500.0 / span).round();
    if servo.reverse {
        centi = -centi;
    }
    let (lo, hi) = (servo.travel.minus().0, servo.travel.plus().0);
    Some((centi as i16).clamp(lo, hi))
}

/// The output of `servo` in one SERVO_OUTPUT_RAW (`None` if the message is another port's).
fn output_of(servo: &ServoConfig, t: &Tapped) -> Option<u16> {
    let (port, index) = servo.servo_output_raw_slot();
    if t.outputs.port != port {
        return None;
    }
    let o = &t.outputs;
    Some(
        [
            o.servo1_raw,
            o.servo2_raw,
            o.servo3_raw,
            o.servo4_raw,
            o.servo5_raw,
            o.servo6_raw,
            o.servo7_raw,
            o.servo8_raw,
            o.servo9_raw,
            o.servo10_raw,
            o.servo11_raw,
            o.servo12_raw,
            o.servo13_raw,
            o.servo14_raw,
            o.servo15_raw,
            o.servo16_raw,
        ][index],
    )
}

/// The goals of every long packet the bus has seen since `events` was taken, with when its
/// first byte came.
fn long_packets(events: &Receiver<BusEvent>) -> Vec<(Instant, Vec<(u8, i16)>)> {
    events
        .try_iter()
        .filter_map(|e| match e {
            BusEvent::Packet(p) if matches!(p.packet, HostPacket::Long(_)) => {
                Some((p.first_byte_at, p.packet.goal_positions()))
            }
            _ => None,
        })
        .collect()
}

/// A long packet follows an output the autopilot sent at most this long before it: four
/// output periods at Plane's 40 Hz. The bridge's own part is under 2 ms (the e2e bench); the
/// rest is the SITL's and the tap's scheduling on a loaded CI machine. A bridge 400 ms late
/// (which the failsafe timeout would still allow) fails.
const LAG_BOUND: Duration = Duration::from_millis(100);

/// Check that every long packet's goals are the mapping of one SERVO_OUTPUT_RAW the autopilot
/// sent at most [`LAG_BOUND`] before it (to ±1 count), and never an output older than one an
/// earlier packet already followed (the latest is kept); and that each servo in `moving` took
/// at least `distinct` different goals. How far each packet is behind the newest output is
/// printed. Returns how many packets were checked.
fn goals_follow_outputs(
    cfg: &Config,
    packets: &[(Instant, Vec<(u8, i16)>)],
    outputs: &[Tapped],
    moving: &[(&str, usize)],
) -> usize {
    let servo = |id: u8| cfg.servos.iter().find(|s| s.id.get() == id).unwrap();
    let mut unexplained = Vec::new();
    let mut went_back = Vec::new();
    let mut lags = Vec::new();
    let mut followed = 0;
    let mut checked = 0;
    for (at, goals) in packets {
        let before = outputs.partition_point(|t| t.at < *at);
        if before == 0 {
            continue;
        }
        checked += 1;
        let explains = |t: &Tapped| {
            goals.iter().all(|(id, goal)| {
                output_of(servo(*id), t)
                    .and_then(|us| expected_goal(servo(*id), us))
                    .is_some_and(|e| (i32::from(e) - i32::from(*goal)).abs() <= 1)
            })
        };
        let newest = outputs[before - 1].at;
        match (0..before)
            .rev()
            .take_while(|&k| *at - outputs[k].at <= LAG_BOUND)
            .find(|&k| explains(&outputs[k]))
        {
            Some(k) if k < followed => went_back.push((goals.clone(), k, followed)),
            Some(k) => {
                followed = k;
                lags.push(newest - outputs[k].at);
            }
            None => unexplained.push((goals.clone(), outputs[before - 1].outputs.clone())),
        }
    }
    assert!(
        checked > 0,
        "no long packet after the first output; the last output: {:?}",
        outputs.last().map(|t| &t.outputs)
    );
    assert!(
        unexplained.is_empty(),
        "{} of {checked} long packets match no output of the {LAG_BOUND:?} before them; the \
         first (goals, the newest output): {:?}",
        unexplained.len(),
        &unexplained[..unexplained.len().min(3)]
    );
    assert!(
        went_back.is_empty(),
        "{} of {checked} long packets follow an output older than one already followed \
         (goals, output, already): {:?}",
        went_back.len(),
        &went_back[..went_back.len().min(3)]
    );
    lags.sort_unstable();
    eprintln!(
        "{checked} long packets follow the autopilot's outputs; behind the newest output: median \
         {:?}, max {:?}",
        lags[lags.len() / 2],
        lags[lags.len() - 1]
    );
    for (name, distinct) in moving {
        let s = cfg.servos.iter().find(|s| s.name == *name).unwrap();
        let mut goals: Vec<i16> = packets
            .iter()
            .flat_map(|(_, g)| {
                g.iter()
                    .filter(|(id, _)| *id == s.id.get())
                    .map(|(_, g)| *g)
            })
            .collect();
        goals.sort_unstable();
        goals.dedup();
        assert!(
            goals.len() >= *distinct,
            "{name} took {} different goals, fewer than the {distinct} its outputs should give: \
             {goals:?}",
            goals.len()
        );
    }
    checked
}

/// The rate of SERVO_OUTPUT_RAW port 0 passed on over `window`, from `since`.
fn tapped_rate(tap: &Tap, since: Instant, window: Duration) -> f64 {
    let n = tap
        .outputs_since(since)
        .iter()
        .filter(|t| t.outputs.port == 0 && t.at < since + window)
        .count();
    n as f64 / window.as_secs_f64()
}

/// Wait until SERVO_OUTPUT_RAW port 0 passes the tap at `hz` or more over a second, or panic
/// after `timeout`.
async fn wait_for_tapped_rate(tap: &Tap, hz: f64, timeout: Duration) {
    let deadline = Instant::now() + timeout;
    loop {
        let since = Instant::now();
        tokio::time::sleep(SECS(1)).await;
        let tapped = tapped_rate(tap, since, SECS(1));
        if tapped >= hz {
            return;
        }
        assert!(
            Instant::now() < deadline,
            "SERVO_OUTPUT_RAW at {tapped:.1} Hz {timeout:?} after the autopilot's return, not {hz} Hz"
        );
    }
}

/// Move the surfaces through the ground station for `seconds`: RC override of roll, pitch and
/// yaw at 20 Hz (the autopilot in MANUAL passes them to its outputs).
async fn sweep_sticks(gcs: &mut GroundStation, seconds: f64) {
    let start = Instant::now();
    while start.elapsed().as_secs_f64() < seconds {
        let t = start.elapsed().as_secs_f64();
        let wave =
            |hz: f64, amp: f64| (1500.0 + amp * (std::f64::consts::TAU * hz * t).sin()) as u16;
        gcs.send(
            "RC_CHANNELS_OVERRIDE",
            json!({
                "target_system": 1, "target_component": 1,
                "chan1_raw": wave(0.5, 450.0), "chan2_raw": wave(0.35, 400.0),
                "chan3_raw": 0, "chan4_raw": wave(0.7, 350.0),
                "chan5_raw": 0, "chan6_raw": 0, "chan7_raw": 0, "chan8_raw": 0,
            }),
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// COMMAND_LONG to the autopilot (1, 1); waits for its COMMAND_ACK and returns the result.
fn command(gcs: &mut GroundStation, command: u32, params: [f32; 7]) -> u64 {
    let mark = gcs.mark();
    gcs.send(
        "COMMAND_LONG",
        json!({
            "target_system": 1, "target_component": 1, "command": command, "confirmation": 0,
            "param1": params[0], "param2": params[1], "param3": params[2], "param4": params[3],
            "param5": params[4], "param6": params[5], "param7": params[6],
        }),
    );
    let ack = gcs.wait_for_after(mark, &format!("COMMAND_ACK of {command}"), SECS(10), |m| {
        m["msg"] == "COMMAND_ACK" && m["command"] == command && autopilots::from(m, 1, 1)
    });
    ack["result"].as_u64().unwrap()
}

/// The ground station hears the bridge through the autopilot: its HEARTBEAT (a servo,
/// component 140), its NAMED_VALUE_FLOAT, and the STATUSTEXT of the rudder (servo 4)
/// overheating in the simulator.
fn sees_the_bridges_health(gcs: &GroundStation, chain: &Chain) {
    let hb = gcs.wait_for("the bridge's HEARTBEAT", SECS(10), |m| {
        m["msg"] == "HEARTBEAT" && autopilots::from(m, 1, 140)
    });
    assert_eq!(hb["type"].as_u64(), Some(MAV_TYPE_SERVO), "{hb}");
    gcs.wait_for("the bridge's NAMED_VALUE_FLOAT", SECS(10), |m| {
        m["msg"] == "NAMED_VALUE_FLOAT" && autopilots::from(m, 1, 140)
    });
    let mark = gcs.mark();
    assert!(chain.sims[0].handle().overheat(4));
    gcs.wait_for_after(mark, "the rudder's overheat STATUSTEXT", SECS(10), |m| {
        m["msg"] == "STATUSTEXT"
            && autopilots::from(m, 1, 140)
            && m["text"]
                .as_str()
                .is_some_and(|t| t.contains("rudder: overheat"))
    });
}

/// ArduPlane to MANUAL, where the sticks go straight to its outputs.
fn arduplane_manual(gcs: &mut GroundStation) {
    let manual = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
    assert_eq!(command(gcs, MAV_CMD_DO_SET_MODE, manual), 0, "MANUAL");
}

/// ArduPlane's sticks swept for 2 s: the ailerons' and the elevator's goals follow its outputs.
async fn sticks_followed(gcs: &mut GroundStation, chain: &Chain, tap: &Tap, cfg: &Config) {
    let events = chain.sims[0].handle().subscribe();
    let sweep_from = Instant::now();
    sweep_sticks(gcs, 2.0).await;
    goals_follow_outputs(
        cfg,
        &long_packets(&events),
        &tap.outputs_since(sweep_from - SECS(1)),
        &[
            ("aileron_left", 10),
            ("aileron_right", 10),
            ("elevator", 10),
        ],
    );
}

const MAV_CMD_DO_SET_MODE: u32 = 176;
const MAV_CMD_DO_SET_SERVO: u32 = 183;
const MAV_TYPE_SERVO: u64 = 33;

/// The mapping `docs/autopilot.md` sets ArduPlane SITL up with: the shipped example and the
/// page's servo on an output with no function.
fn arduplane_mapping(extra_mavlink: &str) -> String {
    let example = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/mappings/ardupilot-plane.toml"
    ))
    .unwrap();
    let example = example.replacen("[mavlink]\n", &format!("[mavlink]\n{extra_mavlink}\n"), 1);
    format!(
        "{example}\n{}",
        block_after(PAGE, "<!-- sitl: the servo moved by DO_SET_SERVO -->")
    )
}

/// The bridge on the page's ArduPlane mapping (with `extra_mavlink` lines in `[mavlink]`),
/// written to `file`, where parameter changes are kept.
async fn bridge_from_file(file: &std::path::Path, extra_mavlink: &str) -> (Chain, Config) {
    let text = arduplane_mapping(extra_mavlink);
    std::fs::write(file, &text).unwrap();
    let cfg = Config::parse(&text, "the page's mapping").expect("the page's mapping is valid");
    let options = ChainOptions {
        mapping_file: Some(file.to_path_buf()),
        ..ChainOptions::default()
    };
    (Chain::start_opts(&text, options).await, cfg)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
#[ignore = "needs ArduPlane SITL and its fixed ports: run by .ci/autopilots"]
async fn arduplane_set_up_as_the_page_says() {
    let log = bridge_log();
    let (binary, defaults) = autopilots::arduplane().expect(
        "no ArduPlane SITL: set LJ9DA_ARDUPLANE to an arduplane program (plane.parm beside it)",
    );
    let dir = fresh_dir("arduplane");
    let parm = dir.join("bridge.parm");
    std::fs::write(
        &parm,
        block_after(PAGE, "<!-- sitl: ArduPlane parameters -->"),
    )
    .unwrap();
    let defaults = format!("{},{}", defaults.display(), parm.display());

    let tap = Tap::start(14560);
    let ap = Autopilot::arduplane(&binary, &dir, &defaults, 14560);
    tap.wait_for_autopilot(SECS(60), || ap.console());
    let mapping_file = dir.join("bridge.toml");
    let (chain, cfg) = bridge_from_file(&mapping_file, "").await;
    tap.to_bridge(chain.autopilot_port);
    let mut gcs = GroundStation::connect("tcp:127.0.0.1:5760");

    // The rate the page promises: 40 Hz on stock Plane, by the bridge's meter and by the tap.
    chain
        .wait_view("outputs at 40 Hz", SECS(30), |v| {
            v.outputs_received_hz
                .iter()
                .any(|(port, hz)| *port == 0 && *hz >= 36.0)
        })
        .await;
    let since = Instant::now();
    tokio::time::sleep(SECS(3)).await;
    let tapped = tapped_rate(&tap, since, SECS(3));
    let metered = chain.view.borrow().outputs_received_hz.clone();
    assert!(
        (36.0..=44.0).contains(&tapped),
        "SERVO_OUTPUT_RAW at {tapped:.1} Hz, not the page's 40 Hz"
    );
    assert!(
        metered
            .iter()
            .any(|(p, hz)| *p == 0 && (36.0..=44.0).contains(hz)),
        "the bridge's meter: {metered:?}, not the page's 40 Hz"
    );

    // The surfaces move: MANUAL, the sticks swept by RC override, then output 6 (no function)
    // set by DO_SET_SERVO.
    arduplane_manual(&mut gcs);
    let events = chain.sims[0].handle().subscribe();
    let sweep_from = Instant::now();
    sweep_sticks(&mut gcs, 4.0).await;
    for us in [1800.0, 1250.0] {
        assert_eq!(
            command(
                &mut gcs,
                MAV_CMD_DO_SET_SERVO,
                [6.0, us, 0.0, 0.0, 0.0, 0.0, 0.0]
            ),
            0,
            "DO_SET_SERVO 6 {us}"
        );
        tokio::time::sleep(Duration::from_millis(500)).await;
    }
    let packets = long_packets(&events);
    goals_follow_outputs(
        &cfg,
        &packets,
        &tap.outputs_since(sweep_from - SECS(1)),
        &[
            ("aileron_left", 20),
            ("aileron_right", 20),
            ("elevator", 20),
            ("rudder", 20),
            ("release", 2),
        ],
    );
    let release = cfg.servos.iter().find(|s| s.name == "release").unwrap();
    let last_release = packets.iter().rev().find_map(|(_, g)| {
        g.iter()
            .find(|(id, _)| *id == release.id.get())
            .map(|g| g.1)
    });
    assert_eq!(
        last_release,
        expected_goal(release, 1250),
        "DO_SET_SERVO's goal"
    );

    // The ground station on the autopilot sees the bridge: its HEARTBEAT, NAMED_VALUE_FLOAT and
    // a servo fault's STATUSTEXT, routed by the autopilot.
    sees_the_bridges_health(&gcs, &chain);

    // The bridge's parameters, listed and set through the autopilot; the change is kept in the
    // mapping file. Asking beyond ArduPilot's cap gives one line naming the parameter.
    let mark = gcs.mark();
    gcs.send(
        "PARAM_REQUEST_LIST",
        json!({"target_system": 1, "target_component": 140}),
    );
    let first = gcs.wait_for_after(mark, "the bridge's PARAM_VALUE", SECS(10), |m| {
        m["msg"] == "PARAM_VALUE" && autopilots::from(m, 1, 140)
    });
    let count = first["param_count"].as_u64().unwrap() as usize;
    let deadline = Instant::now() + SECS(10);
    loop {
        let mut indexes: Vec<u64> = gcs
            .heard_after(mark)
            .iter()
            .filter(|m| m["msg"] == "PARAM_VALUE" && autopilots::from(m, 1, 140))
            .map(|m| m["param_index"].as_u64().unwrap())
            .collect();
        indexes.sort_unstable();
        indexes.dedup();
        if indexes.len() == count {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "{} of the bridge's {count} parameters came through the autopilot",
            indexes.len()
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let mark = gcs.mark();
    gcs.send(
        "PARAM_SET",
        json!({"target_system": 1, "target_component": 140, "param_id": "BRG_OUT_HZ",
               "param_value": 50.0, "param_type": 9}),
    );
    gcs.wait_for_after(mark, "BRG_OUT_HZ = 50 confirmed", SECS(10), |m| {
        m["msg"] == "PARAM_VALUE"
            && autopilots::from(m, 1, 140)
            && m["param_id"] == "BRG_OUT_HZ"
            && m["param_value"] == 50.0
    });
    let deadline = Instant::now() + SECS(10);
    while !std::fs::read_to_string(&mapping_file)
        .unwrap()
        .contains("output_rate_hz = 50")
    {
        assert!(
            Instant::now() < deadline,
            "BRG_OUT_HZ = 50 is not in the mapping file"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let deadline = Instant::now() + SECS(10);
    while log_lines_with(&log, "SCHED_LOOP_RATE").is_empty() {
        assert!(
            Instant::now() < deadline,
            "no line names SCHED_LOOP_RATE after asking 50 Hz"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    // Once: the stream running at the lower rate the autopilot took means no denial is left
    // to come, and so no second line.
    let since = Instant::now();
    tokio::time::sleep(SECS(2)).await;
    let tapped = tapped_rate(&tap, since, SECS(2));
    assert!(
        (36.0..=44.0).contains(&tapped),
        "after the denial: {tapped:.1} Hz"
    );
    let advice = log_lines_with(&log, "SCHED_LOOP_RATE");
    assert_eq!(advice.len(), 1, "one line, not {advice:?}");
    assert!(
        advice[0].contains("denied SERVO_OUTPUT_RAW at 50 Hz"),
        "{advice:?}"
    );
    chain.stop().await;

    // Signing as the page says: the key given to the autopilot with SETUP_SIGNING (what
    // MAVProxy's `signing setup` sends), the same passphrase in the mapping.
    let key = Sha256::digest(PASSPHRASE.as_bytes());
    let key_hex: String = key.iter().map(|b| format!("{b:02x}")).collect();
    let since_2015_10us = (std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_micros()
        / 10
        - 1_420_070_400 * 100_000) as u64;
    gcs.command(json!({
        "send": "SETUP_SIGNING",
        "fields": {"target_system": 1, "target_component": 1, "secret_key": key_hex,
                   "initial_timestamp": since_2015_10us},
        "hex": ["secret_key"],
    }));
    gcs.command(json!({ "sign": key_hex }));
    let signing = format!("signing_passphrase = \"{PASSPHRASE}\"");
    let (chain, _) = bridge_from_file(&mapping_file, &signing).await;
    tap.to_bridge(chain.autopilot_port);
    let mark = gcs.mark();
    gcs.wait_for_after(mark, "the signing bridge's HEARTBEAT", SECS(15), |m| {
        m["msg"] == "HEARTBEAT" && autopilots::from(m, 1, 140)
    });
    sticks_followed(&mut gcs, &chain, &tap, &cfg).await;
    let ((ap_all, ap_signed), (br_all, br_signed)) = tap
        .datagrams_since_first_signed()
        .expect("ArduPlane signed nothing after SETUP_SIGNING");
    assert!(
        ap_all > 0 && ap_signed == ap_all && br_all > 0 && br_signed == br_all,
        "signed datagrams: autopilot {ap_signed} of {ap_all}, bridge {br_signed} of {br_all}"
    );
    // An unsigned command to the bridge is refused: counted as unsigned, its value not taken.
    let before = chain.view.borrow().signing_drops[0].unsigned;
    unsigned_param_set(chain.autopilot_port, "BRG_FS_MS", 900.0);
    chain
        .wait_view("the unsigned PARAM_SET counted", SECS(5), |v| {
            v.signing_drops[0].unsigned > before
        })
        .await;
    let mark = gcs.mark();
    gcs.send(
        "PARAM_REQUEST_READ",
        json!({"target_system": 1, "target_component": 140, "param_id": "BRG_FS_MS",
               "param_index": -1}),
    );
    let value = gcs.wait_for_after(mark, "BRG_FS_MS read", SECS(10), |m| {
        m["msg"] == "PARAM_VALUE" && autopilots::from(m, 1, 140) && m["param_id"] == "BRG_FS_MS"
    });
    assert_eq!(
        value["param_value"], 500.0,
        "the unsigned PARAM_SET was taken: {value}"
    );
    drop(gcs);

    // The autopilot killed: the failsafe within failsafe_timeout_ms + 100 ms of its last output,
    // said once; started again, its outputs are followed without restarting the bridge.
    ap.kill();
    let last_output = tap.outputs().last().unwrap().at;
    chain
        .gcs
        .wait_for("the failsafe's STATUSTEXT", SECS(5), |heard| {
            heard.iter().any(|(_, _, m)| failsafe_text(m))
        })
        .await;
    let announced = chain
        .gcs
        .all()
        .into_iter()
        .find(|(_, _, m)| failsafe_text(m))
        .unwrap()
        .0;
    let after = announced.duration_since(last_output);
    let timeout = Duration::from_millis(cfg.mavlink.failsafe_timeout_ms.into());
    assert!(
        (timeout..=timeout + Duration::from_millis(100)).contains(&after),
        "failsafe announced {after:?} after the autopilot's last output, not within \
         {timeout:?} + 100 ms"
    );
    eprintln!("failsafe announced {after:?} after the autopilot's last output");
    // The view is published after the step that sent the text: wait for it to show the
    // failsafe, or its return below could be read from before the outage.
    chain
        .wait_view("the failsafe in the view", SECS(5), |v| v.failsafe)
        .await;
    let ap = Autopilot::arduplane(&binary, &dir, &defaults, 14560);
    let mut gcs = GroundStation::connect("tcp:127.0.0.1:5760");
    chain
        .wait_view("the failsafe left", SECS(60), |v| !v.failsafe)
        .await;
    let back = Instant::now();
    // The restarted autopilot starts at its default rate: the bridge asks for its rate again,
    // and the stream runs at it before the sticks are swept.
    wait_for_tapped_rate(&tap, 36.0, SECS(30)).await;
    let texts = chain.gcs.all();
    let said = texts.iter().filter(|(_, _, m)| failsafe_text(m)).count();
    assert_eq!(said, 1, "the failsafe was said {said} times");
    arduplane_manual(&mut gcs);
    sticks_followed(&mut gcs, &chain, &tap, &cfg).await;
    // The outage and the autopilot's return at its default rate are not a slow stream: nothing
    // said in the slow-stream rule's span (and a window more) from the return.
    let span = rate::WINDOW * (rate::LOW_WINDOWS + 1);
    tokio::time::sleep((back + span).saturating_duration_since(Instant::now())).await;
    let slow = log_lines_with(&log, "below the");
    assert!(
        slow.is_empty(),
        "a slow stream said across the restart: {slow:?}"
    );
    drop(gcs);
    chain.stop().await;
    drop(ap);
}

const PASSPHRASE: &str = "lj9da bridge sitl";

fn failsafe_text(m: &mavlink::dialects::common::MavMessage) -> bool {
    matches!(m, mavlink::dialects::common::MavMessage::STATUSTEXT(s)
        if s.text.to_str().is_ok_and(|t| t.contains("failsafe: no outputs")))
}

/// An unsigned PARAM_SET of the bridge's `name`, sent to the bridge's autopilot link from a
/// socket of its own (what a stranger on the link could send).
fn unsigned_param_set(bridge_port: u16, name: &str, value: f32) {
    use mavlink::dialects::common::{MavMessage, MavParamType, PARAM_SET_DATA};
    let mut id = [0u8; 16];
    id[..name.len()].copy_from_slice(name.as_bytes());
    let msg = MavMessage::PARAM_SET(PARAM_SET_DATA {
        param_value: value,
        target_system: 1,
        target_component: 140,
        param_id: id.into(),
        param_type: MavParamType::MAV_PARAM_TYPE_REAL32,
    });
    let header = mavlink::MavHeader {
        system_id: 255,
        component_id: 190,
        sequence: 0,
    };
    let mut frame = Vec::new();
    mavlink::write_v2_msg(&mut frame, header, &msg).unwrap();
    let socket = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    socket.send_to(&frame, ("127.0.0.1", bridge_port)).unwrap();
}

const MAV_CMD_DO_SET_ACTUATOR: u32 = 187;
/// param1: MAV_SAFETY_SWITCH_STATE, 0 safe (the switch on), 1 dangerous (off).
const MAV_CMD_DO_SET_SAFETY_SWITCH_STATE: u32 = 5300;
const MAV_CMD_COMPONENT_ARM_DISARM: u32 = 400;

/// PX4's parameters from the page, as `(NAME, value)`.
fn px4_parameters() -> Vec<(String, String)> {
    block_after(PAGE, "<!-- sitl: PX4 parameters -->")
        .lines()
        .filter(|l| !l.trim().is_empty() && !l.starts_with('#'))
        .map(|l| {
            let (name, value) = l.split_once(' ').expect("NAME VALUE");
            (name.to_string(), value.trim().to_string())
        })
        .collect()
}

/// PX4's sticks from the ground station (MANUAL_CONTROL at 20 Hz) for `seconds`: centred, or
/// swept in roll, pitch and yaw; throttle down.
async fn manual_sticks(gcs: &mut GroundStation, seconds: f64, sweep: bool) {
    let start = Instant::now();
    while start.elapsed().as_secs_f64() < seconds {
        let t = start.elapsed().as_secs_f64();
        let wave = |hz: f64| {
            if sweep {
                (800.0 * (std::f64::consts::TAU * hz * t).sin()) as i64
            } else {
                0
            }
        };
        gcs.send(
            "MANUAL_CONTROL",
            json!({"target": 1, "x": wave(0.35), "y": wave(0.5), "z": 0, "r": wave(0.7),
                   "buttons": 0}),
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// PX4's onboard 10 Hz stream raised to `asked` Hz: at least 90 % of it by the bridge's own
/// meter and by the tap.
async fn outputs_raised(chain: &Chain, tap: &Tap, asked: f32) {
    chain
        .wait_view("SERVO_OUTPUT_RAW raised", SECS(30), |v| {
            v.outputs_received_hz
                .iter()
                .any(|(port, hz)| *port == 0 && *hz >= 0.9 * asked)
        })
        .await;
    let since = Instant::now();
    tokio::time::sleep(SECS(3)).await;
    let metered = chain.view.borrow().outputs_received_hz.clone();
    let tapped = tapped_rate(tap, since, SECS(3));
    assert!(
        metered.iter().any(|(p, hz)| *p == 0 && *hz >= 0.9 * asked)
            && tapped >= 0.9 * f64::from(asked),
        "asked {asked} Hz: the bridge's meter {metered:?}, the tap {tapped:.1} Hz"
    );
}

/// The bridge on `mapping`, PX4's outputs passed to it by `tap`, once their stream is raised
/// to the mapping's rate ([`outputs_raised`]).
async fn px4_bridge(mapping: &str, tap: &Tap) -> (Chain, Config) {
    let cfg = Config::parse(mapping, "the PX4 mapping").expect("the mapping is valid");
    let chain = Chain::start_opts(mapping, ChainOptions::default()).await;
    tap.to_bridge(chain.autopilot_port);
    outputs_raised(&chain, tap, cfg.mavlink.output_rate_hz).await;
    (chain, cfg)
}

/// PX4 in Manual and armed (its outputs leave their disarmed 900 µs).
fn px4_armed_in_manual(gcs: &mut GroundStation) {
    let manual = [1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0];
    assert_eq!(command(gcs, MAV_CMD_DO_SET_MODE, manual), 0, "Manual");
    let arm = [1.0, 21196.0, 0.0, 0.0, 0.0, 0.0, 0.0];
    assert_eq!(command(gcs, MAV_CMD_COMPONENT_ARM_DISARM, arm), 0, "arming");
}

/// Actuator Set 1 (the gear door's output, function 301) to +0.5, then −0.4.
async fn gear_door_moved(gcs: &mut GroundStation) {
    for value in [0.5f32, -0.4] {
        let set = [value, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        assert_eq!(
            command(gcs, MAV_CMD_DO_SET_ACTUATOR, set),
            0,
            "DO_SET_ACTUATOR {value}"
        );
        tokio::time::sleep(Duration::from_millis(500)).await;
    }
}

/// PX4 SITL as `model`, with the page's parameter lines, sending its onboard link through a
/// tap on UDP 14540; a ground station on its own link (UDP 14550).
fn px4_as_the_page_says(model: &str) -> (Autopilot, Tap, GroundStation) {
    let root = autopilots::px4()
        .expect("no PX4 SITL: set LJ9DA_PX4 to a folder with bin/px4 and etc/ (a SITL build)");
    let params = px4_parameters();
    let params: Vec<(&str, &str)> = params
        .iter()
        .map(|(n, v)| (n.as_str(), v.as_str()))
        .collect();
    let tap = Tap::start(14540);
    let gcs = GroundStation::connect("udpin:127.0.0.1:14550");
    let px4 = Autopilot::px4(&root, model, &fresh_dir(model), &params);
    tap.wait_for_autopilot(SECS(30), || px4.console());
    (px4, tap, gcs)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
#[ignore = "needs PX4 SITL and its fixed ports: run by .ci/autopilots"]
async fn px4_airplane_set_up_as_the_page_says() {
    let (px4, tap, mut gcs) = px4_as_the_page_says("sihsim_airplane");
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/mappings/px4-vtol.toml"
    ))
    .unwrap();
    let (chain, cfg) = px4_bridge(&text, &tap).await;

    // Disarmed, PX4 outputs its disarmed value (900 µs: no output) however the sticks move:
    // no servo has moved since the bridge started, each still force off from its power-on.
    let disarmed_from = Instant::now();
    manual_sticks(&mut gcs, 2.0, true).await;
    let heard = tap.outputs_since(disarmed_from).len();
    let servos = chain.sims[0].handle().snapshots();
    assert!(
        heard > 20 && servos.iter().all(|s| s.force == lj9da_sim::Force::Off),
        "disarmed: {heard} outputs from PX4, the servos {servos:?}"
    );

    // Armed in Manual, the sticks move the surfaces, DO_SET_ACTUATOR the gear door; every
    // goal follows PX4's outputs.
    manual_sticks(&mut gcs, 1.0, false).await;
    px4_armed_in_manual(&mut gcs);
    let events = chain.sims[0].handle().subscribe();
    let sweep_from = Instant::now();
    manual_sticks(&mut gcs, 4.0, true).await;
    gear_door_moved(&mut gcs).await;
    goals_follow_outputs(
        &cfg,
        &long_packets(&events),
        &tap.outputs_since(sweep_from - SECS(1)),
        &[
            ("aileron_left", 10),
            ("aileron_right", 10),
            ("elevator", 10),
            ("rudder", 10),
            ("gear_door", 2),
        ],
    );

    // A ground station on PX4's own link sees the bridge's health, forwarded by PX4.
    sees_the_bridges_health(&gcs, &chain);
    drop(gcs);
    chain.stop().await;
    drop(px4);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
#[ignore = "needs PX4 SITL and its fixed ports: run by .ci/autopilots"]
async fn px4_quadrotor_with_the_pages_minimal_mapping() {
    let (px4, tap, mut gcs) = px4_as_the_page_says("sihsim_quadx");
    let text = block_after(PAGE, "<!-- sitl: the PX4 minimal mapping -->");
    let (chain, cfg) = px4_bridge(&text, &tap).await;

    manual_sticks(&mut gcs, 1.0, false).await;
    px4_armed_in_manual(&mut gcs);
    let events = chain.sims[0].handle().subscribe();
    let from = Instant::now();
    gear_door_moved(&mut gcs).await;
    goals_follow_outputs(
        &cfg,
        &long_packets(&events),
        &tap.outputs_since(from - SECS(1)),
        &[("gear_door", 2)],
    );
    drop(gcs);
    chain.stop().await;
    drop(px4);
}

/// The applet of `packaging/ardupilot/` as the page installs it.
const APPLET: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/packaging/ardupilot/lj9da.lua");

/// An arm command (not forced: the pre-arm checks, the applet's among them, run); its result
/// and the autopilot's STATUSTEXTs that came with it.
fn try_arming(gcs: &mut GroundStation) -> (u64, Vec<String>) {
    let mark = gcs.mark();
    let result = command(
        gcs,
        MAV_CMD_COMPONENT_ARM_DISARM,
        [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    );
    std::thread::sleep(Duration::from_millis(200));
    let texts = gcs
        .heard_after(mark)
        .iter()
        .filter(|m| m["msg"] == "STATUSTEXT" && autopilots::from(m, 1, 1))
        .filter_map(|m| m["text"].as_str().map(str::to_string))
        .collect();
    (result, texts)
}

/// Arm commands once a second until one is refused with a text holding `reason` (returned);
/// panics if the autopilot arms meanwhile or `timeout` passes.
fn refused_for(gcs: &mut GroundStation, reason: &str, timeout: Duration) -> String {
    let deadline = Instant::now() + timeout;
    let mut last = Vec::new();
    while Instant::now() < deadline {
        let (result, texts) = try_arming(gcs);
        assert_ne!(
            result, 0,
            "armed while waiting for \"{reason}\"; texts: {texts:?}"
        );
        if let Some(t) = texts.iter().find(|t| t.contains(reason)) {
            return t.clone();
        }
        last = texts;
        std::thread::sleep(Duration::from_millis(800));
    }
    panic!("arming never refused with \"{reason}\" in {timeout:?}; the last texts: {last:?}");
}

/// The autopilot's HEARTBEAT (its custom mode, whether armed) after `mark`.
fn autopilot_mode_after(gcs: &GroundStation, mark: usize, what: &str, mode: u64) -> GcsMessage {
    gcs.wait_for_after(mark, what, SECS(10), |m| {
        m["msg"] == "HEARTBEAT" && autopilots::from(m, 1, 1) && m["custom_mode"] == mode
    })
}

/// The applet's LJ9S rows (label, state) in the newest `.BIN` log of `logs`, as pymavlink's
/// log reader (the one `mavlogdump.py` uses) reads them.
fn logged_states(logs: &std::path::Path) -> Vec<(String, i64)> {
    let newest = std::fs::read_dir(logs)
        .unwrap_or_else(|e| panic!("{}: {e}", logs.display()))
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "BIN"))
        .max_by_key(|p| std::fs::metadata(p).and_then(|m| m.modified()).ok())
        .expect("a .BIN log");
    let script = "import json, sys\n\
        from pymavlink import mavutil\n\
        log = mavutil.mavlink_connection(sys.argv[1])\n\
        rows = []\n\
        while (m := log.recv_match(type='LJ9S')) is not None:\n    \
            rows.append([m.Label, m.State])\n\
        print(json.dumps(rows))\n";
    let out = std::process::Command::new(common::python::python())
        .arg("-c")
        .arg(script)
        .arg(&newest)
        .output()
        .expect("python runs");
    assert!(
        out.status.success(),
        "reading {}: {}",
        newest.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("the rows as JSON")
}

/// Whether `m` is a STATUSTEXT `text` from component `component` of system 1 (1: the
/// autopilot's own, 140: the bridge's, relayed by the autopilot).
fn is_text(m: &GcsMessage, component: u8, text: &str) -> bool {
    m["msg"] == "STATUSTEXT" && autopilots::from(m, 1, component) && m["text"] == text
}

/// The STATUSTEXT `text` of `component` after `mark`, within 10 s (the bridge's flood guard
/// holds a second text of a kind for 3 s).
fn text_after(gcs: &GroundStation, mark: usize, component: u8, text: &str) -> GcsMessage {
    let what = format!("\"{text}\" from component {component}");
    gcs.wait_for_after(mark, &what, SECS(10), |m| is_text(m, component, text))
}

/// How many of the autopilot's STATUSTEXTs after `mark` are `text`.
fn texts_after(gcs: &GroundStation, mark: usize, text: &str) -> usize {
    gcs.heard_after(mark)
        .iter()
        .filter(|m| is_text(m, 1, text))
        .count()
}

/// ArduPlane's mode numbers (`ArduPlane/mode.h`).
const PLANE_MANUAL: u64 = 0;
const PLANE_RTL: u64 = 11;
const MAV_MODE_FLAG_SAFETY_ARMED: u64 = 128;

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
#[ignore = "needs ArduPlane SITL and its fixed ports: run by .ci/autopilots"]
async fn arduplane_applet_refuses_arming_for_a_lost_servo_and_acts_when_the_bridge_goes_silent() {
    let (binary, defaults) = autopilots::arduplane().expect(
        "no ArduPlane SITL: set LJ9DA_ARDUPLANE to an arduplane program (plane.parm beside it)",
    );
    let dir = fresh_dir("arduplane-applet");
    std::fs::create_dir_all(dir.join("scripts")).unwrap();
    std::fs::copy(APPLET, dir.join("scripts/lj9da.lua")).expect("the applet");
    let parm = dir.join("bridge.parm");
    std::fs::write(
        &parm,
        block_after(PAGE, "<!-- sitl: ArduPlane parameters -->")
            + &block_after(PAGE, "<!-- sitl: the applet's parameters -->"),
    )
    .unwrap();
    let defaults = format!("{},{}", defaults.display(), parm.display());
    let tap = Tap::start(14560);
    let ap = Autopilot::arduplane(&binary, &dir, &defaults, 14560);
    tap.wait_for_autopilot(SECS(60), || ap.console());
    let mut gcs = GroundStation::connect("tcp:127.0.0.1:5760");

    // No bridge yet: arming is refused, and the reason says so.
    let said = refused_for(&mut gcs, "LJ9DA: bridge silent 3 s", SECS(60));
    assert!(said.starts_with("Arm: "), "{said}");

    // The bridge up with the rudder (servo 4) unplugged: refused, naming the rudder.
    let (chain, _cfg) = bridge_from_file(&dir.join("bridge.toml"), "").await;
    assert!(chain.sims[0].handle().unplug(4));
    tap.to_bridge(chain.autopilot_port);
    refused_for(&mut gcs, "LJ9DA: rudder offline", SECS(30));

    // The autopilot's safety switch on: the bridge reads it from the autopilot's SYS_STATUS
    // and says so; off again before arming (ArduPilot does not arm with it on).
    let mark = gcs.mark();
    assert_eq!(
        command(&mut gcs, MAV_CMD_DO_SET_SAFETY_SWITCH_STATE, [0.0; 7]),
        0,
        "safety on"
    );
    text_after(&gcs, mark, 140, "LJ9DA: autopilot safety on, servos hold");
    let mark = gcs.mark();
    let dangerous = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
    assert_eq!(
        command(&mut gcs, MAV_CMD_DO_SET_SAFETY_SWITCH_STATE, dangerous),
        0,
        "safety off"
    );
    text_after(&gcs, mark, 140, "LJ9DA: autopilot safety off");

    // Plugged back in: the applet lets the autopilot arm (once its own checks pass too).
    assert!(chain.sims[0].handle().plug(4));
    let deadline = Instant::now() + SECS(90);
    loop {
        let (result, texts) = try_arming(&mut gcs);
        if result == 0 {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "not armed 90 s after the rudder came back: {texts:?}"
        );
        std::thread::sleep(Duration::from_millis(800));
    }

    // Armed: the action set to RTL, the vehicle in MANUAL.
    let mark = gcs.mark();
    gcs.send(
        "PARAM_SET",
        json!({"target_system": 1, "target_component": 1, "param_id": "LJ9_FS_MODE",
               "param_value": PLANE_RTL as f32, "param_type": 9}),
    );
    gcs.wait_for_after(mark, "LJ9_FS_MODE set", SECS(10), |m| {
        m["msg"] == "PARAM_VALUE" && m["param_id"] == "LJ9_FS_MODE" && m["param_value"] == 11.0
    });
    arduplane_manual(&mut gcs);
    autopilot_mode_after(&gcs, gcs.mark(), "MANUAL", PLANE_MANUAL);

    // A servo lost in flight: said at CRITICAL, the mode changed; back: said at INFO.
    let mark = gcs.mark();
    let unplugged = Instant::now();
    assert!(chain.sims[0].handle().unplug(4));
    let lost = text_after(&gcs, mark, 1, "LJ9DA: rudder offline");
    let servo_noticed = unplugged.elapsed();
    assert_eq!(lost["severity"], 2, "MAV_SEVERITY_CRITICAL: {lost}");
    autopilot_mode_after(&gcs, mark, "RTL after the rudder was lost", PLANE_RTL);
    // Offline after 3 missed replies or 300 ms of silence (the bus's defaults), its state out
    // within 100 ms, the applet's look every 100 ms: about 0.5 s; 1.5 s allows the loaded
    // machine's TCP path to the ground station.
    assert!(
        servo_noticed < Duration::from_millis(1500),
        "the rudder's loss said after {servo_noticed:?}"
    );
    assert!(chain.sims[0].handle().plug(4));
    let back = text_after(&gcs, mark, 1, "LJ9DA: rudder back");
    assert_eq!(back["severity"], 6, "MAV_SEVERITY_INFO: {back}");
    let said = texts_after(&gcs, mark, "LJ9DA: rudder offline");
    assert_eq!(said, 1, "the rudder's loss said {said} times");

    // MANUAL again; then the bridge goes silent.
    arduplane_manual(&mut gcs);
    let mark = gcs.mark();
    autopilot_mode_after(&gcs, mark, "MANUAL", PLANE_MANUAL);
    let silenced = Instant::now();
    tap.silence_bridge();
    let critical = text_after(&gcs, mark, 1, "LJ9DA: bridge silent 3 s");
    let noticed = silenced.elapsed();
    assert_eq!(critical["severity"], 2, "MAV_SEVERITY_CRITICAL: {critical}");
    let rtl = autopilot_mode_after(&gcs, mark, "RTL after the bridge went silent", PLANE_RTL);
    let armed = rtl["base_mode"].as_u64().unwrap() & MAV_MODE_FLAG_SAFETY_ARMED;
    assert_ne!(armed, 0, "still armed in RTL: {rtl}");
    // The applet's timeout is 3 s from the bridge's last HEARTBEAT (1 Hz), checked every
    // 100 ms: said 2.0–3.1 s after the silence began, and up to 0.9 s more on its way to the
    // ground station over the autopilot's TCP link on a loaded machine.
    assert!(
        (SECS(2)..SECS(4)).contains(&noticed),
        "the silence noticed after {noticed:?}"
    );
    // Said once: the next mode HEARTBEATs come and the text does not again.
    let after = gcs.mark();
    autopilot_mode_after(&gcs, after, "RTL", PLANE_RTL);
    autopilot_mode_after(&gcs, gcs.mark(), "RTL", PLANE_RTL);
    let said = texts_after(&gcs, mark, "LJ9DA: bridge silent 3 s");
    assert_eq!(said, 1, "the bridge's loss said {said} times");

    // The autopilot's own log holds the servos' states, the rudder's loss among them.
    let states = logged_states(&dir.join("logs"));
    for (label, state) in [("rudder", 0), ("rudder", 1), ("ail_l", 0)] {
        assert!(
            states.iter().any(|(l, s)| l == label && *s == state),
            "no LJ9S row {label} = {state} in the autopilot's log: {} rows, the last: {:?}",
            states.len(),
            &states[states.len().saturating_sub(8)..]
        );
    }
    eprintln!(
        "the applet said the rudder lost after {servo_noticed:?}, the bridge after {noticed:?}"
    );
    chain.stop().await;
}

const DRONECAN_PAGE: &str = "docs/dronecan.md";

/// The goal of `servo` for ArduPlane's DroneCAN command `c`, by the page's law: a PWM command
/// is its pulse, an UNITLESS value v the pulse 1500 + 500 v.
fn expected_can_goal(servo: &ServoConfig, c: &Command) -> Option<i16> {
    let us = match c.command_type {
        CommandType::Pwm => c.value,
        CommandType::Unitless => 1500.0 + 500.0 * c.value,
        _ => return None,
    };
    expected_goal(servo, us.round() as u16)
}

/// How much later than the bridge the test's listener may take a datagram both hear.
const LISTENER_SLACK: Duration = Duration::from_millis(5);

/// Every long packet since the sweep follows the newest ArrayCommand ArduPlane sent before it
/// (or the one before that), to ±1 count, by the page's law; returns (long packets checked,
/// ArrayCommands a second, long packets a second) over `window`.
fn goals_follow_can(
    cfg: &Config,
    packets: &[(Instant, Vec<(u8, i16)>)],
    heard: &[Heard],
    window: Duration,
) -> (usize, f64, f64) {
    let servo = |id: u8| cfg.servos.iter().find(|s| s.id.get() == id).unwrap();
    let mut unexplained = Vec::new();
    let mut checked = 0;
    for (at, goals) in packets {
        let before = heard.partition_point(|h| h.at < *at);
        if before == 0 {
            continue;
        }
        checked += 1;
        let explains = |h: &Heard| {
            goals.iter().all(|(id, goal)| {
                let s = servo(*id);
                h.commands
                    .iter()
                    .find(|c| c.actuator_id == s.dronecan_id)
                    .and_then(|c| expected_can_goal(s, c))
                    .is_some_and(|e| (i32::from(e) - i32::from(*goal)).abs() <= 1)
            })
        };
        // The newest ArrayCommand before the packet, or the one before it (the newest may have
        // come while the packet was on its way); the listener, a thread of the test, may have
        // taken the bridge's command a little after the bridge did.
        let upto = heard.partition_point(|h| h.at < *at + LISTENER_SLACK);
        if !(0..upto)
            .rev()
            .take(upto - before + 2)
            .any(|k| explains(&heard[k]))
        {
            unexplained.push((goals.clone(), heard[before - 1].commands.clone()));
        }
    }
    assert!(checked > 0, "no long packet after the first ArrayCommand");
    assert!(
        unexplained.is_empty(),
        "{} of {checked} long packets match neither of the two ArrayCommands before them; the \
         first (goals, the newest commands): {:?}",
        unexplained.len(),
        &unexplained[..unexplained.len().min(3)]
    );
    let mut gaps: Vec<Duration> = heard.windows(2).map(|w| w[1].at - w[0].at).collect();
    gaps.sort_unstable();
    eprintln!(
        "ArrayCommand gaps: shortest {:?}, median {:?}, longest {:?}",
        gaps.first(),
        gaps.get(gaps.len() / 2),
        gaps.last()
    );
    let secs = window.as_secs_f64();
    (
        checked,
        heard.len() as f64 / secs,
        packets.len() as f64 / secs,
    )
}

/// How long an ArrayCommand may wait for its long packet when no newer one replaces it: a
/// long packet and one telemetry exchange on the 115 200-baud bus, with room for a loaded
/// machine.
const FOLLOW_WITHIN: Duration = Duration::from_millis(20);

/// Every ArrayCommand that stood alone for [`FOLLOW_WITHIN`] (no newer one came meanwhile) and
/// changed a goal was followed by a long packet carrying its goals within that time (counted
/// from [`LISTENER_SLACK`] before the listener took it); a newer one may replace it sooner (the
/// newest wins). Returns how many were judged.
fn each_command_followed(
    cfg: &Config,
    packets: &[(Instant, Vec<(u8, i16)>)],
    heard: &[Heard],
) -> usize {
    let goals_of = |h: &Heard| -> Vec<(u8, i16)> {
        let mut g: Vec<(u8, i16)> = cfg
            .servos
            .iter()
            .filter_map(|s| {
                let c = h.commands.iter().find(|c| c.actuator_id == s.dronecan_id)?;
                Some((s.id.get(), expected_can_goal(s, c)?))
            })
            .collect();
        g.sort_unstable();
        g
    };
    let close = |a: &[(u8, i16)], b: &[(u8, i16)]| {
        let mut b = b.to_vec();
        b.sort_unstable();
        a.len() == b.len()
            && a.iter()
                .zip(&b)
                .all(|(x, y)| x.0 == y.0 && (x.1 - y.1).abs() <= 1)
    };
    let mut judged = 0;
    let mut missed = Vec::new();
    for k in 1..heard.len().saturating_sub(1) {
        let (h, next) = (&heard[k], &heard[k + 1]);
        let want = goals_of(h);
        if next.at - h.at < FOLLOW_WITHIN || close(&want, &goals_of(&heard[k - 1])) {
            continue;
        }
        judged += 1;
        // The bridge may have taken the command, and sent its packet, a little before the
        // test's listener took the same datagram.
        let from = h.at - LISTENER_SLACK;
        let followed = packets
            .iter()
            .any(|(at, g)| *at >= from && *at - from <= FOLLOW_WITHIN && close(&want, g));
        if !followed {
            // What the bus did next, and the commands around: for the message.
            let next_packets: Vec<(Duration, Vec<(u8, i16)>)> = packets
                .iter()
                .filter(|(at, _)| *at >= from)
                .take(2)
                .map(|(at, g)| (*at - from, g.clone()))
                .collect();
            missed.push((want, next.at - h.at, next_packets));
        }
    }
    assert!(
        judged > 0,
        "no ArrayCommand stood alone for {FOLLOW_WITHIN:?}"
    );
    assert!(
        missed.is_empty(),
        "{} of {judged} ArrayCommands got no long packet within {FOLLOW_WITHIN:?} (goals, the \
         next command after, the next packets after the listener's slack): {:?}",
        missed.len(),
        &missed[..missed.len().min(3)]
    );
    judged
}

/// ArduPlane's own log: the CSRV rows (TimeUS, Id, Pos) of its newest `.bin` in `dir/logs`.
fn csrv_rows(dir: &std::path::Path) -> Vec<(u64, u8, f64)> {
    log_rows(dir, "CSRV", "Id", "Pos")
}

/// ArduPlane's own log: the rows of type `ty` of its newest `.bin` in `dir/logs`, as (TimeUS,
/// field `id`, field `value`), read with pymavlink's DFReader.
fn log_rows(dir: &std::path::Path, ty: &str, id: &str, value: &str) -> Vec<(u64, u8, f64)> {
    let logs = dir.join("logs");
    let mut bins: Vec<_> = std::fs::read_dir(&logs)
        .unwrap_or_else(|e| panic!("{}: {e}", logs.display()))
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x.eq_ignore_ascii_case("bin")))
        .collect();
    bins.sort();
    let bin = bins.last().expect("ArduPlane wrote a .bin log");
    let script = format!(
        "import sys\nfrom pymavlink import DFReader\nr = DFReader.DFReader_binary(sys.argv[1])\nwhile True:\n    m = r.recv_match(type='{ty}')\n    if m is None:\n        break\n    print(m.TimeUS, m.{id}, repr(m.{value}))\n"
    );
    let out = std::process::Command::new(common::python::python())
        .arg("-c")
        .arg(script)
        .arg(bin)
        .output()
        .expect("pymavlink reads the log");
    assert!(
        out.status.success(),
        "DFReader: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| {
            let mut f = l.split_whitespace();
            Some((
                f.next()?.parse().ok()?,
                f.next()?.parse().ok()?,
                f.next()?.parse().ok()?,
            ))
        })
        .collect()
}

/// A DroneCAN test: pymavlink (the ground station, the log's reader) installed first, as the
/// namespace has no way out to PyPI; then `test` in a network namespace of its own.
fn in_can_namespace(test: impl std::future::Future<Output = ()>) {
    common::python::python();
    autopilots::can::enter_network_namespace();
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(4)
        .enable_all()
        .build()
        .unwrap()
        .block_on(test);
}

/// The shipped example mapping commanded over DroneCAN, with the page's `[dronecan]` table
/// (`table`) on SITL's `mcast:0`.
fn example_on_can(table: &str) -> String {
    let example = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/mappings/ardupilot-plane.toml"
    ))
    .unwrap();
    format!(
        "{}\n{}",
        example.replacen("[bridge]\n", "[bridge]\ncommands = \"dronecan\"\n", 1),
        table.replacen("\"can0\"", "\"mcast:0\"", 1)
    )
}

#[test]
#[ignore = "needs ArduPlane SITL, root for a network namespace: run by .ci/autopilots"]
fn arduplane_gives_the_bridge_its_node_id() {
    in_can_namespace(arduplane_allocates());
}

/// `node_id = "dynamic"`: ArduPlane's allocator (its DroneCAN driver runs one) gives the
/// bridge's node an id, under which the node then speaks and ArduPlane logs its servos.
async fn arduplane_allocates() {
    let _log = bridge_log();
    let dir = fresh_dir("arduplane-dna");
    let listener = CanListener::start(0, &[]);
    let tap = Tap::start(14560);
    let (ap, _) = arduplane_on_can(&dir, "", 14560);
    tap.wait_for_autopilot(SECS(60), || ap.console());
    let table = block_after(DRONECAN_PAGE, "<!-- sitl: the bridge's DroneCAN table -->").replacen(
        "node_id = 42",
        "node_id = \"dynamic\"",
        1,
    );
    assert!(table.contains("\"dynamic\""), "{table}");
    let text = example_on_can(&table);
    let cfg = Config::parse(&text, "the page's mapping").expect("the mapping is valid");
    let chain = Chain::start_opts(&text, ChainOptions::default()).await;
    tap.to_bridge(chain.autopilot_port);

    // ArduPlane's node 10 answers the stages; the last answer carries all 16 bytes and the id.
    let asked = Instant::now();
    let (id, allocator) = loop {
        let done = listener
            .allocations()
            .into_iter()
            .find(|(_, _, a)| a.unique_id.len() == 16 && a.node_id != 0);
        if let Some((at, source, a)) = done {
            eprintln!(
                "node id {} from node {source} after {:?}",
                a.node_id,
                at - asked
            );
            break (a.node_id, source);
        }
        if asked.elapsed() > SECS(30) {
            let heard = listener.allocations();
            let last: Vec<_> = heard.iter().rev().take(3).map(|(_, s, a)| (s, a)).collect();
            panic!(
                "no node id allocated in 30 s; {} answers heard, the last: {last:?}",
                heard.len()
            );
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    };
    assert_eq!(allocator, 10, "ArduPlane's node allocates");
    let named = CanListener::start(id, &[ACTUATOR_STATUS, NODE_STATUS]);
    tokio::time::sleep(SECS(3)).await;
    let node_status = named.node_transfers_since(NODE_STATUS.id, asked).len();
    assert!(
        node_status >= 2,
        "{node_status} NodeStatus from node {id} in 3 s"
    );
    for s in &cfg.servos {
        let n = named
            .node_transfers_since(ACTUATOR_STATUS.id, asked)
            .iter()
            .filter(|(_, p)| {
                decode_actuator_status(p).is_some_and(|a| a.actuator_id == s.dronecan_id)
            })
            .count();
        assert!(
            n >= 15,
            "{}: {n} actuator Status from node {id} in 3 s",
            s.name
        );
    }
    drop(ap);
    chain.stop().await;
}

#[test]
#[ignore = "needs ArduPlane SITL, root for a network namespace: run by .ci/autopilots"]
fn arduplane_drives_the_servos_over_dronecan() {
    in_can_namespace(arduplane_over_dronecan());
}

async fn arduplane_over_dronecan() {
    let _log = bridge_log();
    let dir = fresh_dir("arduplane-can");
    let table = block_after(DRONECAN_PAGE, "<!-- sitl: the bridge's DroneCAN table -->");
    let node_id = Config::parse(
        &format!("[mavlink]\nconnection = \"udpin:0.0.0.0:1\"\n[[bus]]\nname = \"b\"\nport = \"p\"\n[[servo]]\nname = \"s\"\nbus = \"b\"\nid = 1\nchannel = 1\n{table}"),
        "the page's table",
    )
    .expect("the page's [dronecan] table is valid")
    .dronecan
    .unwrap()
    .node_id
    .fixed()
    .expect("the page's node id is static");
    let listener = CanListener::start(node_id, &[ACTUATOR_STATUS, NODE_STATUS]);
    let tap = Tap::start(14560);
    let temperatures = block_after(
        DRONECAN_PAGE,
        "<!-- sitl: ArduPlane's servo temperatures -->",
    );
    let (ap, _) = arduplane_on_can(&dir, &temperatures, 14560);
    tap.wait_for_autopilot(SECS(60), || ap.console());

    // The shipped example (its four surfaces on outputs 1, 2, 4 and 5, the page's
    // CAN_D1_UC_SRV_BM), commanded over DroneCAN.
    // SITL's DroneCAN thread leaves gaps of 400-600 ms between ArrayCommands at times (see
    // docs/dronecan.md): a longer failsafe timeout, so that the sweep is not cut by the failsafe
    // (which the kill below checks).
    let text = example_on_can(&table).replacen(
        "failsafe_timeout_ms = 500",
        "failsafe_timeout_ms = 1000",
        1,
    );
    let cfg = Config::parse(&text, "the page's mapping").expect("the page's mapping is valid");
    let chain = Chain::start_opts(&text, ChainOptions::default()).await;
    tap.to_bridge(chain.autopilot_port);
    let mut gcs = GroundStation::connect("tcp:127.0.0.1:5760");
    arduplane_manual(&mut gcs);

    // 100 Hz, PWM: the surfaces follow the sticks through ArrayCommand.
    let sweep = |gcs: &mut GroundStation| {
        let events = chain.sims[0].handle().subscribe();
        let from = Instant::now();
        (events, from, gcs.mark())
    };
    let (events, from, _) = sweep(&mut gcs);
    sweep_sticks(&mut gcs, 3.0).await;
    let window = from.elapsed();
    let (packets, heard) = (long_packets(&events), listener.commands_since(from));
    let (n, can_hz, bus_hz) = goals_follow_can(&cfg, &packets, &heard, window);
    let judged = each_command_followed(&cfg, &packets, &heard);
    eprintln!(
        "100 Hz asked: {n} long packets; ArrayCommand {can_hz:.1}/s, long packets {bus_hz:.1}/s; {judged} lone ArrayCommands each followed within 20 ms"
    );

    // The bridge's node as ArduPlane hears it: each servo's Status, its NodeStatus at 1 Hz.
    let statuses = listener.node_transfers_since(ACTUATOR_STATUS.id, from);
    for s in &cfg.servos {
        let n = statuses
            .iter()
            .filter(|(_, p)| {
                decode_actuator_status(p).is_some_and(|a| a.actuator_id == s.dronecan_id)
            })
            .count();
        assert!(
            n as f64 >= 0.7 * 10.0 * window.as_secs_f64(),
            "{}: {n} actuator Status in {window:?}",
            s.name
        );
    }
    let node_status = listener.node_transfers_since(NODE_STATUS.id, from).len();
    assert!(
        (2..=5).contains(&node_status),
        "{node_status} NodeStatus in {window:?}"
    );

    // ArduPlane's log has each servo's CSRV rows, at the position the bridge reads.
    tokio::time::sleep(SECS(2)).await;
    let view = chain.view.borrow().clone();
    let rows = csrv_rows(&dir);
    for s in &cfg.servos {
        let mine: Vec<&(u64, u8, f64)> = rows.iter().filter(|r| r.1 == s.dronecan_id).collect();
        assert!(
            mine.len() >= 10,
            "{}: {} CSRV rows of Id {}",
            s.name,
            mine.len(),
            s.dronecan_id
        );
        let logged_mm = mine.last().unwrap().2.to_radians() * 1000.0;
        let read_mm = view
            .servos
            .iter()
            .find(|v| v.name == s.name)
            .and_then(|v| v.report.position_mm)
            .expect("a position read");
        assert!(
            (logged_mm - f64::from(read_mm)).abs() < 0.2,
            "{}: CSRV {logged_mm:.2} mm, the bridge reads {read_mm:.2} mm",
            s.name
        );
    }

    // ArduPlane killed: the failsafe, as on MAVLink.
    ap.kill();
    chain
        .wait_view("the failsafe after ArduPlane's death", SECS(3), |v| {
            v.failsafe
        })
        .await;

    // Started again at 200 Hz with UNITLESS commands (the page's parameters without bit 4):
    // followed again.
    drop(gcs);
    let (ap, _) = arduplane_on_can(
        &dir,
        &format!("CAN_D1_UC_SRV_RT 200\nCAN_D1_UC_OPTION 0\nSCHED_LOOP_RATE 200\n{temperatures}"),
        14560,
    );
    tap.wait_for_autopilot(SECS(60), || ap.console());
    chain
        .wait_view("the failsafe over after the restart", SECS(30), |v| {
            !v.failsafe
        })
        .await;
    let mut gcs = GroundStation::connect("tcp:127.0.0.1:5760");
    arduplane_manual(&mut gcs);
    let (events, from, _) = sweep(&mut gcs);
    sweep_sticks(&mut gcs, 3.0).await;
    let window = from.elapsed();
    let (packets, heard) = (long_packets(&events), listener.commands_since(from));
    let (n, can_hz, bus_hz) = goals_follow_can(&cfg, &packets, &heard, window);
    let judged = each_command_followed(&cfg, &packets, &heard);
    eprintln!(
        "200 Hz asked: {n} long packets; ArrayCommand {can_hz:.1}/s, long packets {bus_hz:.1}/s; {judged} lone ArrayCommands each followed within 20 ms"
    );

    // A servo unwell (the rudder over its temperature alarm): the node's health says so, and
    // ArduPlane refuses to arm, naming the node.
    assert!(chain.sims[0].handle().overheat(4));
    let refusal = refused_for(&mut gcs, &format!("Node {node_id} unhealthy"), SECS(20));
    eprintln!("arming refused: {refusal}");
    // The temperatures the bridge reads meanwhile, per servo (lowest, highest): the rudder's
    // still rises.
    let mut seen: std::collections::HashMap<String, (f32, f32)> = Default::default();
    let sampling = Instant::now();
    while sampling.elapsed() < SECS(3) {
        for v in &chain.view.borrow().servos {
            if let Some(t) = v.report.temperature_c {
                let e = seen.entry(v.name.clone()).or_insert((t, t));
                *e = (e.0.min(t), e.1.max(t));
            }
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    // ArduPlane's TEMP rows, one temperature sensor per servo the page names, each at a
    // temperature the bridge read of its servo in those 3 s (the rudder's over its alarm, the
    // aileron's not: a sensor listening for the wrong id would log the other's).
    let sensors: Vec<(u8, u8)> = temperatures
        .lines()
        .filter_map(|l| {
            let (k, v) = l.split_once(' ')?;
            let n: u8 = k
                .strip_prefix("TEMP")?
                .strip_suffix("_MSG_ID")?
                .parse()
                .ok()?;
            Some((n - 1, v.trim().parse().ok()?))
        })
        .collect();
    assert_eq!(sensors.len(), 2, "{temperatures}");
    let temps = log_rows(&dir, "TEMP", "Instance", "Temp");
    let mut reads = Vec::new();
    for (instance, id) in sensors {
        let s = cfg.servos.iter().find(|s| s.dronecan_id == id).unwrap();
        let mine: Vec<f64> = temps
            .iter()
            .filter(|r| r.1 == instance)
            .map(|r| r.2)
            .collect();
        assert!(
            mine.len() >= 3,
            "{}: {} TEMP rows of Instance {instance}",
            s.name,
            mine.len()
        );
        let (low, high) = *seen.get(&s.name).expect("a temperature read");
        reads.push(high);
        let logged = *mine.last().unwrap();
        assert!(
            f64::from(low) - 0.5 <= logged && logged <= f64::from(high) + 0.5,
            "{}: TEMP {logged:.2} °C, the bridge read {low:.2}–{high:.2} °C",
            s.name
        );
    }
    assert!(
        (reads[0] - reads[1]).abs() > 5.0,
        "the two servos' temperatures tell them apart: {reads:?}"
    );

    drop(ap);
}

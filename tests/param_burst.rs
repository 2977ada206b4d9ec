//! A burst of PARAM_SETs from a ground station, through the binary (`lj9da-bridge run`) on a
//! UDP socket, as a ground station's script or a slider dragged across a parameter's range
//! sends them: 1,000 values of one parameter in about a second, then a last one. The newest
//! value wins: it is the one applied, saved in the mapping file and answered last, and no
//! PARAM_VALUE carries an older value after it; what was coalesced is said within a second of
//! the first, once more when the burst is over, and in all at exit.

mod bus_support;
mod tempdir;

use bus_support::{sim_config, spawn_sim};
use mavlink::dialects::common::{
    HEARTBEAT_DATA, MavAutopilot, MavMessage, MavParamType, MavState, MavType, PARAM_SET_DATA,
};
use mavlink::{MAVLinkV2MessageRaw, MavHeader, MavlinkReader, Message};
use std::io::{BufRead, BufReader};
use std::net::UdpSocket;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};
use tempdir::TempDir;

const PARAM: &str = "S1_PWM_TRIM";
/// The burst's values cycle through these; the last one is none of them.
const BURST_VALUES: std::ops::Range<u32> = 1300..1500;
const LAST: f32 = 1537.0;

fn frame(message: &MavMessage, sequence: u8) -> Vec<u8> {
    let mut frame = MAVLinkV2MessageRaw::new();
    let header = MavHeader {
        system_id: 255,
        component_id: 190,
        sequence,
    };
    frame.serialize_message(header, message);
    frame.raw_bytes().to_vec()
}

fn param_set(value: f32) -> MavMessage {
    MavMessage::PARAM_SET(PARAM_SET_DATA {
        param_value: value,
        target_system: 1,
        target_component: 140,
        param_id: PARAM.into(),
        param_type: MavParamType::MAV_PARAM_TYPE_REAL32,
    })
}

#[test]
fn the_newest_value_of_a_burst_of_param_sets_is_applied_saved_and_answered_last() {
    let dir = TempDir::new("param-burst");
    let sim = spawn_sim(sim_config(&[1], 115_200));
    let port = {
        let udp = UdpSocket::bind("127.0.0.1:0").unwrap();
        udp.local_addr().unwrap().port()
    };
    let mapping = dir.path().join("bridge.toml");
    std::fs::write(
        &mapping,
        format!(
            r#"[mavlink]
connection = "udpin:127.0.0.1:{port}"
system_id = 1

[record]
enabled = false

[[bus]]
name = "wing"
port = "{}"

[[servo]]
name = "left"
bus = "wing"
id = 1
channel = 1
"#,
            sim.path().display(),
        ),
    )
    .unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_lj9da-bridge"))
        .args(["run", "--config"])
        .arg(&mapping)
        .env("RUST_LOG", "lj9da_bridge=warn")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("the bridge starts");
    // The bridge's log, line by line, with when each was read.
    let stderr = child.stderr.take().unwrap();
    let (log_tx, log) = std::sync::mpsc::channel::<(Instant, String)>();
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            eprintln!("{line}");
            let _ = log_tx.send((Instant::now(), line));
        }
    });

    let gcs = UdpSocket::bind("127.0.0.1:0").unwrap();
    gcs.connect(("127.0.0.1", port)).unwrap();
    gcs.set_read_timeout(Some(Duration::from_millis(20)))
        .unwrap();
    let heartbeat = MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        mavtype: MavType::MAV_TYPE_GCS,
        autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
        system_status: MavState::MAV_STATE_ACTIVE,
        ..HEARTBEAT_DATA::default()
    });
    // The PARAM_VALUEs of PARAM, in the order they came.
    let mut answers: Vec<f32> = Vec::new();
    let read = |answers: &mut Vec<f32>| {
        let mut buf = [0u8; 2048];
        while let Ok(n) = gcs.recv(&mut buf) {
            let mut reader = MavlinkReader::new(&buf[..n]);
            while let Ok(raw) = reader.read_any_raw_message::<MavMessage>() {
                let message = MavMessage::parse(raw.version(), raw.message_id(), raw.payload());
                if let Ok(MavMessage::PARAM_VALUE(v)) = message
                    && v.param_id.to_str().is_ok_and(|id| id == PARAM)
                {
                    answers.push(v.param_value);
                }
            }
        }
    };
    // Until the bridge answers (it is up).
    let deadline = Instant::now() + Duration::from_secs(20);
    while answers.is_empty() {
        assert!(Instant::now() < deadline, "no PARAM_VALUE within 20 s");
        // Refused until the bridge's socket is bound.
        let _ = gcs.send(&frame(&heartbeat, 0));
        let _ = gcs.send(&frame(&param_set(1520.0), 0));
        read(&mut answers);
    }
    answers.clear();
    let burst_began = Instant::now();
    // By the 250th, the ground station is over its budget (200 at once, 100 a second).
    let mut over_budget = burst_began;
    for (k, value) in BURST_VALUES.cycle().take(1000).enumerate() {
        gcs.send(&frame(&param_set(value as f32), k as u8)).unwrap();
        if k == 249 {
            over_budget = Instant::now();
        }
        if k % 50 == 49 && k < 999 {
            std::thread::sleep(Duration::from_millis(50));
        }
    }
    gcs.send(&frame(&param_set(LAST), 0)).unwrap();
    let burst_ended = Instant::now();
    // Answers for a while after: the last value, and none older after it.
    let until = Instant::now() + Duration::from_secs(4);
    while Instant::now() < until {
        read(&mut answers);
    }
    let _ = nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(child.id() as i32),
        nix::sys::signal::Signal::SIGTERM,
    );
    let status = child.wait().unwrap();
    std::thread::sleep(Duration::from_millis(200));
    let lines: Vec<(Instant, String)> = log.try_iter().collect();

    println!(
        "{} PARAM_VALUEs for {PARAM} in answer to 1001 PARAM_SETs in {:.2} s; the last {:?}",
        answers.len(),
        (burst_ended - burst_began).as_secs_f64(),
        answers.last()
    );
    let first_last = answers.iter().position(|v| *v == LAST);
    assert!(
        first_last.is_some(),
        "the last value was never answered: {answers:?}"
    );
    let after: Vec<f32> = answers[first_last.unwrap()..].to_vec();
    assert!(
        after.iter().all(|v| *v == LAST),
        "an older value answered after the newest: {after:?}"
    );
    let saved = std::fs::read_to_string(&mapping).unwrap();
    assert!(
        saved.contains("pwm_trim_us = 1537"),
        "the mapping file keeps another value:\n{saved}"
    );
    assert!(status.success(), "the bridge exited with {status}");
    // Said within a second of the burst's start, when the burst is over, and at exit.
    let said: Vec<&(Instant, String)> = lines
        .iter()
        .filter(|(_, l)| l.contains("coalesced"))
        .collect();
    assert!(
        said.first()
            .is_some_and(|(at, _)| *at <= over_budget + Duration::from_secs(1)),
        "nothing said of the coalesced PARAM_SETs within a second of the 250th: {lines:#?}"
    );
    assert!(
        said.iter().any(|(_, l)| l.contains("now within it")),
        "no closing line: {said:#?}"
    );
    assert!(
        said.iter().any(|(_, l)| l.contains("since the start,")),
        "nothing said at exit: {said:#?}"
    );
}

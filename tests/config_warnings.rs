//! `lj9da-bridge check` warns about mappings that are valid but will not do what their author
//! expects with a given autopilot or ground station.

use lj9da_bridge::config::Config;
use std::process::Command;

fn mapping(source: &str, channel: u8) -> String {
    format!(
        r#"
[mavlink]
connection = "udpin:127.0.0.1:14540"
source = "{source}"

[[bus]]
name = "wing"
port = "/dev/null"

[[servo]]
name = "flap_left"
bus = "wing"
id = 1
channel = {channel}
"#
    )
}

#[test]
fn channels_17_to_32_from_servo_output_raw_warn_that_px4_needs_actuator_output_status() {
    let cfg = Config::parse(&mapping("SERVO_OUTPUT_RAW", 17), "t.toml").unwrap();
    let warnings = cfg.warnings();
    assert_eq!(warnings.len(), 1, "{warnings:?}");
    assert!(
        warnings[0].contains("flap_left (channel 17)"),
        "{warnings:?}"
    );
    assert!(
        warnings[0].contains("ACTUATOR_OUTPUT_STATUS"),
        "{warnings:?}"
    );
    assert!(warnings[0].contains("PX4"), "{warnings:?}");
}

#[test]
fn channels_1_to_16_or_actuator_output_status_need_no_warning() {
    for (source, channel) in [("SERVO_OUTPUT_RAW", 16), ("ACTUATOR_OUTPUT_STATUS", 17)] {
        let cfg = Config::parse(&mapping(source, channel), "t.toml").unwrap();
        assert!(cfg.warnings().is_empty(), "{source} ch {channel}");
    }
}

#[test]
fn check_prints_the_warnings_after_the_table() {
    let dir = std::env::temp_dir().join(format!("lj9da-check-warn-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("high.toml");
    std::fs::write(&path, mapping("SERVO_OUTPUT_RAW", 20)).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_lj9da-bridge"))
        .args(["check", "--config"])
        .arg(&path)
        .output()
        .expect("lj9da-bridge runs");
    let _ = std::fs::remove_dir_all(&dir);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}");
    assert!(
        stdout.contains("warning: flap_left (channel 20)"),
        "{stdout}"
    );
}

fn servos(n: usize, telemetry: &str) -> String {
    let mut text = format!(
        "[mavlink]\nconnection = \"udpin:127.0.0.1:14560\"\n[telemetry]\n{telemetry}\n[[bus]]\nname = \"wing\"\nport = \"/dev/null\"\n"
    );
    for i in 1..=n {
        text.push_str(&format!(
            "[[servo]]\nname = \"s{i}\"\nbus = \"wing\"\nid = {i}\nchannel = {i}\n"
        ));
    }
    text
}

#[test]
fn more_than_20_named_values_warn_that_mission_planner_shows_20() {
    let cfg = Config::parse(&servos(6, ""), "t.toml").unwrap();
    let warnings = cfg.warnings();
    assert_eq!(warnings.len(), 1, "{warnings:?}");
    assert!(
        warnings[0].contains("24 NAMED_VALUE_FLOAT names"),
        "{warnings:?}"
    );
    assert!(warnings[0].contains("Mission Planner"), "{warnings:?}");
    assert!(warnings[0].contains("at most 3 per servo"), "{warnings:?}");
    // Five servos × four, or six servos × three, fit.
    assert!(
        Config::parse(&servos(5, ""), "t.toml")
            .unwrap()
            .warnings()
            .is_empty()
    );
    let three = "named_values = [\"pos\", \"cur\", \"tmp\"]";
    assert!(
        Config::parse(&servos(6, three), "t.toml")
            .unwrap()
            .warnings()
            .is_empty()
    );
    let off = "named_value_float = false";
    assert!(
        Config::parse(&servos(6, off), "t.toml")
            .unwrap()
            .warnings()
            .is_empty()
    );
}

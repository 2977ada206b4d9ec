//! `lj9da-bridge check` warns about mappings that are valid but will not do what their author
//! expects with a given autopilot or ground station.

use lj9da_bridge::config::{Config, Quantity};
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
fn channels_17_to_32_warn_that_px4_streams_only_its_first_driver() {
    for source in ["SERVO_OUTPUT_RAW", "ACTUATOR_OUTPUT_STATUS"] {
        let cfg = Config::parse(&mapping(source, 17), "t.toml").unwrap();
        let warnings = cfg.warnings();
        assert_eq!(warnings.len(), 1, "{source}: {warnings:?}");
        let w = &warnings[0];
        assert!(w.contains("flap_left (channel 17)"), "{w}");
        assert!(w.contains("PX4 streams its first output driver's"), "{w}");
        assert!(w.contains("channels 1–16"), "{w}");
        // Switching the source does not bring channels 17–32 from PX4: not advised.
        assert!(!w.contains("set [mavlink] source"), "{w}");
    }
}

#[test]
fn channels_1_to_16_need_no_warning() {
    for source in ["SERVO_OUTPUT_RAW", "ACTUATOR_OUTPUT_STATUS"] {
        let cfg = Config::parse(&mapping(source, 16), "t.toml").unwrap();
        assert!(cfg.warnings().is_empty(), "{source} ch 16");
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
        warnings[0].contains("6 servos send 24 NAMED_VALUE_FLOAT names"),
        "{warnings:?}"
    );
    assert!(warnings[0].contains("Mission Planner"), "{warnings:?}");
    assert!(warnings[0].contains("at most 3 per servo"), "{warnings:?}");
    assert!(
        warnings[0].contains("ESC_INFO"),
        "points at what shows every servo: {warnings:?}"
    );
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

/// With more than 20 servos not one name each fits: the advice is a per-servo list for the
/// servos that matter, none for the others, and that advice, taken, leaves no warning.
#[test]
fn more_than_20_servos_are_advised_a_per_servo_choice_that_fits() {
    let named = |cfg: &Config| -> Vec<String> {
        let w = cfg.warnings();
        w.into_iter()
            .filter(|w| w.contains("NAMED_VALUE_FLOAT"))
            .collect()
    };
    let cfg = Config::parse(&servos(32, ""), "t.toml").unwrap();
    let warnings = named(&cfg);
    assert_eq!(warnings.len(), 1, "{warnings:?}");
    let w = &warnings[0];
    assert!(
        w.contains("32 servos send 128 NAMED_VALUE_FLOAT names"),
        "{w}"
    );
    assert!(!w.contains("at most 0"), "{w}");
    assert!(w.contains("named_values = []"), "{w}");
    assert!(w.contains("in their [[servo]] table"), "{w}");
    // Taken: none by default, position for the first 20.
    let mut taken = servos(32, "named_values = []");
    for i in 1..=20 {
        taken = taken.replacen(
            &format!("name = \"s{i}\"\n"),
            &format!("name = \"s{i}\"\nnamed_values = [\"pos\"]\n"),
            1,
        );
    }
    let cfg = Config::parse(&taken, "t.toml").unwrap();
    assert!(named(&cfg).is_empty(), "{:?}", named(&cfg));
    assert_eq!(
        cfg.servos[0].named_values(&cfg.telemetry),
        [Quantity::Position]
    );
    assert!(cfg.servos[20].named_values(&cfg.telemetry).is_empty());
    // One more servo with a name is over again.
    let over = taken.replacen(
        "name = \"s21\"\n",
        "name = \"s21\"\nnamed_values = [\"tmp\"]\n",
        1,
    );
    assert_eq!(named(&Config::parse(&over, "t.toml").unwrap()).len(), 1);
    // A bad quantity in a servo's list is refused, naming it.
    let bad = servos(2, "").replacen(
        "name = \"s1\"\n",
        "name = \"s1\"\nnamed_values = [\"rpm\"]\n",
        1,
    );
    let e = Config::parse(&bad, "t.toml").unwrap_err().to_string();
    assert!(e.contains("\"rpm\" is not a quantity"), "{e}");
}

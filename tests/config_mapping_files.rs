//! Every mapping file shipped in `mappings/` is valid, and `check` shows what it resolves to.

use lj9da_bridge::config::{
    Config, FailsafeAction, ForceAction, PwmRange, SITL_DEFAULT_TOML, Source,
};
use lj9da_bridge::protocol::{BaudRate, MmCenti, ServoId};
use std::path::{Path, PathBuf};

fn mappings_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("mappings")
}

fn mapping_files() -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(mappings_dir())
        .expect("mappings/ exists")
        .map(|entry| entry.expect("readable directory entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    files.sort();
    files
}

fn load(name: &str) -> Config {
    let path = mappings_dir().join(name);
    Config::load(&path).unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn every_mapping_file_parses_and_validates() {
    let files = mapping_files();
    assert!(
        files.len() >= 3,
        "expected at least 3 mapping files, found {files:?}"
    );
    for path in files {
        let config = Config::load(&path).unwrap_or_else(|e| panic!("{e}"));
        assert!(!config.servos.is_empty(), "{}", path.display());
        let table = config.resolved_table();
        for servo in &config.servos {
            assert!(table.contains(&servo.name), "{}: {table}", path.display());
        }
        println!(
            "$ lj9da-bridge check --config mappings/{}",
            path.file_name().unwrap().to_string_lossy()
        );
        println!("{table}");
    }
}

#[test]
fn every_mapping_file_is_commented_for_a_new_user() {
    for path in mapping_files() {
        let text = std::fs::read_to_string(&path).unwrap();
        let comments = text
            .lines()
            .filter(|l| l.trim_start().starts_with('#'))
            .count();
        assert!(
            comments >= 5,
            "{} has only {comments} comment lines",
            path.display()
        );
        assert!(
            text.contains("lj9da-bridge check --config"),
            "{} does not say how to check it",
            path.display()
        );
    }
}

#[test]
fn the_built_in_airframe_is_the_file_in_mappings() {
    let on_disk = std::fs::read_to_string(mappings_dir().join("sitl-default.toml")).unwrap();
    assert_eq!(on_disk, SITL_DEFAULT_TOML);
    assert_eq!(Config::default_sitl(), load("sitl-default.toml"));
}

#[test]
fn the_ardupilot_plane_has_four_servos_on_one_bus() {
    let c = load("ardupilot-plane.toml");
    assert_eq!(c.mavlink.connection, "udpin:0.0.0.0:14560");
    assert_eq!(c.mavlink.source, Source::ServoOutputRaw);
    // 0.8 × SCHED_LOOP_RATE 50 Hz: the most stock Plane grants.
    assert_eq!(c.mavlink.output_rate_hz, 40.0);
    assert_eq!(c.mavlink.component_id, 140);
    // SYSID_THISMAV's default: back on the autopilot's first output after a restart.
    assert_eq!(c.mavlink.system_id, Some(1));
    assert_eq!(c.bridge.on_exit, ForceAction::Hold);
    assert_eq!(c.buses.len(), 1);
    assert_eq!(c.buses[0].baud, BaudRate::B115200);
    let by_name = |n: &str| c.servos.iter().find(|s| s.name == n).unwrap();
    assert_eq!(c.servos.len(), 4);
    let left = by_name("aileron_left");
    let right = by_name("aileron_right");
    assert_eq!((left.channel, right.channel), (1, 5));
    assert!(!left.reverse && right.reverse);
    assert_eq!(left.map_pwm(1544), Some(MmCenti(100)));
    assert_eq!(right.map_pwm(1544), Some(MmCenti(-100)));
    assert_eq!(left.map_pwm(2120), Some(MmCenti(2000)), "clamped to ±20 mm");
    assert_eq!(left.failsafe, FailsafeAction::Position(MmCenti(0)));
    assert_eq!(by_name("elevator").channel, 2);
    let rudder = by_name("rudder");
    assert_eq!(rudder.channel, 4);
    assert_eq!(rudder.label, "rudder");
    assert_eq!(
        rudder.pwm,
        PwmRange {
            min_us: 1100,
            trim_us: 1500,
            max_us: 1900
        }
    );
    assert_eq!(
        rudder.map_pwm(1900),
        Some(MmCenti(1500)),
        "clamped to ±15 mm"
    );
    assert_eq!(rudder.goal_time_ms, Some(50));
}

#[test]
fn the_px4_example_listens_on_the_onboard_link() {
    let c = load("px4-vtol.toml");
    assert_eq!(c.mavlink.connection, "udpin:0.0.0.0:14540");
    assert_eq!(c.mavlink.system_id, Some(1), "MAV_SYS_ID's default");
    assert_eq!(c.buses[0].baud, BaudRate::B460800);
    // PX4's disarmed 900 µs holds every servo.
    for s in &c.servos {
        assert_eq!(s.map_pwm(900), None, "{}", s.name);
    }
    let door = c.servos.iter().find(|s| s.name == "gear_door").unwrap();
    assert_eq!(door.actuator, Some(1));
    assert_eq!(door.id, ServoId::new(5).unwrap());
    assert_eq!(
        door.map_pwm(1000),
        Some(MmCenti(0)),
        "the door's travel starts at 0"
    );
    assert_eq!(door.map_pwm(2000), Some(MmCenti(2500)));
    assert_eq!(door.map_normalized(1.0), Some(MmCenti(2500)));
    assert_eq!(door.failsafe, FailsafeAction::Brake);
}

#[test]
fn check_prints_the_connection_buses_and_each_servo_resolved() {
    let table = load("ardupilot-plane.toml").resolved_table();
    let lines: Vec<&str> = table.lines().collect();
    assert!(
        lines[0].starts_with("mavlink: udpin:0.0.0.0:14560"),
        "{table}"
    );
    assert!(lines[0].contains("bridge component 140"), "{table}");
    assert!(
        table.contains("SERVO_OUTPUT_RAW requested at 40 Hz"),
        "{table}"
    );
    let bus = lines
        .iter()
        .find(|l| l.starts_with("wing "))
        .expect("a bus row");
    assert!(
        bus.contains("/dev/serial/by-id/usb-FTDI_") && bus.contains("115200 bit/s"),
        "{bus}"
    );
    let row = |name: &str| {
        *lines
            .iter()
            .find(|l| l.starts_with(&format!("{name} ")))
            .unwrap_or_else(|| panic!("no row for {name} in\n{table}"))
    };
    let left = row("aileron_left");
    assert!(left.contains("920→-20.00 1520→+0.00 2120→+20.00"), "{left}");
    assert!(left.contains("-20.00..+20.00"), "{left}");
    let right = row("aileron_right");
    assert!(
        right.contains("920→+20.00 1520→+0.00 2120→-20.00"),
        "{right}"
    );
    assert!(right.contains(" yes "), "{right}");
    let elevator = row("elevator");
    assert!(
        elevator.contains("920→-25.00 1520→+0.00 2120→+25.00"),
        "{elevator}"
    );
    assert!(elevator.contains("80 %"), "{elevator}");
    let rudder = row("rudder");
    assert!(
        rudder.contains("1100→-15.00 1500→+0.00 1900→+15.00"),
        "{rudder}"
    );
    assert!(rudder.contains("50 ms"), "{rudder}");
    // Columns line up: every servo row has its pwm column at the same place.
    let header = lines.iter().find(|l| l.starts_with("servo ")).unwrap();
    let column = header.find("µs → mm").unwrap();
    for name in ["aileron_left", "aileron_right", "elevator", "rudder"] {
        let r = row(name);
        let chars_before = header[..column].chars().count();
        let at: String = r.chars().skip(chars_before).take(3).collect();
        assert!(at.chars().all(|c| c.is_ascii_digit()), "{name}: {r}");
    }
}

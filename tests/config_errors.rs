//! A bad mapping file is refused with the file, the line of the offending key, the key and the
//! reason; an impossible one too. No input, however garbled, makes the reader panic.

use lj9da_bridge::config::{Config, ConfigError};
use proptest::prelude::*;

const ORIGIN: &str = "mappings/bad.toml";

/// A valid file; each test breaks one thing in it.
const GOOD: &str = r#"[mavlink]
connection = "udpin:0.0.0.0:14560"

[[bus]]
name = "wing"
port = "/dev/ttyUSB0"
baud = 115200

[[servo]]
name = "aileron_left"
bus = "wing"
id = 1
channel = 1

[[servo]]
name = "aileron_right"
bus = "wing"
id = 2
channel = 5
"#;

/// `GOOD` with the first occurrence of `from` replaced by `to`.
fn with(from: &str, to: &str) -> String {
    assert!(GOOD.contains(from), "{from:?} is not in the good file");
    GOOD.replacen(from, to, 1)
}

/// `GOOD` with `extra` appended to the first servo (inserted after its `channel = 1`).
fn first_servo_with(extra: &str) -> String {
    with("channel = 1\n", &format!("channel = 1\n{extra}\n"))
}

/// The line (from 1) of the first line of `text` that contains `needle`.
fn line_of(text: &str, needle: &str) -> usize {
    text.lines()
        .position(|l| l.contains(needle))
        .unwrap_or_else(|| panic!("{needle:?} not in the file"))
        + 1
}

/// Parse `text`, expect a refusal on the line holding `needle`, about `key`, whose reason
/// contains `reason`; return the error for further checks.
#[track_caller]
fn refused(text: &str, needle: &str, key: &str, reason: &str) -> ConfigError {
    let line = line_of(text, needle);
    let e = Config::parse(text, ORIGIN).expect_err("the file must be refused");
    let message = e.to_string();
    assert!(
        message.starts_with(&format!("{ORIGIN}:{line}:")),
        "expected {ORIGIN}:{line}: in {message}"
    );
    assert_eq!(e.line(), Some(line), "{message}");
    assert_eq!(e.key(), Some(key), "{message}");
    assert!(
        message.contains(&format!("key \"{key}\"")),
        "key {key} not named in {message}"
    );
    assert!(
        message.contains(reason),
        "reason {reason:?} not in {message}"
    );
    e
}

#[test]
fn the_good_file_is_accepted() {
    let c = Config::parse(GOOD, ORIGIN).unwrap();
    assert_eq!(c.servos.len(), 2);
}

#[test]
fn an_id_outside_1_to_127_is_refused() {
    let text = with("id = 1\n", "id = 200\n");
    let e = refused(&text, "id = 200", "id", "200 is outside 1–127");
    assert_eq!(e.scope(), Some("servo \"aileron_left\""));
    assert!(
        e.to_string()
            .contains("servo \"aileron_left\": key \"id\": 200 is outside 1–127"),
        "{e}"
    );
    // Column 6: the value after `id = `.
    assert_eq!(e.column(), Some(6));
    refused(
        &with("id = 1\n", "id = 0\n"),
        "id = 0",
        "id",
        "outside 1–127",
    );
    refused(
        &with("id = 1\n", "id = -3\n"),
        "id = -3",
        "id",
        "outside 1–127",
    );
}

#[test]
fn two_servos_with_one_id_on_a_bus_are_refused() {
    let text = with("id = 2\n", "id = 1   # same as the left aileron\n");
    let e = refused(
        &text,
        "id = 1   # same",
        "id",
        "id 1 is already used on bus \"wing\" by servo \"aileron_left\" (line 9)",
    );
    assert_eq!(e.scope(), Some("servo \"aileron_right\""));
}

#[test]
fn one_id_on_two_buses_is_fine() {
    let text = with(
        "[[servo]]\nname = \"aileron_right\"\nbus = \"wing\"\nid = 2",
        "[[bus]]\nname = \"tail\"\nport = \"/dev/ttyUSB1\"\n\n[[servo]]\nname = \"aileron_right\"\nbus = \"tail\"\nid = 1",
    );
    let c = Config::parse(&text, ORIGIN).unwrap();
    assert_eq!(c.servos_on("tail").count(), 1);
}

#[test]
fn two_servos_with_one_name_are_refused() {
    let text = with(
        "name = \"aileron_right\"",
        "name = \"aileron_left\"  # again",
    );
    refused(&text, "# again", "name", "already defined on line 9");
}

#[test]
fn a_servo_on_a_bus_that_does_not_exist_is_refused() {
    let text = with("bus = \"wing\"\nid = 2", "bus = \"tail\"\nid = 2");
    refused(
        &text,
        "bus = \"tail\"",
        "bus",
        "no [[bus]] is called \"tail\"; the buses are \"wing\"",
    );
}

#[test]
fn two_buses_on_one_port_are_refused() {
    let text = with(
        "\n[[servo]]\nname = \"aileron_left\"",
        "\n[[bus]]\nname = \"tail\"\nport = \"/dev/ttyUSB0\"   # the wing's port\n\n[[servo]]\nname = \"aileron_left\"",
    );
    let e = refused(
        &text,
        "# the wing's port",
        "port",
        "/dev/ttyUSB0 is already the port of bus \"wing\" (line 4)",
    );
    assert_eq!(e.scope(), Some("bus \"tail\""));
}

#[test]
fn a_bus_on_the_mavlink_links_serial_port_is_refused() {
    let text = with(
        "connection = \"udpin:0.0.0.0:14560\"",
        "connection = \"serial:/dev/ttyUSB0:921600\"",
    );
    let e = refused(
        &text,
        "port = \"/dev/ttyUSB0\"",
        "port",
        "/dev/ttyUSB0 is already the MAVLink link's port ([mavlink] connection)",
    );
    assert_eq!(e.scope(), Some("bus \"wing\""));
    let gcs = with(
        "connection = \"udpin:0.0.0.0:14560\"",
        "connection = \"udpin:0.0.0.0:14560\"\ngcs = \"serial:/dev/ttyUSB0:57600\"",
    );
    refused(
        &gcs,
        "port = \"/dev/ttyUSB0\"",
        "port",
        "already the MAVLink link's port ([mavlink] gcs)",
    );
}

/// `/dev/serial0` is a link to the UART itself on a Raspberry Pi: names that differ can still
/// be one device, which `check` and `run` find by following them.
#[test]
fn a_bus_and_the_mavlink_link_on_one_device_by_two_names_are_refused_by_check() {
    let dir = std::env::temp_dir().join(format!("lj9da-shared-device-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let uart = dir.join("ttyAMA0");
    std::fs::write(&uart, "").unwrap();
    let serial0 = dir.join("serial0");
    std::os::unix::fs::symlink(&uart, &serial0).unwrap();
    let text = GOOD
        .replace(
            "connection = \"udpin:0.0.0.0:14560\"",
            &format!("connection = \"serial:{}:921600\"", serial0.display()),
        )
        .replace("/dev/ttyUSB0", &uart.display().to_string());
    let cfg = Config::parse(&text, ORIGIN).expect("two names: the reader cannot tell");
    let said = cfg
        .shared_device(|p| std::fs::canonicalize(p).ok())
        .expect("one device");
    assert!(said.contains("bus \"wing\""), "{said}");
    assert!(said.contains("[mavlink] connection"), "{said}");
    let mapping = dir.join("m.toml");
    std::fs::write(&mapping, &text).unwrap();
    for command in ["check", "run"] {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_lj9da-bridge"))
            .args([command, "--config"])
            .arg(&mapping)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{command}: {err}");
        assert!(err.contains("are one device"), "{command}: {err}");
    }
    // Distinct devices: nothing said.
    let other = dir.join("ttyUSB0");
    std::fs::write(&other, "").unwrap();
    let apart = text.replace(&uart.display().to_string(), &other.display().to_string());
    let apart = Config::parse(&apart, ORIGIN).unwrap();
    assert_eq!(apart.shared_device(|p| std::fs::canonicalize(p).ok()), None);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn two_buses_with_one_name_are_refused() {
    let text = with(
        "\n[[servo]]\nname = \"aileron_left\"",
        "\n[[bus]]\nname = \"wing\"  # again\nport = \"/dev/ttyUSB1\"\n\n[[servo]]\nname = \"aileron_left\"",
    );
    refused(&text, "# again", "name", "already defined on line 4");
}

#[test]
fn an_unknown_baud_rate_is_refused() {
    let text = with("baud = 115200", "baud = 100000");
    let e = refused(
        &text,
        "baud = 100000",
        "baud",
        "100000 bit/s is not a rate the LJ9DA41 supports",
    );
    assert!(
        e.to_string().contains("460800"),
        "the rates are listed: {e}"
    );
    refused(
        &with("baud = 115200", "baud = -9600"),
        "baud = -9600",
        "baud",
        "not a rate",
    );
}

#[test]
fn travel_beyond_the_stroke_is_refused() {
    let text = first_servo_with("travel_mm = [-26.0, 20.0]");
    refused(
        &text,
        "travel_mm",
        "travel_mm",
        "-26 mm is beyond the stroke (−25.00 … +25.00 mm)",
    );
    let text = first_servo_with("max_mm = 25.5");
    refused(&text, "max_mm", "max_mm", "25.5 mm is beyond the stroke");
}

#[test]
fn travel_with_min_not_below_max_is_refused() {
    let text = first_servo_with("travel_mm = [10.0, -10.0]");
    refused(
        &text,
        "travel_mm",
        "travel_mm",
        "minimum +10.00 mm must be below its maximum -10.00 mm",
    );
    let text = first_servo_with("min_mm = 0.0\nmax_mm = 0.0");
    refused(&text, "max_mm", "max_mm", "must be below its maximum");
}

#[test]
fn travel_that_leaves_out_the_centre_is_refused() {
    let text = first_servo_with("min_mm = 5.0\nmax_mm = 20.0");
    refused(&text, "min_mm", "min_mm", "must include 0.00 mm");
}

#[test]
fn travel_given_twice_is_refused() {
    let text = first_servo_with("travel_mm = [-10.0, 10.0]\nmin_mm = -5.0");
    refused(&text, "min_mm", "min_mm", "already set by travel_mm");
}

#[test]
fn travel_needs_exactly_two_numbers() {
    let text = first_servo_with("travel_mm = [-10.0]");
    refused(
        &text,
        "travel_mm",
        "travel_mm",
        "expected two numbers [min, max]",
    );
}

#[test]
fn a_channel_outside_1_to_32_is_refused() {
    for bad in ["channel = 0", "channel = 33", "channel = 300"] {
        let text = with("channel = 1", bad);
        refused(&text, bad, "channel", "is outside 1–32");
    }
}

#[test]
fn a_pwm_range_out_of_order_is_refused() {
    let text = first_servo_with("pwm_trim_us = 900");
    refused(
        &text,
        "pwm_trim_us",
        "pwm_trim_us",
        "pwm_min_us 920 µs must be below pwm_trim_us 900 µs",
    );
    let text = first_servo_with("pwm_min_us = 1600");
    refused(
        &text,
        "pwm_min_us",
        "pwm_min_us",
        "must be below pwm_trim_us",
    );
    let text = first_servo_with("pwm_max_us = 1400");
    refused(
        &text,
        "pwm_max_us",
        "pwm_max_us",
        "pwm_trim_us 1520 µs must be below pwm_max_us 1400 µs",
    );
    let text = first_servo_with("pwm_min_us = 1100\npwm_trim_us = 1100\npwm_max_us = 1900");
    refused(&text, "pwm_trim_us", "pwm_trim_us", "(min < trim < max)");
}

#[test]
fn a_pwm_value_outside_500_to_2500_is_refused() {
    let text = first_servo_with("pwm_max_us = 2600");
    refused(
        &text,
        "pwm_max_us",
        "pwm_max_us",
        "2600 µs is outside 500–2500 µs",
    );
    let text = first_servo_with("pwm_min_us = 400");
    refused(
        &text,
        "pwm_min_us",
        "pwm_min_us",
        "400 µs is outside 500–2500 µs",
    );
}

#[test]
fn max_force_above_100_is_refused() {
    let text = first_servo_with("max_force_percent = 101");
    refused(
        &text,
        "max_force_percent",
        "max_force_percent",
        "101 % is outside 1–100 %",
    );
    let text = first_servo_with("max_force_percent = 0");
    refused(
        &text,
        "max_force_percent",
        "max_force_percent",
        "unable to move",
    );
}

#[test]
fn a_failsafe_position_beyond_the_travel_is_refused() {
    let text = first_servo_with("travel_mm = [-10.0, 10.0]\nfailsafe = 12.5");
    refused(
        &text,
        "failsafe",
        "failsafe",
        "position 12.5 mm is outside the servo's travel (-10.00 … +10.00 mm)",
    );
    let text = first_servo_with("failsafe = 30");
    refused(&text, "failsafe", "failsafe", "outside the servo's travel");
}

#[test]
fn an_unknown_failsafe_action_is_refused() {
    let text = first_servo_with("failsafe = \"park\"");
    refused(
        &text,
        "failsafe",
        "failsafe",
        "\"park\" is not a failsafe action; use \"hold\", \"off\", \"brake\" or a position in mm",
    );
    let text = first_servo_with("failsafe = true");
    refused(&text, "failsafe", "failsafe", "not a failsafe action");
}

#[test]
fn a_file_without_servos_is_refused() {
    let text = "[mavlink]\nconnection = \"udpin:0.0.0.0:14560\"\n\n[[bus]]\nname = \"wing\"\nport = \"/dev/ttyUSB0\"\n";
    let e = Config::parse(text, ORIGIN).unwrap_err();
    assert_eq!(e.key(), Some("servo"));
    assert!(
        e.to_string()
            .contains("the file has no [[servo]] table; a mapping needs at least one servo"),
        "{e}"
    );
    assert!(e.to_string().starts_with(ORIGIN), "{e}");
}

#[test]
fn a_file_without_a_mavlink_table_is_refused() {
    let text = GOOD.replacen("[mavlink]\nconnection = \"udpin:0.0.0.0:14560\"\n", "", 1);
    let e = Config::parse(&text, ORIGIN).unwrap_err();
    assert_eq!(e.key(), Some("mavlink"));
    assert!(e.to_string().contains("no [mavlink] table"), "{e}");
    let e = Config::parse("", ORIGIN).unwrap_err();
    assert!(e.to_string().contains("no [mavlink] table"), "{e}");
}

#[test]
fn an_unknown_key_is_refused_rather_than_defaulted() {
    let text = first_servo_with("reverze = true");
    let e = refused(&text, "reverze", "reverze", "unknown key (a typo?)");
    assert!(
        e.to_string().contains("`reverse`"),
        "the valid keys are listed: {e}"
    );
    assert_eq!(e.scope(), Some("servo \"aileron_left\""));

    let text = with("connection", "output_rate = 40\nconnection");
    let e = refused(&text, "output_rate = 40", "output_rate", "unknown key");
    assert_eq!(e.scope(), Some("[mavlink]"));

    let text = format!("{GOOD}\n[telemetry]\nrate = 5\n");
    refused(&text, "rate = 5", "rate", "unknown key");
}

#[test]
fn an_unknown_table_is_refused() {
    let text = format!("{GOOD}\n[mavlnk]\nsystem_id = 1\n");
    refused(&text, "[mavlnk]", "mavlnk", "unknown key");
}

#[test]
fn a_value_of_the_wrong_type_is_refused_with_its_key() {
    let text = with("id = 1\n", "id = \"one\"\n");
    let e = refused(&text, "id = \"one\"", "id", "invalid type: string \"one\"");
    assert_eq!(e.scope(), Some("servo \"aileron_left\""));
    let text = with("channel = 5", "channel = 5.5");
    let e = refused(
        &text,
        "channel = 5.5",
        "channel",
        "invalid type: floating point",
    );
    assert_eq!(e.scope(), Some("servo \"aileron_right\""));
    let text = first_servo_with("reverse = \"yes\"");
    refused(&text, "reverse = \"yes\"", "reverse", "invalid type");
}

#[test]
fn a_missing_required_key_is_refused_at_its_table() {
    let text = with("channel = 5\n", "");
    // The table's header: the line before the second servo's name.
    let header = line_of(&text, "name = \"aileron_right\"") - 1;
    let e = Config::parse(&text, ORIGIN).unwrap_err();
    assert_eq!(e.line(), Some(header), "{e}");
    assert_eq!(e.key(), Some("channel"), "{e}");
    assert_eq!(e.scope(), Some("servo \"aileron_right\""));
    assert!(
        e.to_string().starts_with(&format!(
            "{ORIGIN}:{header}:1: servo \"aileron_right\": key \"channel\": required key is missing"
        )),
        "{e}"
    );
}

#[test]
fn a_duplicate_key_is_refused() {
    let text = first_servo_with("id = 3");
    refused(&text, "id = 3", "id", "duplicate key");
}

#[test]
fn a_syntax_error_is_refused_with_its_line() {
    let text = with("name = \"aileron_right\"", "name = \"aileron_right");
    let line = line_of(&text, "name = \"aileron_right");
    let e = Config::parse(&text, ORIGIN).unwrap_err();
    assert_eq!(e.line(), Some(line), "{e}");
    assert!(
        e.to_string().starts_with(&format!("{ORIGIN}:{line}:")),
        "{e}"
    );
    let e = Config::parse("[[servo]\nname = 1\n", ORIGIN).unwrap_err();
    assert_eq!(e.line(), Some(1), "{e}");
}

#[test]
fn a_connection_of_an_unknown_type_is_refused() {
    let text = with("udpin:0.0.0.0:14560", "udp:0.0.0.0:14560");
    let e = refused(
        &text,
        "connection",
        "connection",
        "\"udp:\" is not a connection type; use udpin:, udpout:, udpbcast:, tcpin:, tcpout: or serial:",
    );
    assert_eq!(e.scope(), Some("[mavlink]"));
    let text = with("udpin:0.0.0.0:14560", "serial:/dev/ttyAMA0");
    refused(&text, "connection", "connection", "no baud rate");
}

#[test]
fn a_gcs_output_is_checked_like_the_connection() {
    let text = with("connection", "gcs = \"udpout:127.0.0.1\"\nconnection");
    refused(&text, "gcs", "gcs", "no port");
    let text = with("connection", "gcs = \"udpin:0.0.0.0:14560\"\nconnection");
    refused(&text, "gcs", "gcs", "same address as `connection`");
}

#[test]
fn mavlink_ids_and_rates_are_checked() {
    let text = with("connection", "system_id = 0\nconnection");
    refused(&text, "system_id", "system_id", "0 is outside 1–255");
    let text = with("connection", "component_id = 256\nconnection");
    refused(
        &text,
        "component_id",
        "component_id",
        "256 is outside 1–255",
    );
    let text = with("connection", "component_id = 1\nconnection");
    refused(
        &text,
        "component_id",
        "component_id",
        "the bridge and the autopilot would both be component 1",
    );
    let text = with("connection", "output_rate_hz = 0\nconnection");
    refused(
        &text,
        "output_rate_hz",
        "output_rate_hz",
        "0 Hz is outside (0, 500] Hz",
    );
    let text = with("connection", "failsafe_timeout_ms = 30\nconnection");
    refused(
        &text,
        "failsafe_timeout_ms",
        "failsafe_timeout_ms",
        "shorter than two output intervals at 50 Hz (40 ms)",
    );
    let text = with("connection", "source = \"RC_CHANNELS\"\nconnection");
    refused(&text, "source", "source", "\"RC_CHANNELS\" is not a source");
}

#[test]
fn telemetry_and_bridge_values_are_checked() {
    let text = format!("{GOOD}\n[telemetry]\nrate_hz = 100.0\n");
    let e = refused(&text, "rate_hz", "rate_hz", "100 Hz is outside (0, 50] Hz");
    assert_eq!(e.scope(), Some("[telemetry]"));
    let text = format!("{GOOD}\n[telemetry]\nnamed_values = [\"pos\", \"rpm\"]\n");
    refused(
        &text,
        "named_values",
        "named_values",
        "\"rpm\" is not a quantity",
    );
    let text = format!("{GOOD}\n[telemetry]\nesc_index_base = 256\n");
    refused(
        &text,
        "esc_index_base",
        "esc_index_base",
        "256 is outside 0–255",
    );
    let text = format!("{GOOD}\n[telemetry]\nesc_status_hz = 0\n");
    refused(
        &text,
        "esc_status_hz",
        "esc_status_hz",
        "0 Hz is outside (0, 50] Hz",
    );
    let text = format!("{GOOD}\n[bridge]\non_exit = \"explode\"\n");
    refused(
        &text,
        "on_exit",
        "on_exit",
        "\"explode\" is not an exit action",
    );
    let text = format!("{GOOD}\n[bridge]\nwhile_safe = \"limp\"\n");
    refused(
        &text,
        "while_safe",
        "while_safe",
        "\"limp\" is not an action for the safety switch; use \"hold\", \"off\" or \"brake\"",
    );
}

#[test]
fn bus_values_are_checked() {
    let text = with("baud = 115200", "baud = 115200\nturnaround_ms = -1.0");
    refused(
        &text,
        "turnaround_ms",
        "turnaround_ms",
        "-1 ms is outside 0–100 ms",
    );
    for speed in ["0.0", "200.0", "nan"] {
        let text = with(
            "baud = 115200",
            &format!("baud = 115200\nsoft_start_mm_s = {speed}"),
        );
        refused(
            &text,
            "soft_start_mm_s",
            "soft_start_mm_s",
            "mm/s is outside 1–105 mm/s (the servo's top speed); the soft start cannot be switched off",
        );
    }
    let text = with("port = \"/dev/ttyUSB0\"", "port = \"\"");
    refused(&text, "port = \"\"", "port", "the serial port is empty");
    let text = with("name = \"wing\"", "name = \"left wing\"");
    refused(&text, "name = \"left wing\"", "name", "contains ' '");
}

#[test]
fn labels_are_checked() {
    let text = first_servo_with("label = \"aileron\"");
    refused(&text, "label", "label", "longer than 6 characters");
    let text = with(
        "channel = 5",
        "channel = 5\nlabel = \"s1\"   # the default label of the first servo",
    );
    refused(
        &text,
        "label = \"s1\"",
        "label",
        "label \"s1\" is already used by servo \"aileron_left\"",
    );
}

#[test]
fn goal_time_and_actuator_are_checked() {
    let text = first_servo_with("goal_time_ms = 700000");
    refused(
        &text,
        "goal_time_ms",
        "goal_time_ms",
        "700000 ms is outside 0–655350 ms",
    );
    let text = first_servo_with("actuator = 0");
    refused(&text, "actuator", "actuator", "0 is outside 1–126");
}

#[test]
fn an_unreadable_file_names_its_path() {
    let e = Config::load(std::path::Path::new("/nonexistent/mappings/plane.toml")).unwrap_err();
    assert!(matches!(e, ConfigError::Read { .. }));
    assert!(
        e.to_string()
            .starts_with("/nonexistent/mappings/plane.toml: cannot read the mapping file"),
        "{e}"
    );
}

proptest! {
    #[test]
    fn any_text_is_read_without_panic(text in "\\PC{0,400}") {
        let _ = Config::parse(&text, ORIGIN);
    }

    #[test]
    fn any_damage_to_a_good_file_is_read_without_panic(
        at in 0usize..GOOD.len(),
        cut in 0usize..20,
        insert in "[\\[\\]=\"'#.,{} \\n0-9a-z\\-]{0,12}",
    ) {
        let mut text = GOOD.as_bytes().to_vec();
        let end = (at + cut).min(text.len());
        text.splice(at..end, insert.bytes());
        if let Ok(text) = String::from_utf8(text) {
            match Config::parse(&text, ORIGIN) {
                Ok(c) => prop_assert!(!c.servos.is_empty()),
                Err(e) => {
                    let message = e.to_string();
                    prop_assert!(message.starts_with(ORIGIN), "{}", message);
                    prop_assert!(!e.reason().is_empty());
                }
            }
        }
    }
}

#[test]
fn the_aircraft_is_a_name_or_left_out() {
    let c = Config::parse(GOOD, ORIGIN).unwrap();
    assert_eq!(
        c.record.aircraft, None,
        "left out: the runtime uses the host name"
    );
    let named = format!("{GOOD}\n[record]\naircraft = \"VH-LJ9 #2\"\n");
    let c = Config::parse(&named, ORIGIN).unwrap();
    assert_eq!(c.record.aircraft.as_deref(), Some("VH-LJ9 #2"));
    for (value, reason) in [
        ("\"  \"", "is empty"),
        ("\"a\\u0007b\"", "no control characters"),
        (&format!("\"{}\"", "x".repeat(65)), "at most 64 bytes"),
    ] {
        let text = format!("{GOOD}\n[record]\naircraft = {value}\n");
        refused(&text, "aircraft =", "aircraft", reason);
    }
}

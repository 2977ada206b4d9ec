//! The files of a service installation: the systemd unit and the udev rule.

use lj9da_bridge::deploy::{DEFAULT_BINARY, DEFAULT_CONFIG, latency_fix, systemd_unit, udev_rule};
use std::path::Path;

/// The unit's `[Section]` → `key=value` lines (comments and blank lines skipped); panics on
/// a line that is neither.
fn ini(text: &str) -> Vec<(String, String, String)> {
    let mut section = String::new();
    let mut out = Vec::new();
    for line in text.lines() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') || line.starts_with(';') {
            continue;
        }
        if let Some(name) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
            section = name.to_string();
            continue;
        }
        let (key, value) = line
            .split_once('=')
            .unwrap_or_else(|| panic!("not key=value: {line}"));
        assert!(!section.is_empty(), "{line} before any section");
        out.push((section.clone(), key.to_string(), value.to_string()));
    }
    out
}

fn get<'a>(entries: &'a [(String, String, String)], section: &str, key: &str) -> Vec<&'a str> {
    entries
        .iter()
        .filter(|(s, k, _)| s == section && k == key)
        .map(|(_, _, v)| v.as_str())
        .collect()
}

#[test]
fn the_systemd_unit_runs_the_bridge_as_an_unprivileged_service_logging_to_journald() {
    let unit = systemd_unit(Path::new(DEFAULT_BINARY), Path::new(DEFAULT_CONFIG));
    let e = ini(&unit);
    assert_eq!(get(&e, "Service", "Type"), ["notify"]);
    assert_eq!(
        get(&e, "Service", "ExecStart"),
        ["/usr/local/bin/lj9da-bridge run --config /etc/lj9da-bridge/bridge.toml"]
    );
    assert_eq!(get(&e, "Service", "User"), ["lj9da"]);
    assert_eq!(get(&e, "Service", "SupplementaryGroups"), ["dialout"]);
    assert_eq!(get(&e, "Service", "StandardError"), ["journal"]);
    assert_eq!(get(&e, "Service", "StateDirectory"), ["lj9da-bridge"]);
    // Parameter changes are saved into the mapping file, in a folder /etc otherwise protects.
    assert_eq!(get(&e, "Service", "ProtectSystem"), ["strict"]);
    assert_eq!(get(&e, "Service", "ReadWritePaths"), ["-/etc/lj9da-bridge"]);
    assert!(
        get(&e, "Service", "Environment").contains(&"RUST_LOG=warn,lj9da_bridge=info"),
        "{unit}"
    );
    assert_eq!(get(&e, "Install", "WantedBy"), ["multi-user.target"]);
    assert_eq!(get(&e, "Unit", "After"), ["network-online.target"]);
}

/// A systemd time span of the forms the unit uses (`30`, `2s`, `200ms`), in milliseconds.
fn span_ms(value: &str) -> u64 {
    let digits_end = value
        .find(|c: char| !c.is_ascii_digit())
        .unwrap_or(value.len());
    let (digits, unit) = value.split_at(digits_end);
    let n: u64 = digits.parse().unwrap();
    match unit {
        "ms" => n,
        "s" | "" => n * 1000,
        _ => panic!("time span {value}"),
    }
}

#[test]
fn the_service_comes_back_at_once_from_an_exit_a_kill_or_a_hang() {
    let unit = systemd_unit(Path::new(DEFAULT_BINARY), Path::new(DEFAULT_CONFIG));
    let e = ini(&unit);
    assert_eq!(get(&e, "Service", "Restart"), ["always"]);
    assert!(
        span_ms(get(&e, "Service", "RestartSec")[0]) <= 200,
        "{unit}"
    );
    // The watchdog: pinged every half timeout while every bus thread turns (every 100 ms at
    // least); a hung process is killed outright, a stopped one too.
    let watchdog = span_ms(get(&e, "Service", "WatchdogSec")[0]);
    let shortest = lj9da_bridge::runtime::service::SHORTEST_WATCHDOG.as_millis() as u64;
    assert!((shortest..=2000).contains(&watchdog), "{unit}");
    assert_eq!(get(&e, "Service", "WatchdogSignal"), ["SIGKILL"]);
    assert_eq!(get(&e, "Service", "NotifyAccess"), ["main"]);
    // The start limit trips only for a bridge that never gets going: 100 restarts in 30 s is a
    // cycle under 300 ms, i.e. failing within 100 ms of every start.
    let interval = span_ms(get(&e, "Unit", "StartLimitIntervalSec")[0]);
    let burst: u64 = get(&e, "Unit", "StartLimitBurst")[0].parse().unwrap();
    assert!(interval / burst <= 300, "{unit}");
    // A mapping file that does not load is the one failure a restart cannot fix.
    assert_eq!(get(&e, "Service", "RestartPreventExitStatus"), ["2"]);
}

#[test]
fn the_unit_opens_the_serial_ports_of_every_common_driver_and_no_other_device() {
    let unit = systemd_unit(Path::new(DEFAULT_BINARY), Path::new(DEFAULT_CONFIG));
    let e = ini(&unit);
    assert_eq!(get(&e, "Service", "DevicePolicy"), ["closed"]);
    let allowed = get(&e, "Service", "DeviceAllow");
    for driver in ["ttyS", "ttyAMA", "ttyUSB", "ttyACM", "ttySC", "ttyTHS"] {
        assert!(
            allowed.contains(&format!("char-{driver} rw").as_str()),
            "{driver}: {unit}"
        );
    }
    // Real-time scheduling is what the bus threads ask for: it must not be restricted.
    assert!(get(&e, "Service", "RestrictRealtime").is_empty(), "{unit}");
    assert!(get(&e, "Service", "PrivateDevices").is_empty(), "{unit}");
}

#[test]
fn unit_paths_with_spaces_or_percent_signs_are_quoted_and_escaped() {
    let unit = systemd_unit(
        Path::new("/opt/lj9da bridge/lj9da-bridge"),
        Path::new("/etc/lj9da-bridge/100%.toml"),
    );
    let e = ini(&unit);
    assert_eq!(
        get(&e, "Service", "ExecStart"),
        ["\"/opt/lj9da bridge/lj9da-bridge\" run --config /etc/lj9da-bridge/100%%.toml"]
    );
    let unit = systemd_unit(
        Path::new("/usr/bin/lj9da-bridge"),
        Path::new("/etc/lj9da bridge/plane.toml"),
    );
    assert_eq!(
        get(&ini(&unit), "Service", "ReadWritePaths"),
        ["\"-/etc/lj9da bridge\""]
    );
}

#[test]
fn the_udev_rule_sets_ftdi_latency_timers_to_1_ms() {
    let rule = udev_rule();
    let rules: Vec<&str> = rule
        .lines()
        .filter(|l| !l.trim().is_empty() && !l.starts_with('#'))
        .collect();
    assert_eq!(
        rules[0],
        r#"ACTION=="add|change", SUBSYSTEM=="usb-serial", DRIVER=="ftdi_sio", ATTR{latency_timer}="1""#
    );
    assert!(rules[1].contains(r#"ATTRS{idVendor}=="0403""#));
    assert!(rules[1].contains(r#"ATTRS{idProduct}=="6001|6010|6011|6014|6015""#));
    assert!(rules[1].ends_with(r#"ATTR{device/latency_timer}="1""#));
    assert_eq!(rules.len(), 2);
    for r in rules {
        // Every key is KEY op "value", separated by ", ".
        for part in r.split(", ") {
            let (key, value) = part
                .split_once("==")
                .or_else(|| part.split_once('='))
                .unwrap_or_else(|| panic!("{part}"));
            assert!(
                !key.is_empty() && value.starts_with('"') && value.ends_with('"'),
                "{part}"
            );
        }
    }
    for chip in ["FT232R", "FT232H", "FT-X"] {
        assert!(rule.contains(chip));
    }
}

#[test]
fn the_systemd_unit_grants_real_time_scheduling_at_the_bus_threads_priority_and_locked_memory() {
    let unit = systemd_unit(Path::new(DEFAULT_BINARY), Path::new(DEFAULT_CONFIG));
    let e = ini(&unit);
    let priority = lj9da_bridge::bus::driver::REALTIME_PRIORITY.to_string();
    assert_eq!(get(&e, "Service", "LimitRTPRIO"), [priority.as_str()]);
    assert_eq!(get(&e, "Service", "LimitMEMLOCK"), ["infinity"]);
    let caps = get(&e, "Service", "AmbientCapabilities");
    assert_eq!(caps.len(), 1, "{unit}");
    assert!(
        caps[0].split_whitespace().any(|c| c == "CAP_SYS_NICE"),
        "{unit}"
    );
}

#[test]
fn the_udev_rule_applies_to_an_adapter_already_plugged_in() {
    // `udevadm trigger` sends "change" events unless told otherwise: a rule for "add" only
    // would leave an adapter plugged in before the rule was installed at 16 ms.
    let rule = udev_rule();
    for r in rule.lines().filter(|l| l.starts_with("ACTION")) {
        assert!(r.starts_with(r#"ACTION=="add|change""#), "{r}");
    }
    // And every install instruction replays "add" for the USB-serial devices.
    for text in [rule.as_str(), latency_fix("ttyUSB0", 16).as_str()] {
        let triggers: Vec<&str> = text
            .lines()
            .filter(|l| l.contains("sudo udevadm trigger"))
            .collect();
        assert!(!triggers.is_empty(), "{text}");
        for t in triggers {
            assert!(
                t.trim_end()
                    .ends_with("udevadm trigger --action=add --subsystem-match=usb-serial"),
                "{t}"
            );
        }
    }
}

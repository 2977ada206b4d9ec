//! The real `lj9da-bridge` binary's commissioning subcommands against the simulated bus: exit
//! codes (0 done, 1 failed, 2 refused with nothing written), messages and output.

mod commission_common;

use commission_common::{packets_after_exit, sim, writes_after_exit};
use std::io::Write;
use std::path::Path;
use std::process::{Command, Output, Stdio};

fn bridge(args: &[&str], stdin: Option<&str>) -> Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_lj9da-bridge"))
        .args(args)
        .env("RUST_LOG", "warn")
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("the binary starts");
    if let Some(mut pipe) = child.stdin.take() {
        let _ = pipe.write_all(stdin.unwrap_or("").as_bytes());
    }
    child.wait_with_output().expect("the binary finishes")
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

#[test]
fn the_help_shows_a_commissioning_command_among_its_examples() {
    let out = bridge(&["--help"], None);
    assert!(out.status.success());
    let help = text(&out.stdout);
    let examples = &help[help.find("Examples:").expect("an Examples section")..];
    assert!(
        examples.contains("lj9da-bridge scan --port /dev/ttyUSB0"),
        "{help}"
    );
}

#[test]
fn a_limit_beyond_25_mm_exits_2_with_the_reason_and_nothing_reaches_the_bus() {
    let bus = sim(&[1]);
    let events = bus.handle().subscribe();
    let port = bus.path();
    let port = port.to_str().unwrap();
    let out = bridge(
        &[
            "set",
            "--port",
            port,
            "--id",
            "1",
            "punch=0x100",
            "plus-limit=25.01",
        ],
        None,
    );
    assert_eq!(out.status.code(), Some(2));
    let err = text(&out.stderr);
    assert!(
        err.contains("25.01") && err.contains("±25.00 mm") && err.contains("nothing was written"),
        "{err}"
    );
    assert!(
        packets_after_exit(&events, Path::new(port)).is_empty(),
        "not even a read"
    );
    let servo = bus.handle().snapshot(1).unwrap();
    assert_eq!(&servo.registers[8..10], &[0xC4, 0x09]);
    assert_eq!(&servo.registers[28..30], &[0xC4, 0x09]);
}

#[test]
fn read_only_registers_unknown_bauds_and_bad_ids_exit_2() {
    let bus = sim(&[1]);
    let events = bus.handle().subscribe();
    let port = bus.path();
    let port = port.to_str().unwrap();
    for (arg, reason) in [
        ("model-number=1", "read only"),
        ("baud=921600", "921600"),
        ("id=0", "1–127"),
        ("id=128", "1–127"),
    ] {
        let out = bridge(&["set", "--port", port, "--id", "1", arg], None);
        assert_eq!(out.status.code(), Some(2), "{arg}");
        let err = text(&out.stderr);
        assert!(err.contains(reason), "{arg}: {err}");
    }
    let out = bridge(&["scan", "--port", port, "--baud", "921600"], None);
    assert_eq!(out.status.code(), Some(2));
    assert!(text(&out.stderr).contains("921600"));
    assert!(packets_after_exit(&events, Path::new(port)).is_empty());
}

#[test]
fn an_id_already_on_the_bus_exits_2_and_writes_nothing() {
    let bus = sim(&[1, 2]);
    let events = bus.handle().subscribe();
    let port = bus.path();
    let port = port.to_str().unwrap();
    let out = bridge(
        &["set", "--port", port, "--id", "1", "id=2", "--save"],
        None,
    );
    assert_eq!(out.status.code(), Some(2));
    assert!(text(&out.stderr).contains("ID 2 is already taken"));
    assert!(writes_after_exit(&events, Path::new(port)).is_empty());
    assert_eq!(bus.handle().snapshot(1).unwrap().registers[4], 1);
}

#[test]
fn scan_info_and_monitor_print_what_the_servos_report() {
    let bus = sim(&[1, 3]);
    let port = bus.path();
    let port = port.to_str().unwrap();

    let out = bridge(&["scan", "--port", port, "--ids", "1-5"], None);
    assert_eq!(out.status.code(), Some(0), "{}", text(&out.stderr));
    let table = text(&out.stdout);
    let rows: Vec<&str> = table.lines().filter(|l| l.contains("LJ9DA41")).collect();
    assert_eq!(rows.len(), 2, "{table}");
    assert!(rows[0].trim_start().starts_with("1 ") && rows[1].trim_start().starts_with("3 "));
    assert!(table.contains("2 servos found"), "{table}");

    let out = bridge(&["info", "--port", port, "--id", "3", "--json"], None);
    assert_eq!(out.status.code(), Some(0), "{}", text(&out.stderr));
    let json = text(&out.stdout);
    assert!(
        json.starts_with('{') && json.trim_end().ends_with('}'),
        "{json}"
    );
    assert!(json.contains("\"servo_id\": 3") && json.contains("\"temperature_limit_c\": 85"));

    let out = bridge(&["info", "--port", port, "--id", "3"], None);
    assert!(text(&out.stdout).contains("Temperature Limit"));

    let out = bridge(
        &[
            "monitor",
            "--port",
            port,
            "--ids",
            "1,3",
            "--count",
            "2",
            "--interval-ms",
            "50",
            "--plain",
        ],
        None,
    );
    assert_eq!(out.status.code(), Some(0), "{}", text(&out.stderr));
    let screens = text(&out.stdout);
    assert!(
        screens.contains("sample 1") && screens.contains("sample 2"),
        "{screens}"
    );
    assert!(!screens.contains("sample 3"));
    assert_eq!(screens.matches("12.00 V").count(), 4, "{screens}");
}

#[test]
fn set_move_and_force_through_the_binary() {
    let bus = sim(&[1]);
    let handle = bus.handle();
    let port = bus.path();
    let port = port.to_str().unwrap();

    let out = bridge(
        &["set", "--port", port, "--id", "1", "id=6", "--save"],
        None,
    );
    assert_eq!(out.status.code(), Some(0), "{}", text(&out.stderr));
    let summary = text(&out.stdout);
    assert!(
        summary.contains("verified") && summary.contains("answers as ID 6"),
        "{summary}"
    );
    assert_eq!(handle.snapshot(6).unwrap().flash[0], 6);

    let out = bridge(&["move", "--port", port, "--id", "6", "--mm", "-7.5"], None);
    assert_eq!(out.status.code(), Some(2), "force is off");
    assert!(text(&out.stderr).contains("--force-on"));

    let out = bridge(
        &[
            "move",
            "--port",
            port,
            "--id",
            "6",
            "--mm",
            "-7.5",
            "--force-on",
        ],
        None,
    );
    assert_eq!(out.status.code(), Some(0), "{}", text(&out.stderr));
    assert!(text(&out.stdout).contains("arrived"));
    assert!((handle.snapshot(6).unwrap().position_mm + 7.5).abs() <= 0.1);

    let out = bridge(&["force", "--port", port, "--id", "6", "brake"], None);
    assert_eq!(out.status.code(), Some(0), "{}", text(&out.stderr));
    assert!(text(&out.stdout).contains("on → brake"));
    assert_eq!(handle.snapshot(6).unwrap().force, lj9da_sim::Force::Brake);

    let out = bridge(&["move", "--port", port, "--id", "6", "--mm", "25.5"], None);
    assert_eq!(out.status.code(), Some(2), "beyond the stroke");
}

#[test]
fn factory_reset_asks_for_confirmation() {
    let bus = sim(&[3]);
    let handle = bus.handle();
    let events = handle.subscribe();
    let port = bus.path();
    let port = port.to_str().unwrap();

    let out = bridge(
        &["factory-reset", "--port", port, "--id", "3"],
        Some("yes\n"),
    );
    assert_eq!(out.status.code(), Some(2));
    assert!(text(&out.stderr).contains("type the servo id"));
    assert!(text(&out.stderr).contains("not confirmed"));
    assert!(writes_after_exit(&events, Path::new(port)).is_empty());
    assert_eq!(handle.snapshot(3).unwrap().registers[4], 3);

    let out = bridge(&["factory-reset", "--port", port, "--id", "3"], Some("3\n"));
    assert_eq!(out.status.code(), Some(0), "{}", text(&out.stderr));
    assert!(text(&out.stdout).contains("now ID 1"));
    assert_eq!(handle.snapshot(1).unwrap().registers[4], 1);
}

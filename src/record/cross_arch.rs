//! Flight records move between computers: a record written on the companion computer (aarch64
//! or 32-bit armv7) is read on a laptop (x86-64), and the other way round. The fixtures in
//! `fixtures/` were written by the recorder itself, each on its architecture (the ARM ones by
//! the test binary for that target running under qemu-user), with
//!
//! ```text
//! LJ9DA_RECORD_FIXTURE_DIR=src/record/fixtures cargo test --lib [--target T] -- \
//!     --ignored record::cross_arch::write_the_fixture_of_this_architecture
//! ```
//!
//! Each holds the same records; the one event that differs names the architecture, word size
//! and `time_t` size that wrote it. These tests read all of them on whatever architecture
//! they run on, and write a new one there too.

use super::format::{Record, RecordBody, RecordServo};
use super::reader::Recording;
use super::writer::{RecordLimits, Recorder, RecorderOptions};
use crate::bus::{Goal, Health};
use crate::protocol::{Celsius, Ma10, MmCenti, Motion, Ms10, Mv10, ReplyFlags, Telemetry};
use std::path::{Path, PathBuf};
use std::time::Duration;

/// The fixtures: (architecture, `usize` bits, `time_t` bits), in `fixtures/<architecture>.lj9rec`.
const FIXTURES: [(&str, u32, u32); 3] = [("x86_64", 64, 64), ("aarch64", 64, 64), ("arm", 32, 32)];

/// A fixture's bytes (read at run time: under qemu-user the test sees the host's files).
fn fixture(arch: &str) -> Vec<u8> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("src/record/fixtures")
        .join(format!("{arch}.lj9rec"));
    std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// 5 h in µs: past `u32::MAX` µs (71.6 min), so a `t_us` cut to 32 bits anywhere shows.
const LATE_US: u64 = 5 * 3600 * 1_000_000;

fn servos() -> Vec<RecordServo> {
    vec![
        RecordServo::new("aileron_left", "wing", 1, 1),
        RecordServo::new("élévateur", "tail", 127, 32),
    ]
}

/// The event that says who wrote a file.
fn machine_text(arch: &str, usize_bits: u32, time_t_bits: u32) -> String {
    format!("written on {arch}: usize {usize_bits} bits, time_t {time_t_bits} bits")
}

fn this_machine() -> String {
    machine_text(
        std::env::consts::ARCH,
        usize::BITS,
        8 * std::mem::size_of::<libc::time_t>() as u32,
    )
}

/// The records every fixture holds, in order, with the machine event first; the end record
/// is the recorder's own.
fn expected(machine: &str) -> Vec<Record> {
    let telemetry = Telemetry {
        present_position: MmCenti(-2500),
        present_time: Ms10(u16::MAX),
        present_load: Ma10(65_535),
        present_temperature: Celsius(-40),
        present_voltage: Mv10(1200),
    };
    let bodies = [
        (
            0,
            RecordBody::Event {
                servo: None,
                severity: 6,
                text: machine.to_string(),
            },
        ),
        (
            1,
            RecordBody::Goal {
                servo: 0,
                goal: Goal::Position(MmCenti(2500)),
            },
        ),
        (
            127,
            RecordBody::Goal {
                servo: 1,
                goal: Goal::Brake,
            },
        ),
        (
            128,
            RecordBody::Telemetry {
                servo: 1,
                telemetry,
                flags: ReplyFlags(0xa8),
            },
        ),
        (
            16_384,
            RecordBody::Position {
                servo: 0,
                position: MmCenti(i16::MIN),
                flags: ReplyFlags(0),
            },
        ),
        (
            16_385,
            RecordBody::Motion {
                servo: 1,
                motion: Motion {
                    present_position: MmCenti(i16::MAX),
                    present_time: Ms10(u16::MAX),
                    present_load: Ma10(65_535),
                },
                flags: ReplyFlags(0x20),
            },
        ),
        (
            (1 << 32) - 1,
            RecordBody::Health {
                servo: 0,
                health: Health::TemperatureError,
                stalled: true,
            },
        ),
        (
            1 << 32,
            RecordBody::Replies {
                servo: 1,
                answered: u32::MAX,
                missed: 3,
            },
        ),
        (
            LATE_US,
            RecordBody::Event {
                servo: Some(1),
                severity: 4,
                text: "élévateur: 55 °C — 5 h in".to_string(),
            },
        ),
    ];
    let mut records: Vec<Record> = bodies
        .into_iter()
        .map(|(t_us, body)| Record { t_us, body })
        .collect();
    records.push(Record {
        t_us: 0,
        body: RecordBody::End { continued: false },
    });
    records
}

/// Write this machine's record into `dir` with the recorder, through its public methods where
/// they stamp a given time; the path of the file.
fn write_here(dir: &Path) -> PathBuf {
    let handle = Recorder::start_with(
        dir,
        &servos(),
        RecordLimits::with_total(1 << 20),
        RecorderOptions::default(),
    )
    .expect("start the recorder");
    let start = handle.start_instant();
    let at = |t_us: u64| start + Duration::from_micros(t_us);
    for record in expected(&this_machine()) {
        match record.body {
            RecordBody::Goal { servo, goal } => handle.goal_at(at(record.t_us), servo.into(), goal),
            RecordBody::Telemetry {
                servo,
                telemetry,
                flags,
            } => handle.telemetry(at(record.t_us), servo.into(), &telemetry, flags),
            RecordBody::Position {
                servo,
                position,
                flags,
            } => handle.position(at(record.t_us), servo.into(), position, flags),
            RecordBody::Motion {
                servo,
                motion,
                flags,
            } => handle.motion(at(record.t_us), servo.into(), motion, flags),
            RecordBody::Health {
                servo,
                health,
                stalled,
            } => handle.health(at(record.t_us), servo.into(), health, stalled),
            // More than `u32::MAX` answered: the recorder saturates the count.
            RecordBody::Replies { servo, missed, .. } => handle.replies(
                at(record.t_us),
                servo.into(),
                u64::from(u32::MAX) + 10,
                missed.into(),
            ),
            body @ RecordBody::Event { .. } => handle.record_at(at(record.t_us), body),
            RecordBody::End { .. } => {}
            RecordBody::Dropped { .. } | RecordBody::AutopilotClock { .. } => {
                unreachable!("no such record is written")
            }
        }
    }
    let stats = handle.finish();
    assert_eq!(stats.dropped(), 0, "{stats:?}");
    assert_eq!(stats.files.len(), 1, "{stats:?}");
    stats.files[0].clone()
}

/// The format the fixtures were written in (a later reader reads them as they were).
const FIXTURE_VERSION: (u16, u16) = (1, 3);

/// Check one file's content against the records it must hold; `what` names it in failures,
/// `version` is the format it must be in.
fn check(what: &str, recording: &Recording, machine: &str, version: (u16, u16)) {
    assert_eq!(recording.header.version, version, "{what}");
    assert_eq!(recording.header.part, 0, "{what}");
    assert_eq!(recording.header.servos, servos(), "{what}");
    assert!(
        recording.header.software.starts_with("lj9da-bridge "),
        "{what}: {}",
        recording.header.software
    );
    // Written in 2026 or later, by a clock that knows dates past 2038 as well as before.
    assert!(
        recording.header.run_start_unix_ns > 1_767_225_600_000_000_000,
        "{what}: {}",
        recording.header.run_start_unix_ns
    );
    assert!(recording.notes.is_empty(), "{what}: {:?}", recording.notes);
    assert!(recording.closed, "{what}");
    let mut records = recording.records.clone();
    // The end record is stamped with the time the recorder closed, not one of ours.
    records.last_mut().expect("records").t_us = 0;
    assert_eq!(records, expected(machine), "{what}");
    assert_eq!(recording.end_t_us(), LATE_US, "{what}");
}

#[test]
fn a_record_from_each_architecture_reads_back_with_the_same_records_and_values() {
    for (arch, usize_bits, time_t_bits) in FIXTURES {
        let recording = Recording::from_bytes(&fixture(arch))
            .unwrap_or_else(|e| panic!("fixtures/{arch}.lj9rec: {e}"));
        check(
            &format!("fixtures/{arch}.lj9rec"),
            &recording,
            &machine_text(arch, usize_bits, time_t_bits),
            FIXTURE_VERSION,
        );
    }
}

#[test]
fn a_record_written_here_holds_what_the_fixtures_hold() {
    let dir = std::env::temp_dir().join(format!("lj9da-cross-arch-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let path = write_here(&dir);
    let here = Recording::from_bytes(&std::fs::read(&path).unwrap()).unwrap();
    check(
        &path.display().to_string(),
        &here,
        &this_machine(),
        (super::format::VERSION_MAJOR, super::format::VERSION_MINOR),
    );
    // Record for record, the fixtures differ from it only in the machine event (and the end's
    // time).
    let n = here.records.len();
    for (arch, _, _) in FIXTURES {
        let theirs = Recording::from_bytes(&fixture(arch)).unwrap();
        assert_eq!(theirs.records.len(), n, "fixtures/{arch}.lj9rec");
        assert_eq!(
            here.records[1..n - 1],
            theirs.records[1..n - 1],
            "here vs fixtures/{arch}.lj9rec"
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
#[ignore = "writes a fixture: run by hand with LJ9DA_RECORD_FIXTURE_DIR set"]
fn write_the_fixture_of_this_architecture() {
    let out = PathBuf::from(
        std::env::var_os("LJ9DA_RECORD_FIXTURE_DIR").expect("LJ9DA_RECORD_FIXTURE_DIR"),
    );
    let dir = std::env::temp_dir().join(format!("lj9da-fixture-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let path = write_here(&dir);
    let target = out.join(format!("{}.lj9rec", std::env::consts::ARCH));
    std::fs::copy(&path, &target).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
    println!("{}: {}", target.display(), this_machine());
}

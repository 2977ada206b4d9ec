//! The flight record format: every record kind round-trips through the recorder and the
//! reader, a damaged file reads back everything before the damage, with a note, and the files
//! earlier format versions wrote (tests/fixtures/records) still read as they were written.

mod tempdir;

use lj9da_bridge::bus::{Goal, Health};
use lj9da_bridge::protocol::{Celsius, Ma10, MmCenti, Motion, Ms10, Mv10, ReplyFlags, Telemetry};
use lj9da_bridge::record::csv::CSV_HEADER;
use lj9da_bridge::record::format::{
    HeaderError, MAX_EVENT_TEXT, RecordHeader, RecordServo, encode_header, encode_record,
};
use lj9da_bridge::record::summary;
use lj9da_bridge::record::{
    Record, RecordBody, RecordError, RecordLimits, Recorder, Recording, read_record,
};
use proptest::prelude::*;
use std::collections::BTreeMap;
use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;
use tempdir::TempDir;

fn servos() -> Vec<RecordServo> {
    vec![
        RecordServo::new("aileron_left", "wing", 1, 1),
        RecordServo::new("aileron_right", "wing", 2, 2),
        RecordServo::new("élévateur", "tail", 127, 32),
    ]
}

fn telemetry(position: i16, load: u16, temperature: i16, voltage: u16) -> Telemetry {
    Telemetry {
        present_position: MmCenti(position),
        present_time: Ms10(7),
        present_load: Ma10(load),
        present_temperature: Celsius(temperature),
        present_voltage: Mv10(voltage),
    }
}

/// One of every record kind and value, at distinct times.
fn every_kind() -> Vec<Record> {
    let mut bodies = vec![
        RecordBody::Goal {
            servo: 0,
            goal: Goal::Position(MmCenti(-2500)),
        },
        RecordBody::Goal {
            servo: 1,
            goal: Goal::Position(MmCenti(2500)),
        },
        RecordBody::Goal {
            servo: 0,
            goal: Goal::Hold,
        },
        RecordBody::Goal {
            servo: 1,
            goal: Goal::Off,
        },
        RecordBody::Goal {
            servo: 2,
            goal: Goal::Brake,
        },
        RecordBody::Telemetry {
            servo: 0,
            telemetry: telemetry(-1234, 65_535, -40, 0),
            flags: ReplyFlags(0xAA),
        },
        RecordBody::Telemetry {
            servo: 2,
            telemetry: telemetry(i16::MAX, 0, i16::MIN, u16::MAX),
            flags: ReplyFlags(0),
        },
        RecordBody::Position {
            servo: 1,
            position: MmCenti(-2500),
            flags: ReplyFlags(0x20),
        },
        RecordBody::Position {
            servo: 2,
            position: MmCenti(i16::MAX),
            flags: ReplyFlags(0),
        },
        RecordBody::Motion {
            servo: 0,
            motion: Motion {
                present_position: MmCenti(-2500),
                present_time: Ms10(0),
                present_load: Ma10(u16::MAX),
            },
            flags: ReplyFlags(0x80),
        },
        RecordBody::Motion {
            servo: 2,
            motion: Motion {
                present_position: MmCenti(i16::MIN),
                present_time: Ms10(u16::MAX),
                present_load: Ma10(0),
            },
            flags: ReplyFlags(0),
        },
        RecordBody::Replies {
            servo: 0,
            answered: 123_456,
            missed: 7,
        },
        RecordBody::Replies {
            servo: 2,
            answered: u32::MAX,
            missed: 0,
        },
        RecordBody::AutopilotClock {
            time_usec: u64::from(u32::MAX),
            bits: 32,
        },
        RecordBody::AutopilotClock {
            time_usec: 86_400_000_000_000,
            bits: 64,
        },
    ];
    for (i, health) in [
        Health::Starting,
        Health::Online,
        Health::Stale,
        Health::Offline,
        Health::WrongModel,
        Health::TemperatureError,
    ]
    .into_iter()
    .enumerate()
    {
        bodies.push(RecordBody::Health {
            servo: (i % 3) as u8,
            health,
            stalled: i % 2 == 0,
        });
    }
    bodies.push(RecordBody::Event {
        servo: Some(1),
        severity: 4,
        text: "aileron_right: temperature alarm 76C, \"hot\"".into(),
    });
    bodies.push(RecordBody::Event {
        servo: None,
        severity: 0,
        text: "LJ9DA failsafe: no outputs for 500 ms — ünïcödé".into(),
    });
    bodies.push(RecordBody::Event {
        servo: None,
        severity: 7,
        text: String::new(),
    });
    bodies
        .into_iter()
        .enumerate()
        .map(|(i, body)| Record {
            // Times that need 1, 2, 3 and more LEB128 bytes.
            t_us: (i as u64) * (i as u64) * 977_777,
            body,
        })
        .collect()
}

/// Hand `records` to a real recorder at their times; returns the file written.
fn record_through_recorder(dir: &Path, records: &[Record]) -> PathBuf {
    let handle = Recorder::start(dir, &servos(), RecordLimits::default()).unwrap();
    let start = handle.start_instant();
    for r in records {
        handle.record_at(start + Duration::from_micros(r.t_us), r.body.clone());
    }
    let stats = handle.finish();
    assert_eq!(stats.written, records.len() as u64);
    assert_eq!(stats.dropped(), 0);
    assert_eq!(stats.files.len(), 1);
    stats.files[0].clone()
}

fn file_bytes(records: &[Record]) -> (Vec<u8>, Vec<usize>) {
    let mut bytes = encode_header(&RecordHeader::new(1_763_769_599_000_000_000, servos()));
    let mut starts = Vec::new();
    for r in records {
        starts.push(bytes.len());
        encode_record(r, &mut bytes);
    }
    (bytes, starts)
}

#[test]
fn every_record_kind_round_trips_through_the_recorder_and_the_reader() {
    let dir = TempDir::new("rt");
    let records = every_kind();
    let path = record_through_recorder(dir.path(), &records);
    assert_eq!(path.extension().unwrap(), "lj9rec");
    let rec = read_record(&path).unwrap();
    assert!(rec.closed);
    assert!(rec.notes.is_empty(), "{:?}", rec.notes);
    assert_eq!(rec.header.servos, servos());
    assert_eq!(rec.header.version, (1, 4));
    assert_eq!(rec.header.part, 0);
    assert!(rec.header.software.starts_with("lj9da-bridge "));
    let (last, data) = rec.records.split_last().unwrap();
    assert_eq!(data, &records[..]);
    assert_eq!(last.body, RecordBody::End { continued: false });
}

#[test]
fn event_texts_are_cut_at_1000_bytes_on_a_character_boundary() {
    let dir = TempDir::new("text");
    let long = "é".repeat(700); // 1400 bytes
    let path = record_through_recorder(
        dir.path(),
        &[Record {
            t_us: 5,
            body: RecordBody::Event {
                servo: Some(0),
                severity: 6,
                text: long.clone(),
            },
        }],
    );
    let rec = read_record(&path).unwrap();
    match &rec.records[0].body {
        RecordBody::Event { text, .. } => {
            assert_eq!(text.len(), MAX_EVENT_TEXT);
            assert!(long.starts_with(text.as_str()));
        }
        other => panic!("expected an event, got {other:?}"),
    }
}

#[test]
fn a_file_cut_at_every_byte_of_its_last_record_reads_back_every_earlier_record() {
    let records = every_kind();
    let (bytes, starts) = file_bytes(&records);
    let last_start = *starts.last().unwrap();
    for cut in last_start..bytes.len() {
        let rec = Recording::from_bytes(&bytes[..cut]).unwrap();
        assert_eq!(
            rec.records,
            records[..records.len() - 1],
            "cut at byte {cut}"
        );
        assert!(!rec.closed);
        assert!(
            rec.notes.iter().any(|n| n.contains("no end record")),
            "cut at byte {cut}: {:?}",
            rec.notes
        );
        if cut > last_start {
            let expected = format!(
                "the file ends {} bytes into a record at offset {last_start}",
                cut - last_start
            );
            assert!(
                rec.notes.iter().any(|n| n.starts_with(&expected)),
                "cut at byte {cut}: {:?}",
                rec.notes
            );
        }
    }
    let whole = Recording::from_bytes(&bytes).unwrap();
    assert_eq!(whole.records, records);
}

#[test]
fn a_recorder_file_cut_anywhere_in_its_end_record_keeps_every_data_record() {
    let dir = TempDir::new("cut");
    let records = every_kind();
    let path = record_through_recorder(dir.path(), &records);
    let bytes = std::fs::read(&path).unwrap();
    // The end record: len 2 + kind 1 + time (≤ 10) + 1 + CRC 4.
    let (_, starts) = file_bytes(&records);
    let end_start = *starts.last().unwrap() + {
        let mut one = Vec::new();
        encode_record(records.last().unwrap(), &mut one)
    };
    assert!(end_start < bytes.len());
    for cut in end_start..bytes.len() {
        let cut_path = dir.path().join("cut.lj9rec");
        std::fs::write(&cut_path, &bytes[..cut]).unwrap();
        let rec = read_record(&cut_path).unwrap();
        assert_eq!(rec.records, records, "cut at byte {cut}");
        assert!(!rec.closed);
    }
}

#[test]
fn a_bad_crc_anywhere_in_the_last_record_drops_that_record_only() {
    let records = every_kind();
    let (bytes, starts) = file_bytes(&records);
    let last_start = *starts.last().unwrap();
    for at in last_start..bytes.len() {
        let mut damaged = bytes.clone();
        damaged[at] ^= 0x5A;
        let rec = Recording::from_bytes(&damaged).unwrap();
        assert_eq!(
            rec.records,
            records[..records.len() - 1],
            "byte {at} damaged"
        );
        assert!(
            rec.notes
                .iter()
                .any(|n| n.contains(&format!("offset {last_start}"))),
            "byte {at} damaged: {:?}",
            rec.notes
        );
    }
}

#[test]
fn damage_in_the_middle_skips_to_the_next_whole_record() {
    let records = every_kind();
    let (bytes, starts) = file_bytes(&records);
    let victim = 6;
    for at in starts[victim]..starts[victim + 1] {
        let mut damaged = bytes.clone();
        damaged[at] = damaged[at].wrapping_add(77);
        let rec = Recording::from_bytes(&damaged).unwrap();
        let mut expected = records.clone();
        expected.remove(victim);
        assert_eq!(rec.records, expected, "byte {at} damaged");
        let note = format!("reading resumed at offset {}", starts[victim + 1]);
        assert!(
            rec.notes.iter().any(|n| n.contains(&note)),
            "byte {at} damaged: {:?}",
            rec.notes
        );
    }
}

#[test]
fn a_tail_of_zeros_is_noted_as_a_power_loss() {
    let records = every_kind();
    let (mut bytes, _) = file_bytes(&records);
    let at = bytes.len();
    bytes.extend(std::iter::repeat_n(0u8, 4096));
    let rec = Recording::from_bytes(&bytes).unwrap();
    assert_eq!(rec.records, records);
    assert!(
        rec.notes
            .iter()
            .any(|n| n.starts_with(&format!("the last 4096 bytes, from offset {at}, are zeros"))),
        "{:?}",
        rec.notes
    );
}

#[test]
fn only_an_unreadable_header_is_an_error() {
    let dir = TempDir::new("hdr");
    let path = dir.path().join("x.lj9rec");

    std::fs::write(&path, b"name,value\n1,2\n").unwrap();
    let e = read_record(&path).unwrap_err();
    assert!(matches!(
        e,
        RecordError::Header {
            reason: HeaderError::NotARecord,
            ..
        }
    ));
    assert!(e.to_string().contains("not an lj9da-bridge flight record"));
    assert!(e.to_string().contains("x.lj9rec"));

    let (mut bytes, _) = file_bytes(&every_kind());
    bytes[8] = 2; // major version 2
    bytes[10] = 1; // minor version 1
    std::fs::write(&path, &bytes).unwrap();
    let e = read_record(&path).unwrap_err().to_string();
    assert!(e.contains("record format 2.1"), "{e}");
    assert!(e.contains("reads format 1.x"), "{e}");

    std::fs::write(&path, &bytes[..10]).unwrap();
    let e = read_record(&path).unwrap_err().to_string();
    assert!(e.contains("ends inside its header"), "{e}");

    let e = read_record(&dir.path().join("missing.lj9rec")).unwrap_err();
    assert!(matches!(e, RecordError::Io { .. }));
}

/// A flight record written by the `sitl` of one format version (how each was made:
/// tests/fixtures/records/README.md), and how many records of each kind that version wrote
/// into it; a kind it did not have is not listed.
struct Fixture {
    minor: u16,
    kinds: &'static [(&'static str, usize)],
}

/// 1.0: no position and no replies records; 1.1: position records, no replies; 1.2: replies
/// records too; 1.3: motion records (a position with its current) in place of position ones;
/// 1.4: the aircraft's name in the header, and the autopilot's clock.
const FIXTURES: [Fixture; 5] = [
    Fixture {
        minor: 0,
        kinds: &[
            ("goal", 361),
            ("telemetry", 175),
            ("health", 50),
            ("event", 50),
            ("end", 1),
        ],
    },
    Fixture {
        minor: 1,
        kinds: &[
            ("goal", 368),
            ("telemetry", 95),
            ("position", 390),
            ("health", 21),
            ("event", 20),
            ("end", 1),
        ],
    },
    Fixture {
        minor: 2,
        kinds: &[
            ("goal", 384),
            ("telemetry", 161),
            ("position", 346),
            ("replies", 12),
            ("health", 8),
            ("event", 4),
            ("end", 1),
        ],
    },
    Fixture {
        minor: 3,
        kinds: &[
            ("goal", 410),
            ("telemetry", 176),
            ("motion", 357),
            ("replies", 12),
            ("health", 8),
            ("event", 4),
            ("end", 1),
        ],
    },
    Fixture {
        minor: 4,
        kinds: &[
            ("goal", 416),
            ("telemetry", 179),
            ("motion", 368),
            ("replies", 12),
            ("autopilot clock", 3),
            ("health", 8),
            ("event", 5),
            ("end", 1),
        ],
    },
];

/// Every kind's name, as `RecordBody::kind_name` gives it.
const KIND_NAMES: [&str; 10] = [
    "goal",
    "telemetry",
    "position",
    "motion",
    "replies",
    "autopilot clock",
    "health",
    "event",
    "dropped",
    "end",
];

impl Fixture {
    fn path(&self) -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/fixtures/records")
            .join(format!("format-1.{}.lj9rec", self.minor))
    }

    /// Records of every kind, 0 for the kinds the version did not write.
    fn expected_kinds(&self) -> BTreeMap<&'static str, usize> {
        KIND_NAMES
            .iter()
            .map(|&name| {
                let n = self
                    .kinds
                    .iter()
                    .find(|(k, _)| *k == name)
                    .map_or(0, |k| k.1);
                (name, n)
            })
            .collect()
    }

    fn records(&self) -> usize {
        self.kinds.iter().map(|k| k.1).sum()
    }
}

/// The servo table of `sitl`'s built-in airframe (mappings/sitl-default.toml), the same in
/// every version.
fn sitl_servos() -> Vec<RecordServo> {
    vec![
        RecordServo::new("aileron_left", "sim", 1, 1),
        RecordServo::new("aileron_right", "sim", 2, 2),
        RecordServo::new("elevator", "sim", 3, 3),
        RecordServo::new("rudder", "sim", 4, 4),
    ]
}

/// A position or a goal within the stroke, ±25 mm.
fn assert_in_stroke(position: MmCenti, what: &str) {
    assert!(position.mm().abs() <= 25.0, "{what}: {} mm", position.mm());
}

#[test]
fn files_written_by_formats_1_0_to_1_3_read_back_as_they_were_written() {
    for fixture in &FIXTURES {
        let minor = fixture.minor;
        let path = fixture.path();
        let rec = read_record(&path).unwrap();
        let at = |i: usize| format!("format 1.{minor}, record {i}");

        assert_eq!(rec.header.version, (1, minor), "{}", path.display());
        assert!(rec.closed, "format 1.{minor}: not closed");
        assert!(rec.notes.is_empty(), "format 1.{minor}: {:?}", rec.notes);
        assert_eq!(rec.header.part, 0);
        assert!(
            rec.header.software.starts_with("lj9da-bridge "),
            "{}",
            rec.header.software
        );
        assert_eq!(rec.header.servos, sitl_servos(), "format 1.{minor}");
        if minor < 4 {
            assert_eq!(
                rec.header.aircraft, None,
                "format 1.{minor} names no aircraft"
            );
        } else {
            // `sitl` without a mapping: the aircraft is the host name of the computer it ran on.
            assert!(
                rec.header.aircraft.as_ref().is_some_and(|a| !a.is_empty()),
                "format 1.{minor}: {:?}",
                rec.header.aircraft
            );
        }
        assert_eq!(rec.records.len(), fixture.records(), "format 1.{minor}");
        assert_eq!(
            rec.records.last().unwrap().body,
            RecordBody::End { continued: false }
        );

        let mut kinds: BTreeMap<&str, usize> = KIND_NAMES.iter().map(|&k| (k, 0)).collect();
        let mut samples = [0usize; 4];
        let mut motion_current = false;
        let mut answered = [0u32; 4];
        for (i, r) in rec.records.iter().enumerate() {
            *kinds.get_mut(r.body.kind_name()).unwrap() += 1;
            assert!(r.t_us < 10_000_000, "{}: at {} s", at(i), r.t_s());
            if let Some(servo) = r.body.servo() {
                assert!(servo < 4, "{}: servo {servo}", at(i));
            }
            match &r.body {
                RecordBody::Goal { goal, .. } => {
                    if let Goal::Position(p) = goal {
                        assert_in_stroke(*p, &at(i));
                    }
                }
                RecordBody::Telemetry {
                    servo,
                    telemetry: t,
                    flags,
                } => {
                    samples[usize::from(*servo)] += 1;
                    assert_in_stroke(t.present_position, &at(i));
                    let volts = t.present_voltage.volts();
                    assert!((11.5..=12.5).contains(&volts), "{}: {volts} V", at(i));
                    let celsius = t.present_temperature.0;
                    assert!((0..=80).contains(&celsius), "{}: {celsius} °C", at(i));
                    let amps = t.present_load.amps();
                    assert!((0.0..=5.0).contains(&amps), "{}: {amps} A", at(i));
                    assert_eq!(flags.meaningful(), ReplyFlags(0), "{}", at(i));
                }
                RecordBody::Position {
                    position, flags, ..
                } => {
                    assert_in_stroke(*position, &at(i));
                    assert_eq!(flags.meaningful(), ReplyFlags(0), "{}", at(i));
                }
                RecordBody::Motion {
                    motion: m, flags, ..
                } => {
                    assert_in_stroke(m.present_position, &at(i));
                    let amps = m.present_load.amps();
                    assert!((0.0..=5.0).contains(&amps), "{}: {amps} A", at(i));
                    motion_current |= m.present_load.0 > 0;
                    assert_eq!(flags.meaningful(), ReplyFlags(0), "{}", at(i));
                }
                RecordBody::Replies {
                    servo,
                    answered: good,
                    missed,
                } => {
                    let last = &mut answered[usize::from(*servo)];
                    assert!(*good >= *last, "{}: the count went down", at(i));
                    assert!(*missed <= *good, "{}: {good} good, {missed} bad", at(i));
                    *last = *good;
                }
                RecordBody::Health { .. }
                | RecordBody::Event { .. }
                | RecordBody::AutopilotClock { .. }
                | RecordBody::Dropped { .. }
                | RecordBody::End { .. } => {}
            }
        }
        assert_eq!(kinds, fixture.expected_kinds(), "format 1.{minor}");
        assert!(
            samples.iter().all(|&n| n > 0),
            "format 1.{minor}: telemetry samples per servo {samples:?}"
        );
        assert_eq!(
            motion_current,
            minor >= 3,
            "format 1.{minor}: motion current"
        );
        if minor >= 2 {
            assert!(
                answered.iter().all(|&n| n > 0),
                "format 1.{minor}: good replies per servo {answered:?}"
            );
        }

        let s = summary(&rec);
        assert!(s.closed);
        assert_eq!(s.records, fixture.records());
        assert_eq!(s.dropped, 0);
        assert!(
            (2.5..=4.0).contains(&s.duration_s),
            "format 1.{minor}: {} s",
            s.duration_s
        );
        assert_eq!(s.servos.len(), 4);
        for (servo, n) in s.servos.iter().zip(samples) {
            assert_eq!(
                servo.samples, n as u64,
                "format 1.{minor}: {}",
                servo.servo.name
            );
            let voltage = servo.voltage_v.unwrap();
            assert!(
                (11.5..=12.5).contains(&voltage.mean),
                "format 1.{minor}: {}: {voltage:?}",
                servo.servo.name
            );
            let temperature = servo.temperature_c.unwrap();
            assert!(
                temperature.min >= 0.0 && temperature.max <= 80.0,
                "format 1.{minor}: {}: {temperature:?}",
                servo.servo.name
            );
            assert!(servo.goals > 0, "format 1.{minor}: {}", servo.servo.name);
            assert!(
                servo.max_error_mm.is_some_and(|e| e <= 50.0),
                "format 1.{minor}: {}: {:?}",
                servo.servo.name,
                servo.max_error_mm
            );
            assert_eq!(servo.alarms(), 0, "format 1.{minor}: {}", servo.servo.name);
        }
    }
}

/// Run `lj9da-bridge record …`; returns its stdout, after checking it succeeded without notes.
fn record_cli(args: &[&OsStr]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_lj9da-bridge"))
        .arg("record")
        .args(args)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "record {args:?}: {stderr}");
    assert!(stderr.is_empty(), "record {args:?}: {stderr}");
    String::from_utf8(out.stdout).unwrap()
}

#[test]
fn record_help_names_every_subcommand_in_its_summary_and_examples() {
    let help = record_cli(&["--help".as_ref()]);
    let summary = help.lines().next().unwrap_or_default();
    for word in ["summary", "plots", "CSV", "trend"] {
        assert!(summary.contains(word), "{summary}");
    }
    for command in ["summary", "plot", "csv", "trend"] {
        assert!(
            help.contains(&format!("lj9da-bridge record {command} ")),
            "no example of {command}:\n{help}"
        );
    }
}

#[test]
fn record_summary_csv_and_plot_take_the_file_of_every_format() {
    let names: Vec<String> = sitl_servos().into_iter().map(|s| s.name).collect();
    for fixture in &FIXTURES {
        let minor = fixture.minor;
        let path = fixture.path();
        let dir = TempDir::new("fixture");

        let text = record_cli(&["summary".as_ref(), path.as_os_str()]);
        assert!(
            text.contains(&format!("{} records, closed cleanly", fixture.records())),
            "format 1.{minor}:\n{text}"
        );
        for name in &names {
            assert!(text.contains(name.as_str()), "format 1.{minor}:\n{text}");
        }

        let csv_path = dir.path().join("run.csv");
        record_cli(&[
            "csv".as_ref(),
            path.as_os_str(),
            "--out".as_ref(),
            csv_path.as_os_str(),
        ]);
        let csv = std::fs::read_to_string(&csv_path).unwrap();
        let mut lines = csv.lines();
        assert_eq!(lines.next(), Some(CSV_HEADER));
        let mut kinds: BTreeMap<&str, usize> = KIND_NAMES.iter().map(|&k| (k, 0)).collect();
        for line in lines {
            // No servo name holds a comma: the third field is the kind.
            let kind = line.split(',').nth(2).unwrap();
            *kinds
                .get_mut(kind)
                .unwrap_or_else(|| panic!("format 1.{minor}: kind {kind:?} in {line}")) += 1;
        }
        assert_eq!(kinds, fixture.expected_kinds(), "format 1.{minor}");

        let plots = dir.path().join("plots");
        let text = record_cli(&[
            "plot".as_ref(),
            path.as_os_str(),
            "--out".as_ref(),
            plots.as_os_str(),
        ]);
        let stem = format!("format-1.{minor}");
        let mut expected: Vec<PathBuf> = names
            .iter()
            .map(|name| plots.join(format!("{stem}-{name}.svg")))
            .collect();
        expected.push(plots.join(format!("{stem}.html")));
        let listed: Vec<PathBuf> = text.lines().map(PathBuf::from).collect();
        assert_eq!(listed, expected, "format 1.{minor}");
        for (file, name) in expected.iter().zip(&names) {
            let svg = std::fs::read_to_string(file).unwrap();
            assert!(svg.contains("<svg"), "{}", file.display());
            assert!(svg.contains(name.as_str()), "{}", file.display());
        }
        let page = std::fs::read_to_string(expected.last().unwrap()).unwrap();
        for name in &names {
            assert!(page.contains(name.as_str()), "format 1.{minor}: page");
        }
    }
}

#[test]
fn a_later_minor_version_s_unknown_kind_is_skipped_with_a_note() {
    let records = every_kind();
    let (mut bytes, _) = file_bytes(&records[..3]);
    // A kind-10 record with a correct CRC, as a later minor version might write.
    let inner = [4u8, 0, 10, 0, 1, 2];
    bytes.extend_from_slice(&inner);
    bytes.extend_from_slice(&lj9da_bridge::record::crc32(&inner).to_le_bytes());
    for r in &records[3..] {
        encode_record(r, &mut bytes);
    }
    let rec = Recording::from_bytes(&bytes).unwrap();
    assert_eq!(rec.records, records);
    assert!(
        rec.notes
            .iter()
            .any(|n| n.contains("skipped 1 records of kind 10")),
        "{:?}",
        rec.notes
    );
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    #[test]
    fn arbitrary_bytes_after_a_valid_header_never_panic(tail in proptest::collection::vec(any::<u8>(), 0..3000)) {
        let (mut bytes, _) = file_bytes(&[]);
        bytes.extend_from_slice(&tail);
        let rec = Recording::from_bytes(&bytes);
        prop_assert!(rec.is_ok());
    }

    #[test]
    fn garbage_after_whole_records_never_hides_them(
        n in 0usize..17,
        tail in proptest::collection::vec(any::<u8>(), 0..600),
    ) {
        let records = every_kind();
        let (mut bytes, _) = file_bytes(&records[..n]);
        bytes.extend_from_slice(&tail);
        let rec = Recording::from_bytes(&bytes).unwrap();
        prop_assert_eq!(&rec.records[..n], &records[..n]);
    }

    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
        let _ = Recording::from_bytes(&bytes);
        let mut with_magic = b"LJ9DAREC".to_vec();
        with_magic.extend_from_slice(&bytes);
        let _ = Recording::from_bytes(&with_magic);
    }
}

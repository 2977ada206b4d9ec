//! The flight record format: every record kind round-trips through the recorder and the
//! reader, and a damaged file reads back everything before the damage, with a note.

mod tempdir;

use lj9da_bridge::bus::{Goal, Health};
use lj9da_bridge::protocol::{Celsius, Ma10, MmCenti, Motion, Ms10, Mv10, ReplyFlags, Telemetry};
use lj9da_bridge::record::format::{
    HeaderError, MAX_EVENT_TEXT, RecordHeader, RecordServo, encode_header, encode_record,
};
use lj9da_bridge::record::{
    Record, RecordBody, RecordError, RecordLimits, Recorder, Recording, read_record,
};
use proptest::prelude::*;
use std::path::{Path, PathBuf};
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
    assert_eq!(rec.header.version, (1, 3));
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

#[test]
fn files_of_formats_1_0_to_1_2_still_read() {
    // The kinds each older version had: 1.0 no position or replies records, 1.1 no replies,
    // and none of them motion records.
    let v1_2: Vec<Record> = every_kind()
        .into_iter()
        .filter(|r| !matches!(r.body, RecordBody::Motion { .. }))
        .collect();
    let older: Vec<Record> = v1_2
        .iter()
        .filter(|r| !matches!(r.body, RecordBody::Replies { .. }))
        .cloned()
        .collect();
    for (minor, records) in [
        (
            0u16,
            older
                .iter()
                .filter(|r| !matches!(r.body, RecordBody::Position { .. }))
                .cloned()
                .collect::<Vec<_>>(),
        ),
        (1, older.clone()),
        (2, v1_2),
    ] {
        let mut header = RecordHeader::new(1_763_769_599_000_000_000, servos());
        header.version = (1, minor);
        let mut bytes = encode_header(&header);
        for r in &records {
            encode_record(r, &mut bytes);
        }
        let rec = Recording::from_bytes(&bytes).unwrap();
        assert_eq!(rec.header.version, (1, minor));
        assert_eq!(rec.records, records, "format 1.{minor}");
    }
}

#[test]
fn a_later_minor_version_s_unknown_kind_is_skipped_with_a_note() {
    let records = every_kind();
    let (mut bytes, _) = file_bytes(&records[..3]);
    // A kind-9 record with a correct CRC, as a later minor version might write.
    let inner = [4u8, 0, 9, 0, 1, 2];
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
            .any(|n| n.contains("skipped 1 records of kind 9")),
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

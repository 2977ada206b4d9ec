use super::*;
use crate::protocol::{Celsius, Ma10, MmCenti, Ms10, Mv10, ReplyFlags, Telemetry};
use crate::record::format::{Record, RecordHeader, RecordServo};
use std::collections::BTreeMap;

const WRAP: u64 = 1 << 32;

fn clock(t_us: u64, time_usec: u64, bits: u8) -> ClockSample {
    ClockSample {
        t_us,
        time_usec,
        bits,
    }
}

#[test]
fn without_clock_samples_there_is_no_offset() {
    assert_eq!(autopilot_offset_us([]), None);
}

#[test]
fn the_offset_is_the_median_difference_of_64_bit_samples() {
    let boot = 5_000_000_000u64; // the autopilot was up 83 min when the run started
    // Differences of boot + 40, + 10, + 30, + 900 (one late message), + 20: median boot + 30.
    let late = [40, 10, 30, 900, 20];
    let samples = late
        .iter()
        .enumerate()
        .map(|(i, &d)| clock(i as u64 * 1_000_000, boot + i as u64 * 1_000_000 + d, 64));
    assert_eq!(autopilot_offset_us(samples), Some(boot as i64 + 30));
    // An even count takes the lower middle difference.
    let samples = [10, 40, 20, 30]
        .iter()
        .enumerate()
        .map(|(i, &d)| clock(i as u64 * 1_000_000, boot + i as u64 * 1_000_000 + d, 64));
    assert_eq!(autopilot_offset_us(samples), Some(boot as i64 + 20));
}

#[test]
fn a_32_bit_clock_is_unwrapped_with_the_record_time() {
    // Up for 71.5 min at the run's start: the 32-bit clock wraps 5 s into the run.
    let boot = WRAP - 5_000_000;
    let samples: Vec<_> = (0..10u64)
        .map(|s| {
            let t = s * 1_000_000 + 7;
            clock(t, (boot + t + 100 + s) % WRAP, 32)
        })
        .collect();
    assert!(samples.iter().any(|s| s.time_usec < 1_000_000), "it wraps");
    // Differences boot + 100 … boot + 109: the lower median is boot + 104.
    assert_eq!(autopilot_offset_us(samples), Some(boot as i64 + 104));
}

#[test]
fn a_64_bit_sample_gives_a_32_bit_clock_its_turns() {
    // Up for 3 h: only a 64-bit sample tells how many times the 32-bit clock wrapped.
    let boot = 3 * 3_600_000_000u64;
    let mut samples: Vec<_> = (0..6u64)
        .map(|s| clock(s * 1_000_000, (boot + s * 1_000_000) % WRAP, 32))
        .collect();
    assert_eq!(
        autopilot_offset_us(samples.clone()),
        Some((boot % WRAP) as i64),
        "32-bit samples alone: whole turns early"
    );
    samples.push(clock(6_000_000, boot + 6_000_000, 64));
    assert_eq!(autopilot_offset_us(samples), Some(boot as i64));
}

#[test]
fn after_an_autopilot_restart_the_clock_of_most_samples_wins() {
    // Up for 10 s at the start; restarted 3 s into the run, up again for 0.5 s at 3.5 s.
    let before = (0..3u64).map(|s| clock(s * 1_000_000, 10_000_000 + s * 1_000_000, 64));
    let after = (4..10u64).map(|s| clock(s * 1_000_000, s * 1_000_000 - 3_500_000, 64));
    assert_eq!(autopilot_offset_us(before.chain(after)), Some(-3_500_000));
}

fn servos() -> Vec<RecordServo> {
    vec![
        RecordServo::new("left", "wing", 1, 1),
        RecordServo::new("right", "wing", 2, 2),
    ]
}

fn recording(records: Vec<Record>) -> Recording {
    Recording {
        header: RecordHeader::new(1_763_769_599_123_456_789, servos()),
        records,
        notes: vec!["a note".to_string()],
        closed: false,
    }
}

fn telemetry(t_us: u64, servo: u8) -> Record {
    Record {
        t_us,
        body: RecordBody::Telemetry {
            servo,
            telemetry: Telemetry {
                present_position: MmCenti(-1234),
                present_time: Ms10(3),
                present_load: Ma10(45),
                present_temperature: Celsius(31),
                present_voltage: Mv10(1200),
            },
            flags: ReplyFlags(0x20),
        },
    }
}

fn autopilot_clock(t_us: u64, time_usec: u64) -> Record {
    Record {
        t_us,
        body: RecordBody::AutopilotClock {
            time_usec,
            bits: 64,
        },
    }
}

#[test]
fn the_time_base_is_the_autopilot_boot_only_when_every_time_fits() {
    let plain = recording(vec![telemetry(100, 0)]);
    assert_eq!(time_base(&plain), TimeBase::RunStart);
    let aligned = recording(vec![
        telemetry(100, 0),
        autopilot_clock(200, 9_000_200),
        telemetry(300, 1),
    ]);
    assert_eq!(
        time_base(&aligned),
        TimeBase::AutopilotBoot {
            offset_us: 9_000_000
        }
    );
    // The autopilot booted 1 s after the run started: the run's start is no ULog timestamp.
    let late_boot = recording(vec![
        telemetry(100, 0),
        autopilot_clock(2_000_000, 1_000_000),
    ]);
    assert_eq!(time_base(&late_boot), TimeBase::RunStart);
}

#[test]
fn every_16_bit_register_value_comes_back_from_its_float() {
    for raw in i32::from(i16::MIN)..=i32::from(u16::MAX) {
        let back = (f64::from(hundredths(raw)) * 100.0).round();
        assert_eq!(back, f64::from(raw), "raw {raw}");
    }
}

/// A ULog file's messages: (type, body), after checking the header.
fn messages(bytes: &[u8]) -> Vec<(u8, &[u8])> {
    assert_eq!(bytes.get(..7), Some(&MAGIC[..]));
    assert_eq!(bytes.get(7), Some(&VERSION));
    let mut pos = 16;
    let mut out = Vec::new();
    while pos < bytes.len() {
        let head = bytes.get(pos..pos + 3).expect("a whole message header");
        let size = usize::from(u16::from_le_bytes([head[0], head[1]]));
        let body = bytes
            .get(pos + 3..pos + 3 + size)
            .expect("a whole message body");
        out.push((head[2], body));
        pos += 3 + size;
    }
    out
}

fn u16_at(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes(b[at..at + 2].try_into().unwrap())
}

fn u64_at(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(b[at..at + 8].try_into().unwrap())
}

#[test]
fn the_file_is_framed_as_the_ulog_specification_says() {
    let mut records = vec![
        telemetry(500, 1),
        telemetry(100, 1), // out of time order in the record
        autopilot_clock(200, 9_000_200),
        Record {
            t_us: 300,
            body: RecordBody::Event {
                servo: Some(1),
                severity: 4,
                text: "right: temperature alarm".into(),
            },
        },
        Record {
            t_us: 400,
            body: RecordBody::Dropped { count: 3 },
        },
    ];
    records.push(Record {
        t_us: 600,
        body: RecordBody::End { continued: false },
    });
    let bytes = encode_ulog(&recording(records));
    assert_eq!(
        u64_at(&bytes, 8),
        9_000_000,
        "the log starts at the run's start"
    );
    let msgs = messages(&bytes);
    let kinds: String = msgs.iter().map(|(k, _)| char::from(*k)).collect();
    // B first, then definitions, then subscriptions, then data and strings in time order.
    let definitions = format!("BFFFFFFFFF{}M", "I".repeat(9 + 2 * 4));
    assert!(kinds.starts_with(&definitions), "{kinds}");
    assert_eq!(msgs[0].1, &[0u8; 40][..], "no flags, no appended data");
    let rest = &kinds[definitions.len()..];
    // Telemetry for both servos of the table (instances 0 and 1), event, dropped, clock.
    assert_eq!(rest, "AAAAADDDLDLD", "{kinds}");

    let mut info = BTreeMap::new();
    for (_, body) in msgs.iter().filter(|(k, _)| *k == b'I') {
        let key_len = usize::from(body[0]);
        let key = std::str::from_utf8(&body[1..1 + key_len]).unwrap();
        let (kind, name) = key.split_once(' ').unwrap();
        let value = &body[1 + key_len..];
        if let Some(len) = kind.strip_prefix("char[") {
            assert_eq!(len, format!("{}]", value.len()), "{key}");
        }
        assert!(
            info.insert(name.to_string(), value.to_vec()).is_none(),
            "{name} twice"
        );
    }
    assert_eq!(info["sys_name"], b"lj9da-bridge");
    assert_eq!(info["lj9da_time_base"], b"autopilot boot");
    assert_eq!(info["lj9da_time_offset_us"], 9_000_000i64.to_le_bytes());
    assert_eq!(info["lj9da_run_start_utc"], b"2025-11-21T23:59:59.123456Z");
    assert_eq!(info["lj9da_servo_1_name"], b"right");
    assert_eq!(info["lj9da_servo_1_id"], [2]);

    // Subscriptions: msg_id from 0 up, names of format messages, per-servo multi_ids.
    let subs: Vec<(u8, u16, String)> = msgs
        .iter()
        .filter(|(k, _)| *k == b'A')
        .map(|(_, b)| {
            (
                b[0],
                u16_at(b, 1),
                String::from_utf8(b[3..].to_vec()).unwrap(),
            )
        })
        .collect();
    assert_eq!(
        subs,
        [
            (0, 0, "lj9da_telemetry".to_string()),
            (1, 1, "lj9da_telemetry".to_string()),
            (0, 2, "lj9da_event".to_string()),
            (0, 3, "lj9da_dropped".to_string()),
            (0, 4, "lj9da_autopilot_clock".to_string()),
        ]
    );
    // Data: msg_id, then the timestamp, in time order.
    let data: Vec<(u16, u64)> = msgs
        .iter()
        .filter(|(k, _)| *k == b'D')
        .map(|(_, b)| (u16_at(b, 0), u64_at(b, 2)))
        .collect();
    let at = |t: u64| 9_000_000 + t;
    assert_eq!(
        data,
        [
            (1, at(100)),
            (4, at(200)),
            (2, at(300)),
            (3, at(400)),
            (1, at(500))
        ]
    );
    let telemetry = msgs.iter().find(|(k, _)| *k == b'D').unwrap().1;
    assert_eq!(telemetry.len(), 2 + 8 + 4 * 4 + 2 + 1);
    let logged: Vec<(u8, u64, String)> = msgs
        .iter()
        .filter(|(k, _)| *k == b'L')
        .map(|(_, b)| {
            (
                b[0],
                u64_at(b, 1),
                String::from_utf8(b[9..].to_vec()).unwrap(),
            )
        })
        .collect();
    assert_eq!(
        logged[0],
        (b'4', at(300), "right: temperature alarm".to_string())
    );
    assert_eq!((logged[1].0, logged[1].1), (b'4', at(400)));
    assert!(logged[1].2.contains("3 records dropped"), "{}", logged[1].2);
}

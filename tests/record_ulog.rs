//! `lj9da-bridge record ulog`: records exported as ULog files by the real binary and read back
//! by PX4's own reader, the real `pyulog` (from PyPI, see `common/python.rs`), which must find
//! every sample of the record, in the topic and instance of its kind and servo, with the
//! recorded values and times to the µs: for a record whose contents this test writes, for a
//! record a real `sitl` run wrote, for the file each format version wrote
//! (tests/fixtures/records), for a record cut in the middle, and for a record that holds the
//! autopilot's clock (its timestamps then count from the autopilot's boot).
//!
//! The expected ULog contents are built here from the records by the rules of
//! `src/record/ulog.rs`'s documentation (docs/export.md), not by the exporter's code.

mod common;
mod tempdir;

use common::python::data_python;
use common::sitl::sitl_records;
use lj9da_bridge::bus::{Goal, Health};
use lj9da_bridge::protocol::{Celsius, Ma10, MmCenti, Motion, Ms10, Mv10, ReplyFlags, Telemetry};
use lj9da_bridge::record::format::{
    RecordHeader, RecordServo, encode_header, encode_record, health_code,
};
use lj9da_bridge::record::{Record, RecordBody, read_record};
use serde_json::Value;
use std::collections::{BTreeMap, BTreeSet};
use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use tempdir::TempDir;

const BIN: &str = env!("CARGO_BIN_EXE_lj9da-bridge");

/// Reads a ULog file with pyulog and prints, as one line of JSON, everything it decoded. A
/// float32 column is given as its values' bits (`{"f32": [...]}`), integers as they are
/// (`{"int": [...]}`): decimal text of a float would round on the way.
const READ_BACK: &str = r#"
import json, sys
import numpy as np
from pyulog import ULog
u = ULog(sys.argv[1])
def plain(v):
    return v if isinstance(v, (int, float, str)) else repr(v)
def column(v):
    if v.dtype == np.float32:
        return {"f32": np.ascontiguousarray(v).view(np.uint32).tolist()}
    if np.issubdtype(v.dtype, np.integer):
        return {"int": v.tolist()}
    return {str(v.dtype): repr(v)}
print(json.dumps({
    "start": u.start_timestamp,
    "corrupt": bool(u.file_corruption),
    "info": {k: plain(v) for k, v in u.msg_info_dict.items()},
    "multi": u.msg_info_multiple_dict,
    "data": [{"name": d.name, "multi_id": d.multi_id,
              "fields": {k: column(v) for k, v in d.data.items()}} for d in u.data_list],
    "logged": [[m.log_level, m.timestamp, m.message] for m in u.logged_messages],
}))
"#;

/// What pyulog decoded from a file (stdout must be the JSON alone: pyulog prints its warnings
/// about a malformed file, a missing subscription or a misplaced flag bits message there).
fn pyulog(ulg: &Path) -> Value {
    let out = Command::new(data_python())
        .arg("-c")
        .arg(READ_BACK)
        .arg(ulg)
        .output()
        .expect("the data Python runs");
    assert!(
        out.status.success(),
        "pyulog could not read {}: {}",
        ulg.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8(out.stdout).expect("UTF-8 from pyulog");
    let lines: Vec<&str> = stdout.lines().collect();
    assert_eq!(
        lines.len(),
        1,
        "pyulog printed more than its JSON about {}:\n{stdout}",
        ulg.display()
    );
    let json: Value = serde_json::from_str(lines[0]).expect("pyulog's JSON");
    assert_eq!(
        json["corrupt"],
        false,
        "pyulog found {} corrupt",
        ulg.display()
    );
    json
}

/// Run `lj9da-bridge record ulog` with `args`.
fn export(args: &[&OsStr]) -> Output {
    Command::new(BIN)
        .args(["record", "ulog"])
        .args(args)
        .stdin(Stdio::null())
        .output()
        .expect("lj9da-bridge runs")
}

/// Export `record` into `out`: the ULog file written, after checking the command said so.
fn export_into(record: &Path, out: &Path) -> (PathBuf, String) {
    let done = export(&[record.as_os_str(), "--out".as_ref(), out.as_os_str()]);
    let stderr = String::from_utf8_lossy(&done.stderr).into_owned();
    assert!(done.status.success(), "{:?}: {stderr}", done.status);
    let stem = record.file_stem().unwrap().to_string_lossy();
    let ulg = out.join(format!("{stem}.ulg"));
    assert_eq!(
        String::from_utf8_lossy(&done.stdout),
        format!("{}\n", ulg.display()),
        "the file written, on stdout"
    );
    (ulg, stderr)
}

/// A field's expected value.
#[derive(Debug, Clone, PartialEq)]
enum V {
    /// An integer field.
    Int(i128),
    /// A float32 field holding a register value ÷ 100: × 100 and rounded, the value.
    Hundredths(i32),
}

/// A field's value as pyulog decoded it.
#[derive(Debug, Clone, PartialEq)]
enum Got {
    Int(Value),
    F32(f32),
}

/// A logged string's expected text.
#[derive(Debug, Clone, PartialEq)]
enum Text {
    Exact(String),
    /// A note that names these words.
    Mentions(Vec<String>),
}

type Row = BTreeMap<&'static str, V>;

#[derive(Debug, Default)]
struct Expected {
    /// Per (topic, multi_id): the samples in time order.
    data: BTreeMap<(String, u8), Vec<Row>>,
    /// Logged strings: (level, timestamp, text), in time order.
    logged: Vec<(u8, u64, Text)>,
}

fn goal_code(goal: Goal) -> (i128, i16) {
    match goal {
        Goal::Position(p) => (0, p.0),
        Goal::Hold => (1, 0),
        Goal::Off => (2, 0),
        Goal::Brake => (3, 0),
    }
}

/// What the ULog file of `records` must hold, its timestamps moved by `offset_us`: the
/// documented topics and fields, samples of equal time in the record's order.
fn expected(records: &[Record], offset_us: i64) -> Expected {
    let mut sorted = records.to_vec();
    sorted.sort_by_key(|r| r.t_us);
    let mut e = Expected::default();
    let h = |raw: i32| V::Hundredths(raw);
    for r in &sorted {
        let t = u64::try_from(i128::from(r.t_us) + i128::from(offset_us)).unwrap();
        let mut row: Row = BTreeMap::from([("timestamp", V::Int(i128::from(t)))]);
        let (topic, multi_id) = match &r.body {
            RecordBody::Goal { servo, goal } => {
                let (code, position) = goal_code(*goal);
                row.insert("goal", V::Int(code));
                row.insert("position_mm", h(i32::from(position)));
                ("lj9da_goal", *servo)
            }
            RecordBody::Telemetry {
                servo,
                telemetry: tm,
                flags,
            } => {
                row.insert("position_mm", h(i32::from(tm.present_position.0)));
                row.insert("present_time_s", h(i32::from(tm.present_time.0)));
                row.insert("current_a", h(i32::from(tm.present_load.0)));
                row.insert("voltage_v", h(i32::from(tm.present_voltage.0)));
                row.insert(
                    "temperature_c",
                    V::Int(i128::from(tm.present_temperature.0)),
                );
                row.insert("flags", V::Int(i128::from(flags.0)));
                ("lj9da_telemetry", *servo)
            }
            RecordBody::Position {
                servo,
                position,
                flags,
            } => {
                row.insert("position_mm", h(i32::from(position.0)));
                row.insert("flags", V::Int(i128::from(flags.0)));
                ("lj9da_position", *servo)
            }
            RecordBody::Motion {
                servo,
                motion: m,
                flags,
            } => {
                row.insert("position_mm", h(i32::from(m.present_position.0)));
                row.insert("present_time_s", h(i32::from(m.present_time.0)));
                row.insert("current_a", h(i32::from(m.present_load.0)));
                row.insert("flags", V::Int(i128::from(flags.0)));
                ("lj9da_motion", *servo)
            }
            RecordBody::Replies {
                servo,
                answered,
                missed,
            } => {
                row.insert("answered", V::Int(i128::from(*answered)));
                row.insert("missed", V::Int(i128::from(*missed)));
                ("lj9da_replies", *servo)
            }
            RecordBody::Health {
                servo,
                health,
                stalled,
            } => {
                row.insert("health", V::Int(i128::from(health_code(*health))));
                row.insert("stalled", V::Int(i128::from(*stalled)));
                ("lj9da_health", *servo)
            }
            RecordBody::Event {
                servo,
                severity,
                text,
            } => {
                row.insert("servo", V::Int(i128::from(servo.unwrap_or(255))));
                row.insert("severity", V::Int(i128::from(*severity)));
                e.logged
                    .push((b'0' + (*severity).min(7), t, Text::Exact(text.clone())));
                ("lj9da_event", 0)
            }
            RecordBody::Dropped { count } => {
                row.insert("count", V::Int(i128::from(*count)));
                e.logged.push((
                    b'4',
                    t,
                    Text::Mentions(vec![count.to_string(), "dropped".to_string()]),
                ));
                ("lj9da_dropped", 0)
            }
            RecordBody::AutopilotClock { time_usec, bits } => {
                row.insert("time_usec", V::Int(i128::from(*time_usec)));
                row.insert("bits", V::Int(i128::from(*bits)));
                ("lj9da_autopilot_clock", 0)
            }
            RecordBody::End { .. } => continue,
        };
        e.data
            .entry((topic.to_string(), multi_id))
            .or_default()
            .push(row);
    }
    e
}

/// Check that pyulog's reading `got` of a file holds exactly `want`: every topic and instance,
/// every sample with every field, every logged string.
fn check(what: &str, got: &Value, want: &Expected) {
    let mut decoded: BTreeMap<(String, u8), Vec<BTreeMap<String, Got>>> = BTreeMap::new();
    for d in got["data"].as_array().unwrap() {
        let key = (
            d["name"].as_str().unwrap().to_string(),
            u8::try_from(d["multi_id"].as_u64().unwrap()).unwrap(),
        );
        let fields = d["fields"].as_object().unwrap();
        let n = fields["timestamp"]["int"].as_array().unwrap().len();
        let rows = (0..n)
            .map(|i| {
                fields
                    .iter()
                    .map(|(name, column)| {
                        let value = match (column.get("int"), column.get("f32")) {
                            (Some(ints), _) => Got::Int(ints[i].clone()),
                            (_, Some(bits)) => Got::F32(f32::from_bits(
                                u32::try_from(bits[i].as_u64().unwrap()).unwrap(),
                            )),
                            _ => panic!("{what}: {key:?}: {name} is neither integer nor float32"),
                        };
                        (name.clone(), value)
                    })
                    .collect()
            })
            .collect();
        assert!(decoded.insert(key.clone(), rows).is_none(), "{key:?} twice");
    }
    assert_eq!(
        decoded.keys().collect::<Vec<_>>(),
        want.data.keys().collect::<Vec<_>>(),
        "{what}: the topics and instances"
    );
    for (key, rows) in &want.data {
        let got_rows = &decoded[key];
        assert_eq!(got_rows.len(), rows.len(), "{what}: samples of {key:?}");
        for (i, (want_row, got_row)) in rows.iter().zip(got_rows).enumerate() {
            let names: BTreeSet<&str> = got_row.keys().map(String::as_str).collect();
            assert_eq!(
                names,
                want_row.keys().copied().collect::<BTreeSet<&str>>(),
                "{what}: fields of {key:?}"
            );
            for (field, value) in want_row {
                let v = &got_row[*field];
                let ok = match (value, v) {
                    (V::Int(n), Got::Int(v)) => {
                        v.as_u64()
                            .map(i128::from)
                            .or_else(|| v.as_i64().map(i128::from))
                            == Some(*n)
                    }
                    (V::Hundredths(raw), Got::F32(f)) => {
                        (f64::from(*f) * 100.0).round() == f64::from(*raw)
                    }
                    _ => false,
                };
                assert!(
                    ok,
                    "{what}: {key:?} sample {i} (time {:?}): {field} is {v:?}, expected {value:?}",
                    want_row["timestamp"]
                );
            }
        }
    }
    let logged = got["logged"].as_array().unwrap();
    assert_eq!(logged.len(), want.logged.len(), "{what}: logged strings");
    for (i, (l, (level, t, text))) in logged.iter().zip(&want.logged).enumerate() {
        assert_eq!(
            l[0],
            u64::from(*level),
            "{what}: level of logged string {i}"
        );
        assert_eq!(l[1], *t, "{what}: time of logged string {i}");
        let message = l[2].as_str().unwrap();
        match text {
            Text::Exact(s) => assert_eq!(message, s, "{what}: logged string {i}"),
            Text::Mentions(words) => assert!(
                words.iter().all(|w| message.contains(w.as_str())),
                "{what}: logged string {i} {message:?} does not name {words:?}"
            ),
        }
    }
}

fn info(got: &Value, key: &str) -> Value {
    got["info"][key].clone()
}

fn servos() -> Vec<RecordServo> {
    vec![
        RecordServo::new("aileron_left", "wing", 1, 1),
        RecordServo::new("aileron_right", "wing", 2, 2),
        RecordServo::new("élévateur", "tail", 127, 32),
    ]
}

/// 2025-11-21T23:59:59.123456789Z.
const RUN_START_NS: i64 = 1_763_769_599_123_456_789;

fn telemetry(position: i16, load: u16, temperature: i16, voltage: u16, time: u16) -> Telemetry {
    Telemetry {
        present_position: MmCenti(position),
        present_time: Ms10(time),
        present_load: Ma10(load),
        present_temperature: Celsius(temperature),
        present_voltage: Mv10(voltage),
    }
}

/// Every kind of record, for all three servos and the bridge, with the extreme values of
/// each field, every health, goal and event severity (and one beyond MAV_SEVERITY's), two
/// dropped records, records out of time order and records of equal time, and a time 9.5 h
/// into the run.
fn every_kind() -> Vec<Record> {
    let mut r = Vec::new();
    let mut at = |t_us: u64, body: RecordBody| r.push(Record { t_us, body });
    at(
        0,
        RecordBody::Health {
            servo: 0,
            health: Health::Starting,
            stalled: false,
        },
    );
    at(
        0,
        RecordBody::Goal {
            servo: 0,
            goal: Goal::Position(MmCenti(-2500)),
        },
    );
    at(
        1_000,
        RecordBody::Goal {
            servo: 1,
            goal: Goal::Position(MmCenti(2500)),
        },
    );
    at(
        1_000,
        RecordBody::Goal {
            servo: 2,
            goal: Goal::Hold,
        },
    );
    at(
        10_000,
        RecordBody::Telemetry {
            servo: 0,
            telemetry: telemetry(-1234, u16::MAX, -40, 0, 7),
            flags: ReplyFlags(0xAA),
        },
    );
    at(
        20_000,
        RecordBody::Telemetry {
            servo: 2,
            telemetry: telemetry(i16::MAX, 0, i16::MIN, u16::MAX, u16::MAX),
            flags: ReplyFlags(0),
        },
    );
    // Heard before the previous one, recorded after it.
    at(
        15_000,
        RecordBody::Telemetry {
            servo: 1,
            telemetry: telemetry(i16::MIN, 1, i16::MAX, 1199, 0),
            flags: ReplyFlags(0x20),
        },
    );
    // Heard before the first telemetry of the same servo, recorded after it.
    at(
        9_000,
        RecordBody::Telemetry {
            servo: 0,
            telemetry: telemetry(1, 37, 31, 1201, 1),
            flags: ReplyFlags(0),
        },
    );
    at(
        30_000,
        RecordBody::Position {
            servo: 1,
            position: MmCenti(-2500),
            flags: ReplyFlags(0x20),
        },
    );
    at(
        30_000,
        RecordBody::Position {
            servo: 2,
            position: MmCenti(i16::MAX),
            flags: ReplyFlags(0),
        },
    );
    at(
        30_000,
        RecordBody::Position {
            servo: 1,
            position: MmCenti(-2499),
            flags: ReplyFlags(0x08),
        },
    );
    at(
        30_500,
        RecordBody::Position {
            servo: 0,
            position: MmCenti(0),
            flags: ReplyFlags(0),
        },
    );
    at(
        40_002,
        RecordBody::Motion {
            servo: 1,
            motion: Motion {
                present_position: MmCenti(5),
                present_time: Ms10(1),
                present_load: Ma10(1),
            },
            flags: ReplyFlags(0x20),
        },
    );
    at(
        40_000,
        RecordBody::Motion {
            servo: 0,
            motion: Motion {
                present_position: MmCenti(-2500),
                present_time: Ms10(0),
                present_load: Ma10(u16::MAX),
            },
            flags: ReplyFlags(0x80),
        },
    );
    at(
        40_001,
        RecordBody::Motion {
            servo: 2,
            motion: Motion {
                present_position: MmCenti(i16::MIN),
                present_time: Ms10(u16::MAX),
                present_load: Ma10(0),
            },
            flags: ReplyFlags(0),
        },
    );
    for (servo, answered, missed) in [(0, 123_456, 7), (1, 0, u32::MAX), (2, u32::MAX, 0)] {
        at(
            1_000_000,
            RecordBody::Replies {
                servo,
                answered,
                missed,
            },
        );
    }
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
        at(
            2_000_000 + i as u64,
            RecordBody::Health {
                servo: (i % 3) as u8,
                health,
                stalled: i % 2 == 0,
            },
        );
    }
    at(
        3_000_000,
        RecordBody::Goal {
            servo: 1,
            goal: Goal::Off,
        },
    );
    at(
        3_000_000,
        RecordBody::Goal {
            servo: 2,
            goal: Goal::Brake,
        },
    );
    for severity in 0..=7u8 {
        at(
            4_000_000 + u64::from(severity) * 1_000,
            RecordBody::Event {
                servo: (severity % 2 == 1).then_some(severity % 3),
                severity,
                text: format!("severity {severity}: LJ9DA \"failsafe\", — ünïcödé"),
            },
        );
    }
    // An event recorded after later ones.
    at(
        3_999_999,
        RecordBody::Event {
            servo: None,
            severity: 5,
            text: "heard first, recorded late".into(),
        },
    );
    at(
        4_100_000,
        RecordBody::Event {
            servo: Some(2),
            severity: 200,
            text: String::new(),
        },
    );
    at(4_100_000, RecordBody::Dropped { count: 42 });
    at(
        4_100_000,
        RecordBody::Event {
            servo: None,
            severity: 6,
            text: "after the drop".into(),
        },
    );
    at(5_000_000, RecordBody::Dropped { count: u64::MAX });
    // 9.5 h into the run.
    at(
        34_200_000_000,
        RecordBody::Telemetry {
            servo: 1,
            telemetry: telemetry(100, 50, 60, 1150, 3),
            flags: ReplyFlags(0),
        },
    );
    at(34_200_000_001, RecordBody::End { continued: false });
    r
}

fn header() -> RecordHeader {
    RecordHeader::new(RUN_START_NS, servos()).with_aircraft(Some("VT-LJ9 «Ørn»"))
}

/// A record file of `records` and where each record starts in it.
fn file_bytes(header: &RecordHeader, records: &[Record]) -> (Vec<u8>, Vec<usize>) {
    let mut bytes = encode_header(header);
    let mut starts = Vec::new();
    for r in records {
        starts.push(bytes.len());
        encode_record(r, &mut bytes);
    }
    (bytes, starts)
}

/// The servo table and the header's facts, in the information messages.
fn check_header_info(got: &Value, header: &RecordHeader) {
    assert_eq!(info(got, "sys_name"), "lj9da-bridge");
    assert_eq!(info(got, "ver_sw"), header.software.as_str());
    assert_eq!(
        info(got, "lj9da_record_format"),
        format!("{}.{}", header.version.0, header.version.1).as_str()
    );
    assert_eq!(info(got, "lj9da_record_part"), header.part);
    assert_eq!(
        info(got, "lj9da_run_start_unix_ns"),
        header.run_start_unix_ns
    );
    match &header.aircraft {
        Some(a) => assert_eq!(info(got, "lj9da_aircraft"), a.as_str()),
        None => assert_eq!(info(got, "lj9da_aircraft"), Value::Null),
    }
    assert_eq!(info(got, "lj9da_servo_count"), header.servos.len());
    for (i, s) in header.servos.iter().enumerate() {
        assert_eq!(info(got, &format!("lj9da_servo_{i}_name")), s.name.as_str());
        assert_eq!(info(got, &format!("lj9da_servo_{i}_bus")), s.bus.as_str());
        assert_eq!(info(got, &format!("lj9da_servo_{i}_id")), s.id);
        assert_eq!(info(got, &format!("lj9da_servo_{i}_channel")), s.channel);
    }
    assert_eq!(
        info(got, &format!("lj9da_servo_{}_name", header.servos.len())),
        Value::Null
    );
}

#[test]
fn every_sample_of_a_known_record_comes_back_from_pyulog() {
    let dir = TempDir::new("ulog-known");
    let records = every_kind();
    let header = header();
    let file = dir.path().join("20251121T235959Z.lj9rec");
    std::fs::write(&file, file_bytes(&header, &records).0).unwrap();

    // Beside the record by default.
    let done = export(&[file.as_os_str()]);
    let stderr = String::from_utf8_lossy(&done.stderr);
    assert!(done.status.success(), "{:?}: {stderr}", done.status);
    assert_eq!(stderr, "", "a record closed cleanly exports without a note");
    let ulg = dir.path().join("20251121T235959Z.ulg");
    assert_eq!(
        String::from_utf8_lossy(&done.stdout),
        format!("{}\n", ulg.display())
    );
    let leftovers: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(
        leftovers.len(),
        2,
        "only the record and its ULog: {leftovers:?}"
    );

    let got = pyulog(&ulg);
    let want = expected(&records, 0);
    assert_eq!(
        want.data.len(),
        3 * 6 + 2,
        "every per-servo topic for every servo"
    );
    check("the known record", &got, &want);
    check_header_info(&got, &header);
    check_time_base(&got, "run start", 0);
    assert_eq!(
        info(&got, "lj9da_run_start_utc"),
        "2025-11-21T23:59:59.123456Z"
    );
    assert_eq!(got["multi"], serde_json::json!({}), "no notes");
}

#[test]
fn a_record_cut_in_the_middle_exports_what_it_holds_and_says_what_it_could_not() {
    let dir = TempDir::new("ulog-cut");
    let records = every_kind();
    let header = header();
    let (bytes, starts) = file_bytes(&header, &records);
    // Cut 5 bytes into a record in the middle, as a power loss leaves a file.
    let cut_at = records.len() / 2;
    let file = dir.path().join("cut.lj9rec");
    std::fs::write(&file, &bytes[..starts[cut_at] + 5]).unwrap();
    let notes = read_record(&file).unwrap().notes;
    assert_eq!(
        notes.len(),
        2,
        "the cut record and the missing end: {notes:?}"
    );

    let (ulg, stderr) = export_into(&file, &dir.path().join("out"));
    for note in &notes {
        assert!(
            stderr.contains(&format!("note: {}: {note}", file.display())),
            "{stderr}"
        );
    }
    let got = pyulog(&ulg);
    check("the cut record", &got, &expected(&records[..cut_at], 0));
    check_header_info(&got, &header);
    assert_eq!(
        got["multi"]["lj9da_record_note"],
        serde_json::json!(notes.iter().map(|n| [n]).collect::<Vec<_>>()),
        "the reader's notes, in the file"
    );
}

/// The lower median of `time_usec − t_us` over a record's autopilot clock samples, for a
/// clock that does not wrap during the record (checked); 0 without samples.
fn offset_of_unwrapped_clock(records: &[Record]) -> i64 {
    let mut diffs: Vec<(u64, i64)> = records
        .iter()
        .filter_map(|r| match r.body {
            RecordBody::AutopilotClock { time_usec, .. } => {
                Some((r.t_us, time_usec as i64 - r.t_us as i64))
            }
            _ => None,
        })
        .collect();
    diffs.sort();
    let clocks: Vec<i64> = diffs.iter().map(|(t, d)| *t as i64 + d).collect();
    assert!(
        clocks.windows(2).all(|w| w[0] <= w[1]),
        "the clock does not wrap: {clocks:?}"
    );
    let mut d: Vec<i64> = diffs.into_iter().map(|(_, d)| d).collect();
    d.sort_unstable();
    d.get(d.len().saturating_sub(1) / 2).copied().unwrap_or(0)
}

/// The documented time base of a record without a wrap of the autopilot's clock: the
/// autopilot's boot, offset by [`offset_of_unwrapped_clock`], if the record holds its clock
/// and the autopilot booted before the run started, else the run's start.
fn time_base(records: &[Record]) -> (&'static str, i64) {
    let has_clock = records
        .iter()
        .any(|r| matches!(r.body, RecordBody::AutopilotClock { .. }));
    match offset_of_unwrapped_clock(records) {
        offset if has_clock && offset >= 0 => ("autopilot boot", offset),
        _ => ("run start", 0),
    }
}

fn check_time_base(got: &Value, base: &str, offset: i64) {
    assert_eq!(info(got, "lj9da_time_base"), base);
    assert_eq!(info(got, "lj9da_time_offset_us"), offset);
    assert_eq!(got["start"], offset, "the log starts at the run's start");
}

#[test]
fn every_sample_of_a_sitl_run_comes_back_from_pyulog() {
    let dir = TempDir::new("ulog-sitl");
    let records = sitl_records(dir.path(), "3", &[]);
    assert_eq!(records.len(), 1, "{records:?}");
    let rec = read_record(&records[0]).unwrap();
    assert!(rec.closed && rec.notes.is_empty(), "{:?}", rec.notes);
    let kinds: BTreeSet<&str> = rec.records.iter().map(|r| r.body.kind_name()).collect();
    for kind in ["goal", "telemetry", "motion", "health", "autopilot clock"] {
        assert!(
            kinds.contains(kind),
            "no {kind} record in the run: {kinds:?}"
        );
    }

    let (ulg, stderr) = export_into(&records[0], &dir.path().join("ulog"));
    assert_eq!(stderr, "");
    let got = pyulog(&ulg);
    let (base, offset) = time_base(&rec.records);
    check("the sitl run", &got, &expected(&rec.records, offset));
    check_header_info(&got, &rec.header);
    check_time_base(&got, base, offset);
    let ulg_len = std::fs::metadata(&ulg).unwrap().len();
    let rec_len = std::fs::metadata(&records[0]).unwrap().len();
    eprintln!(
        "sitl run: {} records, record {rec_len} bytes, ULog {ulg_len} bytes, time base {base}",
        rec.records.len()
    );
}

#[test]
fn every_sample_of_each_format_versions_file_comes_back_from_pyulog() {
    let dir = TempDir::new("ulog-fixtures");
    for minor in 0..=4 {
        let file = PathBuf::from(format!(
            "{}/tests/fixtures/records/format-1.{minor}.lj9rec",
            env!("CARGO_MANIFEST_DIR")
        ));
        let rec = read_record(&file).unwrap();
        assert_eq!(rec.header.version, (1, minor));
        let (ulg, stderr) = export_into(&file, dir.path());
        assert_eq!(stderr, "", "format 1.{minor}");
        let got = pyulog(&ulg);
        let (base, offset) = time_base(&rec.records);
        check(
            &format!("format 1.{minor}"),
            &got,
            &expected(&rec.records, offset),
        );
        check_header_info(&got, &rec.header);
        check_time_base(&got, base, offset);
    }
}

#[test]
fn with_the_autopilots_clock_the_timestamps_count_from_its_boot() {
    let dir = TempDir::new("ulog-clock");
    // The autopilot was up for 71.5 min at the run's start: its 32-bit SERVO_OUTPUT_RAW
    // clock wraps 5 s into the run. Each clock sample is heard 100 + i µs late.
    let boot: u64 = (1 << 32) - 5_000_000;
    let mut records = Vec::new();
    for i in 0..10u64 {
        let t_us = 250_000 + i * 1_000_000;
        records.push(Record {
            t_us,
            body: RecordBody::AutopilotClock {
                time_usec: (boot + t_us - 100 - i) % (1 << 32),
                bits: 32,
            },
        });
        records.push(Record {
            t_us: t_us + 3,
            body: RecordBody::Telemetry {
                servo: (i % 3) as u8,
                telemetry: telemetry(i as i16 * 10, 40, 30, 1200, 0),
                flags: ReplyFlags(0),
            },
        });
        records.push(Record {
            t_us: t_us + 5,
            body: RecordBody::Event {
                servo: None,
                severity: 6,
                text: format!("second {i}"),
            },
        });
    }
    assert!(
        records.iter().any(|r| matches!(
            r.body,
            RecordBody::AutopilotClock { time_usec, .. } if time_usec < 5_000_000
        )),
        "the clock wraps in the record"
    );
    // Differences boot − 100 … boot − 109: the lower median is boot − 105.
    let offset = boot as i64 - 105;
    let file = dir.path().join("clock.lj9rec");
    std::fs::write(&file, file_bytes(&header(), &records).0).unwrap();
    let (ulg, _) = export_into(&file, dir.path());
    let got = pyulog(&ulg);
    check("the aligned record", &got, &expected(&records, offset));
    assert_eq!(info(&got, "lj9da_time_base"), "autopilot boot");
    assert_eq!(info(&got, "lj9da_time_offset_us"), offset);
    assert_eq!(got["start"], offset, "the log starts at the run's start");
}

#[test]
fn a_file_that_cannot_be_read_is_an_error_and_the_others_are_still_exported() {
    let dir = TempDir::new("ulog-errors");
    let good = dir.path().join("good.lj9rec");
    std::fs::write(&good, file_bytes(&header(), &every_kind()[..5]).0).unwrap();
    let not_a_record = dir.path().join("notes.lj9rec");
    std::fs::write(&not_a_record, "shopping list\n").unwrap();
    let missing = dir.path().join("missing.lj9rec");
    let out = dir.path().join("out");
    let done = export(&[
        not_a_record.as_os_str(),
        missing.as_os_str(),
        good.as_os_str(),
        "--out".as_ref(),
        out.as_os_str(),
    ]);
    let stderr = String::from_utf8_lossy(&done.stderr);
    assert_eq!(done.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains(&format!(
            "error: {}: it is not an lj9da-bridge flight record",
            not_a_record.display()
        )),
        "{stderr}"
    );
    assert!(
        stderr.contains(&format!("error: cannot read {}", missing.display())),
        "{stderr}"
    );
    assert_eq!(
        String::from_utf8_lossy(&done.stdout),
        format!("{}\n", out.join("good.ulg").display())
    );
    let written: Vec<_> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(
        written,
        [std::ffi::OsString::from("good.ulg")],
        "nothing else, no part file"
    );
}

#[test]
fn records_of_one_name_are_not_exported_over_each_other() {
    let dir = TempDir::new("ulog-same-name");
    let (a, b) = (dir.path().join("a"), dir.path().join("b"));
    for (folder, n) in [(&a, 3), (&b, 7)] {
        std::fs::create_dir_all(folder).unwrap();
        let bytes = file_bytes(&header(), &every_kind()[..n]).0;
        std::fs::write(folder.join("flight.lj9rec"), bytes).unwrap();
    }
    let out = dir.path().join("out");
    let first = a.join("flight.lj9rec");
    let second = b.join("flight.lj9rec");
    let done = export(&[
        first.as_os_str(),
        second.as_os_str(),
        "--out".as_ref(),
        out.as_os_str(),
    ]);
    let stderr = String::from_utf8_lossy(&done.stderr);
    assert_eq!(done.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains(&format!("error: {}: its ULog file", second.display())),
        "{stderr}"
    );
    assert_eq!(
        String::from_utf8_lossy(&done.stdout),
        format!("{}\n", out.join("flight.ulg").display())
    );
    // The first record's samples, not the second's.
    let got = pyulog(&out.join("flight.ulg"));
    check("the first record", &got, &expected(&every_kind()[..3], 0));
}

//! `lj9da-bridge record parquet`: flights exported as Parquet and read back by DuckDB and by
//! pyarrow (from the Python package index, `common::python::data_python`), row by row and
//! value by value against the records: records this test writes (every kind, several servos,
//! a run in two parts), a real `sitl` run, the fixtures of earlier format versions, and a
//! record cut short. Records that name no aircraft are refused unless one is given.

mod common;
mod tempdir;

use lj9da_bridge::bus::{Goal, Health};
use lj9da_bridge::protocol::{Celsius, Ma10, MmCenti, Motion, Ms10, Mv10, ReplyFlags, Telemetry};
use lj9da_bridge::record::format::{RecordHeader, RecordServo, encode_header, encode_record};
use lj9da_bridge::record::format::{goal_name, health_name};
use lj9da_bridge::record::trend::{Flight, read_flights};
use lj9da_bridge::record::{Record, RecordBody, read_record};
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use tempdir::TempDir;

/// 2026-01-01T08:00:00Z and some nanoseconds (the export keeps µs, the file name ns).
const RUN_START_NS: i64 = 1_767_254_400 * 1_000_000_000 + 123_456_789;

/// Reads every Parquet file of an export folder with pyarrow and with DuckDB, and prints one
/// JSON object: per reader, per table, per file name, the rows in file order. Timestamps as
/// integer µs since 1970 (pyarrow: the column cast to int64; DuckDB: `epoch_us`), floats as
/// `"f:"` and Python's shortest round-trip text (parsed exactly on the Rust side), and per
/// table the pyarrow column types and the compression codecs of the column chunks.
const READ_BACK: &str = r#"
import glob, json, os, sys
import duckdb
import pyarrow as pa
import pyarrow.parquet as pq

out = sys.argv[1]

def plain(v):
    if isinstance(v, float):
        return "f:" + repr(v)
    return v

result = {"pyarrow": {}, "duckdb": {}, "types": {}, "codecs": {}}
con = duckdb.connect()
con.execute("SET TimeZone = 'UTC'")
for table in ("samples", "flights"):
    files = sorted(glob.glob(os.path.join(out, table, "*.parquet")))
    result["pyarrow"][table] = {}
    result["duckdb"][table] = {}
    codecs = set()
    for f in files:
        name = os.path.basename(f)
        t = pq.read_table(f)
        times = [fld.name for fld in t.schema if pa.types.is_timestamp(fld.type)]
        result["types"][table] = {fld.name: str(fld.type) for fld in t.schema}
        for col in times:
            t = t.set_column(t.schema.get_field_index(col), col, t.column(col).cast(pa.int64()))
        result["pyarrow"][table][name] = [
            {k: plain(v) for k, v in row.items()} for row in t.to_pylist()
        ]
        meta = pq.ParquetFile(f).metadata
        for g in range(meta.num_row_groups):
            for c in range(meta.num_columns):
                codecs.add(meta.row_group(g).column(c).compression)
        replace = ", ".join(f"epoch_us({c}) AS {c}" for c in times)
        select = f"SELECT * REPLACE ({replace}) FROM read_parquet(?)"
        cur = con.execute(select, [f])
        names = [d[0] for d in cur.description]
        result["duckdb"][table][name] = [
            {k: plain(v) for k, v in zip(names, row)} for row in cur.fetchall()
        ]
    result["codecs"][table] = sorted(codecs)
print(json.dumps(result))
"#;

fn bridge() -> Command {
    Command::new(env!("CARGO_BIN_EXE_lj9da-bridge"))
}

/// `lj9da-bridge record parquet ARGS…`.
fn export<P: AsRef<Path>>(paths: &[P], out: &Path, aircraft: Option<&str>) -> Output {
    let mut cmd = bridge();
    cmd.args(["record", "parquet"])
        .args(paths.iter().map(|p| p.as_ref()))
        .arg("--out")
        .arg(out);
    if let Some(name) = aircraft {
        cmd.args(["--aircraft", name]);
    }
    cmd.output().expect("lj9da-bridge runs")
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// Run the read-back script over an export folder.
fn read_back(out: &Path) -> Value {
    let python = common::python::data_python();
    let run = Command::new(&python)
        .arg("-c")
        .arg(READ_BACK)
        .arg(out)
        .output()
        .expect("the tests' Python runs");
    assert!(
        run.status.success(),
        "the read-back script failed:\n{}",
        String::from_utf8_lossy(&run.stderr)
    );
    serde_json::from_slice(&run.stdout).expect("the read-back script prints JSON")
}

/// What a cell must hold.
#[derive(Debug, Clone, PartialEq)]
enum Cell {
    Null,
    Int(i64),
    Float(f64),
    Text(String),
    Bool(bool),
}

fn text(s: &str) -> Cell {
    Cell::Text(s.to_string())
}

fn opt_float(v: Option<f64>) -> Cell {
    v.map_or(Cell::Null, Cell::Float)
}

/// Whether the JSON value the script printed is `want`.
fn holds(got: &Value, want: &Cell) -> bool {
    match want {
        Cell::Null => got.is_null(),
        Cell::Int(i) => got.as_i64() == Some(*i),
        Cell::Bool(b) => got.as_bool() == Some(*b),
        Cell::Text(s) => got.as_str() == Some(s.as_str()),
        Cell::Float(f) => got
            .as_str()
            .and_then(|s| s.strip_prefix("f:"))
            .and_then(|s| s.parse::<f64>().ok())
            .is_some_and(|g| g == *f || (g.is_nan() && f.is_nan())),
    }
}

type Row = BTreeMap<&'static str, Cell>;

/// The row a record must become, stated from the record format's units: 0.01 mm, 10 mA,
/// 10 mV, 10 ms.
fn sample_row(
    aircraft: &str,
    run_start_ns: i64,
    part: u16,
    servos: &[RecordServo],
    seq: usize,
    record: &Record,
) -> Row {
    let start_us = run_start_ns.div_euclid(1000);
    let mut row: Row = [
        "goal",
        "goal_mm",
        "position_mm",
        "current_a",
        "temperature_c",
        "voltage_v",
        "present_time_ms",
        "flags",
        "next_telemetry_us",
        "health",
        "stalled",
        "answered",
        "missed",
        "severity",
        "text",
        "autopilot_usec",
        "autopilot_bits",
        "dropped",
        "continued",
    ]
    .into_iter()
    .map(|c| (c, Cell::Null))
    .collect();
    row.insert("aircraft", text(aircraft));
    row.insert("flight_start", Cell::Int(start_us));
    row.insert("sample_time", Cell::Int(start_us + record.t_us as i64));
    row.insert("t_us", Cell::Int(record.t_us as i64));
    row.insert("seq", Cell::Int(seq as i64));
    row.insert("part", Cell::Int(i64::from(part)));
    let servo = record.body.servo().and_then(|s| servos.get(usize::from(s)));
    row.insert("servo", servo.map_or(Cell::Null, |s| text(&s.name)));
    row.insert("bus", servo.map_or(Cell::Null, |s| text(&s.bus)));
    row.insert(
        "id",
        servo.map_or(Cell::Null, |s| Cell::Int(i64::from(s.id))),
    );
    row.insert("kind", text(record.body.kind_name()));
    let centi = |v: i16| Cell::Float(f64::from(v) / 100.0);
    let tens = |v: u16| Cell::Float(f64::from(v) / 100.0);
    match &record.body {
        RecordBody::Goal { goal, .. } => {
            row.insert("goal", text(goal_name(*goal)));
            if let Goal::Position(p) = goal {
                row.insert("goal_mm", centi(p.0));
            }
        }
        RecordBody::Telemetry {
            telemetry: t,
            flags,
            ..
        } => {
            row.insert("position_mm", centi(t.present_position.0));
            row.insert("current_a", tens(t.present_load.0));
            row.insert(
                "temperature_c",
                Cell::Int(i64::from(t.present_temperature.0)),
            );
            row.insert("voltage_v", tens(t.present_voltage.0));
            row.insert(
                "present_time_ms",
                Cell::Int(i64::from(t.present_time.0) * 10),
            );
            row.insert("flags", Cell::Int(i64::from(flags.0)));
        }
        RecordBody::Position {
            position, flags, ..
        } => {
            row.insert("position_mm", centi(position.0));
            row.insert("flags", Cell::Int(i64::from(flags.0)));
        }
        RecordBody::Motion {
            motion: m, flags, ..
        } => {
            row.insert("position_mm", centi(m.present_position.0));
            row.insert("current_a", tens(m.present_load.0));
            row.insert(
                "present_time_ms",
                Cell::Int(i64::from(m.present_time.0) * 10),
            );
            row.insert("flags", Cell::Int(i64::from(flags.0)));
        }
        RecordBody::Replies {
            answered, missed, ..
        } => {
            row.insert("answered", Cell::Int(i64::from(*answered)));
            row.insert("missed", Cell::Int(i64::from(*missed)));
        }
        RecordBody::Health {
            health, stalled, ..
        } => {
            row.insert("health", text(health_name(*health)));
            row.insert("stalled", Cell::Bool(*stalled));
        }
        RecordBody::Event {
            severity, text: t, ..
        } => {
            row.insert("severity", Cell::Int(i64::from(*severity)));
            row.insert("text", text(t));
        }
        RecordBody::AutopilotClock { time_usec, bits } => {
            row.insert("autopilot_usec", Cell::Int(*time_usec as i64));
            row.insert("autopilot_bits", Cell::Int(i64::from(*bits)));
        }
        RecordBody::Dropped { count } => {
            row.insert("dropped", Cell::Int(*count as i64));
        }
        RecordBody::End { continued } => {
            row.insert("continued", Cell::Bool(*continued));
        }
    }
    row
}

/// The row a servo's flight must become: its figures as `record trend` computes them.
fn flight_row(aircraft: &str, name: &str, bus: &str, id: u8, f: &Flight) -> Row {
    let mut row = Row::new();
    row.insert("aircraft", text(aircraft));
    row.insert(
        "flight_start",
        Cell::Int(f.run_start_unix_ns.div_euclid(1000)),
    );
    row.insert("run_start_unix_ns", Cell::Int(f.run_start_unix_ns));
    row.insert("servo", text(name));
    row.insert("bus", text(bus));
    row.insert("id", Cell::Int(i64::from(id)));
    row.insert("parts", Cell::Int(f.files.len() as i64));
    row.insert("force_on_s", Cell::Float(f.force_on_s));
    row.insert("travel_mm", Cell::Float(f.travel_mm));
    row.insert("reversals", Cell::Int(f.reversals as i64));
    row.insert("motion_s", Cell::Float(f.motion_s));
    row.insert("friction_ma_per_mm_s", opt_float(f.friction_ma_per_mm_s));
    row.insert("holding_a", opt_float(f.holding_a));
    row.insert("peak_a", opt_float(f.peak_a));
    row.insert("stalled_s", Cell::Float(f.stalled_s));
    row.insert("peak_c", opt_float(f.peak_c));
    row.insert("mean_c", opt_float(f.mean_c));
    row.insert("start_c", opt_float(f.start_c));
    row.insert("hot_min", Cell::Float(f.hot_min));
    row.insert("heating_c_per_min", opt_float(f.heating_c_per_min));
    row.insert("rise_c", opt_float(f.rise_c));
    row.insert("margin_c", opt_float(f.margin_c));
    row.insert("bad_replies", opt_float(f.bad_replies));
    row.insert("alarms", Cell::Int(i64::from(f.alarms)));
    row
}

/// A flight as the test knows it: the aircraft, and its parts in order (path, part, records).
struct KnownFlight {
    aircraft: String,
    parts: Vec<PathBuf>,
}

impl KnownFlight {
    /// The flight's files' name, as `record parquet` names them.
    fn file_name(&self) -> String {
        let first = read_record(&self.parts[0]).unwrap();
        lj9da_bridge::record::parquet::flight_stem(&self.aircraft, first.header.run_start_unix_ns)
            + ".parquet"
    }

    /// The samples' rows, from the records as the reader reads them.
    fn sample_rows(&self) -> Vec<Row> {
        let mut rows = Vec::new();
        for path in &self.parts {
            let rec = read_record(path).unwrap();
            for record in &rec.records {
                let seq = rows.len();
                rows.push(sample_row(
                    &self.aircraft,
                    rec.header.run_start_unix_ns,
                    rec.header.part,
                    &rec.header.servos,
                    seq,
                    record,
                ));
            }
        }
        // A telemetry row's time to the same servo's next telemetry row, across parts.
        let mut last: BTreeMap<(String, String, String), usize> = BTreeMap::new();
        for k in 0..rows.len() {
            if rows[k]["kind"] != text("telemetry") {
                continue;
            }
            let key = |c: &str| format!("{:?}", rows[k][c]);
            if let Some(earlier) = last.insert((key("servo"), key("bus"), key("id")), k) {
                let (Cell::Int(now), Cell::Int(then)) = (&rows[k]["t_us"], &rows[earlier]["t_us"])
                else {
                    unreachable!("t_us is an integer")
                };
                let next = Cell::Int(now - then);
                rows[earlier].insert("next_telemetry_us", next);
            }
        }
        rows
    }

    /// The flights' rows, from `record trend`'s reader over the flight's files, in servo
    /// order (name, bus, ID).
    fn flight_rows(&self) -> Vec<Row> {
        let (servos, notes) = read_flights(&self.parts);
        assert!(notes.errors.is_empty(), "{:?}", notes.errors);
        servos
            .iter()
            .flat_map(|(key, flights)| {
                flights
                    .iter()
                    .map(|f| flight_row(&self.aircraft, &key.name, &key.bus, key.id, f))
            })
            .collect()
    }
}

/// Every row of `got` (one file's rows as a reader printed them) against `want`, cell by cell,
/// and no other column.
fn assert_rows(reader: &str, file: &str, got: &Value, want: &[Row]) {
    let got = got
        .as_array()
        .unwrap_or_else(|| panic!("{reader}: no file {file}"));
    assert_eq!(got.len(), want.len(), "{reader}: {file}: rows");
    for (k, (g, w)) in got.iter().zip(want).enumerate() {
        let g = g.as_object().unwrap();
        let columns: Vec<&str> = g.keys().map(String::as_str).collect();
        let wanted: Vec<&str> = w.keys().copied().collect();
        let mut sorted = columns.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, wanted, "{reader}: {file}: row {k}: columns");
        for (column, cell) in w {
            assert!(
                holds(&g[*column], cell),
                "{reader}: {file}: row {k}: {column} is {} where the record says {cell:?}",
                g[*column]
            );
        }
    }
}

/// Both readers hold exactly `flights`, row by row and value by value.
fn assert_export(out: &Path, flights: &[KnownFlight]) -> Value {
    let back = read_back(out);
    for reader in ["pyarrow", "duckdb"] {
        for table in ["samples", "flights"] {
            let files: Vec<&String> = back[reader][table].as_object().unwrap().keys().collect();
            let mut names: Vec<String> = flights.iter().map(KnownFlight::file_name).collect();
            names.sort();
            assert_eq!(
                files.iter().map(|s| s.as_str()).collect::<Vec<_>>(),
                names,
                "{reader}: {table}: the files"
            );
        }
        for flight in flights {
            let name = flight.file_name();
            assert_rows(
                reader,
                &format!("samples/{name}"),
                &back[reader]["samples"][&name],
                &flight.sample_rows(),
            );
            assert_rows(
                reader,
                &format!("flights/{name}"),
                &back[reader]["flights"][&name],
                &flight.flight_rows(),
            );
        }
    }
    back
}

fn servos() -> Vec<RecordServo> {
    vec![
        RecordServo::new("aileron_left", "wing", 1, 1),
        RecordServo::new("elevator", "tail", 3, 3),
        RecordServo::new("rudder", "tail", 4, 4),
    ]
}

fn header(run_start_ns: i64, part: u16, aircraft: Option<&str>) -> RecordHeader {
    let mut h = RecordHeader::new(run_start_ns, servos());
    h.part = part;
    h.part_start_unix_ns = run_start_ns + i64::from(part) * 60_000_000_000;
    h.aircraft = aircraft.map(str::to_string);
    h
}

/// Records of every kind: the aileron sweeps for 12 s (telemetry every 20 ms: position,
/// current that follows the speed, a temperature that rises, flags now and then), then holds;
/// the elevator answers with position and motion reads and stalls once; the rudder only has
/// goals and health (it never answers: no flight row); events of a servo and of the bridge; a
/// record about a servo index beyond the table; a dropped count; the autopilot's clock, of a
/// 32-bit and a 64-bit field; the end.
fn part0_records() -> Vec<Record> {
    let mut records = Vec::new();
    let mut put = |t_us: u64, body: RecordBody| records.push(Record { t_us, body });
    for servo in 0..3 {
        put(
            0,
            RecordBody::Health {
                servo,
                health: Health::Online,
                stalled: false,
            },
        );
    }
    for (k, goal) in [
        Goal::Position(MmCenti(-1234)),
        Goal::Hold,
        Goal::Off,
        Goal::Brake,
        Goal::Position(MmCenti(2500)),
    ]
    .into_iter()
    .enumerate()
    {
        put(
            1_000 + k as u64 * 10,
            RecordBody::Goal {
                servo: (k % 3) as u8,
                goal,
            },
        );
    }
    let mut last = 0i16;
    for k in 0..750u64 {
        let t = k as f64 * 0.02;
        let centi = if t < 12.0 {
            (1000.0 * (t * 1.3).sin()).round() as i16
        } else {
            last
        };
        let speed = f64::from((centi - last).abs()) / 100.0 / 0.02;
        last = centi;
        put(
            20_000 + k * 20_000,
            RecordBody::Telemetry {
                servo: 0,
                telemetry: Telemetry {
                    present_position: MmCenti(centi),
                    present_time: Ms10((k % 50) as u16),
                    present_load: Ma10(7 + (speed * 0.4).round() as u16),
                    present_temperature: Celsius(28 + (k / 60) as i16),
                    present_voltage: Mv10(1190 + (k % 7) as u16),
                },
                flags: ReplyFlags(if k % 200 == 150 { 0x20 } else { 0 }),
            },
        );
        if k % 5 == 0 {
            put(
                20_500 + k * 20_000,
                RecordBody::Position {
                    servo: 1,
                    position: MmCenti(-300 + (k % 40) as i16),
                    flags: ReplyFlags(0),
                },
            );
            put(
                20_700 + k * 20_000,
                RecordBody::Motion {
                    servo: 1,
                    motion: Motion {
                        present_position: MmCenti(-290 + (k % 30) as i16),
                        present_time: Ms10(3),
                        present_load: Ma10(12 + (k % 9) as u16),
                    },
                    flags: ReplyFlags(if k == 400 { 0x08 } else { 0 }),
                },
            );
        }
    }
    put(
        4_000_000,
        RecordBody::Health {
            servo: 1,
            health: Health::Stale,
            stalled: true,
        },
    );
    put(
        4_500_000,
        RecordBody::Health {
            servo: 1,
            health: Health::Online,
            stalled: false,
        },
    );
    put(
        5_000_000,
        RecordBody::Event {
            servo: Some(2),
            severity: 4,
            text: "rudder: degraded, 12% replies bad, \"quoted\", ünïcode".to_string(),
        },
    );
    put(
        5_100_000,
        RecordBody::Event {
            servo: None,
            severity: 6,
            text: "bridge: link up".to_string(),
        },
    );
    put(
        5_200_000,
        RecordBody::Health {
            servo: 7,
            health: Health::Offline,
            stalled: false,
        },
    );
    put(6_000_000, RecordBody::Dropped { count: 42 });
    put(
        6_100_000,
        RecordBody::AutopilotClock {
            time_usec: 4_294_967_295,
            bits: 32,
        },
    );
    put(
        6_200_000,
        RecordBody::AutopilotClock {
            time_usec: 123_456_789_012,
            bits: 64,
        },
    );
    put(
        15_000_000,
        RecordBody::Replies {
            servo: 0,
            answered: 750,
            missed: 3,
        },
    );
    put(15_000_001, RecordBody::End { continued: true });
    records
}

/// The second part of the run: the aileron goes on, the temperature error shows, the run ends.
fn part1_records() -> Vec<Record> {
    let mut records = Vec::new();
    for k in 0..30u64 {
        records.push(Record {
            t_us: 15_100_000 + k * 20_000,
            body: RecordBody::Telemetry {
                servo: 0,
                telemetry: Telemetry {
                    present_position: MmCenti(-700 + k as i16 * 50),
                    present_time: Ms10(2),
                    present_load: Ma10(65_535 - k as u16),
                    present_temperature: Celsius(-5 + k as i16),
                    present_voltage: Mv10(0),
                },
                flags: ReplyFlags(if k == 7 { 0xA0 } else { 0x02 }),
            },
        });
    }
    records.push(Record {
        t_us: 16_000_000,
        body: RecordBody::Replies {
            servo: 0,
            answered: u32::MAX,
            missed: 0,
        },
    });
    records.push(Record {
        t_us: 16_000_000,
        body: RecordBody::End { continued: false },
    });
    records
}

/// Write a record file: the header, then the records; returns the byte offset where each
/// record ends.
fn write_file(path: &Path, header: &RecordHeader, records: &[Record]) -> Vec<usize> {
    let mut bytes = encode_header(header);
    let mut ends = Vec::new();
    for record in records {
        encode_record(record, &mut bytes);
        ends.push(bytes.len());
    }
    std::fs::write(path, &bytes).unwrap();
    ends
}

/// Two flights of aircraft "test-plane": the first in two parts, the second in one.
fn write_flights(dir: &Path) -> Vec<KnownFlight> {
    let a0 = dir.join("20260101T080000Z.lj9rec");
    let a1 = dir.join("20260101T080100Z.lj9rec");
    let b = dir.join("20260102T080000Z.lj9rec");
    write_file(
        &a0,
        &header(RUN_START_NS, 0, Some("test-plane")),
        &part0_records(),
    );
    write_file(
        &a1,
        &header(RUN_START_NS, 1, Some("test-plane")),
        &part1_records(),
    );
    let next_day = RUN_START_NS + 86_400 * 1_000_000_000;
    let mut second = part0_records();
    second.retain(|r| !matches!(r.body, RecordBody::End { .. }));
    second.push(Record {
        t_us: 15_000_002,
        body: RecordBody::End { continued: false },
    });
    write_file(&b, &header(next_day, 0, Some("test-plane")), &second);
    vec![
        KnownFlight {
            aircraft: "test-plane".into(),
            parts: vec![a0, a1],
        },
        KnownFlight {
            aircraft: "test-plane".into(),
            parts: vec![b],
        },
    ]
}

fn parquet_files(dir: &Path) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = ["samples", "flights"]
        .iter()
        .filter_map(|t| std::fs::read_dir(dir.join(t)).ok())
        .flatten()
        .map(|e| e.unwrap().path())
        .collect();
    files.sort();
    files
}

#[test]
fn every_record_of_every_kind_reads_back_in_duckdb_and_pyarrow_as_recorded() {
    let dir = TempDir::new("parquet-kinds");
    let records = dir.path().join("records");
    std::fs::create_dir_all(&records).unwrap();
    let flights = write_flights(&records);
    let out = dir.path().join("fleet");
    let run = export(&[&records], &out, None);
    assert!(run.status.success(), "{}", stderr(&run));
    // The files written, one line each.
    let listed: Vec<PathBuf> = String::from_utf8_lossy(&run.stdout)
        .lines()
        .map(PathBuf::from)
        .collect();
    let mut listed_sorted = listed.clone();
    listed_sorted.sort();
    assert_eq!(listed_sorted, parquet_files(&out));
    assert_eq!(listed.len(), 2 * flights.len());

    let back = assert_export(&out, &flights);
    // Every kind is there, and the servo beyond the table has no name.
    let rows = &back["duckdb"]["samples"][flights[0].file_name()];
    let kinds: std::collections::BTreeSet<&str> = rows
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["kind"].as_str().unwrap())
        .collect();
    assert_eq!(kinds.len(), 10, "{kinds:?}");
    // The flights' table has a row per servo that answered: the rudder never did.
    let servos: Vec<&str> = back["pyarrow"]["flights"][flights[0].file_name()]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["servo"].as_str().unwrap())
        .collect();
    assert_eq!(servos, ["aileron_left", "elevator"]);

    // Typed columns, timestamps in µs (UTC), compressed.
    let types = &back["types"]["samples"];
    for (column, want) in [
        ("flight_start", "timestamp[us, tz=UTC]"),
        ("sample_time", "timestamp[us, tz=UTC]"),
        ("t_us", "int64"),
        ("position_mm", "double"),
        ("temperature_c", "int32"),
        ("stalled", "bool"),
        ("servo", "string"),
    ] {
        assert_eq!(types[column], want, "{column}");
    }
    assert_eq!(
        back["types"]["flights"]["flight_start"],
        "timestamp[us, tz=UTC]"
    );
    for table in ["samples", "flights"] {
        assert_eq!(
            back["codecs"][table],
            serde_json::json!(["SNAPPY"]),
            "{table}"
        );
    }
}

#[test]
fn exporting_again_rewrites_the_same_files_and_a_new_flight_adds_its_own() {
    let dir = TempDir::new("parquet-again");
    let records = dir.path().join("records");
    std::fs::create_dir_all(&records).unwrap();
    let mut flights = write_flights(&records);
    let out = dir.path().join("fleet");
    assert!(export(&[&records], &out, None).status.success());
    let first: Vec<(PathBuf, Vec<u8>)> = parquet_files(&out)
        .into_iter()
        .map(|p| (p.clone(), std::fs::read(&p).unwrap()))
        .collect();
    assert_eq!(first.len(), 4);

    assert!(export(&[&records], &out, None).status.success());
    let again: Vec<(PathBuf, Vec<u8>)> = parquet_files(&out)
        .into_iter()
        .map(|p| (p.clone(), std::fs::read(&p).unwrap()))
        .collect();
    assert_eq!(first, again, "a second export changed the files");

    // A third flight, alone in its folder: two files more, the others untouched.
    let later = dir.path().join("later");
    std::fs::create_dir_all(&later).unwrap();
    let path = later.join("20260105T080000Z.lj9rec");
    write_file(
        &path,
        &header(
            RUN_START_NS + 4 * 86_400 * 1_000_000_000,
            0,
            Some("test-plane"),
        ),
        &part0_records(),
    );
    assert!(export(&[&path], &out, None).status.success());
    let now = parquet_files(&out);
    assert_eq!(now.len(), 6);
    for (p, bytes) in &first {
        assert_eq!(&std::fs::read(p).unwrap(), bytes, "{}", p.display());
    }
    flights.push(KnownFlight {
        aircraft: "test-plane".into(),
        parts: vec![path],
    });
    assert_export(&out, &flights);
}

#[test]
fn a_cut_record_exports_what_it_holds_and_says_what_it_could_not() {
    let dir = TempDir::new("parquet-cut");
    let path = dir.path().join("20260101T080000Z.lj9rec");
    let records = part0_records();
    let ends = write_file(&path, &header(RUN_START_NS, 0, Some("cut-plane")), &records);
    // Cut in the middle of a record some 60 % into the file.
    let whole = std::fs::read(&path).unwrap();
    let cut_at = ends[ends.len() * 3 / 5] + 5;
    std::fs::write(&path, &whole[..cut_at]).unwrap();
    let intact = ends.iter().filter(|&&e| e <= cut_at).count();
    assert!(intact > 100 && intact < records.len());

    let out = dir.path().join("fleet");
    let run = export(&[&path], &out, None);
    let err = stderr(&run);
    assert!(run.status.success(), "{err}");
    assert!(
        err.contains("note: ") && err.contains("the last record was cut"),
        "{err}"
    );
    let flight = KnownFlight {
        aircraft: "cut-plane".into(),
        parts: vec![path],
    };
    // What the reader reads of the cut file is exactly the records before the cut.
    assert_eq!(flight.sample_rows().len(), intact);
    let back = assert_export(&out, &[flight]);
    let name = read_record(&dir.path().join("20260101T080000Z.lj9rec"))
        .map(|r| {
            lj9da_bridge::record::parquet::flight_stem("cut-plane", r.header.run_start_unix_ns)
        })
        .unwrap()
        + ".parquet";
    let rows = back["pyarrow"]["samples"][&name].as_array().unwrap();
    assert_eq!(rows.len(), intact);
    for (row, record) in rows.iter().zip(&records) {
        assert_eq!(row["t_us"].as_i64(), Some(record.t_us as i64));
    }
}

/// The records of earlier format versions (no aircraft in their header): refused without
/// `--aircraft`, naming each such file and writing nothing; with it, every record of each is
/// exported, and a record that names its own aircraft keeps it.
#[test]
fn records_that_name_no_aircraft_are_refused_unless_one_is_given() {
    let dir = TempDir::new("parquet-aircraft");
    let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/records");
    let old: Vec<PathBuf> = (0..=3)
        .map(|minor| fixtures.join(format!("format-1.{minor}.lj9rec")))
        .collect();
    for file in &old {
        assert_eq!(read_record(file).unwrap().header.aircraft, None);
    }
    let named = dir.path().join("20260101T080000Z.lj9rec");
    write_file(
        &named,
        &header(RUN_START_NS, 0, Some("named-plane")),
        &part0_records(),
    );

    let out = dir.path().join("fleet");
    let mut all: Vec<&Path> = old.iter().map(PathBuf::as_path).collect();
    all.push(&named);
    let refused = export(&all, &out, None);
    let err = stderr(&refused);
    assert_eq!(refused.status.code(), Some(1), "{err}");
    assert!(err.contains("--aircraft"), "{err}");
    for file in &old {
        assert!(err.contains(&file.display().to_string()), "{err}");
    }
    assert!(!err.contains(&named.display().to_string()), "{err}");
    assert!(parquet_files(&out).is_empty(), "{:?}", parquet_files(&out));

    let given = export(&all, &out, Some("old-plane"));
    assert!(given.status.success(), "{}", stderr(&given));
    let mut flights: Vec<KnownFlight> = old
        .iter()
        .map(|file| KnownFlight {
            aircraft: "old-plane".into(),
            parts: vec![file.clone()],
        })
        .collect();
    flights.push(KnownFlight {
        aircraft: "named-plane".into(),
        parts: vec![named.clone()],
    });
    assert_export(&out, &flights);

    let empty = export(&[&named], &out, Some(""));
    assert_eq!(empty.status.code(), Some(1), "{}", stderr(&empty));
}

/// A real run: `sitl` for 3 s writes its record, named after the aircraft of its mapping
/// (the host's name by default), and every record of it comes back.
#[test]
fn a_sitl_record_reads_back_record_by_record() {
    let dir = TempDir::new("parquet-sitl");
    let run = bridge()
        .args(["sitl", "--seconds", "3", "--plain"])
        .current_dir(dir.path())
        .stdin(std::process::Stdio::null())
        .output()
        .expect("lj9da-bridge sitl runs");
    assert!(run.status.success(), "{}", stderr(&run));
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir.path().join("records"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "lj9rec"))
        .collect();
    files.sort();
    assert!(!files.is_empty());
    let header = read_record(&files[0]).unwrap().header;
    let aircraft = header.aircraft.clone().expect("sitl names its aircraft");
    assert!(!aircraft.is_empty());
    let out = dir.path().join("fleet");
    let exported = export(&[&dir.path().join("records")], &out, None);
    assert!(exported.status.success(), "{}", stderr(&exported));
    let flight = KnownFlight {
        aircraft,
        parts: files,
    };
    let rows = flight.sample_rows().len();
    assert!(rows > 100, "{rows} records in 3 s of sitl");
    assert_export(&out, &[flight]);
}

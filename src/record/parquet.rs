//! `lj9da-bridge record parquet`: flight records as Parquet, for a fleet's tools (DuckDB,
//! Spark, pandas, pyarrow).
//!
//! Every flight (the parts of one run, as `record trend` groups them, of one aircraft) becomes
//! two files under the folder given:
//! - `samples/<aircraft>_<run start>.parquet`: one row per record of the flight, in file order;
//! - `flights/<aircraft>_<run start>.parquet`: one row per servo that answered in the flight,
//!   with every figure `record trend` computes per flight ([`super::trend`]).
//!
//! `<run start>` is the run's start in UTC to the nanosecond, `20261121T235959.123456789Z`
//! (the run's identity in the records), and `<aircraft>` the aircraft's name with every
//! character but ASCII letters, digits, `-` and `.` written as `_`. Exporting the same
//! records again writes the same files (each is written beside its place under a hidden name
//! and then renamed over it); a new flight adds two files. A folder of exports is a fleet's
//! table: `read_parquet('DIR/flights/*.parquet')` in DuckDB, `spark.read.parquet('DIR/flights')`
//! in Spark.
//!
//! The aircraft is the one the record's header names (the mapping's `[record] aircraft`,
//! format 1.4); for older records, the name given to the command. Records with neither are
//! refused, all at once, before anything is written: a fleet's table without the aircraft
//! would mix its servos.
//!
//! # `samples`
//!
//! | column | type | what |
//! |---|---|---|
//! | `aircraft` | string | the aircraft's name |
//! | `flight_start` | timestamp (µs, UTC) | the run's start |
//! | `sample_time` | timestamp (µs, UTC) | the record's time: the run's start plus `t_us` |
//! | `t_us` | int64 | µs since the run's start, as recorded |
//! | `seq` | int64 | the record's place in the flight: 0, 1, 2, … in file order, part after part (the order `record trend` reads them in) |
//! | `part` | int32 | the record file's part (0 for a run's first file) |
//! | `servo`, `bus`, `id` | string, string, int32 | the servo's name, bus and ID; null for a record about the bridge (`dropped`, `end`, a bridge event) or a servo index beyond the header's table |
//! | `kind` | string | `goal`, `telemetry`, `position`, `motion`, `replies`, `health`, `event`, `autopilot clock`, `dropped`, `end` |
//! | `goal` | string | goal: `position`, `hold`, `off`, `brake` |
//! | `goal_mm` | double | goal: the position goal, mm (null but for `position`) |
//! | `position_mm` | double | telemetry, position, motion: the present position, mm |
//! | `current_a` | double | telemetry, motion: the present current, A |
//! | `temperature_c` | int32 | telemetry: the present temperature, °C |
//! | `voltage_v` | double | telemetry: the present voltage, V |
//! | `present_time_ms` | int32 | telemetry, motion: the present time register, ms |
//! | `flags` | int32 | telemetry, position, motion: the reply's status byte (0x80 temperature error, 0x20 temperature alarm, 0x08 flash write error) |
//! | `next_telemetry_us` | int64 | telemetry: µs from this sample to the servo's next telemetry sample in the flight, the time this sample's readings stand for (null for its last); a query of time spent in a state sums it without a window over the flight |
//! | `health` | string | health: `starting`, `online`, `stale`, `offline`, `wrong model`, `temperature error` |
//! | `stalled` | boolean | health: the servo is stalled |
//! | `answered`, `missed` | int64 | replies: the servo's good replies, and garbled or missing ones, since its bus started |
//! | `severity` | int32 | event: MAV_SEVERITY (0 emergency … 7 debug) |
//! | `text` | string | event: its text |
//! | `autopilot_usec`, `autopilot_bits` | int64, int32 | autopilot clock: the autopilot's boot clock, µs, as the output message carried it, and the width of its field (32: modulo 2³², 64) |
//! | `dropped` | int64 | dropped: records the writer could not take |
//! | `continued` | boolean | end: the run goes on in the next part |
//!
//! Every value is the record's, in the units the record commands show (the registers' 0.01 mm,
//! 10 mA and 10 mV steps divided out as `record csv` does); a column that a kind does not have
//! is null in its rows.
//!
//! # `flights`
//!
//! `aircraft`, `flight_start` (timestamp, µs, UTC), `run_start_unix_ns` (int64: the run's
//! start to the nanosecond, which orders a servo's flights as `record trend` does), `servo`,
//! `bus`, `id`, `parts` (the record files of the run), then the figures of
//! [`super::trend::Flight`] under their names there: `force_on_s`, `travel_mm`, `reversals`,
//! `motion_s`, `friction_ma_per_mm_s`, `holding_a`, `peak_a`, `stalled_s`, `peak_c`, `mean_c`,
//! `start_c`, `hot_min`, `heating_c_per_min`, `rise_c`, `margin_c`, `bad_replies`, `alarms`
//! (null where `record trend` has none). The verdicts are a query over it:
//! `docs/fleet/verdicts.sql`.
//!
//! # Encoding
//!
//! Plain Parquet of format 1.0 data pages, written with the `parquet` crate's column writer
//! (no Arrow): Snappy-compressed, dictionary-encoded strings and values (a servo's positions
//! and currents repeat), the times delta-encoded, at most [`ROW_GROUP_ROWS`] rows per row
//! group. Row groups of `samples` carry min/max statistics for the columns a query selects by
//! (the aircraft, the times, the servo's ID, the kind, the temperature and the flags), those of
//! `flights` for every column. The file's key-value metadata names the program
//! (`lj9da.software`) and the record files the flight was read from (`lj9da.records`, one path
//! a line); `created_by` is the `parquet` crate's own, which readers know.

use super::clock::Utc;
use super::format::{Record, RecordBody, RecordHeader, goal_name, health_name};
use super::reader::scan_record;
use super::trend::{Flight, RunFlights, RunFold, ServoKey, read_header, record_files, servo_keys};
use crate::bus::Goal;
use ::parquet::basic::{Compression, Encoding};
use ::parquet::data_type::{
    BoolType, ByteArray, ByteArrayType, DataType, DoubleType, Int32Type, Int64Type,
};
use ::parquet::errors::ParquetError;
use ::parquet::file::metadata::KeyValue;
use ::parquet::file::properties::{EnabledStatistics, WriterProperties};
use ::parquet::file::writer::{SerializedFileWriter, SerializedRowGroupWriter};
use ::parquet::schema::parser::parse_message_type;
use ::parquet::schema::types::ColumnPath;
use bytes::Bytes;
use std::collections::BTreeMap;
use std::fmt;
use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;

/// The most rows of one row group of `samples` (some 20 MB of records held while a group is
/// gathered).
pub const ROW_GROUP_ROWS: usize = 1 << 18;

/// The folder of the samples' files, under the export's folder.
pub const SAMPLES_DIR: &str = "samples";
/// The folder of the flights' files, under the export's folder.
pub const FLIGHTS_DIR: &str = "flights";

const SAMPLES_SCHEMA: &str = "
message sample {
  REQUIRED BYTE_ARRAY aircraft (STRING);
  REQUIRED INT64 flight_start (TIMESTAMP(MICROS,true));
  REQUIRED INT64 sample_time (TIMESTAMP(MICROS,true));
  REQUIRED INT64 t_us;
  REQUIRED INT64 seq;
  REQUIRED INT32 part;
  OPTIONAL BYTE_ARRAY servo (STRING);
  OPTIONAL BYTE_ARRAY bus (STRING);
  OPTIONAL INT32 id;
  REQUIRED BYTE_ARRAY kind (STRING);
  OPTIONAL BYTE_ARRAY goal (STRING);
  OPTIONAL DOUBLE goal_mm;
  OPTIONAL DOUBLE position_mm;
  OPTIONAL DOUBLE current_a;
  OPTIONAL INT32 temperature_c;
  OPTIONAL DOUBLE voltage_v;
  OPTIONAL INT32 present_time_ms;
  OPTIONAL INT32 flags;
  OPTIONAL INT64 next_telemetry_us;
  OPTIONAL BYTE_ARRAY health (STRING);
  OPTIONAL BOOLEAN stalled;
  OPTIONAL INT64 answered;
  OPTIONAL INT64 missed;
  OPTIONAL INT32 severity;
  OPTIONAL BYTE_ARRAY text (STRING);
  OPTIONAL INT64 autopilot_usec;
  OPTIONAL INT32 autopilot_bits;
  OPTIONAL INT64 dropped;
  OPTIONAL BOOLEAN continued;
}";

const FLIGHTS_SCHEMA: &str = "
message flight {
  REQUIRED BYTE_ARRAY aircraft (STRING);
  REQUIRED INT64 flight_start (TIMESTAMP(MICROS,true));
  REQUIRED INT64 run_start_unix_ns;
  REQUIRED BYTE_ARRAY servo (STRING);
  REQUIRED BYTE_ARRAY bus (STRING);
  REQUIRED INT32 id;
  REQUIRED INT32 parts;
  REQUIRED DOUBLE force_on_s;
  REQUIRED DOUBLE travel_mm;
  REQUIRED INT64 reversals;
  REQUIRED DOUBLE motion_s;
  OPTIONAL DOUBLE friction_ma_per_mm_s;
  OPTIONAL DOUBLE holding_a;
  OPTIONAL DOUBLE peak_a;
  REQUIRED DOUBLE stalled_s;
  OPTIONAL DOUBLE peak_c;
  OPTIONAL DOUBLE mean_c;
  OPTIONAL DOUBLE start_c;
  REQUIRED DOUBLE hot_min;
  OPTIONAL DOUBLE heating_c_per_min;
  OPTIONAL DOUBLE rise_c;
  OPTIONAL DOUBLE margin_c;
  OPTIONAL DOUBLE bad_replies;
  REQUIRED INT32 alarms;
}";

/// Why nothing was exported.
#[derive(Debug)]
pub enum ExportError {
    /// These records name no aircraft, and none was given for them.
    NoAircraft(Vec<PathBuf>),
    /// The name given for the aircraft is empty.
    EmptyAircraft,
    /// The export's folders cannot be made.
    Folder {
        path: PathBuf,
        source: std::io::Error,
    },
}

impl fmt::Display for ExportError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ExportError::NoAircraft(files) => {
                write!(
                    f,
                    "{} record file(s) name no aircraft (written before record format 1.4): give \
                     the aircraft they come from with --aircraft NAME (export each aircraft's \
                     records separately); nothing was exported. The files:",
                    files.len()
                )?;
                for file in files {
                    write!(f, "\n  {}", file.display())?;
                }
                Ok(())
            }
            ExportError::EmptyAircraft => write!(f, "--aircraft needs a name, not an empty one"),
            ExportError::Folder { path, source } => {
                write!(f, "cannot make the folder {}: {source}", path.display())
            }
        }
    }
}

impl std::error::Error for ExportError {}

/// What an export wrote and found.
#[derive(Debug, Default)]
pub struct Exported {
    /// The files written, a flight's samples then its flights file, flight after flight.
    pub files: Vec<PathBuf>,
    /// Flights exported.
    pub flights: usize,
    /// Rows of the samples' files (records).
    pub samples: u64,
    /// Notes on damaged or unclosed records, one line each, `path: note`.
    pub notes: Vec<String>,
    /// Records that could not be read at all, and flights that could not be written.
    pub errors: Vec<String>,
}

/// One file of a flight: part, path and header.
type Part = (u16, PathBuf, RecordHeader);

/// Export the records among `paths` (files, or folders of `*.lj9rec`) into `out`; `aircraft`
/// names the aircraft of records that do not name it.
pub fn export(
    paths: &[PathBuf],
    out: &Path,
    aircraft: Option<&str>,
) -> Result<Exported, ExportError> {
    if aircraft.is_some_and(str::is_empty) {
        return Err(ExportError::EmptyAircraft);
    }
    let mut done = Exported::default();
    let files = match record_files(paths) {
        Ok(files) => files,
        Err(e) => {
            done.errors
                .push(format!("cannot list the record files: {e}"));
            return Ok(done);
        }
    };
    let mut flights: BTreeMap<(String, i64), Vec<Part>> = BTreeMap::new();
    let mut unnamed = Vec::new();
    for path in files {
        let header = match read_header(&path) {
            Ok(header) => header,
            Err(e) => {
                done.errors.push(e.to_string());
                continue;
            }
        };
        let name = header
            .aircraft
            .clone()
            .filter(|a| !a.is_empty())
            .or_else(|| aircraft.map(str::to_string));
        match name {
            Some(name) => flights
                .entry((name, header.run_start_unix_ns))
                .or_default()
                .push((header.part, path, header)),
            None => unnamed.push(path),
        }
    }
    if !unnamed.is_empty() {
        return Err(ExportError::NoAircraft(unnamed));
    }
    for dir in [SAMPLES_DIR, FLIGHTS_DIR] {
        let path = out.join(dir);
        std::fs::create_dir_all(&path).map_err(|source| ExportError::Folder { path, source })?;
    }
    let flights: Vec<((String, i64), Vec<Part>)> = flights
        .into_iter()
        .map(|(key, mut parts)| {
            parts.sort_by(|a, b| (a.0, &a.1).cmp(&(b.0, &b.1)));
            (key, parts)
        })
        .collect();
    // Flights on up to the machine's cores, each written whole by one.
    let workers = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .min(flights.len().max(1));
    let next = std::sync::atomic::AtomicUsize::new(0);
    let mut results: Vec<(usize, FlightExport)> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..workers)
            .map(|_| {
                scope.spawn(|| {
                    let mut out_of_worker = Vec::new();
                    loop {
                        let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        let Some(((name, start), parts)) = flights.get(i) else {
                            break;
                        };
                        out_of_worker.push((i, export_flight(name, *start, parts, out)));
                    }
                    out_of_worker
                })
            })
            .collect();
        handles
            .into_iter()
            .flat_map(|h| h.join().unwrap_or_default())
            .collect()
    });
    results.sort_by_key(|(i, _)| *i);
    for (_, flight) in results {
        done.notes.extend(flight.notes);
        done.errors.extend(flight.errors);
        if !flight.files.is_empty() {
            done.flights += 1;
            done.samples += flight.samples;
            done.files.extend(flight.files);
        }
    }
    Ok(done)
}

/// What exporting one flight did.
#[derive(Debug, Default)]
struct FlightExport {
    files: Vec<PathBuf>,
    samples: u64,
    notes: Vec<String>,
    errors: Vec<String>,
}

/// The stem of a flight's files: `<aircraft>_<run start>`.
pub fn flight_stem(aircraft: &str, run_start_unix_ns: i64) -> String {
    let safe: String = aircraft
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '.' {
                c
            } else {
                '_'
            }
        })
        .collect();
    let stamp = Utc::from_unix_ns(run_start_unix_ns).file_stamp();
    let seconds = stamp.trim_end_matches('Z');
    format!(
        "{safe}_{seconds}.{:09}Z",
        run_start_unix_ns.rem_euclid(1_000_000_000)
    )
}

fn export_flight(aircraft: &str, run_start: i64, parts: &[Part], out: &Path) -> FlightExport {
    let mut done = FlightExport::default();
    let name = format!("{}.parquet", flight_stem(aircraft, run_start));
    let samples_path = out.join(SAMPLES_DIR).join(&name);
    let flights_path = out.join(FLIGHTS_DIR).join(&name);
    let sources: Vec<String> = parts.iter().map(|p| p.1.display().to_string()).collect();
    let mut fold = RunFold::new(run_start);
    let telemetry = TelemetryTimes::read(parts);
    let written = write_atomically(&samples_path, |file| {
        let mut samples = SampleWriter::new(file, aircraft, run_start, &sources, telemetry)?;
        for (part, path, header) in parts {
            let keys = servo_keys(header);
            fold.begin_part(&keys);
            samples.begin_part(*part, &keys);
            let mut failed: Option<ParquetError> = None;
            let scanned = scan_record(path, |record| {
                fold.record(&record);
                if failed.is_none()
                    && let Err(e) = samples.push(record)
                {
                    failed = Some(e);
                }
            });
            if let Some(e) = failed {
                return Err(e);
            }
            match scanned {
                Ok(scan) => {
                    for note in scan.notes {
                        done.notes.push(format!("{}: {note}", path.display()));
                    }
                    fold.end_part(Some(path));
                }
                Err(e) => {
                    done.errors.push(e.to_string());
                    fold.end_part(None);
                }
            }
        }
        samples.finish()
    });
    match written {
        Ok(rows) => {
            done.samples = rows;
            done.files.push(samples_path.clone());
        }
        Err(e) => {
            done.errors.push(format!(
                "cannot write {}: {e} (the flight is left out)",
                samples_path.display()
            ));
            return done;
        }
    }
    let flights = fold.finish();
    match write_atomically(&flights_path, |file| {
        write_flights(file, aircraft, run_start, &flights, &sources)
    }) {
        Ok(()) => done.files.push(flights_path),
        Err(e) => {
            // The samples without their figures would be half a flight.
            let _ = std::fs::remove_file(&samples_path);
            done.files.clear();
            done.errors.push(format!(
                "cannot write {}: {e} (the flight is left out)",
                flights_path.display()
            ));
        }
    }
    done
}

/// Every servo's telemetry times in one flight (µs since the run's start), in the order its
/// parts hold them: a first pass, so that each sample's row knows the time to the next one.
#[derive(Debug, Default)]
struct TelemetryTimes {
    keys: Vec<ServoKey>,
    times: Vec<Vec<i64>>,
}

impl TelemetryTimes {
    /// Read the flight's parts for their telemetry times (what cannot be read is the second
    /// pass's to say).
    fn read(parts: &[Part]) -> TelemetryTimes {
        let mut telemetry = TelemetryTimes::default();
        for (_, path, header) in parts {
            let slots: Vec<usize> = servo_keys(header)
                .into_iter()
                .map(|key| telemetry.slot(key))
                .collect();
            let _ = scan_record(path, |record| {
                if let RecordBody::Telemetry { servo, .. } = record.body
                    && let Some(&slot) = slots.get(usize::from(servo))
                {
                    telemetry.times[slot].push(t_us(&record));
                }
            });
        }
        telemetry
    }

    /// The servo's slot, a new one for a servo not met before.
    fn slot(&mut self, key: ServoKey) -> usize {
        match self.keys.iter().position(|k| *k == key) {
            Some(slot) => slot,
            None => {
                self.keys.push(key);
                self.times.push(Vec::new());
                self.keys.len() - 1
            }
        }
    }
}

/// Write `path` through a hidden file beside it, renamed over it once whole.
fn write_atomically<T>(
    path: &Path,
    write: impl FnOnce(File) -> Result<T, ParquetError>,
) -> Result<T, ParquetError> {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let temporary = path.with_file_name(format!(".{name}.{}.tmp", std::process::id()));
    let result = File::create(&temporary)
        .map_err(ParquetError::from)
        .and_then(write)
        .and_then(|value| {
            std::fs::rename(&temporary, path)?;
            Ok(value)
        });
    if result.is_err() {
        let _ = std::fs::remove_file(&temporary);
    }
    result
}

/// The columns of `samples` whose row groups carry min/max statistics: the times and the
/// identity a query selects by, the temperature and the flags. Statistics of every column cost
/// some 15 % of the export's time (each value compared), for columns no reader prunes by.
const SAMPLES_STATISTICS: &[&str] = &[
    "aircraft",
    "flight_start",
    "sample_time",
    "t_us",
    "seq",
    "part",
    "id",
    "kind",
    "temperature_c",
    "flags",
];

/// The writer's settings: `delta`, the columns delta-encoded; `statistics`, the only columns
/// with statistics (`None`: every column, per page).
fn properties(
    sources: &[String],
    delta: &[&str],
    statistics: Option<&[&str]>,
) -> Arc<WriterProperties> {
    let mut builder = WriterProperties::builder()
        .set_compression(Compression::SNAPPY)
        .set_key_value_metadata(Some(vec![
            KeyValue::new(
                "lj9da.software".to_string(),
                concat!("lj9da-bridge ", env!("CARGO_PKG_VERSION")).to_string(),
            ),
            KeyValue::new("lj9da.records".to_string(), sources.join("\n")),
        ]));
    if let Some(columns) = statistics {
        builder = builder.set_statistics_enabled(EnabledStatistics::None);
        for column in columns {
            builder = builder
                .set_column_statistics_enabled(ColumnPath::from(*column), EnabledStatistics::Chunk);
        }
    }
    for column in delta {
        let path = ColumnPath::from(*column);
        builder = builder
            .set_column_dictionary_enabled(path.clone(), false)
            .set_column_encoding(path, Encoding::DELTA_BINARY_PACKED);
    }
    Arc::new(builder.build())
}

/// Write one column of a row group: its values in row order (`None`: null).
fn put<T: DataType, W: Write + Send>(
    group: &mut SerializedRowGroupWriter<'_, W>,
    values: impl Iterator<Item = Option<T::T>>,
) -> Result<(), ParquetError> {
    let mut column = group
        .next_column()?
        .ok_or_else(|| ParquetError::General("more columns written than the schema has".into()))?;
    let writer = column.typed::<T>();
    let optional = writer.get_descriptor().max_def_level() > 0;
    let mut present = Vec::new();
    let mut levels = Vec::new();
    for value in values {
        levels.push(i16::from(value.is_some()));
        match value {
            Some(v) => present.push(v),
            None if optional => {}
            None => {
                return Err(ParquetError::General(format!(
                    "a null in the required column {}",
                    writer.get_descriptor().name()
                )));
            }
        }
    }
    writer.write_batch(&present, optional.then_some(&levels[..]), None)?;
    column.close()
}

/// A servo of a part's table, as its columns hold it.
#[derive(Debug, Clone)]
struct ServoColumns {
    name: ByteArray,
    bus: ByteArray,
    id: i32,
    /// The servo's place in [`TelemetryTimes`]' keys.
    slot: usize,
}

/// The samples' file of one flight, gathered a row group at a time.
struct SampleWriter {
    file: SerializedFileWriter<File>,
    aircraft: ByteArray,
    flight_start_us: i64,
    /// Each part's number and servo table, in the order the parts were begun.
    parts: Vec<(i32, Vec<ServoColumns>)>,
    /// The rows of the row group being gathered: the part (an index of `parts`), the record
    /// and, for telemetry, the µs to the servo's next telemetry sample.
    rows: Vec<(usize, Record, Option<i64>)>,
    written: u64,
    /// Every servo's telemetry times in the flight, from a first pass over its parts.
    telemetry: TelemetryTimes,
    /// Per servo (by slot): how many of its telemetry samples were pushed.
    telemetry_seen: Vec<usize>,
}

fn text(s: &str) -> ByteArray {
    ByteArray::from(s.as_bytes().to_vec())
}

/// A name the program holds (a kind, goal or health), with no copy per row.
fn name(s: &'static str) -> ByteArray {
    ByteArray::from(Bytes::from_static(s.as_bytes()))
}

impl SampleWriter {
    fn new(
        file: File,
        aircraft: &str,
        run_start_unix_ns: i64,
        sources: &[String],
        telemetry: TelemetryTimes,
    ) -> Result<SampleWriter, ParquetError> {
        let schema = Arc::new(parse_message_type(SAMPLES_SCHEMA)?);
        let props = properties(
            sources,
            &["sample_time", "t_us", "seq"],
            Some(SAMPLES_STATISTICS),
        );
        Ok(SampleWriter {
            file: SerializedFileWriter::new(file, schema, props)?,
            aircraft: text(aircraft),
            flight_start_us: run_start_unix_ns.div_euclid(1000),
            parts: Vec::new(),
            rows: Vec::new(),
            written: 0,
            telemetry_seen: vec![0; telemetry.keys.len()],
            telemetry,
        })
    }

    /// A part with this servo table (its header's, as [`servo_keys`] gives it) begins.
    fn begin_part(&mut self, part: u16, keys: &[ServoKey]) {
        let servos = keys
            .iter()
            .map(|key| ServoColumns {
                name: text(&key.name),
                bus: text(&key.bus),
                id: i32::from(key.id),
                slot: self.telemetry.slot(key.clone()),
            })
            .collect();
        self.parts.push((i32::from(part), servos));
    }

    fn push(&mut self, record: Record) -> Result<(), ParquetError> {
        let part = self.parts.len().saturating_sub(1);
        let next = match &record.body {
            RecordBody::Telemetry { servo, .. } => self
                .parts
                .get(part)
                .and_then(|(_, table)| table.get(usize::from(*servo)))
                .and_then(|columns| {
                    let seen = self.telemetry_seen.get_mut(columns.slot)?;
                    *seen += 1;
                    let times = self.telemetry.times.get(columns.slot)?;
                    Some(times.get(*seen)? - times.get(*seen - 1)?)
                }),
            _ => None,
        };
        self.rows.push((part, record, next));
        if self.rows.len() >= ROW_GROUP_ROWS {
            self.flush()?;
        }
        Ok(())
    }

    fn flush(&mut self) -> Result<(), ParquetError> {
        if self.rows.is_empty() {
            return Ok(());
        }
        let rows = std::mem::take(&mut self.rows);
        let parts = &self.parts;
        let servos: Vec<Option<&ServoColumns>> = rows
            .iter()
            .map(|(p, r, _)| {
                let (_, table) = parts.get(*p)?;
                table.get(usize::from(r.body.servo()?))
            })
            .collect();
        let mut g = self.file.next_row_group()?;
        let start = self.flight_start_us;
        let bodies = || rows.iter().map(|(_, r, _)| &r.body);
        put::<ByteArrayType, _>(&mut g, rows.iter().map(|_| Some(self.aircraft.clone())))?;
        put::<Int64Type, _>(&mut g, rows.iter().map(|_| Some(start)))?;
        put::<Int64Type, _>(
            &mut g,
            rows.iter()
                .map(|(_, r, _)| Some(start.saturating_add(t_us(r)))),
        )?;
        put::<Int64Type, _>(&mut g, rows.iter().map(|(_, r, _)| Some(t_us(r))))?;
        let first = i64::try_from(self.written).unwrap_or(i64::MAX);
        put::<Int64Type, _>(&mut g, (0..rows.len()).map(|k| Some(first + k as i64)))?;
        put::<Int32Type, _>(
            &mut g,
            rows.iter()
                .map(|(p, _, _)| parts.get(*p).map(|(part, _)| *part)),
        )?;
        put::<ByteArrayType, _>(&mut g, servos.iter().map(|s| s.map(|s| s.name.clone())))?;
        put::<ByteArrayType, _>(&mut g, servos.iter().map(|s| s.map(|s| s.bus.clone())))?;
        put::<Int32Type, _>(&mut g, servos.iter().map(|s| s.map(|s| s.id)))?;
        put::<ByteArrayType, _>(&mut g, bodies().map(|b| Some(name(b.kind_name()))))?;
        put::<ByteArrayType, _>(
            &mut g,
            bodies().map(|b| match b {
                RecordBody::Goal { goal, .. } => Some(name(goal_name(*goal))),
                _ => None,
            }),
        )?;
        put::<DoubleType, _>(
            &mut g,
            bodies().map(|b| match b {
                RecordBody::Goal {
                    goal: Goal::Position(p),
                    ..
                } => Some(p.mm()),
                _ => None,
            }),
        )?;
        put::<DoubleType, _>(
            &mut g,
            bodies().map(|b| match b {
                RecordBody::Telemetry { telemetry, .. } => Some(telemetry.present_position.mm()),
                RecordBody::Position { position, .. } => Some(position.mm()),
                RecordBody::Motion { motion, .. } => Some(motion.present_position.mm()),
                _ => None,
            }),
        )?;
        put::<DoubleType, _>(
            &mut g,
            bodies().map(|b| match b {
                RecordBody::Telemetry { telemetry, .. } => Some(telemetry.present_load.amps()),
                RecordBody::Motion { motion, .. } => Some(motion.present_load.amps()),
                _ => None,
            }),
        )?;
        put::<Int32Type, _>(
            &mut g,
            bodies().map(|b| match b {
                RecordBody::Telemetry { telemetry, .. } => {
                    Some(i32::from(telemetry.present_temperature.0))
                }
                _ => None,
            }),
        )?;
        put::<DoubleType, _>(
            &mut g,
            bodies().map(|b| match b {
                RecordBody::Telemetry { telemetry, .. } => Some(telemetry.present_voltage.volts()),
                _ => None,
            }),
        )?;
        put::<Int32Type, _>(
            &mut g,
            bodies().map(|b| match b {
                RecordBody::Telemetry { telemetry, .. } => {
                    Some(telemetry.present_time.millis() as i32)
                }
                RecordBody::Motion { motion, .. } => Some(motion.present_time.millis() as i32),
                _ => None,
            }),
        )?;
        put::<Int32Type, _>(
            &mut g,
            bodies().map(|b| match b {
                RecordBody::Telemetry { flags, .. }
                | RecordBody::Position { flags, .. }
                | RecordBody::Motion { flags, .. } => Some(i32::from(flags.0)),
                _ => None,
            }),
        )?;
        put::<Int64Type, _>(&mut g, rows.iter().map(|(_, _, next)| *next))?;
        put::<ByteArrayType, _>(
            &mut g,
            bodies().map(|b| match b {
                RecordBody::Health { health, .. } => Some(name(health_name(*health))),
                _ => None,
            }),
        )?;
        put::<BoolType, _>(
            &mut g,
            bodies().map(|b| match b {
                RecordBody::Health { stalled, .. } => Some(*stalled),
                _ => None,
            }),
        )?;
        put::<Int64Type, _>(
            &mut g,
            bodies().map(|b| match b {
                RecordBody::Replies { answered, .. } => Some(i64::from(*answered)),
                _ => None,
            }),
        )?;
        put::<Int64Type, _>(
            &mut g,
            bodies().map(|b| match b {
                RecordBody::Replies { missed, .. } => Some(i64::from(*missed)),
                _ => None,
            }),
        )?;
        put::<Int32Type, _>(
            &mut g,
            bodies().map(|b| match b {
                RecordBody::Event { severity, .. } => Some(i32::from(*severity)),
                _ => None,
            }),
        )?;
        put::<ByteArrayType, _>(
            &mut g,
            bodies().map(|b| match b {
                RecordBody::Event { text: t, .. } => Some(text(t)),
                _ => None,
            }),
        )?;
        put::<Int64Type, _>(
            &mut g,
            bodies().map(|b| match b {
                RecordBody::AutopilotClock { time_usec, .. } => {
                    Some(i64::try_from(*time_usec).unwrap_or(i64::MAX))
                }
                _ => None,
            }),
        )?;
        put::<Int32Type, _>(
            &mut g,
            bodies().map(|b| match b {
                RecordBody::AutopilotClock { bits, .. } => Some(i32::from(*bits)),
                _ => None,
            }),
        )?;
        put::<Int64Type, _>(
            &mut g,
            bodies().map(|b| match b {
                RecordBody::Dropped { count } => Some(i64::try_from(*count).unwrap_or(i64::MAX)),
                _ => None,
            }),
        )?;
        put::<BoolType, _>(
            &mut g,
            bodies().map(|b| match b {
                RecordBody::End { continued } => Some(*continued),
                _ => None,
            }),
        )?;
        g.close()?;
        self.written += rows.len() as u64;
        Ok(())
    }

    /// Write the last row group and the footer: the rows written.
    fn finish(mut self) -> Result<u64, ParquetError> {
        self.flush()?;
        self.file.close()?;
        Ok(self.written)
    }
}

/// A record's time, µs since the run's start (as `i64`, saturated).
fn t_us(record: &Record) -> i64 {
    i64::try_from(record.t_us).unwrap_or(i64::MAX)
}

/// The flights' file of one flight: one row per servo.
fn write_flights(
    file: File,
    aircraft: &str,
    run_start: i64,
    flights: &RunFlights,
    sources: &[String],
) -> Result<(), ParquetError> {
    let schema = Arc::new(parse_message_type(FLIGHTS_SCHEMA)?);
    let mut writer = SerializedFileWriter::new(file, schema, properties(sources, &[], None))?;
    let mut g = writer.next_row_group()?;
    let rows = || flights.iter();
    let keys = || rows().map(|(k, _)| k);
    let figures = || rows().map(|(_, f)| f);
    let aircraft = text(aircraft);
    put::<ByteArrayType, _>(&mut g, rows().map(|_| Some(aircraft.clone())))?;
    put::<Int64Type, _>(&mut g, rows().map(|_| Some(run_start.div_euclid(1000))))?;
    put::<Int64Type, _>(&mut g, rows().map(|_| Some(run_start)))?;
    put::<ByteArrayType, _>(&mut g, keys().map(|k: &ServoKey| Some(text(&k.name))))?;
    put::<ByteArrayType, _>(&mut g, keys().map(|k| Some(text(&k.bus))))?;
    put::<Int32Type, _>(&mut g, keys().map(|k| Some(i32::from(k.id))))?;
    put::<Int32Type, _>(
        &mut g,
        figures().map(|f| Some(i32::try_from(f.files.len()).unwrap_or(i32::MAX))),
    )?;
    let number = |get: fn(&Flight) -> Option<f64>| figures().map(get);
    put::<DoubleType, _>(&mut g, number(|f| Some(f.force_on_s)))?;
    put::<DoubleType, _>(&mut g, number(|f| Some(f.travel_mm)))?;
    put::<Int64Type, _>(
        &mut g,
        figures().map(|f| Some(i64::try_from(f.reversals).unwrap_or(i64::MAX))),
    )?;
    put::<DoubleType, _>(&mut g, number(|f| Some(f.motion_s)))?;
    put::<DoubleType, _>(&mut g, number(|f| f.friction_ma_per_mm_s))?;
    put::<DoubleType, _>(&mut g, number(|f| f.holding_a))?;
    put::<DoubleType, _>(&mut g, number(|f| f.peak_a))?;
    put::<DoubleType, _>(&mut g, number(|f| Some(f.stalled_s)))?;
    put::<DoubleType, _>(&mut g, number(|f| f.peak_c))?;
    put::<DoubleType, _>(&mut g, number(|f| f.mean_c))?;
    put::<DoubleType, _>(&mut g, number(|f| f.start_c))?;
    put::<DoubleType, _>(&mut g, number(|f| Some(f.hot_min)))?;
    put::<DoubleType, _>(&mut g, number(|f| f.heating_c_per_min))?;
    put::<DoubleType, _>(&mut g, number(|f| f.rise_c))?;
    put::<DoubleType, _>(&mut g, number(|f| f.margin_c))?;
    put::<DoubleType, _>(&mut g, number(|f| f.bad_replies))?;
    put::<Int32Type, _>(
        &mut g,
        figures().map(|f| Some(i32::try_from(f.alarms).unwrap_or(i32::MAX))),
    )?;
    g.close()?;
    writer.close()?;
    Ok(())
}

/// `lj9da-bridge record parquet PATHS… --out DIR [--aircraft NAME]`: the files written on
/// stdout, notes and errors on stderr; exit status 1 if a record could not be read or a
/// flight not written (the others are exported), or nothing was exported.
pub fn run(paths: &[PathBuf], out: &Path, aircraft: Option<&str>) -> ExitCode {
    let done = match export(paths, out, aircraft) {
        Ok(done) => done,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::FAILURE;
        }
    };
    for note in &done.notes {
        eprintln!("note: {note}");
    }
    for error in &done.errors {
        eprintln!("error: {error}");
    }
    if done.flights == 0 && done.errors.is_empty() {
        eprintln!("error: no record files (*.lj9rec) in what was given");
        return ExitCode::FAILURE;
    }
    let listed: String = done
        .files
        .iter()
        .map(|f| format!("{}\n", f.display()))
        .collect();
    let stdout = std::io::stdout();
    let mut lock = stdout.lock();
    let printed = lock
        .write_all(listed.as_bytes())
        .and_then(|()| lock.flush());
    if let Err(e) = printed
        && e.kind() != std::io::ErrorKind::BrokenPipe
    {
        eprintln!("error: cannot write to stdout: {e}");
        return ExitCode::FAILURE;
    }
    eprintln!(
        "exported {} flight(s), {} sample row(s), into {}",
        done.flights,
        done.samples,
        out.display()
    );
    if done.errors.is_empty() {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_flights_files_are_named_by_aircraft_and_run_start_to_the_nanosecond() {
        // 2026-01-01T08:00:00Z and 5 ns.
        let start = 1_767_254_400 * 1_000_000_000 + 5;
        assert_eq!(
            flight_stem("plane 1/ä", start),
            "plane_1___20260101T080000.000000005Z"
        );
        assert_ne!(flight_stem("a", start), flight_stem("a", start + 1));
    }

    #[test]
    fn the_schemas_parse() {
        for schema in [SAMPLES_SCHEMA, FLIGHTS_SCHEMA] {
            parse_message_type(schema).unwrap();
        }
    }
}

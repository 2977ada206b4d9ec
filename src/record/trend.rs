//! Wear across flights: what `lj9da-bridge record trend` prints.
//!
//! Every record file given (or found in a folder given) is read once, in parallel, without
//! keeping its records: the parts of one run (same run start) make one flight. A servo is
//! matched across flights by its name, bus and ID. For each servo and flight the figures below
//! are computed; the servo's first [`BASELINE_FLIGHTS`] flights (since `--since`, if given)
//! make its baseline (the median of each figure), and every later flight is judged against it.
//! `docs/wear.md` says why each figure is a wear signal.
//!
//! Figures of one flight (times in the run's clock; a break of more than [`MAX_GAP_S`] between
//! two position samples of the servo is not counted as time at all):
//! - **force on**: time between position samples (telemetry or position-only reads) while the
//!   servo is online (health online or stale; no health record yet counts as online) and its
//!   latest goal is not `off` or `brake`;
//! - **travel**: an odometer: the sum of |Δposition|, where the position is followed with a
//!   [`ODOMETER_DEADBAND_MM`] dead band so that the 0.02 mm jitter of a servo holding still adds
//!   nothing; **reversals**: changes of direction of that followed position;
//! - **speed** at a sample: |Δposition| over the latest span of at least [`SPEED_WINDOW_S`]
//!   (and at most [`MAX_GAP_S`]) ending at it; **in motion** from [`MOVING_MM_S`] up, **holding**
//!   below [`HOLDING_MM_S`]; **time in motion**: time between samples whose later sample is in
//!   motion;
//! - **friction**: the current while moving per unit of speed, Σ current / Σ speed over the
//!   current reads (telemetry samples and motion records) in motion with force on and not
//!   stalled, in mA per mm/s (at least [`MIN_SAMPLES`] reads);
//! - **holding current**: the mean current over the current reads holding with force on and
//!   not stalled (at least [`MIN_SAMPLES`]);
//! - **peak current**; **time stalled** (health records that say stalled, to the next that does
//!   not or the run's end);
//! - **peak** and **mean temperature** (mean over samples), **minutes above
//!   [`HOT_C`]** (time between telemetry samples whose earlier sample was above it), and
//!   **heating**: (peak − first temperature of the flight) per minute in motion (at least
//!   [`MIN_MOTION_S`] in motion); **temperature margin**: [`ALARM_C`] − peak;
//! - **bad replies**: the share of the servo's requests that got a garbled reply or none, from
//!   the replies records (format 1.2; older records have none);
//! - **alarms**: times a status flag went on (temperature alarm, temperature error, flash write
//!   error), in any reply the record keeps (samples, position and motion records).
//!
//! The state (online, stalled, goal), the alarms, the time stalled, the temperatures and the
//! peak current come from [`super::analysis::ServoFold`], which `record summary` uses too.
//!
//! A judged flight is marked **inspect** by each of these (the thresholds are constants here):
//! friction or holding current above the baseline by more than [`RISE_LIMIT`] (+25 %), the
//! holding current also by at least [`HOLDING_MIN_RISE_A`]; heating above its baseline by
//! more than +25 %, the flight's temperature rise also [`HEATING_MIN_EXTRA_C`] above its
//! baseline's; the temperature margin
//! smaller than its baseline by more than [`MARGIN_MIN_DROP_C`] °C. A servo is **inspect** when
//! its latest flight is marked, **watch** when an earlier one was but not the latest, **ok**
//! otherwise, and **baseline** while it has no flight beyond its baseline.

mod text;

use super::analysis::ServoFold;
use super::clock::Utc;
use super::format::{FILE_EXTENSION, Record, RecordBody, RecordHeader, decode_header};
use super::format::{HeaderError, MAX_HEADER_BODY};
use super::reader::{RecordError, scan_record};
use serde::Serialize;
use std::collections::{BTreeMap, VecDeque};
use std::fmt;
use std::io::Read;
use std::path::{Path, PathBuf};

/// Flights that make a servo's baseline.
pub const BASELINE_FLIGHTS: usize = 5;
/// Friction, holding current and heating: a rise above the baseline by more than this share
/// marks a flight.
pub const RISE_LIMIT: f64 = 0.25;
/// The smallest rise of the holding current that marks a flight (the current is reported in
/// 10 mA steps, and a servo holding without load draws some 70 mA).
pub const HOLDING_MIN_RISE_A: f64 = 0.02;
/// Heating marks a flight only if the flight's temperature rise (peak − first) is also this
/// much above its baseline's, °C: the register counts whole degrees, and in a short flight one
/// degree more is a large share.
pub const HEATING_MIN_EXTRA_C: f64 = 2.0;
/// A temperature margin smaller than its baseline by more than this marks a flight, °C.
pub const MARGIN_MIN_DROP_C: f64 = 10.0;
/// The LJ9DA41's default temperature alarm: the temperature margin is counted to it.
pub const ALARM_C: f64 = 75.0;
/// "Hot": minutes above this are counted.
pub const HOT_C: f64 = 70.0;
/// A longer break between two samples of a servo is not counted as time.
pub const MAX_GAP_S: f64 = 1.0;
/// The shortest span a speed is measured over.
pub const SPEED_WINDOW_S: f64 = 0.1;
/// From this speed a servo is in motion.
pub const MOVING_MM_S: f64 = 2.0;
/// Below this speed a servo is holding.
pub const HOLDING_MM_S: f64 = 0.5;
/// The odometer's dead band.
pub const ODOMETER_DEADBAND_MM: f64 = 0.1;
/// The fewest samples a current figure is computed from.
pub const MIN_SAMPLES: u64 = 20;
/// The least time in motion the heating figure is computed from.
pub const MIN_MOTION_S: f64 = 10.0;

/// A servo as matched across records: an aircraft's servo where the records name the aircraft
/// (format 1.4 on), so that a fleet's folders given at once keep each aircraft's servos apart.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize)]
pub struct ServoKey {
    /// The aircraft the records name (`[record] aircraft`, or the host name); `None` for older
    /// records.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub aircraft: Option<String>,
    pub name: String,
    pub bus: String,
    pub id: u8,
}

/// The figures of one servo in one flight.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Flight {
    /// The run's start, ns since 1970-01-01 UTC.
    pub run_start_unix_ns: i64,
    /// The run's start, `2026-11-21T23:59:59Z`.
    pub date: String,
    /// The record files of the run, in part order.
    pub files: Vec<PathBuf>,
    pub force_on_s: f64,
    pub travel_mm: f64,
    pub reversals: u64,
    pub motion_s: f64,
    /// mA per mm/s.
    pub friction_ma_per_mm_s: Option<f64>,
    pub holding_a: Option<f64>,
    pub peak_a: Option<f64>,
    pub stalled_s: f64,
    pub peak_c: Option<f64>,
    pub mean_c: Option<f64>,
    pub start_c: Option<f64>,
    pub hot_min: f64,
    /// °C per minute in motion.
    pub heating_c_per_min: Option<f64>,
    /// Peak − first temperature.
    pub rise_c: Option<f64>,
    /// [`ALARM_C`] − peak temperature.
    pub margin_c: Option<f64>,
    /// Share (0–1) of requests with a garbled reply or none; `None` before format 1.2.
    pub bad_replies: Option<f64>,
    pub alarms: u32,
    /// Whether the flight is part of the servo's baseline.
    pub baseline: bool,
    /// What marks this flight "inspect" (empty: nothing, or not judged).
    pub findings: Vec<Finding>,
}

/// A figure of a flight beyond its threshold.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Finding {
    /// `friction`, `holding current`, `heating` or `temperature margin`.
    pub figure: &'static str,
    pub value: f64,
    pub baseline: f64,
    /// (value − baseline) / baseline, for the rises; the change in °C for the margin.
    pub change: f64,
}

impl fmt::Display for Finding {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.figure {
            "temperature margin" => write!(
                f,
                "temperature margin {:.0} °C, {:.0} °C less than its baseline {:.0} °C",
                self.value, -self.change, self.baseline
            ),
            "friction" => write!(
                f,
                "friction {:+.0} % ({:.2} vs {:.2} mA per mm/s)",
                self.change * 100.0,
                self.value,
                self.baseline
            ),
            "holding current" => write!(
                f,
                "holding current {:+.0} % ({:.3} vs {:.3} A)",
                self.change * 100.0,
                self.value,
                self.baseline
            ),
            _ => write!(
                f,
                "{} {:+.0} % ({:.2} vs {:.2} °C per minute moving)",
                self.figure,
                self.change * 100.0,
                self.value,
                self.baseline
            ),
        }
    }
}

/// The baseline of a servo: the median of each figure over its first flights.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Baseline {
    /// Flights in it.
    pub flights: usize,
    pub friction_ma_per_mm_s: Option<f64>,
    pub holding_a: Option<f64>,
    pub heating_c_per_min: Option<f64>,
    pub rise_c: Option<f64>,
    pub margin_c: Option<f64>,
}

/// The verdict on a servo.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Verdict {
    /// Too few flights beyond the baseline to judge.
    Baseline,
    Ok,
    /// An earlier flight was marked, the latest is not.
    Watch,
    /// The latest flight is marked.
    Inspect,
}

impl fmt::Display for Verdict {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Verdict::Baseline => "baseline",
            Verdict::Ok => "ok",
            Verdict::Watch => "watch",
            Verdict::Inspect => "inspect",
        })
    }
}

/// Totals of a servo over its flights.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Totals {
    pub flights: usize,
    pub force_on_h: f64,
    pub motion_h: f64,
    pub travel_m: f64,
    pub reversals: u64,
    pub stalled_s: f64,
    pub hot_min: f64,
    pub alarms: u32,
    /// The latest flight's friction against the baseline, (value − baseline) / baseline.
    pub friction_change: Option<f64>,
    /// The latest flight's heating against the baseline.
    pub heating_change: Option<f64>,
}

/// One servo's flights and verdict.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ServoTrend {
    pub servo: ServoKey,
    pub verdict: Verdict,
    /// The latest flight's findings when inspect; the last marked flight's when watch.
    pub triggers: Vec<Finding>,
    /// The first marked flight (1-based, in `flights`) of the run of marked flights that
    /// reaches the latest one, or the latest marked flight when watch.
    pub marked_since: Option<usize>,
    /// Flights before `--since` left out.
    pub left_out: usize,
    pub baseline: Baseline,
    pub totals: Totals,
    pub flights: Vec<Flight>,
}

/// What `record trend` found.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Trend {
    pub thresholds: Thresholds,
    pub files: usize,
    pub servos: Vec<ServoTrend>,
}

/// The thresholds used, for a fleet tool reading the JSON.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Thresholds {
    pub baseline_flights: usize,
    pub rise_limit: f64,
    pub holding_min_rise_a: f64,
    pub heating_min_extra_c: f64,
    pub margin_min_drop_c: f64,
    pub alarm_c: f64,
}

impl Default for Thresholds {
    fn default() -> Self {
        Thresholds {
            baseline_flights: BASELINE_FLIGHTS,
            rise_limit: RISE_LIMIT,
            holding_min_rise_a: HOLDING_MIN_RISE_A,
            heating_min_extra_c: HEATING_MIN_EXTRA_C,
            margin_min_drop_c: MARGIN_MIN_DROP_C,
            alarm_c: ALARM_C,
        }
    }
}

/// Where a new baseline starts: for every servo, or for the servo of that name.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Since {
    pub servo: Option<String>,
    pub unix_ns: i64,
}

impl std::str::FromStr for Since {
    type Err = String;
    /// `DATE` or `SERVO=DATE`; DATE as `2026-11-21` or `2026-11-21T08:30[:00]` (UTC).
    fn from_str(s: &str) -> Result<Self, String> {
        let (servo, date) = match s.rsplit_once('=') {
            Some((servo, date)) => (Some(servo.to_string()), date),
            None => (None, s),
        };
        let unix_ns = Utc::parse_unix_ns(date).ok_or_else(|| {
            format!("{date:?} is not a date: give 2026-11-21 or 2026-11-21T08:30 (UTC)")
        })?;
        Ok(Since { servo, unix_ns })
    }
}

// ---------------------------------------------------------------------------------------------
// One servo through one run

/// A servo's running state while its run is read: the fold every record command shares, and
/// the motion figures of this one.
#[derive(Debug, Clone)]
struct Acc {
    fold: ServoFold,
    last_pos: Option<(f64, f64)>,
    window: VecDeque<(f64, f64)>,
    moving: bool,
    speed: Option<f64>,
    anchor: Option<f64>,
    direction: i8,
    last_temp: Option<(f64, f64)>,
    moving_i: f64,
    moving_v: f64,
    moving_n: u64,
    holding_i: f64,
    holding_n: u64,
    flight: Flight,
}

impl Acc {
    fn new(run_start_unix_ns: i64) -> Acc {
        Acc {
            fold: ServoFold::new(),
            last_pos: None,
            window: VecDeque::new(),
            moving: false,
            speed: None,
            anchor: None,
            direction: 0,
            last_temp: None,
            moving_i: 0.0,
            moving_v: 0.0,
            moving_n: 0,
            holding_i: 0.0,
            holding_n: 0,
            flight: Flight {
                run_start_unix_ns,
                date: Utc::from_unix_ns(run_start_unix_ns).iso(),
                files: Vec::new(),
                force_on_s: 0.0,
                travel_mm: 0.0,
                reversals: 0,
                motion_s: 0.0,
                friction_ma_per_mm_s: None,
                holding_a: None,
                peak_a: None,
                stalled_s: 0.0,
                peak_c: None,
                mean_c: None,
                start_c: None,
                hot_min: 0.0,
                heating_c_per_min: None,
                rise_c: None,
                margin_c: None,
                bad_replies: None,
                alarms: 0,
                baseline: false,
                findings: Vec::new(),
            },
        }
    }

    fn force_on(&self) -> bool {
        self.fold.force_on()
    }

    /// A present position `mm` seen at `t` s.
    fn position(&mut self, t: f64, mm: f64) {
        // Speed over the latest span of at least SPEED_WINDOW_S.
        while self.window.len() >= 2
            && self
                .window
                .get(1)
                .is_some_and(|w| t - w.0 >= SPEED_WINDOW_S)
        {
            self.window.pop_front();
        }
        self.speed = self.window.front().and_then(|&(t0, p0)| {
            let dt = t - t0;
            (SPEED_WINDOW_S..=MAX_GAP_S)
                .contains(&dt)
                .then(|| (mm - p0).abs() / dt)
        });
        if self.window.back().is_some_and(|w| t - w.0 > MAX_GAP_S) {
            self.window.clear();
        }
        self.window.push_back((t, mm));
        self.moving = self.speed.is_some_and(|v| v >= MOVING_MM_S);
        if let Some((t0, _)) = self.last_pos {
            let dt = t - t0;
            if dt > 0.0 && dt <= MAX_GAP_S {
                if self.force_on() {
                    self.flight.force_on_s += dt;
                }
                if self.moving {
                    self.flight.motion_s += dt;
                }
            }
        }
        self.last_pos = Some((t, mm));
        match self.anchor {
            None => self.anchor = Some(mm),
            Some(anchor) => {
                let d = mm - anchor;
                if d.abs() >= ODOMETER_DEADBAND_MM {
                    let direction = if d > 0.0 { 1 } else { -1 };
                    if self.direction != 0 && direction != self.direction {
                        self.flight.reversals += 1;
                    }
                    self.direction = direction;
                    self.flight.travel_mm += d.abs();
                    self.anchor = Some(mm);
                }
            }
        }
    }

    /// A temperature read at `t`.
    fn temperature(&mut self, t: f64, temperature_c: f64) {
        if let Some((t0, c0)) = self.last_temp {
            let dt = t - t0;
            if dt > 0.0 && dt <= MAX_GAP_S && c0 > HOT_C {
                self.flight.hot_min += dt / 60.0;
            }
        }
        self.last_temp = Some((t, temperature_c));
    }

    /// A current read (with the full telemetry, or with the position between two full reads).
    fn current(&mut self, current_a: f64) {
        if self.force_on()
            && !self.fold.stalled
            && let Some(v) = self.speed
        {
            if v >= MOVING_MM_S {
                self.moving_i += current_a;
                self.moving_v += v;
                self.moving_n += 1;
            } else if v < HOLDING_MM_S {
                self.holding_i += current_a;
                self.holding_n += 1;
            }
        }
    }

    fn record(&mut self, t: f64, body: &RecordBody) {
        self.fold.record(t, body);
        match body {
            RecordBody::Telemetry { telemetry, .. } => {
                self.position(t, telemetry.present_position.mm());
                self.current(telemetry.present_load.amps());
                self.temperature(t, f64::from(telemetry.present_temperature.0));
            }
            RecordBody::Position { position, .. } => self.position(t, position.mm()),
            RecordBody::Motion { motion: m, .. } => {
                self.position(t, m.present_position.mm());
                self.current(m.present_load.amps());
            }
            _ => {}
        }
    }

    /// The flight's figures, the run ending at `end` s; `None` if the servo never answered.
    fn finish(mut self, end: f64) -> Option<Flight> {
        self.last_pos?;
        let fold = &mut self.fold;
        fold.finish(end);
        let f = &mut self.flight;
        f.stalled_s = fold.stalled_spans.total();
        f.alarms = fold.alarms.len() as u32;
        f.peak_a = fold.current_a.peak();
        f.peak_c = fold.temperature_c.peak();
        f.start_c = fold.temperature_c.first();
        f.mean_c = fold.temperature_c.mean();
        if self.moving_n >= MIN_SAMPLES && self.moving_v > 0.0 {
            f.friction_ma_per_mm_s = Some(1000.0 * self.moving_i / self.moving_v);
        }
        if self.holding_n >= MIN_SAMPLES {
            f.holding_a = Some(self.holding_i / self.holding_n as f64);
        }
        if let (Some(peak), Some(start)) = (f.peak_c, f.start_c) {
            f.rise_c = Some(peak - start);
            if f.motion_s >= MIN_MOTION_S {
                f.heating_c_per_min = Some((peak - start) / (f.motion_s / 60.0));
            }
        }
        f.margin_c = f.peak_c.map(|p| ALARM_C - p);
        f.bad_replies = fold.replies.and_then(|(good, bad)| {
            let all = u64::from(good) + u64::from(bad);
            (all > 0).then(|| bad as f64 / all as f64)
        });
        Some(self.flight)
    }
}

// ---------------------------------------------------------------------------------------------
// Reading files

/// The record files among `paths`: files as given, folders' `*.lj9rec` files (not recursing).
pub fn record_files(paths: &[PathBuf]) -> std::io::Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    for path in paths {
        if path.is_dir() {
            let mut found: Vec<PathBuf> = std::fs::read_dir(path)?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.is_file() && p.extension().is_some_and(|e| e == FILE_EXTENSION))
                .collect();
            found.sort();
            files.extend(found);
        } else {
            files.push(path.clone());
        }
    }
    Ok(files)
}

/// A file's header alone (read from its first bytes).
pub fn read_header(path: &Path) -> Result<RecordHeader, RecordError> {
    let io = |source| RecordError::Io {
        path: path.to_path_buf(),
        source,
    };
    let mut file = std::fs::File::open(path).map_err(io)?;
    let mut bytes = Vec::new();
    let mut want = 64 * 1024;
    loop {
        let have = bytes.len();
        (&mut file)
            .take((want - have) as u64)
            .read_to_end(&mut bytes)
            .map_err(io)?;
        match decode_header(&bytes) {
            Err(HeaderError::Truncated { needed, .. })
                if needed > bytes.len() && bytes.len() == want && want < MAX_HEADER_BODY + 64 =>
            {
                want = needed;
            }
            Ok((header, _)) => return Ok(header),
            Err(reason) => {
                return Err(RecordError::Header {
                    path: path.to_path_buf(),
                    reason,
                });
            }
        }
    }
}

/// What reading the files said besides the figures: one line each, for stderr.
#[derive(Debug, Default)]
pub struct ReadNotes {
    /// Files that could not be read at all.
    pub errors: Vec<String>,
    /// Notes on damaged or unclosed files.
    pub notes: Vec<String>,
}

/// One run: its figures per servo.
pub type RunFlights = Vec<(ServoKey, Flight)>;

/// One file of a run: its part, path and servo table.
type Part = (u16, PathBuf, Vec<ServoKey>);

/// The servo table of a header, as servos are matched across records.
pub fn servo_keys(header: &RecordHeader) -> Vec<ServoKey> {
    header
        .servos
        .iter()
        .map(|s| ServoKey {
            aircraft: header.aircraft.clone().filter(|a| !a.is_empty()),
            name: s.name.clone(),
            bus: s.bus.clone(),
            id: s.id,
        })
        .collect()
}

/// One run folded record by record, part after part, into its flights' figures: what
/// `record trend` computes per flight, for a reader that reads the records for more than the
/// figures (the Parquet export).
///
/// For each part in part order: [`RunFold::begin_part`] with its servo table, every record
/// of the part to [`RunFold::record`] in file order, then [`RunFold::end_part`]; at the end,
/// [`RunFold::finish`].
#[derive(Debug)]
pub struct RunFold {
    run_start: i64,
    /// The servos of the parts read so far.
    accs: BTreeMap<ServoKey, Acc>,
    /// The servos of the part being read, in its table's order.
    part: Vec<(ServoKey, Acc)>,
    /// The latest record's time in the run, s.
    end: f64,
}

impl RunFold {
    /// A run that started at `run_start_unix_ns`.
    pub fn new(run_start_unix_ns: i64) -> RunFold {
        RunFold {
            run_start: run_start_unix_ns,
            accs: BTreeMap::new(),
            part: Vec::new(),
            end: 0.0,
        }
    }

    /// A part with this servo table begins (its servo indices are the table's).
    pub fn begin_part(&mut self, keys: &[ServoKey]) {
        self.end_part(None);
        self.part = keys
            .iter()
            .map(|key| {
                let acc = self
                    .accs
                    .remove(key)
                    .unwrap_or_else(|| Acc::new(self.run_start));
                (key.clone(), acc)
            })
            .collect();
    }

    /// A record of the current part.
    pub fn record(&mut self, record: &Record) {
        let t = record.t_us as f64 / 1e6;
        self.end = self.end.max(t);
        if let Some((_, acc)) = record
            .body
            .servo()
            .and_then(|s| self.part.get_mut(usize::from(s)))
        {
            acc.record(t, &record.body);
        }
    }

    /// The current part ends; `read` is its path if it was read (its header was), which the
    /// flights then name among their files.
    pub fn end_part(&mut self, read: Option<&Path>) {
        let part = std::mem::take(&mut self.part);
        // A name listed twice in one table keeps its first slot's figures.
        for (key, mut acc) in part.into_iter().rev() {
            if let Some(path) = read {
                acc.flight.files.push(path.to_path_buf());
            }
            self.accs.insert(key, acc);
        }
    }

    /// The run's flights: each servo that answered in it, with its figures.
    pub fn finish(mut self) -> RunFlights {
        self.end_part(None);
        let end = self.end;
        self.accs
            .into_iter()
            .filter_map(|(key, acc)| acc.finish(end).map(|f| (key, f)))
            .collect()
    }
}

/// Read the parts of one run (sorted by part) into flights.
fn read_run(run_start: i64, parts: &[Part], notes: &mut ReadNotes) -> RunFlights {
    let mut fold = RunFold::new(run_start);
    for (_, path, keys) in parts {
        fold.begin_part(keys);
        let result = scan_record(path, |r| fold.record(&r));
        match result {
            Ok(scan) => {
                for note in scan.notes {
                    notes.notes.push(format!("{}: {note}", path.display()));
                }
                fold.end_part(Some(path));
            }
            Err(e) => {
                notes.errors.push(e.to_string());
                fold.end_part(None);
            }
        }
    }
    fold.finish()
}

/// Read `files` (on up to the machine's cores) into each servo's flights, sorted by date.
pub fn read_flights(files: &[PathBuf]) -> (BTreeMap<ServoKey, Vec<Flight>>, ReadNotes) {
    let mut notes = ReadNotes::default();
    // Group the files by run.
    let mut runs: BTreeMap<i64, Vec<Part>> = BTreeMap::new();
    for path in files {
        match read_header(path) {
            Ok(h) => {
                let keys = servo_keys(&h);
                runs.entry(h.run_start_unix_ns)
                    .or_default()
                    .push((h.part, path.clone(), keys));
            }
            Err(e) => notes.errors.push(e.to_string()),
        }
    }
    let runs: Vec<(i64, Vec<Part>)> = runs
        .into_iter()
        .map(|(start, mut parts)| {
            parts.sort();
            (start, parts)
        })
        .collect();
    let workers = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .min(runs.len().max(1));
    let next = std::sync::atomic::AtomicUsize::new(0);
    let results: Vec<(Vec<(usize, RunFlights)>, ReadNotes)> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..workers)
            .map(|_| {
                scope.spawn(|| {
                    let mut out = Vec::new();
                    let mut notes = ReadNotes::default();
                    loop {
                        let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        let Some((start, parts)) = runs.get(i) else {
                            break;
                        };
                        out.push((i, read_run(*start, parts, &mut notes)));
                    }
                    (out, notes)
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().unwrap_or_default())
            .collect()
    });
    let mut by_run: Vec<(usize, RunFlights)> = Vec::new();
    for (out, n) in results {
        by_run.extend(out);
        notes.errors.extend(n.errors);
        notes.notes.extend(n.notes);
    }
    by_run.sort_by_key(|(i, _)| *i);
    let mut servos: BTreeMap<ServoKey, Vec<Flight>> = BTreeMap::new();
    for (_, flights) in by_run {
        for (key, flight) in flights {
            servos.entry(key).or_default().push(flight);
        }
    }
    (servos, notes)
}

// ---------------------------------------------------------------------------------------------
// Judging

fn median(mut values: Vec<f64>) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    values.sort_by(f64::total_cmp);
    let n = values.len();
    Some(if n % 2 == 1 {
        values[n / 2]
    } else {
        (values[n / 2 - 1] + values[n / 2]) / 2.0
    })
}

fn rise(
    figure: &'static str,
    value: Option<f64>,
    baseline: Option<f64>,
    min_rise: f64,
) -> Option<Finding> {
    let (value, baseline) = (value?, baseline?);
    let change = (value - baseline) / baseline;
    (baseline > 0.0 && change > RISE_LIMIT && value - baseline >= min_rise).then_some(Finding {
        figure,
        value,
        baseline,
        change,
    })
}

/// Judge one servo's flights (sorted by date), leaving out those before `since`.
pub fn judge(servo: ServoKey, flights: Vec<Flight>, since: Option<i64>) -> ServoTrend {
    let total = flights.len();
    let mut flights: Vec<Flight> = flights
        .into_iter()
        .filter(|f| since.is_none_or(|s| f.run_start_unix_ns >= s))
        .collect();
    let left_out = total - flights.len();
    let n = flights.len().min(BASELINE_FLIGHTS);
    let base = flights.get(..n).unwrap_or_default();
    let baseline = Baseline {
        flights: n,
        friction_ma_per_mm_s: median(base.iter().filter_map(|f| f.friction_ma_per_mm_s).collect()),
        holding_a: median(base.iter().filter_map(|f| f.holding_a).collect()),
        heating_c_per_min: median(base.iter().filter_map(|f| f.heating_c_per_min).collect()),
        rise_c: median(base.iter().filter_map(|f| f.rise_c).collect()),
        margin_c: median(base.iter().filter_map(|f| f.margin_c).collect()),
    };
    for (i, f) in flights.iter_mut().enumerate() {
        f.baseline = i < n;
        if i < BASELINE_FLIGHTS {
            continue;
        }
        let mut findings: Vec<Finding> = [
            rise(
                "friction",
                f.friction_ma_per_mm_s,
                baseline.friction_ma_per_mm_s,
                0.0,
            ),
            rise(
                "holding current",
                f.holding_a,
                baseline.holding_a,
                HOLDING_MIN_RISE_A,
            ),
            rise(
                "heating",
                f.heating_c_per_min,
                baseline.heating_c_per_min,
                0.0,
            )
            .filter(|_| {
                matches!((f.rise_c, baseline.rise_c), (Some(r), Some(b)) if r - b >= HEATING_MIN_EXTRA_C)
            }),
        ]
        .into_iter()
        .flatten()
        .collect();
        if let (Some(margin), Some(base)) = (f.margin_c, baseline.margin_c)
            && base - margin > MARGIN_MIN_DROP_C
        {
            findings.push(Finding {
                figure: "temperature margin",
                value: margin,
                baseline: base,
                change: margin - base,
            });
        }
        f.findings = findings;
    }
    let judged = flights.len() > BASELINE_FLIGHTS;
    let marked: Vec<usize> = (0..flights.len())
        .filter(|&i| !flights[i].findings.is_empty())
        .collect();
    let latest_marked = flights.last().is_some_and(|f| !f.findings.is_empty());
    let (verdict, triggers, marked_since) = if !judged {
        (Verdict::Baseline, Vec::new(), None)
    } else if latest_marked {
        let mut first = flights.len() - 1;
        while first > 0 && !flights[first - 1].findings.is_empty() {
            first -= 1;
        }
        (
            Verdict::Inspect,
            flights[flights.len() - 1].findings.clone(),
            Some(first + 1),
        )
    } else if let Some(&last) = marked.last() {
        (
            Verdict::Watch,
            flights[last].findings.clone(),
            Some(last + 1),
        )
    } else {
        (Verdict::Ok, Vec::new(), None)
    };
    let change = |value: Option<f64>, base: Option<f64>| match (value, base) {
        (Some(v), Some(b)) if b > 0.0 && judged => Some((v - b) / b),
        _ => None,
    };
    let latest = flights.last();
    let totals = Totals {
        flights: flights.len(),
        force_on_h: flights.iter().map(|f| f.force_on_s).sum::<f64>() / 3600.0,
        motion_h: flights.iter().map(|f| f.motion_s).sum::<f64>() / 3600.0,
        travel_m: flights.iter().map(|f| f.travel_mm).sum::<f64>() / 1000.0,
        reversals: flights.iter().map(|f| f.reversals).sum(),
        stalled_s: flights.iter().map(|f| f.stalled_s).sum(),
        hot_min: flights.iter().map(|f| f.hot_min).sum(),
        alarms: flights.iter().map(|f| f.alarms).sum(),
        friction_change: change(
            latest.and_then(|f| f.friction_ma_per_mm_s),
            baseline.friction_ma_per_mm_s,
        ),
        heating_change: change(
            latest.and_then(|f| f.heating_c_per_min),
            baseline.heating_c_per_min,
        ),
    };
    ServoTrend {
        servo,
        verdict,
        triggers,
        marked_since,
        left_out,
        baseline,
        totals,
        flights,
    }
}

/// Read `files` and judge every servo in them; `since` starts new baselines.
pub fn trend(files: &[PathBuf], since: &[Since]) -> (Trend, ReadNotes) {
    let (servos, notes) = read_flights(files);
    let servos = servos
        .into_iter()
        .map(|(key, flights)| {
            let since = since
                .iter()
                .filter(|s| s.servo.as_ref().is_none_or(|n| *n == key.name))
                // A servo's own date wins over one for every servo.
                .max_by_key(|s| (s.servo.is_some(), s.unix_ns))
                .map(|s| s.unix_ns);
            judge(key, flights, since)
        })
        .collect();
    (
        Trend {
            thresholds: Thresholds::default(),
            files: files.len(),
            servos,
        },
        notes,
    )
}

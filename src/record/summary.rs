//! Per-servo figures of a recording: what `lj9da-bridge record summary` prints.
//!
//! Definitions (every time in seconds since the run's start):
//! - **duration**: from the servo's first telemetry sample to its last;
//! - **samples**: telemetry records; temperature and voltage minimum / mean / maximum over
//!   them, current over them and the motion records (reads of position and current between two
//!   full ones; plain means over reads, not weighted by time);
//! - **time stalled** / **time offline**: the total time between a health record that says
//!   stalled (offline) and the next that does not, or the end of the recording;
//! - **max error**: the largest |goal − present position| over the samples and the position
//!   and motion records (reads of the position alone, or with the current), each paired with
//!   the goal in force at its time (the latest position goal; `hold` keeps it; `off` and
//!   `brake` end it, and samples without a goal in force are not paired). It includes the
//!   travel right after each new goal; **settled error** is the same over the samples taken
//!   at least [`SETTLE_S`] after the goal last changed;
//! - **alarms**: times a status flag of the servo's replies went on — temperature alarm,
//!   temperature error, flash write error — each counted separately, over every reply the
//!   record keeps (samples, position and motion records).
//!
//! The records of a servo are folded by [`ServoFold`], as `record trend` and `record plot`
//! fold them: the state, alarms, spans and temperatures are counted in one place.

use super::analysis::ServoFold;
pub use super::analysis::{Range, flag_alarms, servo_records, state_spans};
use super::format::{RecordBody, RecordServo};
use super::reader::Recording;
use crate::protocol::MmCenti;
use std::fmt;

/// How long after a goal change a sample counts towards the settled error, in seconds.
pub const SETTLE_S: f64 = 1.0;

/// The figures of one servo.
#[derive(Debug, Clone, PartialEq)]
pub struct ServoSummary {
    /// The servo's index in the record (its position in the mapping file).
    pub index: usize,
    pub servo: RecordServo,
    pub samples: u64,
    pub first_sample_s: Option<f64>,
    pub last_sample_s: Option<f64>,
    pub temperature_c: Option<Range>,
    pub current_a: Option<Range>,
    pub voltage_v: Option<Range>,
    /// Goal records.
    pub goals: u64,
    pub max_error_mm: Option<f64>,
    /// When the largest error was seen.
    pub max_error_at_s: Option<f64>,
    pub max_settled_error_mm: Option<f64>,
    pub stalled_s: f64,
    pub offline_s: f64,
    pub temperature_alarms: u32,
    pub temperature_errors: u32,
    pub flash_errors: u32,
    /// Event records about this servo.
    pub events: u32,
}

impl ServoSummary {
    /// Seconds from the first sample to the last (0 without samples).
    pub fn duration_s(&self) -> f64 {
        match (self.first_sample_s, self.last_sample_s) {
            (Some(a), Some(b)) => b - a,
            _ => 0.0,
        }
    }

    /// The highest current drawn, in A.
    pub fn peak_current_a(&self) -> Option<f64> {
        self.current_a.map(|r| r.max)
    }

    /// All flag alarms together.
    pub fn alarms(&self) -> u32 {
        self.temperature_alarms + self.temperature_errors + self.flash_errors
    }
}

/// The figures of a recording.
#[derive(Debug, Clone, PartialEq)]
pub struct Summary {
    pub run_start_unix_ns: i64,
    pub part: u16,
    /// From the first record to the last, in seconds.
    pub duration_s: f64,
    pub records: usize,
    /// Records the writer could not take (its `dropped` records).
    pub dropped: u64,
    /// Whether the file ends with the writer's end record.
    pub closed: bool,
    pub servos: Vec<ServoSummary>,
}

/// The figures of every servo of the recording's servo table.
pub fn summary(rec: &Recording) -> Summary {
    let servos = rec
        .header
        .servos
        .iter()
        .enumerate()
        .map(|(index, servo)| servo_summary(rec, index, servo))
        .collect();
    Summary {
        run_start_unix_ns: rec.header.run_start_unix_ns,
        part: rec.header.part,
        duration_s: rec.end_t_us().saturating_sub(rec.start_t_us()) as f64 / 1e6,
        records: rec.records.len(),
        dropped: rec.dropped(),
        closed: rec.closed,
        servos,
    }
}

impl ServoSummary {
    /// A present position seen at `t`, `since_goal` s after the goal in force (if any) changed.
    fn note_error(&mut self, goal: Option<MmCenti>, since_goal: f64, position: MmCenti, t: f64) {
        let Some(goal) = goal else {
            return;
        };
        let error = (goal.mm() - position.mm()).abs();
        if self.max_error_mm.is_none_or(|m| error > m) {
            self.max_error_mm = Some(error);
            self.max_error_at_s = Some(t);
        }
        if since_goal >= SETTLE_S {
            let m = self.max_settled_error_mm.get_or_insert(error);
            *m = m.max(error);
        }
    }
}

fn servo_summary(rec: &Recording, index: usize, servo: &RecordServo) -> ServoSummary {
    let mut s = ServoSummary {
        index,
        servo: servo.clone(),
        samples: 0,
        first_sample_s: None,
        last_sample_s: None,
        temperature_c: None,
        current_a: None,
        voltage_v: None,
        goals: 0,
        max_error_mm: None,
        max_error_at_s: None,
        max_settled_error_mm: None,
        stalled_s: 0.0,
        offline_s: 0.0,
        temperature_alarms: 0,
        temperature_errors: 0,
        flash_errors: 0,
        events: 0,
    };
    let mut fold = ServoFold::new();
    for r in servo_records(rec, index) {
        let t = r.t_s();
        fold.record(t, &r.body);
        let position = match &r.body {
            RecordBody::Telemetry { telemetry: tm, .. } => tm.present_position,
            RecordBody::Position { position, .. } => *position,
            RecordBody::Motion { motion: m, .. } => m.present_position,
            _ => continue,
        };
        s.note_error(fold.position_goal, t - fold.goal_since_s, position, t);
    }
    fold.finish(rec.end_t_us() as f64 / 1e6);
    for (_, name) in &fold.alarms {
        match *name {
            "temperature alarm" => s.temperature_alarms += 1,
            "temperature error" => s.temperature_errors += 1,
            _ => s.flash_errors += 1,
        }
    }
    s.samples = fold.samples;
    s.first_sample_s = fold.first_sample_s;
    s.last_sample_s = fold.last_sample_s;
    s.goals = fold.goals;
    s.events = fold.events;
    s.stalled_s = fold.stalled_spans.total();
    s.offline_s = fold.offline_spans.total();
    s.temperature_c = fold.temperature_c.range();
    s.current_a = fold.current_a.range();
    s.voltage_v = fold.voltage_v.range();
    s
}

fn opt(v: Option<f64>, decimals: usize) -> String {
    v.map_or_else(|| "-".to_string(), |v| format!("{v:.decimals$}"))
}

impl fmt::Display for Summary {
    /// An aligned table, one row per servo, then the alarms of each servo that had any.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "run started {}{}: {:.1} s, {} records, {}",
            super::clock::Utc::from_unix_ns(self.run_start_unix_ns),
            if self.part > 0 {
                format!(" (part {})", self.part)
            } else {
                String::new()
            },
            self.duration_s,
            self.records,
            if self.closed {
                "closed cleanly"
            } else {
                "not closed (see notes)"
            }
        )?;
        if self.dropped > 0 {
            writeln!(
                f,
                "{} records were dropped by the writer (queue full or disk error)",
                self.dropped
            )?;
        }
        let head = [
            "servo",
            "bus",
            "id",
            "ch",
            "duration s",
            "samples",
            "min °C",
            "mean °C",
            "max °C",
            "peak A",
            "mean V",
            "stalled s",
            "offline s",
            "max err mm",
            "settled err mm",
            "alarms",
        ];
        let mut rows: Vec<Vec<String>> = vec![head.iter().map(|h| h.to_string()).collect()];
        for s in &self.servos {
            rows.push(vec![
                s.servo.name.clone(),
                s.servo.bus.clone(),
                s.servo.id.to_string(),
                s.servo.channel.to_string(),
                format!("{:.1}", s.duration_s()),
                s.samples.to_string(),
                opt(s.temperature_c.map(|r| r.min), 0),
                opt(s.temperature_c.map(|r| r.mean), 1),
                opt(s.temperature_c.map(|r| r.max), 0),
                opt(s.peak_current_a(), 2),
                opt(s.voltage_v.map(|r| r.mean), 2),
                format!("{:.1}", s.stalled_s),
                format!("{:.1}", s.offline_s),
                opt(s.max_error_mm, 2),
                opt(s.max_settled_error_mm, 2),
                s.alarms().to_string(),
            ]);
        }
        let widths: Vec<usize> = (0..head.len())
            .map(|c| {
                rows.iter()
                    .map(|r| r.get(c).map_or(0, |s| s.chars().count()))
                    .max()
                    .unwrap_or(0)
            })
            .collect();
        for row in &rows {
            let mut line = String::new();
            for (c, (cell, width)) in row.iter().zip(&widths).enumerate() {
                if c > 0 {
                    line.push_str("  ");
                }
                let pad = width.saturating_sub(cell.chars().count());
                if c < 2 {
                    line.push_str(cell);
                    line.push_str(&" ".repeat(pad));
                } else {
                    line.push_str(&" ".repeat(pad));
                    line.push_str(cell);
                }
            }
            writeln!(f, "{}", line.trim_end())?;
        }
        for s in self.servos.iter().filter(|s| s.alarms() > 0) {
            let mut parts = Vec::new();
            for (n, what) in [
                (s.temperature_alarms, "temperature alarm"),
                (s.temperature_errors, "temperature error"),
                (s.flash_errors, "flash write error"),
            ] {
                if n > 0 {
                    parts.push(format!("{n} × {what}"));
                }
            }
            writeln!(f, "{}: {}", s.servo.name, parts.join(", "))?;
        }
        Ok(())
    }
}

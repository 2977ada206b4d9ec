//! One servo's records, folded record by record: the state and the counts that `record
//! summary`, `record trend` and `record plot` all take from them. Each of those adds only its
//! own figures on top (the summary its goal-to-position error, the trend its speeds, travel and
//! currents per speed).
//!
//! [`ServoFold`] takes the records of one servo in the order it is given them (the summary and
//! the pictures give a recording's records sorted by time, the trend a run's records as the
//! files hold them) and keeps:
//! - the servo's state after each record: online (health online or stale; no health record
//!   yet counts as online), stalled, whether its latest goal is one with force (not `off` or
//!   `brake`; no goal yet counts as with force), and the position goal in force (the latest
//!   position goal; `hold` keeps it, `off` and `brake` end it) with the time it last changed;
//! - the telemetry samples: how many, the first and the last one's time, and the temperature,
//!   current and voltage over them ([`Stats`]); the current also over the motion records;
//! - the times each status flag went on (temperature alarm, temperature error, flash write
//!   error), over every reply the record keeps: samples, position and motion records;
//! - the spans stalled and offline (a health record that says so, to the next that does not or
//!   the end given to [`ServoFold::finish`]);
//! - goal and event records, and the latest reply counts.

use super::format::{Record, RecordBody};
use super::reader::Recording;
use crate::bus::{Goal, Health};
use crate::protocol::{MmCenti, ReplyFlags};

/// Minimum, mean and maximum of a quantity.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Range {
    pub min: f64,
    pub mean: f64,
    pub max: f64,
}

/// A quantity's values so far: count, sum, extremes and the first.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Stats {
    pub n: u64,
    pub sum: f64,
    pub min: f64,
    pub max: f64,
    pub first: f64,
}

impl Stats {
    pub fn add(&mut self, v: f64) {
        if self.n == 0 {
            self.min = v;
            self.max = v;
            self.first = v;
        } else {
            self.min = self.min.min(v);
            self.max = self.max.max(v);
        }
        self.sum += v;
        self.n += 1;
    }

    /// The mean, if there was a value.
    pub fn mean(&self) -> Option<f64> {
        (self.n > 0).then(|| self.sum / self.n as f64)
    }

    /// The largest value, if any.
    pub fn peak(&self) -> Option<f64> {
        (self.n > 0).then_some(self.max)
    }

    /// The first value, if any.
    pub fn first(&self) -> Option<f64> {
        (self.n > 0).then_some(self.first)
    }

    pub fn range(&self) -> Option<Range> {
        (self.n > 0).then(|| Range {
            min: self.min,
            mean: self.sum / self.n as f64,
            max: self.max,
        })
    }
}

/// The spans during which a state holds, from the times it is seen to change.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Spans {
    since: Option<f64>,
    pub spans: Vec<(f64, f64)>,
}

impl Spans {
    /// The state is `on` from `t`.
    pub fn set(&mut self, t: f64, on: bool) {
        match (self.since, on) {
            (None, true) => self.since = Some(t),
            (Some(s), false) => {
                self.spans.push((s, t.max(s)));
                self.since = None;
            }
            _ => {}
        }
    }

    /// The records end at `end`: a span still open ends there.
    pub fn close(&mut self, end: f64) {
        if let Some(s) = self.since.take() {
            self.spans.push((s, end.max(s)));
        }
    }

    /// The spans' total length.
    pub fn total(&self) -> f64 {
        // A fold from +0.0: an empty float sum is −0.0, which prints as "-0.0".
        self.spans.iter().fold(0.0, |sum, (a, b)| sum + (b - a))
    }
}

/// The flags an alarm is counted for, with their names.
pub const ALARM_FLAGS: [(u8, &str); 3] = [
    (ReplyFlags::TEMPERATURE_ALARM, "temperature alarm"),
    (ReplyFlags::TEMPERATURE_ERROR, "temperature error"),
    (ReplyFlags::FLASH_WRITE_ERROR, "flash write error"),
];

/// One servo's records folded so far (see the module documentation).
#[derive(Debug, Clone)]
pub struct ServoFold {
    pub online: bool,
    pub stalled: bool,
    /// Whether the latest goal is one with force (not `off` or `brake`).
    pub goal_on: bool,
    /// The position goal in force.
    pub position_goal: Option<MmCenti>,
    /// When the position goal last changed, s.
    pub goal_since_s: f64,
    flags: ReplyFlags,
    pub goals: u64,
    pub events: u32,
    /// Telemetry records.
    pub samples: u64,
    pub first_sample_s: Option<f64>,
    pub last_sample_s: Option<f64>,
    /// Over the telemetry samples.
    pub temperature_c: Stats,
    /// Over the telemetry samples and the motion records.
    pub current_a: Stats,
    /// Over the telemetry samples.
    pub voltage_v: Stats,
    /// When a flag went on, and its name.
    pub alarms: Vec<(f64, &'static str)>,
    pub stalled_spans: Spans,
    pub offline_spans: Spans,
    /// The latest reply counts: answered, missed.
    pub replies: Option<(u32, u32)>,
}

impl Default for ServoFold {
    fn default() -> Self {
        ServoFold::new()
    }
}

impl ServoFold {
    pub fn new() -> ServoFold {
        ServoFold {
            online: true,
            stalled: false,
            goal_on: true,
            position_goal: None,
            goal_since_s: 0.0,
            flags: ReplyFlags(0),
            goals: 0,
            events: 0,
            samples: 0,
            first_sample_s: None,
            last_sample_s: None,
            temperature_c: Stats::default(),
            current_a: Stats::default(),
            voltage_v: Stats::default(),
            alarms: Vec::new(),
            stalled_spans: Spans::default(),
            offline_spans: Spans::default(),
            replies: None,
        }
    }

    /// The servo's records of `rec` (sorted by time), folded, the spans closed at the end of
    /// the recording.
    pub fn over(rec: &Recording, servo: usize) -> ServoFold {
        let mut fold = ServoFold::new();
        for r in servo_records(rec, servo) {
            fold.record(r.t_s(), &r.body);
        }
        fold.finish(rec.end_t_us() as f64 / 1e6);
        fold
    }

    /// Online with a goal that has force.
    pub fn force_on(&self) -> bool {
        self.online && self.goal_on
    }

    /// The status flags of a reply: each flag that went on is an alarm.
    fn flags(&mut self, t: f64, flags: ReplyFlags) {
        let rose = flags.risen_since(self.flags).0;
        for (bit, name) in ALARM_FLAGS {
            if rose & bit != 0 {
                self.alarms.push((t, name));
            }
        }
        self.flags = flags;
    }

    /// One record of the servo, at `t` s.
    pub fn record(&mut self, t: f64, body: &RecordBody) {
        match body {
            RecordBody::Goal { goal, .. } => {
                self.goals += 1;
                self.goal_on = !matches!(goal, Goal::Off | Goal::Brake);
                match goal {
                    Goal::Position(p) => {
                        if self.position_goal != Some(*p) {
                            self.goal_since_s = t;
                        }
                        self.position_goal = Some(*p);
                    }
                    Goal::Hold => {}
                    Goal::Off | Goal::Brake => self.position_goal = None,
                }
            }
            RecordBody::Telemetry {
                telemetry: tm,
                flags,
                ..
            } => {
                self.samples += 1;
                self.first_sample_s.get_or_insert(t);
                self.last_sample_s = Some(t);
                self.temperature_c.add(f64::from(tm.present_temperature.0));
                self.current_a.add(tm.present_load.amps());
                self.voltage_v.add(tm.present_voltage.volts());
                self.flags(t, *flags);
            }
            RecordBody::Position { flags, .. } => self.flags(t, *flags),
            RecordBody::Motion {
                motion: m, flags, ..
            } => {
                self.current_a.add(m.present_load.amps());
                self.flags(t, *flags);
            }
            RecordBody::Health {
                health, stalled, ..
            } => {
                self.online = matches!(health, Health::Online | Health::Stale);
                self.stalled_spans.set(t, *stalled);
                self.offline_spans.set(t, *health == Health::Offline);
                self.stalled = *stalled;
            }
            RecordBody::Replies {
                answered, missed, ..
            } => self.replies = Some((*answered, *missed)),
            RecordBody::Event { .. } => self.events += 1,
            RecordBody::AutopilotClock { .. }
            | RecordBody::Dropped { .. }
            | RecordBody::End { .. } => {}
        }
    }

    /// The records end at `end` s: close the spans still open.
    pub fn finish(&mut self, end: f64) {
        self.stalled_spans.close(end);
        self.offline_spans.close(end);
    }
}

/// The records about servo `servo`, in time order (stable for equal times).
pub fn servo_records(rec: &Recording, servo: usize) -> Vec<&Record> {
    let mut records: Vec<&Record> = rec
        .records
        .iter()
        .filter(|r| r.body.servo().map(usize::from) == Some(servo))
        .collect();
    records.sort_by_key(|r| r.t_us);
    records
}

/// The time spans, in seconds, during which servo `servo`'s health records satisfy `state`
/// (the last span ends at the end of the recording).
pub fn state_spans(
    rec: &Recording,
    servo: usize,
    state: impl Fn(Health, bool) -> bool,
) -> Vec<(f64, f64)> {
    let mut spans = Spans::default();
    for r in servo_records(rec, servo) {
        if let RecordBody::Health {
            health, stalled, ..
        } = r.body
        {
            spans.set(r.t_s(), state(health, stalled));
        }
    }
    spans.close(rec.end_t_us() as f64 / 1e6);
    spans.spans
}

/// The times, in seconds, at which a flag of servo `servo`'s replies went on, with the flag's
/// name. Every reply carries the flags, the reads of position (and current) between two full
/// reads too: a flag that came and went between two full reads counts.
pub fn flag_alarms(rec: &Recording, servo: usize) -> Vec<(f64, &'static str)> {
    ServoFold::over(rec, servo).alarms
}

//! A flight record as a ULog file, PX4's log format: pure encoding, no I/O.
//!
//! ULog opens in PlotJuggler, PX4 Flight Review, Foxglove, UAV Log Viewer and `pyulog`, so a
//! servo's record can be looked at beside the autopilot's own log. [`encode_ulog`] writes a
//! file of ULog file version 1 as PX4's "ULog File Format" specification describes it, all
//! integers little-endian:
//!
//! - the 16-byte header: the magic `ULog` `0x01 0x12 0x35`, version 1, and the time the log
//!   starts: the run's start in the file's time base (below);
//! - the definitions: the flag bits message (`B`: no flags, no appended data), one format
//!   message (`F`) per topic, information messages (`I`, below) and one multi information
//!   message (`M`, key `lj9da_record_note`) per note the reader made (a record cut by a power
//!   loss, damaged bytes skipped);
//! - the data: one subscription (`A`) per topic and instance, then every sample as a logged
//!   data message (`D`) and every event as a logged string (`L`), in time order (records of
//!   equal time in the record's order).
//!
//! # Topics
//!
//! Each topic's first field is `uint64_t timestamp` (µs, see Time). The per-servo topics have
//! one instance per servo: the `multi_id` is the servo's index in the record's servo table (the
//! mapping file's order), every servo of the table is subscribed to each topic the record has
//! samples of, so that instances count from 0. The others have the single instance 0.
//!
//! | topic | per servo | fields after `timestamp` | from record |
//! |---|---|---|---|
//! | `lj9da_goal` | yes | `float position_mm`, `uint8_t goal` (0 position, 1 hold, 2 off, 3 brake; `position_mm` 0 unless 0) | goal |
//! | `lj9da_telemetry` | yes | `float position_mm`, `float present_time_s`, `float current_a`, `float voltage_v`, `int16_t temperature_c`, `uint8_t flags` | telemetry |
//! | `lj9da_position` | yes | `float position_mm`, `uint8_t flags` | position |
//! | `lj9da_motion` | yes | `float position_mm`, `float present_time_s`, `float current_a`, `uint8_t flags` | motion |
//! | `lj9da_replies` | yes | `uint32_t answered`, `uint32_t missed` | replies |
//! | `lj9da_health` | yes | `uint8_t health` (0 starting, 1 online, 2 stale, 3 offline, 4 wrong model, 5 temperature error), `bool stalled` | health |
//! | `lj9da_event` | no | `uint8_t servo` (255: the bridge), `uint8_t severity` (MAV_SEVERITY) | event (its text is the logged string of the same time) |
//! | `lj9da_dropped` | no | `uint64_t count` | dropped |
//! | `lj9da_autopilot_clock` | no | `uint64_t time_usec`, `uint8_t bits` (32 or 64: the field it came in) | the autopilot's clock |
//!
//! Units are in the field names, as in PX4's own topics (`voltage_v`, `current_a`): mm, s, A,
//! V, °C. `flags` is the servo's reply status byte (0x80 temperature error, 0x20 temperature
//! alarm, 0x08 flash write error). A `float` is the float32 nearest to the servo's register
//! value ÷ 100 (0.01 mm, 10 ms, 10 mA, 10 mV): × 100 and rounded to the nearest integer it
//! gives the recorded value back exactly. The other fields are the recorded integers.
//!
//! Events are logged strings (`L`) with the event's text as it was recorded and the log level
//! of its MAVLink severity (`'0'` emergency … `'7'` debug, the same scale; a severity beyond 7
//! is logged as debug). Records the recorder had to drop are a warning (`'4'`) saying how many,
//! besides their `lj9da_dropped` sample. An end record is not exported.
//!
//! # Time
//!
//! A sample's `timestamp` is its record's `t_us` (µs since the run's start) plus one offset
//! for the whole file, [`TimeBase::offset_us`]:
//! - when the record holds the autopilot's boot clock (the `time_usec` of its output messages
//!   as the bridge heard them), the offset is [`autopilot_offset_us`] of those samples, and the
//!   timestamps count µs since the autopilot booted, the time base of the autopilot's own log;
//! - otherwise it is 0 and the timestamps count from the run's start.
//!
//! # Information messages
//!
//! | key | value |
//! |---|---|
//! | `char[] sys_name` | `lj9da-bridge` |
//! | `char[] ver_sw` | the program that wrote the record (`lj9da-bridge 0.1.0`) |
//! | `char[] lj9da_record_format` | the record's format version (`1.4`) |
//! | `uint16_t lj9da_record_part` | the record file's part of its run (0 the first) |
//! | `int64_t lj9da_run_start_unix_ns` | the run's start (record time 0), ns since 1970-01-01 UTC |
//! | `char[] lj9da_run_start_utc` | the same, `2026-11-21T23:59:59.123456Z` |
//! | `char[] lj9da_aircraft` | the aircraft the record names (only when it names one) |
//! | `char[] lj9da_time_base` | `autopilot boot` or `run start` |
//! | `int64_t lj9da_time_offset_us` | what was added to every record time |
//! | `uint8_t lj9da_servo_count` | the servos of the record's table |
//! | `char[] lj9da_servo_<i>_name`, `char[] lj9da_servo_<i>_bus`, `uint8_t lj9da_servo_<i>_id`, `uint8_t lj9da_servo_<i>_channel` | servo `i` (its `multi_id`): name, bus, RS485 ID, autopilot output |
//!
//! A sample's UTC time is `lj9da_run_start_unix_ns` + (`timestamp` − `lj9da_time_offset_us`) µs.
//! PX4's `time_ref_utc` (the local time zone's offset) is not written: the record knows UTC,
//! not the zone it was flown in.

use super::clock::Utc;
use super::format::{NO_SERVO, RecordBody, goal_code, health_code, truncate_utf8};
use super::reader::Recording;
use std::collections::BTreeSet;

/// The first 7 bytes of every ULog file.
pub const MAGIC: [u8; 7] = [0x55, 0x4C, 0x6F, 0x67, 0x01, 0x12, 0x35];
/// The ULog file version written.
pub const VERSION: u8 = 1;
/// The extension of ULog files.
pub const FILE_EXTENSION: &str = "ulg";
/// `sys_name` of every file.
pub const SYS_NAME: &str = "lj9da-bridge";
/// The `servo` of an `lj9da_event` about the bridge rather than one servo.
pub const BRIDGE: u8 = NO_SERVO;

/// ULog message types.
mod msg {
    pub const FLAG_BITS: u8 = b'B';
    pub const FORMAT: u8 = b'F';
    pub const INFO: u8 = b'I';
    pub const INFO_MULTIPLE: u8 = b'M';
    pub const SUBSCRIPTION: u8 = b'A';
    pub const DATA: u8 = b'D';
    pub const LOGGING: u8 = b'L';
}

/// The flag bits message's length: compat and incompat flags, three appended offsets.
const FLAG_BITS_LEN: usize = 8 + 8 + 3 * 8;
/// The log level of the note on dropped records: warning.
const DROPPED_LEVEL: u8 = b'4';
/// The longest text value of an information message (its message stays within `u16` bytes).
const MAX_INFO_TEXT: usize = 60_000;

/// The topics of the data section.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Topic {
    Goal,
    Telemetry,
    Position,
    Motion,
    Replies,
    Health,
    Event,
    Dropped,
    AutopilotClock,
}

impl Topic {
    /// Every topic, in the order of their format messages.
    pub const ALL: [Topic; 9] = [
        Topic::Goal,
        Topic::Telemetry,
        Topic::Position,
        Topic::Motion,
        Topic::Replies,
        Topic::Health,
        Topic::Event,
        Topic::Dropped,
        Topic::AutopilotClock,
    ];

    /// The topic's message name.
    pub fn name(self) -> &'static str {
        match self {
            Topic::Goal => "lj9da_goal",
            Topic::Telemetry => "lj9da_telemetry",
            Topic::Position => "lj9da_position",
            Topic::Motion => "lj9da_motion",
            Topic::Replies => "lj9da_replies",
            Topic::Health => "lj9da_health",
            Topic::Event => "lj9da_event",
            Topic::Dropped => "lj9da_dropped",
            Topic::AutopilotClock => "lj9da_autopilot_clock",
        }
    }

    /// The fields after `uint64_t timestamp`, as its format message lists them.
    pub fn fields(self) -> &'static str {
        match self {
            Topic::Goal => "float position_mm;uint8_t goal;",
            Topic::Telemetry => {
                "float position_mm;float present_time_s;float current_a;float voltage_v;\
                 int16_t temperature_c;uint8_t flags;"
            }
            Topic::Position => "float position_mm;uint8_t flags;",
            Topic::Motion => {
                "float position_mm;float present_time_s;float current_a;uint8_t flags;"
            }
            Topic::Replies => "uint32_t answered;uint32_t missed;",
            Topic::Health => "uint8_t health;bool stalled;",
            Topic::Event => "uint8_t servo;uint8_t severity;",
            Topic::Dropped => "uint64_t count;",
            Topic::AutopilotClock => "uint64_t time_usec;uint8_t bits;",
        }
    }

    /// The topic's format message: `name:uint64_t timestamp;fields`.
    pub fn format(self) -> String {
        format!("{}:uint64_t timestamp;{}", self.name(), self.fields())
    }

    /// Whether the topic has one instance per servo (else the single instance 0).
    pub fn per_servo(self) -> bool {
        !matches!(self, Topic::Event | Topic::Dropped | Topic::AutopilotClock)
    }

    fn index(self) -> usize {
        self as usize
    }
}

/// What the timestamps of a ULog file count from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TimeBase {
    /// The run's start: a timestamp is the record's time.
    RunStart,
    /// The autopilot's boot: a timestamp is the record's time plus `offset_us`.
    AutopilotBoot { offset_us: i64 },
}

impl TimeBase {
    /// What is added to every record time (µs).
    pub fn offset_us(self) -> i64 {
        match self {
            TimeBase::RunStart => 0,
            TimeBase::AutopilotBoot { offset_us } => offset_us,
        }
    }

    /// `run start` or `autopilot boot`, the value of `lj9da_time_base`.
    pub fn name(self) -> &'static str {
        match self {
            TimeBase::RunStart => "run start",
            TimeBase::AutopilotBoot { .. } => "autopilot boot",
        }
    }
}

/// One reading of the autopilot's boot clock: its `time_usec` as heard at record time `t_us`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ClockSample {
    /// The record's time, µs since the run's start.
    pub t_us: u64,
    /// µs since the autopilot booted, modulo 2^`bits` when `bits` is below 64.
    pub time_usec: u64,
    /// The width of the field it came in: 32 (SERVO_OUTPUT_RAW) or 64 (ACTUATOR_OUTPUT_STATUS).
    pub bits: u8,
}

impl ClockSample {
    /// The clock's period in µs: 2^`bits` for a field narrower than 64 bits, else `None`.
    fn period(self) -> Option<i128> {
        (1..64).contains(&self.bits).then(|| 1i128 << self.bits)
    }
}

/// The offset (µs) from record time to the autopilot's boot clock: the median, over the
/// samples, of `time_usec` − `t_us`; `None` without samples.
///
/// A 32-bit clock (SERVO_OUTPUT_RAW's, which wraps every 2³² µs, 71.6 min) is unwrapped with
/// the record's time: each sample is given the whole number of wraps that brings its
/// difference nearest to a reference, the median difference of the 64-bit samples if there
/// are any, else the earliest sample's own, taken as unwrapped. With only 32-bit samples, an
/// autopilot that had been up for more than 71.6 min at that first sample is therefore placed
/// a whole number of 71.6-min turns early; a 64-bit clock (ACTUATOR_OUTPUT_STATUS) has no
/// such limit.
///
/// The median (of an even count, the lower of the two middle differences) follows the clock
/// most samples share: a late or early message moves it by nothing, and after an autopilot
/// restart during the run, the clock of the longer part wins. The record stamps a sample when
/// the bridge handled the message, so the offset is late by the message's time on the link
/// (typically a few ms).
pub fn autopilot_offset_us(samples: impl IntoIterator<Item = ClockSample>) -> Option<i64> {
    let mut samples: Vec<ClockSample> = samples.into_iter().collect();
    samples.sort_by_key(|s| s.t_us);
    let diff = |value: u64, t_us: u64| i128::from(value) - i128::from(t_us);
    let full: Vec<i128> = samples
        .iter()
        .filter(|s| s.period().is_none())
        .map(|s| diff(s.time_usec, s.t_us))
        .collect();
    let reference = match lower_median(full) {
        Some(median) => median,
        None => {
            let first = samples.first()?;
            let period = first.period().unwrap_or(i128::MAX);
            i128::from(first.time_usec) % period - i128::from(first.t_us)
        }
    };
    let diffs = samples
        .iter()
        .map(|s| match s.period() {
            None => diff(s.time_usec, s.t_us),
            Some(period) => {
                let wrapped = i128::from(s.time_usec) % period - i128::from(s.t_us);
                let turns = (reference - wrapped + period / 2).div_euclid(period);
                wrapped + turns * period
            }
        })
        .collect();
    lower_median(diffs).and_then(|m| i64::try_from(m).ok())
}

/// The lower median of `values` (the middle one, or the lower of the two middle ones).
fn lower_median(mut values: Vec<i128>) -> Option<i128> {
    if values.is_empty() {
        return None;
    }
    let middle = (values.len() - 1) / 2;
    let (_, median, _) = values.select_nth_unstable(middle);
    Some(*median)
}

/// The autopilot clock samples a record holds.
pub fn clock_samples(rec: &Recording) -> impl Iterator<Item = ClockSample> + '_ {
    rec.records.iter().filter_map(|r| match r.body {
        RecordBody::AutopilotClock { time_usec, bits } => Some(ClockSample {
            t_us: r.t_us,
            time_usec,
            bits,
        }),
        _ => None,
    })
}

/// The time base of a record's ULog file: the autopilot's boot when the record holds the
/// autopilot's clock ([`autopilot_offset_us`]) and the run's start and every record's time,
/// moved by that offset, are ULog timestamps (0 … 2⁶⁴ − 1: not so when the autopilot booted
/// after the run started), else the run's start.
pub fn time_base(rec: &Recording) -> TimeBase {
    let Some(offset_us) = autopilot_offset_us(clock_samples(rec)) else {
        return TimeBase::RunStart;
    };
    let fits = |t_us: u64| {
        (0..=i128::from(u64::MAX)).contains(&(i128::from(t_us) + i128::from(offset_us)))
    };
    if fits(rec.start_t_us()) && fits(rec.end_t_us()) && fits(0) {
        TimeBase::AutopilotBoot { offset_us }
    } else {
        TimeBase::RunStart
    }
}

/// The record `rec` as a ULog file, in the time base [`time_base`] chooses.
pub fn encode_ulog(rec: &Recording) -> Vec<u8> {
    encode_in(rec, time_base(rec))
}

/// A record time moved into the time base (saturating: [`time_base`] only chooses offsets that
/// never saturate).
fn stamp(t_us: u64, base: TimeBase) -> u64 {
    let t = i128::from(t_us) + i128::from(base.offset_us());
    u64::try_from(t.max(0)).unwrap_or(u64::MAX)
}

fn encode_in(rec: &Recording, base: TimeBase) -> Vec<u8> {
    let mut sorted: Vec<_> = rec.records.iter().collect();
    // Stable: records of equal time keep the record's order.
    sorted.sort_by_key(|r| r.t_us);

    // Every (topic, instance) the data section needs, and its msg_id.
    let mut fields = Vec::with_capacity(32);
    let mut used: BTreeSet<(Topic, u8)> = BTreeSet::new();
    for r in &sorted {
        fields.clear();
        if let Some(key) = sample(&r.body, &mut fields) {
            used.insert(key);
        }
    }
    let table = u8::try_from(rec.header.servos.len()).unwrap_or(u8::MAX);
    let topics: BTreeSet<Topic> = used.iter().map(|&(topic, _)| topic).collect();
    for topic in topics.into_iter().filter(|t| t.per_servo()) {
        used.extend((0..table).map(|servo| (topic, servo)));
    }
    // At most 9 × 256 subscriptions: every msg_id fits a u16.
    let mut msg_ids: Vec<Option<u16>> = vec![None; Topic::ALL.len() * 256];
    for (id, &(topic, multi_id)) in used.iter().enumerate() {
        if let Some(slot) = msg_ids.get_mut(topic.index() * 256 + usize::from(multi_id)) {
            *slot = u16::try_from(id).ok();
        }
    }

    let mut out = Vec::with_capacity(4096 + rec.records.len() * 32);
    // Header.
    out.extend_from_slice(&MAGIC);
    out.push(VERSION);
    out.extend_from_slice(&stamp(0, base).to_le_bytes());
    // Definitions.
    message(&mut out, msg::FLAG_BITS, &[0u8; FLAG_BITS_LEN]);
    for topic in Topic::ALL {
        message(&mut out, msg::FORMAT, topic.format().as_bytes());
    }
    for (name, value) in info(rec, base) {
        info_message(&mut out, None, &name, &value);
    }
    for note in &rec.notes {
        info_message(
            &mut out,
            Some(false),
            "lj9da_record_note",
            &Info::Text(note.clone()),
        );
    }
    // Data.
    for (id, &(topic, multi_id)) in used.iter().enumerate() {
        let mut body = vec![multi_id];
        body.extend_from_slice(&u16::try_from(id).unwrap_or(u16::MAX).to_le_bytes());
        body.extend_from_slice(topic.name().as_bytes());
        message(&mut out, msg::SUBSCRIPTION, &body);
    }
    let mut body = Vec::with_capacity(64);
    for r in &sorted {
        let timestamp = stamp(r.t_us, base);
        fields.clear();
        if let Some((topic, multi_id)) = sample(&r.body, &mut fields)
            && let Some(Some(id)) = msg_ids.get(topic.index() * 256 + usize::from(multi_id))
        {
            body.clear();
            body.extend_from_slice(&id.to_le_bytes());
            body.extend_from_slice(&timestamp.to_le_bytes());
            body.extend_from_slice(&fields);
            message(&mut out, msg::DATA, &body);
        }
        let logged = match &r.body {
            RecordBody::Event { severity, text, .. } => {
                Some((b'0' + (*severity).min(7), text.clone()))
            }
            RecordBody::Dropped { count } => Some((
                DROPPED_LEVEL,
                format!(
                    "lj9da-bridge: {count} records dropped here by the recorder (its queue was \
                     full, or the disk failed)"
                ),
            )),
            _ => None,
        };
        if let Some((level, text)) = logged {
            body.clear();
            body.push(level);
            body.extend_from_slice(&timestamp.to_le_bytes());
            body.extend_from_slice(text.as_bytes());
            message(&mut out, msg::LOGGING, &body);
        }
    }
    out
}

/// The data sample a record becomes: its topic and instance, and its fields after the
/// timestamp appended to `out`; `None` for an end record.
fn sample(body: &RecordBody, out: &mut Vec<u8>) -> Option<(Topic, u8)> {
    let float = |out: &mut Vec<u8>, raw: i32| out.extend_from_slice(&hundredths(raw).to_le_bytes());
    Some(match body {
        RecordBody::Goal { servo, goal } => {
            let (code, position) = goal_code(*goal);
            float(out, i32::from(position));
            out.push(code);
            (Topic::Goal, *servo)
        }
        RecordBody::Telemetry {
            servo,
            telemetry: t,
            flags,
        } => {
            float(out, i32::from(t.present_position.0));
            float(out, i32::from(t.present_time.0));
            float(out, i32::from(t.present_load.0));
            float(out, i32::from(t.present_voltage.0));
            out.extend_from_slice(&t.present_temperature.0.to_le_bytes());
            out.push(flags.0);
            (Topic::Telemetry, *servo)
        }
        RecordBody::Position {
            servo,
            position,
            flags,
        } => {
            float(out, i32::from(position.0));
            out.push(flags.0);
            (Topic::Position, *servo)
        }
        RecordBody::Motion {
            servo,
            motion: m,
            flags,
        } => {
            float(out, i32::from(m.present_position.0));
            float(out, i32::from(m.present_time.0));
            float(out, i32::from(m.present_load.0));
            out.push(flags.0);
            (Topic::Motion, *servo)
        }
        RecordBody::Replies {
            servo,
            answered,
            missed,
        } => {
            out.extend_from_slice(&answered.to_le_bytes());
            out.extend_from_slice(&missed.to_le_bytes());
            (Topic::Replies, *servo)
        }
        RecordBody::Health {
            servo,
            health,
            stalled,
        } => {
            out.push(health_code(*health));
            out.push(u8::from(*stalled));
            (Topic::Health, *servo)
        }
        RecordBody::Event {
            servo, severity, ..
        } => {
            out.push(servo.unwrap_or(BRIDGE));
            out.push(*severity);
            (Topic::Event, 0)
        }
        RecordBody::Dropped { count } => {
            out.extend_from_slice(&count.to_le_bytes());
            (Topic::Dropped, 0)
        }
        RecordBody::AutopilotClock { time_usec, bits } => {
            out.extend_from_slice(&time_usec.to_le_bytes());
            out.push(*bits);
            (Topic::AutopilotClock, 0)
        }
        RecordBody::End { .. } => return None,
    })
}

/// The float32 nearest to `raw` ÷ 100: × 100 and rounded, `raw` again for every `raw` of 16
/// bits (the float's 24-bit significand keeps it within 0.004 of `raw` ÷ 100 × 100).
pub fn hundredths(raw: i32) -> f32 {
    (f64::from(raw) / 100.0) as f32
}

/// An information message's value.
#[derive(Debug, Clone, PartialEq, Eq)]
enum Info {
    Text(String),
    U8(u8),
    U16(u16),
    I64(i64),
}

/// The information messages of a record's file, in order.
fn info(rec: &Recording, base: TimeBase) -> Vec<(String, Info)> {
    let h = &rec.header;
    let text = |s: &str| Info::Text(s.to_string());
    let mut info = vec![
        ("sys_name".to_string(), text(SYS_NAME)),
        ("ver_sw".to_string(), text(&h.software)),
        (
            "lj9da_record_format".to_string(),
            Info::Text(format!("{}.{}", h.version.0, h.version.1)),
        ),
        ("lj9da_record_part".to_string(), Info::U16(h.part)),
        (
            "lj9da_run_start_unix_ns".to_string(),
            Info::I64(h.run_start_unix_ns),
        ),
        (
            "lj9da_run_start_utc".to_string(),
            Info::Text(Utc::from_unix_ns(h.run_start_unix_ns).iso_micros()),
        ),
    ];
    if let Some(aircraft) = &h.aircraft {
        info.push(("lj9da_aircraft".to_string(), text(aircraft)));
    }
    info.push(("lj9da_time_base".to_string(), text(base.name())));
    info.push((
        "lj9da_time_offset_us".to_string(),
        Info::I64(base.offset_us()),
    ));
    info.push((
        "lj9da_servo_count".to_string(),
        Info::U8(u8::try_from(h.servos.len()).unwrap_or(u8::MAX)),
    ));
    for (i, s) in h.servos.iter().enumerate() {
        info.push((format!("lj9da_servo_{i}_name"), text(&s.name)));
        info.push((format!("lj9da_servo_{i}_bus"), text(&s.bus)));
        info.push((format!("lj9da_servo_{i}_id"), Info::U8(s.id)));
        info.push((format!("lj9da_servo_{i}_channel"), Info::U8(s.channel)));
    }
    info
}

/// Append an information message (`I`), or with `continued` a multi information message
/// (`M`): key `type name`, then the value's bytes.
fn info_message(out: &mut Vec<u8>, continued: Option<bool>, name: &str, value: &Info) {
    let (kind, bytes) = match value {
        Info::Text(s) => {
            let s = truncate_utf8(s, MAX_INFO_TEXT);
            (format!("char[{}]", s.len()), s.as_bytes().to_vec())
        }
        Info::U8(v) => ("uint8_t".to_string(), vec![*v]),
        Info::U16(v) => ("uint16_t".to_string(), v.to_le_bytes().to_vec()),
        Info::I64(v) => ("int64_t".to_string(), v.to_le_bytes().to_vec()),
    };
    let key = format!("{kind} {name}");
    let mut body = Vec::with_capacity(2 + key.len() + bytes.len());
    if let Some(continued) = continued {
        body.push(u8::from(continued));
    }
    // Keys are short: a type and a name of at most 40 bytes.
    body.push(u8::try_from(key.len()).unwrap_or(u8::MAX));
    body.extend_from_slice(key.as_bytes());
    body.extend_from_slice(&bytes);
    let kind = if continued.is_some() {
        msg::INFO_MULTIPLE
    } else {
        msg::INFO
    };
    message(out, kind, &body);
}

/// Append a message: `msg_size` (`u16`), `msg_type`, `body`. Every body this module makes is
/// far below 65 535 bytes (an event's text is at most a record's 4 096).
fn message(out: &mut Vec<u8>, kind: u8, body: &[u8]) {
    let body = body.get(..usize::from(u16::MAX)).unwrap_or(body);
    let size = u16::try_from(body.len()).unwrap_or(u16::MAX);
    out.extend_from_slice(&size.to_le_bytes());
    out.push(kind);
    out.extend_from_slice(body);
}

#[cfg(test)]
mod tests;

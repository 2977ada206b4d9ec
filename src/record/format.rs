//! The flight record file format, version 1.4: pure encoding and decoding, no I/O.
//!
//! A record file (`*.lj9rec`) is a header followed by records, all integers little-endian.
//! Every part of the file is checked by a CRC-32 ([`super::crc32`]: IEEE, as zlib), so that
//! a file cut by a power loss, or damaged on the card, reads back everything before the
//! damage.
//!
//! # Header
//!
//! | offset | size | field |
//! |---|---|---|
//! | 0 | 8 | magic: the ASCII bytes `LJ9DAREC` |
//! | 8 | 2 | format major version, `u16` (1). A reader refuses a major version it does not know |
//! | 10 | 2 | format minor version, `u16` (4; 1.0 to 1.3 files are still read). Minor versions only add: a reader of 1.0 reads 1.x |
//! | 12 | 4 | `body_len`, `u32`: the bytes of the header body that follows (at most 1 MiB) |
//! | 16 | `body_len` | the header body, below |
//! | 16 + `body_len` | 4 | CRC-32 of bytes 0 … 16 + `body_len` − 1 |
//!
//! Header body:
//!
//! | size | field |
//! |---|---|
//! | 8 | `run_start_unix_ns`, `i64`: wall-clock time of the run's start in ns since 1970-01-01 UTC. Every record's time counts from it, in every part of the run |
//! | 8 | `part_start_unix_ns`, `i64`: wall-clock time this file was opened |
//! | 2 | `part`, `u16`: 0 for a run's first file, then 1, 2, … when a long run continues in a new file |
//! | 1 + n | `software`: length `u8`, then that many bytes of UTF-8 (e.g. `lj9da-bridge 0.1.0`) |
//! | 2 | `servo_count`, `u16`, at most 255 |
//! | … | the servo table: for each servo, in the mapping file's order (its position is the servo index records use): `name` (length `u8` + UTF-8), `bus` (length `u8` + UTF-8), `id` `u8` (1–127), `channel` `u8` (autopilot output 1–32) |
//! | 1 + n | `aircraft` (1.4): length `u8`, then that many bytes of UTF-8: the aircraft the bridge flew on (the mapping's `[record] aircraft`, else the computer's host name); empty if unknown. A file before 1.4 ends its body before it |
//! | … | (a later minor version may append fields here; a reader skips to the end of the body) |
//!
//! # Records
//!
//! | size | field |
//! |---|---|
//! | 2 | `len`, `u16`: the bytes of `kind`, `t_us` and `payload` together (2 … 4096) |
//! | 1 | `kind`, `u8` (below; 0 is never used, so a zero-filled tail is never a record) |
//! | 1–10 | `t_us`: microseconds since `run_start_unix_ns`, unsigned LEB128 (7 bits per byte, low bits first, high bit set on every byte but the last) |
//! | `len` − 1 − size of `t_us` | `payload` |
//! | 4 | CRC-32 of the record's bytes from `len` to the end of `payload` |
//!
//! Kinds and their payloads (a later minor version may append bytes to a payload; a reader
//! ignores what it does not know, and skips a kind it does not know):
//!
//! | kind | name | payload |
//! |---|---|---|
//! | 1 | goal | `servo` `u8` · `goal` `u8` (0 position, 1 hold, 2 off, 3 brake) · `position` `i16` in 0.01 mm (0 unless `goal` is 0) — 4 bytes |
//! | 2 | telemetry | `servo` `u8` · `flags` `u8` (the reply's status byte: 0x80 temperature error, 0x20 temperature alarm, 0x08 flash write error) · `present_position` `i16` 0.01 mm · `present_time` `u16` 10 ms · `present_load` `u16` 10 mA · `present_temperature` `i16` °C · `present_voltage` `u16` 10 mV — 12 bytes |
//! | 3 | health | `servo` `u8` · `health` `u8` (0 starting, 1 online, 2 stale, 3 offline, 4 wrong model, 5 temperature error) · `stalled` `u8` (0 or 1) — 3 bytes |
//! | 4 | event | `servo` `u8` (255: the bridge, not one servo) · `severity` `u8` (MAV_SEVERITY: 0 emergency … 7 debug) · `text`: the rest of the payload, UTF-8, at most 1000 bytes |
//! | 5 | dropped | `count` `u64`: records the writer could not take since the previous `dropped` record (its queue was full, or the disk failed) |
//! | 6 | end | `next` `u8`: 0 the run ended here cleanly, 1 the run continues in the next part |
//! | 7 | position (1.1) | `servo` `u8` · `flags` `u8` (as in telemetry) · `present_position` `i16` 0.01 mm — 4 bytes; from 1.3, a read of position and current (a motion record) appends `present_time` `u16` 10 ms · `present_load` `u16` 10 mA — 8 bytes |
//! | 8 | replies (1.2) | `servo` `u8` · `answered` `u32` · `missed` `u32`: the servo's requests since its bus started that got a good reply, and that got a garbled reply or none (both saturate at `u32::MAX`) — 9 bytes |
//! | 9 | autopilot clock (1.4) | `bits` `u8` (32 or 64) · `time_usec` `u64`: the autopilot's boot clock, µs, as an output message the bridge took from it carried it (SERVO_OUTPUT_RAW's 32-bit `time_usec`, which wraps every 71.6 min; ACTUATOR_OUTPUT_STATUS's 64-bit one), stamped with the time the bridge handled it — 9 bytes |
//!
//! A goal is what the bridge handed to the bus (one record per change); a telemetry record is
//! one reply of registers 42–59, stamped with the time it arrived; a position record is one
//! reply of registers 42–43 alone (the bus master reads the position by itself in bus time too
//! short for a full poll), and a motion record one reply of registers 42–49 (position, present
//! time and current: the reads between two full ones; a 1.1 or 1.2 reader takes it for a
//! position record); a health record is written
//! when a servo's health or its stall state changes; an event is a STATUSTEXT or bus event; a
//! replies record is written at most once a second per servo while its counts change (the
//! share of bad replies over a flight is the last one's `missed` over its sum: a wiring figure
//! for `record trend`); an autopilot clock record is written for the first output message
//! that carries a clock and then at most once a second (`time_usec` − `t_us` places the
//! record on the autopilot's own log's time axis, within the message's transit).
//!
//! A telemetry record takes 22–24 bytes (24 from 4.5 min to 9.5 h into a run).
//!
//! # Reading damaged files
//!
//! [`decode_record`] says whether the bytes at a position are a whole record, a record the
//! file ends in the middle of, or not a record. The reader ([`super::reader`]) skips what is
//! not a record to the next position where a whole record with a correct CRC starts, and
//! notes what it skipped; see there.

use super::crc::crc32;
use crate::bus::{Goal, Health};
use crate::config::Config;
use crate::protocol::{Celsius, Ma10, MmCenti, Motion, Ms10, Mv10, ReplyFlags, Telemetry};
use std::fmt;

/// The first 8 bytes of every record file.
pub const MAGIC: [u8; 8] = *b"LJ9DAREC";
/// The format's major version: a reader refuses any other.
pub const VERSION_MAJOR: u16 = 1;
/// The format's minor version (additions only).
pub const VERSION_MINOR: u16 = 4;
/// The extension of record files (rotation only ever deletes files with it).
pub const FILE_EXTENSION: &str = "lj9rec";
/// The largest `len` a record may have.
pub const MAX_RECORD_LEN: usize = 4096;
/// The largest header body a reader accepts.
pub const MAX_HEADER_BODY: usize = 1 << 20;
/// The longest event text, in bytes (longer texts are cut at a character boundary).
pub const MAX_EVENT_TEXT: usize = 1000;
/// The servo index of an event about the bridge rather than one servo.
pub const NO_SERVO: u8 = 255;
/// The most servos a record can name (indices 0–254).
pub const MAX_SERVOS: usize = 255;

/// Bytes before the header body: magic, versions, `body_len`.
const HEADER_PREFIX: usize = 16;
/// Bytes of a record around `kind`, `t_us` and payload: `len` and the CRC.
const RECORD_FRAME: usize = 2 + 4;

/// Record kinds.
pub mod kind {
    pub const GOAL: u8 = 1;
    pub const TELEMETRY: u8 = 2;
    pub const HEALTH: u8 = 3;
    pub const EVENT: u8 = 4;
    pub const DROPPED: u8 = 5;
    pub const END: u8 = 6;
    /// Since format 1.1; with a longer payload, a motion record (1.3).
    pub const POSITION: u8 = 7;
    /// Since format 1.2.
    pub const REPLIES: u8 = 8;
    /// Since format 1.4.
    pub const AUTOPILOT_CLOCK: u8 = 9;
    /// Every kind this version reads (they are numbered without gaps).
    pub const KNOWN: std::ops::RangeInclusive<u8> = GOAL..=AUTOPILOT_CLOCK;
}

/// Payload bytes of each fixed-size kind (a longer payload is a later minor version's).
const GOAL_LEN: usize = 4;
const TELEMETRY_LEN: usize = 12;
const HEALTH_LEN: usize = 3;
const EVENT_MIN_LEN: usize = 2;
const DROPPED_LEN: usize = 8;
const END_LEN: usize = 1;
const POSITION_LEN: usize = 4;
const MOTION_LEN: usize = 8;
const REPLIES_LEN: usize = 9;
const AUTOPILOT_CLOCK_LEN: usize = 9;

/// One servo of the header's servo table.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecordServo {
    pub name: String,
    pub bus: String,
    pub id: u8,
    pub channel: u8,
}

impl RecordServo {
    pub fn new(name: impl Into<String>, bus: impl Into<String>, id: u8, channel: u8) -> Self {
        RecordServo {
            name: name.into(),
            bus: bus.into(),
            id,
            channel,
        }
    }

    /// The servo table of a mapping file, in its order (the servo indices of the bridge).
    pub fn from_config(cfg: &Config) -> Vec<RecordServo> {
        cfg.servos
            .iter()
            .map(|s| RecordServo::new(&s.name, &s.bus, s.id.get(), s.channel))
            .collect()
    }
}

/// A record file's header.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecordHeader {
    /// (major, minor) of the file.
    pub version: (u16, u16),
    /// The run's start, ns since 1970-01-01 UTC: time 0 of every record.
    pub run_start_unix_ns: i64,
    /// When this file was opened, ns since 1970-01-01 UTC.
    pub part_start_unix_ns: i64,
    /// 0 for a run's first file, then 1, 2, …
    pub part: u16,
    /// The program that wrote the file.
    pub software: String,
    pub servos: Vec<RecordServo>,
    /// The aircraft the bridge flew on (format 1.4); `None` in older files, or if the bridge
    /// did not know it.
    pub aircraft: Option<String>,
}

impl RecordHeader {
    /// The header of a run's first file, written by this program, naming no aircraft.
    pub fn new(run_start_unix_ns: i64, servos: Vec<RecordServo>) -> Self {
        RecordHeader {
            version: (VERSION_MAJOR, VERSION_MINOR),
            run_start_unix_ns,
            part_start_unix_ns: run_start_unix_ns,
            part: 0,
            software: concat!("lj9da-bridge ", env!("CARGO_PKG_VERSION")).to_string(),
            servos,
            aircraft: None,
        }
    }

    /// The same header naming `aircraft` (cut to 255 bytes as the file keeps it; an empty
    /// name is none).
    pub fn with_aircraft(mut self, aircraft: Option<&str>) -> Self {
        self.aircraft = aircraft
            .map(|a| truncate_utf8(a, usize::from(u8::MAX)).to_string())
            .filter(|a| !a.is_empty());
        self
    }
}

/// MAVLink severities (MAV_SEVERITY), as recorded in events.
pub mod severity {
    pub const EMERGENCY: u8 = 0;
    pub const ALERT: u8 = 1;
    pub const CRITICAL: u8 = 2;
    pub const ERROR: u8 = 3;
    pub const WARNING: u8 = 4;
    pub const NOTICE: u8 = 5;
    pub const INFO: u8 = 6;
    pub const DEBUG: u8 = 7;

    /// The severity's name in lower case (`"warning"`), or its number for an unknown one.
    pub fn name(severity: u8) -> String {
        match severity {
            EMERGENCY => "emergency",
            ALERT => "alert",
            CRITICAL => "critical",
            ERROR => "error",
            WARNING => "warning",
            NOTICE => "notice",
            INFO => "info",
            DEBUG => "debug",
            other => return format!("severity {other}"),
        }
        .to_string()
    }
}

/// What a record says.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum RecordBody {
    /// The goal the bridge handed to the bus for this servo.
    Goal { servo: u8, goal: Goal },
    /// One telemetry reply (registers 42–59) and the reply's status flags.
    Telemetry {
        servo: u8,
        telemetry: Telemetry,
        flags: ReplyFlags,
    },
    /// One reply of registers 42–43 alone (the present position) and its status flags.
    Position {
        servo: u8,
        position: MmCenti,
        flags: ReplyFlags,
    },
    /// One reply of registers 42–49 (present position, time and current) and its status flags
    /// (since format 1.3).
    Motion {
        servo: u8,
        motion: Motion,
        flags: ReplyFlags,
    },
    /// The servo's reply counts since its bus started: good replies, and garbled or missing
    /// ones (since format 1.2).
    Replies {
        servo: u8,
        answered: u32,
        missed: u32,
    },
    /// The autopilot's boot clock, µs, carried by an output message the bridge took (since
    /// format 1.4). `bits` is the width of the message's field: 32 (SERVO_OUTPUT_RAW: the
    /// clock modulo 2³²) or 64 (ACTUATOR_OUTPUT_STATUS).
    AutopilotClock { time_usec: u64, bits: u8 },
    /// The servo's health or stall state changed.
    Health {
        servo: u8,
        health: Health,
        stalled: bool,
    },
    /// A STATUSTEXT or bus event; `servo` is `None` for the bridge as a whole.
    Event {
        servo: Option<u8>,
        severity: u8,
        text: String,
    },
    /// Records the writer could not take since the previous `Dropped` record.
    Dropped { count: u64 },
    /// The writer closed the file: the run ended, or (`continued`) goes on in the next part.
    End { continued: bool },
}

impl RecordBody {
    /// The servo the record is about, if any.
    pub fn servo(&self) -> Option<u8> {
        match self {
            RecordBody::Goal { servo, .. }
            | RecordBody::Telemetry { servo, .. }
            | RecordBody::Position { servo, .. }
            | RecordBody::Motion { servo, .. }
            | RecordBody::Replies { servo, .. }
            | RecordBody::Health { servo, .. } => Some(*servo),
            RecordBody::Event { servo, .. } => *servo,
            RecordBody::AutopilotClock { .. }
            | RecordBody::Dropped { .. }
            | RecordBody::End { .. } => None,
        }
    }

    /// The kind's name, as in CSV exports.
    pub fn kind_name(&self) -> &'static str {
        match self {
            RecordBody::Goal { .. } => "goal",
            RecordBody::Telemetry { .. } => "telemetry",
            RecordBody::Position { .. } => "position",
            RecordBody::Motion { .. } => "motion",
            RecordBody::Replies { .. } => "replies",
            RecordBody::AutopilotClock { .. } => "autopilot clock",
            RecordBody::Health { .. } => "health",
            RecordBody::Event { .. } => "event",
            RecordBody::Dropped { .. } => "dropped",
            RecordBody::End { .. } => "end",
        }
    }
}

/// A record: what happened, and when (µs since the run's start).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Record {
    pub t_us: u64,
    pub body: RecordBody,
}

impl Record {
    /// The record's time in seconds since the run's start.
    pub fn t_s(&self) -> f64 {
        self.t_us as f64 / 1e6
    }
}

/// The wire code of a health state.
pub fn health_code(health: Health) -> u8 {
    match health {
        Health::Starting => 0,
        Health::Online => 1,
        Health::Stale => 2,
        Health::Offline => 3,
        Health::WrongModel => 4,
        Health::TemperatureError => 5,
    }
}

fn health_from_code(code: u8) -> Option<Health> {
    Some(match code {
        0 => Health::Starting,
        1 => Health::Online,
        2 => Health::Stale,
        3 => Health::Offline,
        4 => Health::WrongModel,
        5 => Health::TemperatureError,
        _ => return None,
    })
}

/// A health state's name in lower case, as in CSV exports.
pub fn health_name(health: Health) -> &'static str {
    match health {
        Health::Starting => "starting",
        Health::Online => "online",
        Health::Stale => "stale",
        Health::Offline => "offline",
        Health::WrongModel => "wrong model",
        Health::TemperatureError => "temperature error",
    }
}

/// A goal's wire code (0 position, 1 hold, 2 off, 3 brake) and its position in 0.01 mm (0 but
/// for a position).
pub fn goal_code(goal: Goal) -> (u8, i16) {
    match goal {
        Goal::Position(p) => (0, p.0),
        Goal::Hold => (1, 0),
        Goal::Off => (2, 0),
        Goal::Brake => (3, 0),
    }
}

/// A goal's name in lower case, as in CSV exports.
pub fn goal_name(goal: Goal) -> &'static str {
    match goal {
        Goal::Position(_) => "position",
        Goal::Hold => "hold",
        Goal::Off => "off",
        Goal::Brake => "brake",
    }
}

// ---------------------------------------------------------------------------------------------
// Encoding

/// Append `value` as unsigned LEB128.
pub fn put_varint(out: &mut Vec<u8>, mut value: u64) {
    loop {
        let byte = (value & 0x7F) as u8;
        value >>= 7;
        if value == 0 {
            out.push(byte);
            return;
        }
        out.push(byte | 0x80);
    }
}

/// The longest prefix of `s` of at most `max` bytes that ends at a character boundary.
pub fn truncate_utf8(s: &str, max: usize) -> &str {
    if s.len() <= max {
        return s;
    }
    let mut end = max;
    while end > 0 && !s.is_char_boundary(end) {
        end -= 1;
    }
    s.get(..end).unwrap_or_default()
}

fn put_str8(out: &mut Vec<u8>, s: &str) {
    let s = truncate_utf8(s, usize::from(u8::MAX));
    out.push(s.len() as u8);
    out.extend_from_slice(s.as_bytes());
}

/// The header's bytes. Names longer than 255 bytes are cut; servos beyond [`MAX_SERVOS`] are
/// left out (the writer refuses such a table before it gets here).
pub fn encode_header(header: &RecordHeader) -> Vec<u8> {
    let mut body = Vec::with_capacity(64 + header.servos.len() * 24);
    body.extend_from_slice(&header.run_start_unix_ns.to_le_bytes());
    body.extend_from_slice(&header.part_start_unix_ns.to_le_bytes());
    body.extend_from_slice(&header.part.to_le_bytes());
    put_str8(&mut body, &header.software);
    let servos = header.servos.get(..MAX_SERVOS).unwrap_or(&header.servos);
    body.extend_from_slice(&(servos.len() as u16).to_le_bytes());
    for s in servos {
        put_str8(&mut body, &s.name);
        put_str8(&mut body, &s.bus);
        body.push(s.id);
        body.push(s.channel);
    }
    put_str8(&mut body, header.aircraft.as_deref().unwrap_or_default());
    let mut out = Vec::with_capacity(HEADER_PREFIX + body.len() + 4);
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&header.version.0.to_le_bytes());
    out.extend_from_slice(&header.version.1.to_le_bytes());
    out.extend_from_slice(&(body.len() as u32).to_le_bytes());
    out.extend_from_slice(&body);
    let crc = crc32(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    out
}

/// Append the record's bytes to `out`; returns how many were appended. An event's text is cut
/// to [`MAX_EVENT_TEXT`] bytes; an event about servo [`NO_SERVO`] reads back as one about the bridge.
pub fn encode_record(record: &Record, out: &mut Vec<u8>) -> usize {
    let start = out.len();
    out.extend_from_slice(&[0, 0]); // len, filled in below
    let kind = match &record.body {
        RecordBody::Goal { .. } => kind::GOAL,
        RecordBody::Telemetry { .. } => kind::TELEMETRY,
        RecordBody::Position { .. } | RecordBody::Motion { .. } => kind::POSITION,
        RecordBody::Replies { .. } => kind::REPLIES,
        RecordBody::AutopilotClock { .. } => kind::AUTOPILOT_CLOCK,
        RecordBody::Health { .. } => kind::HEALTH,
        RecordBody::Event { .. } => kind::EVENT,
        RecordBody::Dropped { .. } => kind::DROPPED,
        RecordBody::End { .. } => kind::END,
    };
    out.push(kind);
    put_varint(out, record.t_us);
    match &record.body {
        RecordBody::Goal { servo, goal } => {
            let (code, position) = goal_code(*goal);
            out.push(*servo);
            out.push(code);
            out.extend_from_slice(&position.to_le_bytes());
        }
        RecordBody::Telemetry {
            servo,
            telemetry: t,
            flags,
        } => {
            out.push(*servo);
            out.push(flags.0);
            out.extend_from_slice(&t.present_position.0.to_le_bytes());
            out.extend_from_slice(&t.present_time.0.to_le_bytes());
            out.extend_from_slice(&t.present_load.0.to_le_bytes());
            out.extend_from_slice(&t.present_temperature.0.to_le_bytes());
            out.extend_from_slice(&t.present_voltage.0.to_le_bytes());
        }
        RecordBody::Position {
            servo,
            position,
            flags,
        } => {
            out.push(*servo);
            out.push(flags.0);
            out.extend_from_slice(&position.0.to_le_bytes());
        }
        RecordBody::Motion {
            servo,
            motion: m,
            flags,
        } => {
            out.push(*servo);
            out.push(flags.0);
            out.extend_from_slice(&m.present_position.0.to_le_bytes());
            out.extend_from_slice(&m.present_time.0.to_le_bytes());
            out.extend_from_slice(&m.present_load.0.to_le_bytes());
        }
        RecordBody::Replies {
            servo,
            answered,
            missed,
        } => {
            out.push(*servo);
            out.extend_from_slice(&answered.to_le_bytes());
            out.extend_from_slice(&missed.to_le_bytes());
        }
        RecordBody::AutopilotClock { time_usec, bits } => {
            out.push(*bits);
            out.extend_from_slice(&time_usec.to_le_bytes());
        }
        RecordBody::Health {
            servo,
            health,
            stalled,
        } => {
            out.push(*servo);
            out.push(health_code(*health));
            out.push(u8::from(*stalled));
        }
        RecordBody::Event {
            servo,
            severity,
            text,
        } => {
            out.push(servo.unwrap_or(NO_SERVO));
            out.push(*severity);
            out.extend_from_slice(truncate_utf8(text, MAX_EVENT_TEXT).as_bytes());
        }
        RecordBody::Dropped { count } => out.extend_from_slice(&count.to_le_bytes()),
        RecordBody::End { continued } => out.push(u8::from(*continued)),
    }
    // At most 1 + 10 + 2 + MAX_EVENT_TEXT bytes, well below u16::MAX.
    let len = (out.len() - start - 2) as u16;
    if let Some(slot) = out.get_mut(start..start + 2) {
        slot.copy_from_slice(&len.to_le_bytes());
    }
    let crc = crc32(out.get(start..).unwrap_or_default());
    out.extend_from_slice(&crc.to_le_bytes());
    out.len() - start
}

// ---------------------------------------------------------------------------------------------
// Decoding

/// Why a header cannot be read.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum HeaderError {
    /// The bytes do not start with [`MAGIC`].
    NotARecord,
    /// A major version this reader does not know.
    UnsupportedVersion { major: u16, minor: u16 },
    /// The file ends inside the header.
    Truncated { len: usize, needed: usize },
    /// The header's CRC or layout is wrong.
    Damaged(String),
}

impl fmt::Display for HeaderError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            HeaderError::NotARecord => write!(
                f,
                "it is not an lj9da-bridge flight record (it does not start with \"LJ9DAREC\")"
            ),
            HeaderError::UnsupportedVersion { major, minor } => write!(
                f,
                "it is in record format {major}.{minor}, but this lj9da-bridge reads format \
                 {VERSION_MAJOR}.x only: read it with the lj9da-bridge version that wrote it, or a newer one"
            ),
            HeaderError::Truncated { len, needed } => write!(
                f,
                "the file ends inside its header ({len} of {needed} bytes): nothing was recorded in it"
            ),
            HeaderError::Damaged(why) => write!(f, "its header is damaged: {why}"),
        }
    }
}

/// A bounds-checked little-endian reader over a byte slice.
struct Cursor<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> Cursor<'a> {
    fn new(bytes: &'a [u8]) -> Self {
        Cursor { bytes, pos: 0 }
    }
    fn take(&mut self, n: usize) -> Option<&'a [u8]> {
        let end = self.pos.checked_add(n)?;
        let s = self.bytes.get(self.pos..end)?;
        self.pos = end;
        Some(s)
    }
    fn array<const N: usize>(&mut self) -> Option<[u8; N]> {
        self.take(N)?.try_into().ok()
    }
    fn u8(&mut self) -> Option<u8> {
        Some(self.array::<1>()?[0])
    }
    fn u16(&mut self) -> Option<u16> {
        Some(u16::from_le_bytes(self.array()?))
    }
    fn i16(&mut self) -> Option<i16> {
        Some(i16::from_le_bytes(self.array()?))
    }
    fn u32(&mut self) -> Option<u32> {
        Some(u32::from_le_bytes(self.array()?))
    }
    fn u64(&mut self) -> Option<u64> {
        Some(u64::from_le_bytes(self.array()?))
    }
    fn i64(&mut self) -> Option<i64> {
        Some(i64::from_le_bytes(self.array()?))
    }
    fn str8(&mut self) -> Option<String> {
        let n = self.u8()?;
        Some(String::from_utf8_lossy(self.take(usize::from(n))?).into_owned())
    }
    fn rest(&mut self) -> &'a [u8] {
        let s = self.bytes.get(self.pos..).unwrap_or_default();
        self.pos = self.bytes.len();
        s
    }
}

/// Read an unsigned LEB128 value: (value, bytes used), `None` if it runs past `bytes` or
/// over 64 bits.
pub fn get_varint(bytes: &[u8]) -> Option<(u64, usize)> {
    let mut value = 0u64;
    for (i, &b) in bytes.iter().enumerate().take(10) {
        let part = u64::from(b & 0x7F);
        if i == 9 && part > 1 {
            return None;
        }
        value |= part << (7 * i);
        if b & 0x80 == 0 {
            return Some((value, i + 1));
        }
    }
    None
}

/// Decode the header at the start of `bytes`: the header and its length in bytes.
pub fn decode_header(bytes: &[u8]) -> Result<(RecordHeader, usize), HeaderError> {
    let magic_len = MAGIC.len().min(bytes.len());
    if bytes.get(..magic_len) != MAGIC.get(..magic_len) {
        return Err(HeaderError::NotARecord);
    }
    let mut c = Cursor::new(bytes);
    let prefix = c
        .take(HEADER_PREFIX)
        .ok_or(HeaderError::Truncated {
            len: bytes.len(),
            needed: HEADER_PREFIX + 4,
        })?
        .to_vec();
    let mut p = Cursor::new(&prefix);
    let _magic = p.take(MAGIC.len());
    let major = p.u16().unwrap_or_default();
    let minor = p.u16().unwrap_or_default();
    let body_len = p.u32().unwrap_or_default() as usize;
    if major != VERSION_MAJOR {
        return Err(HeaderError::UnsupportedVersion { major, minor });
    }
    if body_len > MAX_HEADER_BODY {
        return Err(HeaderError::Damaged(format!(
            "it claims a {body_len}-byte header, more than the {MAX_HEADER_BODY} allowed"
        )));
    }
    let total = HEADER_PREFIX + body_len + 4;
    let (Some(body), Some(crc)) = (c.take(body_len), c.u32()) else {
        return Err(HeaderError::Truncated {
            len: bytes.len(),
            needed: total,
        });
    };
    let computed = crc32(bytes.get(..HEADER_PREFIX + body_len).unwrap_or_default());
    if computed != crc {
        return Err(HeaderError::Damaged(format!(
            "its CRC is 0x{crc:08X} but its bytes give 0x{computed:08X}"
        )));
    }
    let mut b = Cursor::new(body);
    let short = || HeaderError::Damaged("its body is shorter than its fields".to_string());
    let run_start_unix_ns = b.i64().ok_or_else(short)?;
    let part_start_unix_ns = b.i64().ok_or_else(short)?;
    let part = b.u16().ok_or_else(short)?;
    let software = b.str8().ok_or_else(short)?;
    let count = b.u16().ok_or_else(short)?;
    let mut servos = Vec::with_capacity(usize::from(count).min(MAX_SERVOS));
    for _ in 0..count {
        let name = b.str8().ok_or_else(short)?;
        let bus = b.str8().ok_or_else(short)?;
        let id = b.u8().ok_or_else(short)?;
        let channel = b.u8().ok_or_else(short)?;
        servos.push(RecordServo {
            name,
            bus,
            id,
            channel,
        });
    }
    // 1.4: the aircraft's name. A 1.4 writer always writes it; an older file has no byte here.
    let aircraft = if minor >= 4 {
        Some(b.str8().ok_or_else(short)?).filter(|a| !a.is_empty())
    } else {
        None
    };
    Ok((
        RecordHeader {
            version: (major, minor),
            run_start_unix_ns,
            part_start_unix_ns,
            part,
            software,
            servos,
            aircraft,
        },
        total,
    ))
}

/// What the bytes at one position of a file are.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Decoded {
    /// A whole record with a correct CRC, `len` bytes long.
    Record { record: Record, len: usize },
    /// A whole record with a correct CRC that this reader cannot use (a later minor version's
    /// kind or value): skip `len` bytes.
    Unsupported { what: String, len: usize },
    /// The bytes end before the record they start: `needed` bytes would make it whole.
    Incomplete { needed: usize },
    /// Not a record: a wrong CRC, length or layout.
    Invalid { why: String },
}

/// Decode the record that starts at `bytes[0]`.
pub fn decode_record(bytes: &[u8]) -> Decoded {
    let Some(len_bytes) = bytes.get(..2) else {
        return Decoded::Incomplete { needed: 2 };
    };
    let len = usize::from(u16::from_le_bytes([len_bytes[0], len_bytes[1]]));
    if !(2..=MAX_RECORD_LEN).contains(&len) {
        return Decoded::Invalid {
            why: format!("a record length of {len} bytes (allowed: 2 … {MAX_RECORD_LEN})"),
        };
    }
    let total = RECORD_FRAME + len;
    let kind = bytes.get(2).copied();
    if kind == Some(0) {
        return Decoded::Invalid {
            why: "record kind 0".to_string(),
        };
    }
    let Some(whole) = bytes.get(..total) else {
        return Decoded::Incomplete { needed: total };
    };
    let (covered, crc_bytes) = whole.split_at(2 + len);
    let stored = u32::from_le_bytes(crc_bytes.try_into().unwrap_or_default());
    let computed = crc32(covered);
    if stored != computed {
        return Decoded::Invalid {
            why: format!("a CRC of 0x{stored:08X} where the bytes give 0x{computed:08X}"),
        };
    }
    let inner = covered.get(2..).unwrap_or_default();
    let kind = inner.first().copied().unwrap_or_default();
    let Some((t_us, used)) = get_varint(inner.get(1..).unwrap_or_default()) else {
        return Decoded::Invalid {
            why: "a time field that runs past the record".to_string(),
        };
    };
    let payload = inner.get(1 + used..).unwrap_or_default();
    match decode_body(kind, payload) {
        Body::Ok(body) => Decoded::Record {
            record: Record { t_us, body },
            len: total,
        },
        Body::Short { name, needed } => Decoded::Invalid {
            why: format!(
                "a {name} record with {} payload bytes (needs {needed})",
                payload.len()
            ),
        },
        Body::Unsupported(what) => Decoded::Unsupported { what, len: total },
    }
}

enum Body {
    Ok(RecordBody),
    Short { name: &'static str, needed: usize },
    Unsupported(String),
}

fn decode_body(kind: u8, payload: &[u8]) -> Body {
    let (name, needed) = match kind {
        kind::GOAL => ("goal", GOAL_LEN),
        kind::TELEMETRY => ("telemetry", TELEMETRY_LEN),
        kind::HEALTH => ("health", HEALTH_LEN),
        kind::EVENT => ("event", EVENT_MIN_LEN),
        kind::DROPPED => ("dropped", DROPPED_LEN),
        kind::END => ("end", END_LEN),
        kind::POSITION => ("position", POSITION_LEN),
        kind::REPLIES => ("replies", REPLIES_LEN),
        kind::AUTOPILOT_CLOCK => ("autopilot clock", AUTOPILOT_CLOCK_LEN),
        other => return Body::Unsupported(format!("records of kind {other}")),
    };
    let mut c = Cursor::new(payload);
    let body = match kind {
        kind::GOAL => (|| {
            let servo = c.u8()?;
            let code = c.u8()?;
            let position = MmCenti(c.i16()?);
            Some(
                match code {
                    0 => Ok(Goal::Position(position)),
                    1 => Ok(Goal::Hold),
                    2 => Ok(Goal::Off),
                    3 => Ok(Goal::Brake),
                    other => Err(format!("goal records with goal code {other}")),
                }
                .map(|goal| RecordBody::Goal { servo, goal }),
            )
        })(),
        kind::TELEMETRY => (|| {
            let servo = c.u8()?;
            let flags = ReplyFlags(c.u8()?);
            let telemetry = Telemetry {
                present_position: MmCenti(c.i16()?),
                present_time: Ms10(c.u16()?),
                present_load: Ma10(c.u16()?),
                present_temperature: Celsius(c.i16()?),
                present_voltage: Mv10(c.u16()?),
            };
            Some(Ok(RecordBody::Telemetry {
                servo,
                telemetry,
                flags,
            }))
        })(),
        kind::POSITION => (|| {
            let servo = c.u8()?;
            let flags = ReplyFlags(c.u8()?);
            let position = MmCenti(c.i16()?);
            if payload.len() < MOTION_LEN {
                return Some(Ok(RecordBody::Position {
                    servo,
                    position,
                    flags,
                }));
            }
            let motion = Motion {
                present_position: position,
                present_time: Ms10(c.u16()?),
                present_load: Ma10(c.u16()?),
            };
            Some(Ok(RecordBody::Motion {
                servo,
                motion,
                flags,
            }))
        })(),
        kind::REPLIES => (|| {
            let servo = c.u8()?;
            let answered = c.u32()?;
            let missed = c.u32()?;
            Some(Ok(RecordBody::Replies {
                servo,
                answered,
                missed,
            }))
        })(),
        kind::AUTOPILOT_CLOCK => (|| {
            let bits = c.u8()?;
            let time_usec = c.u64()?;
            Some(match bits {
                32 | 64 => Ok(RecordBody::AutopilotClock { time_usec, bits }),
                other => Err(format!("autopilot clock records of {other} bits")),
            })
        })(),
        kind::HEALTH => (|| {
            let servo = c.u8()?;
            let code = c.u8()?;
            let stalled = c.u8()? != 0;
            Some(
                health_from_code(code)
                    .map(|health| RecordBody::Health {
                        servo,
                        health,
                        stalled,
                    })
                    .ok_or_else(|| format!("health records with health code {code}")),
            )
        })(),
        kind::EVENT => (|| {
            let servo = c.u8()?;
            let severity = c.u8()?;
            let text = String::from_utf8_lossy(c.rest()).into_owned();
            Some(Ok(RecordBody::Event {
                servo: (servo != NO_SERVO).then_some(servo),
                severity,
                text,
            }))
        })(),
        kind::DROPPED => c.u64().map(|count| Ok(RecordBody::Dropped { count })),
        _ => c.u8().map(|next| {
            Ok(RecordBody::End {
                continued: next != 0,
            })
        }),
    };
    match body {
        None => Body::Short { name, needed },
        Some(Ok(body)) => Body::Ok(body),
        Some(Err(what)) => Body::Unsupported(what),
    }
}

#[cfg(test)]
mod tests;

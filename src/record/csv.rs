//! A recording as CSV for spreadsheets: a header line, then one row per record in file order.
//!
//! Columns ([`CSV_HEADER`]): `time_s` (since the run's start, µs resolution), `servo` (its
//! name, empty for the bridge), `kind` (`goal`, `telemetry`, `position`, `motion`, `replies`,
//! `health`, `event`, `dropped`, `end`), then the fields of that kind, the others left empty:
//! - goal: `goal` (`position`, `hold`, `off`, `brake`) and `goal_mm`;
//! - telemetry: `position_mm`, `current_a`, `temperature_c`, `voltage_v`, `present_time_ms`,
//!   `flags` (`ok` or the flags' names);
//! - position: `position_mm`, `flags`; motion: `position_mm`, `current_a`, `present_time_ms`,
//!   `flags`; replies: `text` (`replies: N good, M garbled or missing`);
//! - health: `health`, `stalled` (0 or 1);
//! - event: `severity` (`warning`, …) and `text`; dropped: `text` (`records dropped: N`);
//!   end: `text` (`end of run` or `continued in the next file`).
//!
//! Fields are separated by commas and quoted (RFC 4180, by the `csv` crate) when they hold a
//! comma, a quote or a line break. Numbers use a full stop as decimal mark.

use super::format::{Record, RecordBody, goal_name, health_name, severity};
use super::reader::Recording;
use crate::bus::Goal;
use std::io::{self, Write};

/// The first line of every export.
pub const CSV_HEADER: &str = "time_s,servo,kind,goal,goal_mm,position_mm,current_a,temperature_c,\
voltage_v,present_time_ms,flags,health,stalled,severity,text";

/// The number of columns of [`CSV_HEADER`].
pub const CSV_COLUMNS: usize = 15;

/// One record's fields, unquoted, in the order of [`CSV_HEADER`].
pub fn csv_fields(rec: &Recording, record: &Record) -> [String; CSV_COLUMNS] {
    let mut row: [String; CSV_COLUMNS] = Default::default();
    row[0] = format!("{}.{:06}", record.t_us / 1_000_000, record.t_us % 1_000_000);
    row[1] = record
        .body
        .servo()
        .map(|s| rec.servo_name(s))
        .unwrap_or_default();
    row[2] = record.body.kind_name().to_string();
    // goal, goal_mm, position_mm, current_a, temperature_c, voltage_v, present_time_ms,
    // flags, health, stalled, severity, text
    let cols = &mut row[3..];
    match &record.body {
        RecordBody::Goal { goal, .. } => {
            cols[0] = goal_name(*goal).to_string();
            if let Goal::Position(p) = goal {
                cols[1] = format!("{:.2}", p.mm());
            }
        }
        RecordBody::Telemetry {
            telemetry: t,
            flags,
            ..
        } => {
            cols[2] = format!("{:.2}", t.present_position.mm());
            cols[3] = format!("{:.2}", t.present_load.amps());
            cols[4] = t.present_temperature.0.to_string();
            cols[5] = format!("{:.2}", t.present_voltage.volts());
            cols[6] = t.present_time.millis().to_string();
            cols[7] = flags.meaningful().to_string();
        }
        RecordBody::Position {
            position, flags, ..
        } => {
            cols[2] = format!("{:.2}", position.mm());
            cols[7] = flags.meaningful().to_string();
        }
        RecordBody::Motion {
            motion: m, flags, ..
        } => {
            cols[2] = format!("{:.2}", m.present_position.mm());
            cols[3] = format!("{:.2}", m.present_load.amps());
            cols[6] = m.present_time.millis().to_string();
            cols[7] = flags.meaningful().to_string();
        }
        RecordBody::Replies {
            answered, missed, ..
        } => cols[11] = format!("replies: {answered} good, {missed} garbled or missing"),
        RecordBody::Health {
            health, stalled, ..
        } => {
            cols[8] = health_name(*health).to_string();
            cols[9] = u8::from(*stalled).to_string();
        }
        RecordBody::Event {
            severity: sev,
            text,
            ..
        } => {
            cols[10] = severity::name(*sev);
            cols[11] = text.clone();
        }
        RecordBody::AutopilotClock { time_usec, bits } => {
            cols[11] = format!("autopilot clock: {time_usec} us ({bits}-bit field)");
        }
        RecordBody::Dropped { count } => cols[11] = format!("records dropped: {count}"),
        RecordBody::End { continued } => {
            cols[11] = if *continued {
                "continued in the next file"
            } else {
                "end of run"
            }
            .to_string();
        }
    }
    row
}

/// Write the recording as CSV; returns the number of rows after the header.
pub fn write_csv(rec: &Recording, out: &mut impl Write) -> io::Result<u64> {
    let mut csv = csv::WriterBuilder::new()
        .terminator(csv::Terminator::Any(b'\n'))
        .from_writer(out);
    csv.write_record(CSV_HEADER.split(','))?;
    let mut rows = 0;
    for record in &rec.records {
        csv.write_record(csv_fields(rec, record))?;
        rows += 1;
    }
    csv.flush()?;
    Ok(rows)
}

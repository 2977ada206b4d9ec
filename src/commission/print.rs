//! Reports as text for people: tables and short summaries. Pure functions of the reports.

use super::info::{InfoReport, access_label, area_label};
use super::monitor::MonitorRow;
use super::motion::{ForceReport, MoveReport, force_label};
use super::reset::ResetReport;
use super::scan::ScanReport;
use super::set::SetReport;
use crate::protocol::{BaudRate, ForceMode};
use std::fmt::Write as _;

fn bauds_text(bauds: &[BaudRate]) -> String {
    if bauds.len() == BaudRate::ALL.len() {
        "every rate of the table".into()
    } else {
        bauds
            .iter()
            .map(|b| b.bits_per_second().to_string())
            .collect::<Vec<_>>()
            .join(", ")
            + " bit/s"
    }
}

/// The table of `scan`.
pub fn scan_table(report: &ScanReport) -> String {
    let mut out = String::new();
    if report.found.is_empty() {
        let _ = writeln!(
            out,
            "no servo answered ({} IDs at {}, {:.2} s)",
            report.ids_probed,
            bauds_text(&report.bauds),
            report.elapsed.as_secs_f64()
        );
        let _ = writeln!(
            out,
            "check power, the A/B wiring and the baud rate (try --all-bauds); a servo in PWM/S.BUS mode does not answer on RS485"
        );
        return out;
    }
    let _ = writeln!(
        out,
        "{:>3}  {:>6}  {:<16}  {:>8}  {:>10}  {:>6}  {:>8}  flags",
        "ID", "baud", "model", "firmware", "position", "temp", "voltage"
    );
    for s in &report.found {
        let model = match s.model {
            Some(m) if m == crate::protocol::LJ9DA41_MODEL_NUMBER => format!("0x{m:04X} LJ9DA41"),
            Some(m) => format!("0x{m:04X} unknown"),
            None => "?".into(),
        };
        let firmware = s.firmware.map_or("?".into(), |f| format!("0x{f:02X}"));
        let (position, temperature, voltage) = match s.telemetry {
            Some(t) => (
                t.present_position.to_string(),
                t.present_temperature.to_string(),
                t.present_voltage.to_string(),
            ),
            None => ("?".into(), "?".into(), "?".into()),
        };
        let flags = s.flags.map_or("?".into(), |f| f.to_string());
        let _ = writeln!(
            out,
            "{:>3}  {:>6}  {:<16}  {:>8}  {:>10}  {:>6}  {:>8}  {}",
            s.id,
            s.baud.bits_per_second(),
            model,
            firmware,
            position,
            temperature,
            voltage,
            flags
        );
        if let Some(problem) = &s.problem {
            let _ = writeln!(out, "     ^ {problem}");
        }
    }
    let _ = writeln!(
        out,
        "{} servo{} found ({} IDs at {}, {:.2} s)",
        report.found.len(),
        if report.found.len() == 1 { "" } else { "s" },
        report.ids_probed,
        bauds_text(&report.bauds),
        report.elapsed.as_secs_f64()
    );
    let mut seen: Vec<u8> = Vec::new();
    for s in &report.found {
        if seen.contains(&s.id.get()) {
            let _ = writeln!(
                out,
                "warning: ID {} answers at more than one rate: give each servo its own ID",
                s.id
            );
        }
        seen.push(s.id.get());
    }
    out
}

/// The table of `info`.
pub fn info_table(report: &InfoReport) -> String {
    let mut out = String::new();
    let _ = writeln!(out, "servo {} at {}", report.id, report.baud);
    let _ = writeln!(
        out,
        "{:>5}  {:>3}  {:<24}  {:<8}  {:<5}  {:>5}  {:<26}  unit",
        "No.", "hex", "name", "access", "area", "raw", "reading"
    );
    for (r, raw, reading) in report.registers() {
        let no = if r.size == 2 {
            format!("{}–{}", r.address, r.address + 1)
        } else {
            r.address.to_string()
        };
        let raw_text = if r.size == 2 {
            format!("{raw:04X}h")
        } else {
            format!("{raw:02X}h")
        };
        let line = format!(
            "{:>5}  {:>2}h  {:<24}  {:<8}  {:<5}  {:>5}  {:<26}  {}",
            no,
            format!("{:02X}", r.address),
            r.name,
            access_label(r.access),
            area_label(r.area),
            raw_text,
            reading,
            r.unit
        );
        let _ = writeln!(out, "{}", line.trim_end());
    }
    let _ = writeln!(
        out,
        "reply flags: 0x{:02X} ({})",
        report.flags.0, report.flags
    );
    for (name, set, meaning) in report.flag_explanations() {
        let _ = writeln!(
            out,
            "  {:<26} {}{}",
            name,
            if set { "SET" } else { "clear" },
            if set {
                format!(": {meaning}")
            } else {
                String::new()
            }
        );
    }
    out
}

/// The summary of `set`.
pub fn set_summary(report: &SetReport) -> String {
    let mut out = String::new();
    let _ = writeln!(out, "servo {} at {}:", report.id_before, report.baud_before);
    for c in &report.changes {
        let _ = writeln!(
            out,
            "  {:<13} {:>16} → {:<16} verified",
            c.key, c.before, c.after
        );
    }
    if report.id_after != report.id_before || report.baud_after != report.baud_before {
        let _ = writeln!(
            out,
            "the servo now answers as ID {} at {}",
            report.id_after, report.baud_after
        );
    }
    for note in &report.notes {
        let _ = writeln!(out, "note: {note}");
    }
    out
}

/// The summary of `move`.
pub fn move_summary(report: &MoveReport) -> String {
    let mut out = String::new();
    if report.switched_force_on {
        let _ = writeln!(out, "servo {}: force switched on", report.id);
    }
    if report.clamped() {
        let _ = writeln!(
            out,
            "servo {}: goal {} clamped by the servo's limits to {}",
            report.id, report.requested, report.goal
        );
    }
    let state = if report.arrived {
        "arrived"
    } else if report.waited {
        "did NOT arrive"
    } else {
        "moving"
    };
    let _ = writeln!(
        out,
        "servo {}: goal {}, position {} — {} ({:.2} s)",
        report.id,
        report.goal,
        report.position,
        state,
        report.elapsed.as_secs_f64()
    );
    out
}

/// The summary of `force`.
pub fn force_summary(report: &ForceReport) -> String {
    let before = report.before.map_or("unknown", force_label);
    let mut out = format!(
        "servo {}: force {} → {} (position {}, flags {})\n",
        report.id,
        before,
        force_label(report.after),
        report.position,
        report.flags
    );
    if report.after == ForceMode::On {
        out.push_str("note: force on holds the present position as the goal\n");
    }
    out
}

/// The summary of `factory-reset`.
pub fn reset_summary(report: &ResetReport) -> String {
    let mut out = format!(
        "servo {} ({}) factory-reset: now ID {} at {}, limits {} … {}\n",
        report.id_before,
        report.baud_before,
        report.id_after,
        report.baud_after,
        report.map_after.minus_limit(),
        report.map_after.plus_limit()
    );
    for note in &report.notes {
        let _ = writeln!(out, "note: {note}");
    }
    out
}

/// One screen of `monitor`.
pub fn monitor_table(sample: u64, rows: &[MonitorRow]) -> String {
    let mut out = String::new();
    let _ = writeln!(out, "sample {sample} (Ctrl-C to stop)");
    let _ = writeln!(
        out,
        "{:>3}  {:>10}  {:>10}  {:>5}  {:>4}  {:>8}  {:>6}  {:>8}  flags",
        "ID", "position", "goal", "force", "max", "load", "temp", "voltage"
    );
    for row in rows {
        match &row.reading {
            Ok(s) => {
                let _ = writeln!(
                    out,
                    "{:>3}  {:>10}  {:>10}  {:>5}  {:>3}%  {:>8}  {:>6}  {:>8}  {}",
                    row.id,
                    s.telemetry.present_position.to_string(),
                    s.goal.to_string(),
                    s.force.map_or("?", force_label),
                    s.max_force_percent.min(100),
                    s.telemetry.present_load.to_string(),
                    s.telemetry.present_temperature.to_string(),
                    s.telemetry.present_voltage.to_string(),
                    s.flags
                );
            }
            Err(why) => {
                let _ = writeln!(out, "{:>3}  {why}", row.id);
            }
        }
    }
    out
}

//! The trend as text: what `lj9da-bridge record trend` prints, a paragraph and a table of flights
//! per servo.

use super::{BASELINE_FLIGHTS, MARGIN_MIN_DROP_C, RISE_LIMIT, ServoTrend, Trend, Verdict};
use crate::record::clock::Utc;
use std::fmt;

fn opt(v: Option<f64>, decimals: usize) -> String {
    v.map_or_else(|| "-".to_string(), |v| format!("{v:.decimals$}"))
}

fn percent(v: Option<f64>) -> String {
    v.map_or_else(|| "-".to_string(), |v| format!("{:+.0}%", v * 100.0))
}

fn table(rows: &[Vec<String>], left: usize) -> String {
    let columns = rows.iter().map(Vec::len).max().unwrap_or(0);
    let widths: Vec<usize> = (0..columns)
        .map(|c| {
            rows.iter()
                .map(|r| r.get(c).map_or(0, |s| s.chars().count()))
                .max()
                .unwrap_or(0)
        })
        .collect();
    let mut out = String::new();
    for row in rows {
        let mut line = String::from("  ");
        for (c, (cell, width)) in row.iter().zip(&widths).enumerate() {
            if c > 0 {
                line.push_str("  ");
            }
            let pad = " ".repeat(width.saturating_sub(cell.chars().count()));
            if c < left {
                line.push_str(cell);
                line.push_str(&pad);
            } else {
                line.push_str(&pad);
                line.push_str(cell);
            }
        }
        out.push_str(line.trim_end());
        out.push('\n');
    }
    out
}

impl fmt::Display for ServoTrend {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let s = &self.servo;
        let t = &self.totals;
        if let Some(aircraft) = &s.aircraft {
            write!(f, "{aircraft}: ")?;
        }
        write!(
            f,
            "{} (bus {}, ID {}): {}",
            s.name,
            s.bus,
            s.id,
            self.verdict.to_string().to_uppercase()
        )?;
        match (self.verdict, self.marked_since) {
            (Verdict::Inspect, Some(since)) => {
                let what: Vec<String> = self.triggers.iter().map(|t| t.to_string()).collect();
                write!(f, " — {}, since flight {since}", what.join("; "))?;
            }
            (Verdict::Watch, Some(last)) => write!(f, " — flight {last} was marked")?,
            (Verdict::Baseline, _) => write!(
                f,
                " — flights are judged from the {}th on",
                BASELINE_FLIGHTS + 1
            )?,
            _ => {}
        }
        writeln!(f)?;
        writeln!(
            f,
            "  {} flights{}: {:.2} h with force on, {:.2} h in motion, {:.1} m travelled, {} \
             reversals, {:.1} s stalled, {} alarms; latest against baseline: friction {}, heating {}",
            t.flights,
            if self.left_out > 0 {
                format!(" ({} earlier left out by --since)", self.left_out)
            } else {
                String::new()
            },
            t.force_on_h,
            t.motion_h,
            t.travel_m,
            t.reversals,
            t.stalled_s,
            t.alarms,
            percent(t.friction_change),
            percent(t.heating_change),
        )?;
        let b = &self.baseline;
        let head = [
            "#",
            "date (UTC)",
            "on min",
            "travel m",
            "revs",
            "moving min",
            "friction",
            "Δ",
            "hold A",
            "Δ",
            "peak A",
            "stall s",
            "max °C",
            "mean °C",
            ">70° min",
            "°C/min",
            "Δ",
            "bad rep",
            "alarms",
            "",
        ];
        let mut rows = vec![head.iter().map(|h| h.to_string()).collect::<Vec<_>>()];
        let change = |v: Option<f64>, base: Option<f64>| match (v, base) {
            (Some(v), Some(b)) if b > 0.0 => percent(Some((v - b) / b)),
            _ => "-".to_string(),
        };
        for (i, fl) in self.flights.iter().enumerate() {
            let mark = if fl.baseline {
                "baseline".to_string()
            } else if fl.findings.is_empty() {
                String::new()
            } else {
                format!(
                    "INSPECT: {}",
                    fl.findings
                        .iter()
                        .map(|x| x.figure)
                        .collect::<Vec<_>>()
                        .join(", ")
                )
            };
            rows.push(vec![
                (i + 1).to_string(),
                Utc::from_unix_ns(fl.run_start_unix_ns).minute(),
                format!("{:.1}", fl.force_on_s / 60.0),
                format!("{:.2}", fl.travel_mm / 1000.0),
                fl.reversals.to_string(),
                format!("{:.1}", fl.motion_s / 60.0),
                opt(fl.friction_ma_per_mm_s, 2),
                change(fl.friction_ma_per_mm_s, b.friction_ma_per_mm_s),
                opt(fl.holding_a, 3),
                change(fl.holding_a, b.holding_a),
                opt(fl.peak_a, 2),
                format!("{:.1}", fl.stalled_s),
                opt(fl.peak_c, 0),
                opt(fl.mean_c, 1),
                format!("{:.1}", fl.hot_min),
                opt(fl.heating_c_per_min, 2),
                change(fl.heating_c_per_min, b.heating_c_per_min),
                fl.bad_replies
                    .map_or_else(|| "-".to_string(), |v| format!("{:.1}%", v * 100.0)),
                fl.alarms.to_string(),
                mark,
            ]);
        }
        f.write_str(&table(&rows, 2))
    }
}

impl fmt::Display for Trend {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let inspect = self
            .servos
            .iter()
            .filter(|s| s.verdict == Verdict::Inspect)
            .count();
        writeln!(
            f,
            "{} servos in {} record files; {} to inspect (friction, holding current or heating \
             +{:.0} % over the median of a servo's first {} flights, or its temperature margin \
             {:.0} °C less)",
            self.servos.len(),
            self.files,
            inspect,
            RISE_LIMIT * 100.0,
            BASELINE_FLIGHTS,
            MARGIN_MIN_DROP_C
        )?;
        for s in &self.servos {
            writeln!(f)?;
            write!(f, "{s}")?;
        }
        Ok(())
    }
}

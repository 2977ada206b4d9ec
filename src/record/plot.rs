//! Pictures of a recording: one SVG file per servo, drawn without a plotting library.
//!
//! Each picture has four panels over the same time axis (the whole recording, so the
//! pictures of one run line up): goal and present position (mm), current (A), temperature
//! (°C, with lines at the LJ9DA41's default temperature alarm, 75 °C, and limit, 85 °C) and
//! voltage (V). Alarms are marked across all panels: a dashed red line where a status flag
//! went on (temperature alarm, temperature error, flash write error), a red band while the
//! servo was stalled and a grey band while it was offline. Telemetry lines are broken where
//! samples stop for a while (more than five typical intervals, and at least 0.5 s); the goal
//! is drawn as steps and broken while there is no position goal (`off`, `brake`).
//!
//! SVG is text: it opens in every browser, and tests can check what was drawn. Every data
//! line is a `<polyline>` with a `data-series` attribute (`goal`, `position`, `current`,
//! `temperature`, `voltage`), every alarm marker has `class="alarm"`, every panel is a `<g>`
//! with a `data-panel` attribute. Long recordings are thinned to the extremes of each pixel
//! column, so peaks survive and files stay small.

use super::analysis::{ServoFold, servo_records};
use super::format::RecordBody;
use super::reader::Recording;
use super::svg::{Area, escape, nice_step, polyline, tick_label, ticks};
use crate::bus::Goal;
use std::fmt::Write as _;
use std::io;
use std::path::{Path, PathBuf};

/// The LJ9DA41's default temperature alarm (10 °C below the limit), drawn for reference.
pub const TEMPERATURE_ALARM_C: f64 = 75.0;
/// The LJ9DA41's default temperature limit, drawn for reference.
pub const TEMPERATURE_LIMIT_C: f64 = 85.0;

const WIDTH: f64 = 1200.0;
const LEFT: f64 = 80.0;
const RIGHT: f64 = 30.0;
const TOP: f64 = 72.0;
const PANEL_HEIGHT: f64 = 170.0;
const PANEL_GAP: f64 = 34.0;
const BOTTOM: f64 = 56.0;
const PLOT_WIDTH: f64 = WIDTH - LEFT - RIGHT;
/// The shortest break in samples that breaks a line, in seconds.
const MIN_GAP_S: f64 = 0.5;

type Point = (f64, f64);
type Points = Vec<Point>;

struct Series {
    name: &'static str,
    label: &'static str,
    color: &'static str,
    dashed: bool,
    segments: Vec<Points>,
}

struct Panel {
    name: &'static str,
    title: &'static str,
    series: Vec<Series>,
    references: Vec<(f64, &'static str, &'static str)>,
}

/// Split time-ordered points where the time between two exceeds the gap for these samples.
fn split_at_gaps(points: Points) -> Vec<Points> {
    let mut gaps: Vec<f64> = points.windows(2).map(|w| w[1].0 - w[0].0).collect();
    gaps.sort_by(f64::total_cmp);
    let typical = gaps.get(gaps.len() / 2).copied().unwrap_or(0.0);
    let limit = (typical * 5.0).max(MIN_GAP_S);
    let mut segments = Vec::new();
    let mut current: Points = Vec::new();
    for p in points {
        if let Some(last) = current.last()
            && p.0 - last.0 > limit
        {
            segments.push(std::mem::take(&mut current));
        }
        current.push(p);
    }
    if !current.is_empty() {
        segments.push(current);
    }
    segments
}

/// Keep, of each pixel column, the lowest and the highest point (in time order), and the
/// segment's ends.
fn thin(points: &[(f64, f64)], x_of: &impl Fn(f64) -> f64) -> Points {
    if points.len() as f64 <= PLOT_WIDTH * 2.0 {
        return points.to_vec();
    }
    let mut out = Vec::with_capacity((PLOT_WIDTH * 2.0) as usize + 2);
    let mut column: Option<(i64, Point, Point)> = None;
    let flush = |out: &mut Points, lo: Point, hi: Point| {
        if lo.0 <= hi.0 {
            out.push(lo);
            if hi != lo {
                out.push(hi);
            }
        } else {
            out.push(hi);
            out.push(lo);
        }
    };
    for &p in points {
        let px = x_of(p.0).floor() as i64;
        match &mut column {
            Some((c, lo, hi)) if *c == px => {
                if p.1 < lo.1 {
                    *lo = p;
                }
                if p.1 > hi.1 {
                    *hi = p;
                }
            }
            _ => {
                if let Some((_, lo, hi)) = column {
                    flush(&mut out, lo, hi);
                }
                column = Some((px, p, p));
            }
        }
    }
    if let Some((_, lo, hi)) = column {
        flush(&mut out, lo, hi);
    }
    if let (Some(first), Some(&last)) = (points.first(), points.last()) {
        if out.first() != Some(first) {
            out.insert(0, *first);
        }
        if out.last() != Some(&last) {
            out.push(last);
        }
    }
    out
}

/// The panels of servo `servo`, data in seconds and panel units.
fn panels(rec: &Recording, servo: usize, end_s: f64) -> Vec<Panel> {
    let records = servo_records(rec, servo);
    let mut position = Vec::new();
    let mut current = Vec::new();
    let mut temperature = Vec::new();
    let mut voltage = Vec::new();
    let mut goal_segments: Vec<Points> = Vec::new();
    let mut goal_line: Points = Vec::new();
    let mut goal: Option<f64> = None;
    for r in &records {
        let t = r.t_s();
        match &r.body {
            RecordBody::Telemetry { telemetry: tm, .. } => {
                position.push((t, tm.present_position.mm()));
                current.push((t, tm.present_load.amps()));
                temperature.push((t, f64::from(tm.present_temperature.0)));
                voltage.push((t, tm.present_voltage.volts()));
            }
            RecordBody::Position { position: p, .. } => position.push((t, p.mm())),
            RecordBody::Motion { motion: m, .. } => {
                position.push((t, m.present_position.mm()));
                current.push((t, m.present_load.amps()));
            }
            RecordBody::Goal { goal: g, .. } => match g {
                Goal::Position(p) => {
                    if let Some(previous) = goal {
                        goal_line.push((t, previous));
                    }
                    goal_line.push((t, p.mm()));
                    goal = Some(p.mm());
                }
                Goal::Hold => {}
                Goal::Off | Goal::Brake => {
                    if let Some(previous) = goal.take() {
                        goal_line.push((t, previous));
                        goal_segments.push(std::mem::take(&mut goal_line));
                    }
                }
            },
            _ => {}
        }
    }
    if let Some(previous) = goal {
        goal_line.push((end_s, previous));
    }
    if !goal_line.is_empty() {
        goal_segments.push(goal_line);
    }
    let series = |name, label, color, points: Points| Series {
        name,
        label,
        color,
        dashed: false,
        segments: split_at_gaps(points),
    };
    vec![
        Panel {
            name: "position",
            title: "position (mm)",
            series: vec![
                Series {
                    name: "goal",
                    label: "goal",
                    color: "#ff7f0e",
                    dashed: true,
                    segments: goal_segments,
                },
                series("position", "present position", "#1f77b4", position),
            ],
            references: vec![],
        },
        Panel {
            name: "current",
            title: "current (A)",
            series: vec![series("current", "current", "#2ca02c", current)],
            references: vec![],
        },
        Panel {
            name: "temperature",
            title: "temperature (°C)",
            series: vec![series("temperature", "temperature", "#d62728", temperature)],
            references: vec![
                (TEMPERATURE_ALARM_C, "alarm 75 °C", "#ff7f0e"),
                (TEMPERATURE_LIMIT_C, "limit 85 °C", "#d62728"),
            ],
        },
        Panel {
            name: "voltage",
            title: "voltage (V)",
            series: vec![series("voltage", "voltage", "#9467bd", voltage)],
            references: vec![],
        },
    ]
}

/// The y range of a panel: its data and reference lines, padded by 5 %.
fn y_range(panel: &Panel) -> (f64, f64) {
    let values = panel
        .series
        .iter()
        .flat_map(|s| s.segments.iter().flatten().map(|p| p.1))
        .chain(panel.references.iter().map(|r| r.0))
        .filter(|v| v.is_finite());
    let (lo, hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
        (lo.min(v), hi.max(v))
    });
    if !lo.is_finite() || !hi.is_finite() {
        return (0.0, 1.0);
    }
    let span = hi - lo;
    if span < 1e-6 {
        let pad = (lo.abs() * 0.05).max(0.5);
        return (lo - pad, hi + pad);
    }
    (lo - span * 0.05, hi + span * 0.05)
}

/// The SVG picture of servo `servo` (its index in the record). `title` names the record.
pub fn servo_svg(rec: &Recording, servo: usize, title: &str) -> String {
    let t0 = rec.start_t_us() as f64 / 1e6;
    let mut t1 = rec.end_t_us() as f64 / 1e6;
    if t1 - t0 < 1e-3 {
        t1 = t0 + 1.0;
    }
    let x_of = |t: f64| LEFT + (t - t0) / (t1 - t0) * PLOT_WIDTH;
    let panels = panels(rec, servo, t1);
    let height = TOP + 4.0 * PANEL_HEIGHT + 3.0 * PANEL_GAP + BOTTOM;
    let name = rec.servo_name(u8::try_from(servo).unwrap_or(u8::MAX));
    let about = rec.header.servos.get(servo).map_or_else(String::new, |s| {
        format!(" — bus {}, ID {}, channel {}", s.bus, s.id, s.channel)
    });
    let fold = ServoFold::over(rec, servo);
    let alarms = fold.alarms;
    let stalled = fold.stalled_spans.spans;
    let offline = fold.offline_spans.spans;

    let mut svg = String::with_capacity(64 * 1024);
    let _ = writeln!(svg, r#"<?xml version="1.0" encoding="UTF-8"?>"#);
    let _ = writeln!(
        svg,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{WIDTH}" height="{height}" viewBox="0 0 {WIDTH} {height}" font-family="sans-serif" font-size="12">"#
    );
    let _ = writeln!(svg, "<title>{} — {}</title>", escape(&name), escape(title));
    let _ = writeln!(svg, r#"<rect width="100%" height="100%" fill="white"/>"#);
    let _ = writeln!(
        svg,
        r#"<text x="{LEFT}" y="24" font-size="16" font-weight="bold">{}{}</text>"#,
        escape(&name),
        escape(&about)
    );
    let _ = writeln!(
        svg,
        r##"<text x="{LEFT}" y="44" fill="#555">{} — run started {}; dashed red: flag alarms, red bands: stalled, grey bands: offline</text>"##,
        escape(title),
        super::clock::Utc::from_unix_ns(rec.header.run_start_unix_ns)
    );
    let x_step = nice_step(t1 - t0, 12.0);
    let x_ticks = ticks(t0, t1, 12.0);
    for (i, panel) in panels.iter().enumerate() {
        let area = Area {
            left: LEFT,
            top: TOP + i as f64 * (PANEL_HEIGHT + PANEL_GAP),
            width: PLOT_WIDTH,
            height: PANEL_HEIGHT,
        };
        let (top, bottom) = (area.top, area.bottom());
        let range = y_range(panel);
        let y_of = |v: f64| area.y_of(v, range);
        let _ = writeln!(svg, r#"<g class="panel" data-panel="{}">"#, panel.name);
        area.frame(&mut svg);
        for (spans, class, color) in [
            (&stalled, "stalled", "#ff9896"),
            (&offline, "offline", "#c7c7c7"),
        ] {
            for (a, b) in spans {
                let (xa, xb) = (x_of(*a), x_of(*b));
                let _ = writeln!(
                    svg,
                    r#"<rect class="{class}" x="{xa:.1}" y="{top}" width="{:.1}" height="{PANEL_HEIGHT}" fill="{color}" fill-opacity="0.4"/>"#,
                    (xb - xa).max(1.0)
                );
            }
        }
        area.y_grid(&mut svg, range, 5.0);
        let last = i == panels.len() - 1;
        for &t in &x_ticks {
            let label = tick_label(t, x_step);
            let labels: &[&str] = if last { &[&label] } else { &[] };
            area.x_tick(&mut svg, x_of(t), labels);
        }
        area.title(&mut svg, panel.title);
        for &(v, label, color) in &panel.references {
            area.reference_line(&mut svg, y_of(v), color, label);
        }
        let mut drawn = false;
        for s in &panel.series {
            for segment in &s.segments {
                let mut points = thin(segment, &x_of);
                if points.len() == 1 {
                    points.push(points[0]);
                }
                let attributes = format!(
                    r#"data-series="{}" fill="none" stroke="{}" stroke-width="1.3" stroke-linecap="round"{}"#,
                    s.name,
                    s.color,
                    if s.dashed {
                        r#" stroke-dasharray="6 3""#
                    } else {
                        ""
                    }
                );
                polyline(
                    &mut svg,
                    &attributes,
                    points.into_iter().map(|(t, v)| (x_of(t), y_of(v))),
                );
                drawn = true;
            }
        }
        if !drawn {
            area.no_data(&mut svg);
        }
        for &(t, what) in &alarms {
            let x = x_of(t);
            let _ = writeln!(
                svg,
                r##"<line class="alarm" data-alarm="{what}" x1="{x:.1}" y1="{top}" x2="{x:.1}" y2="{bottom}" stroke="#d62728" stroke-width="1.5" stroke-dasharray="4 3"><title>{what} at {t:.3} s</title></line>"##
            );
        }
        // The legend, above the panel's right end, last series rightmost.
        for (k, s) in panel.series.iter().rev().enumerate() {
            let x = LEFT + PLOT_WIDTH - 150.0 * (k as f64 + 1.0);
            let y = top - 7.0;
            let _ = writeln!(
                svg,
                r#"<g class="legend"><line x1="{x:.1}" y1="{:.1}" x2="{:.1}" y2="{:.1}" stroke="{}" stroke-width="2"{}/><text x="{:.1}" y="{y:.1}">{}</text></g>"#,
                y - 4.0,
                x + 20.0,
                y - 4.0,
                s.color,
                if s.dashed {
                    r#" stroke-dasharray="6 3""#
                } else {
                    ""
                },
                x + 26.0,
                escape(s.label)
            );
        }
        let _ = writeln!(svg, "</g>");
    }
    let _ = writeln!(
        svg,
        r#"<text x="{:.1}" y="{:.1}" text-anchor="middle">time since the run's start (s)</text>"#,
        LEFT + PLOT_WIDTH / 2.0,
        height - 12.0
    );
    let _ = writeln!(svg, "</svg>");
    svg
}

/// A servo name as part of a file name: letters, digits, `-` and `_` kept, the rest `_`.
fn file_part(name: &str) -> String {
    let s: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect();
    if s.is_empty() { "servo".to_string() } else { s }
}

/// Write one SVG per servo of the recording into `out_dir` (created if missing), named
/// `<stem>-<servo name>.svg`; returns the files written.
pub fn plot(rec: &Recording, out_dir: &Path, stem: &str) -> io::Result<Vec<PathBuf>> {
    std::fs::create_dir_all(out_dir)?;
    let mut written: Vec<PathBuf> = Vec::new();
    for (index, servo) in rec.header.servos.iter().enumerate() {
        let mut path = out_dir.join(format!("{stem}-{}.svg", file_part(&servo.name)));
        if written.contains(&path) {
            path = out_dir.join(format!("{stem}-{}-{index}.svg", file_part(&servo.name)));
        }
        std::fs::write(&path, servo_svg(rec, index, stem))?;
        written.push(path);
    }
    Ok(written)
}

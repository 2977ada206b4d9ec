//! The page of `record trend --html`: per servo, each wear figure against the flight number
//! (the flights in date order, so that ten flights of one day do not stack on one date; each
//! point's tooltip gives its date and time, and the last panel's flight numbers their dates),
//! the band from its baseline to the threshold that marks a flight, and the flights that
//! crossed it. A figure that is the same in every flight (no bad reply at all, say) gets an
//! axis around its value (0 to 1 for zeros), not one a few millionths wide.
//! One file that opens in any browser without a network, as `record plot`'s page
//! ([`super::page`]): inline SVG, and the same few lines of script to zoom (wheel), pan (drag)
//! and reset (double click).
//!
//! Every point is a `<circle>` with `data-figure` (`friction`, `holding current`, `heating`,
//! `peak temperature`, `bad replies`) and `data-flight` (its number); a flight that crossed
//! the threshold of that figure has `class="crossed"`, a baseline flight `class="baseline"`.
//! Each band is a `<rect class="band">`.

use super::clock::Utc;
use super::page::ZOOM_SCRIPT;
use super::svg::{Area, axis_range, escape, nice_step, polyline, ticks};
use super::trend::{
    ALARM_C, Flight, HOLDING_MIN_RISE_A, MARGIN_MIN_DROP_C, RISE_LIMIT, ServoTrend, Trend,
};
use std::fmt::Write as _;
use std::io;
use std::path::Path;

const WIDTH: f64 = 1000.0;
const LEFT: f64 = 80.0;
const RIGHT: f64 = 30.0;
const TOP: f64 = 40.0;
const PANEL_HEIGHT: f64 = 130.0;
const PANEL_GAP: f64 = 40.0;
const BOTTOM: f64 = 40.0;
const PLOT_WIDTH: f64 = WIDTH - LEFT - RIGHT;

/// One figure's panel.
struct Panel {
    figure: &'static str,
    title: &'static str,
    color: &'static str,
    /// (flight number, date in ns, value, crossed)
    points: Vec<(usize, i64, f64, bool)>,
    /// The band: baseline value to threshold.
    band: Option<(f64, f64)>,
    reference: Option<(f64, &'static str)>,
}

fn crossed(f: &Flight, figure: &str) -> bool {
    f.findings.iter().any(|x| x.figure == figure)
}

fn panels(s: &ServoTrend) -> Vec<Panel> {
    let b = &s.baseline;
    let series = |get: &dyn Fn(&Flight) -> Option<f64>, figure: &str| {
        s.flights
            .iter()
            .enumerate()
            .filter_map(|(i, f)| {
                get(f).map(|v| (i + 1, f.run_start_unix_ns, v, crossed(f, figure)))
            })
            .collect::<Vec<_>>()
    };
    let rise_band = |base: Option<f64>, min_rise: f64| {
        base.map(|v| (v, (v * (1.0 + RISE_LIMIT)).max(v + min_rise)))
    };
    vec![
        Panel {
            figure: "friction",
            title: "friction: current per speed while moving (mA per mm/s)",
            color: "#1f77b4",
            points: series(&|f| f.friction_ma_per_mm_s, "friction"),
            band: rise_band(b.friction_ma_per_mm_s, 0.0),
            reference: None,
        },
        Panel {
            figure: "holding current",
            title: "holding current (A)",
            color: "#2ca02c",
            points: series(&|f| f.holding_a, "holding current"),
            band: rise_band(b.holding_a, HOLDING_MIN_RISE_A),
            reference: None,
        },
        Panel {
            figure: "heating",
            title: "heating: temperature rise per minute in motion (°C/min)",
            color: "#d62728",
            points: series(&|f| f.heating_c_per_min, "heating"),
            band: rise_band(b.heating_c_per_min, 0.0),
            reference: None,
        },
        Panel {
            figure: "peak temperature",
            title: "peak temperature (°C)",
            color: "#ff7f0e",
            points: series(&|f| f.peak_c, "temperature margin"),
            band: b
                .margin_c
                .map(|m| (ALARM_C - m, ALARM_C - m + MARGIN_MIN_DROP_C)),
            reference: Some((ALARM_C, "alarm 75 °C")),
        },
        Panel {
            figure: "bad replies",
            title: "garbled or missing replies (%)",
            color: "#9467bd",
            points: series(&|f| f.bad_replies.map(|v| v * 100.0), "bad replies"),
            band: None,
            reference: None,
        },
    ]
}

/// The SVG of one servo's figures.
pub fn servo_trend_svg(s: &ServoTrend) -> String {
    let panels = panels(s);
    // Flight numbers 1..=n, padded so that the first and last points are inside.
    let n = s.flights.len().max(1) as f64;
    let pad = ((n - 1.0) * 0.03).max(0.5);
    let (d0, d1) = (1.0 - pad, n + pad);
    let x_of = |flight: usize| LEFT + (flight as f64 - d0) / (d1 - d0) * PLOT_WIDTH;
    let height = TOP + panels.len() as f64 * (PANEL_HEIGHT + PANEL_GAP) + BOTTOM;
    let mut svg = String::with_capacity(32 * 1024);
    let _ = writeln!(
        svg,
        r#"<svg data-zoom="" xmlns="http://www.w3.org/2000/svg" width="{WIDTH}" height="{height}" viewBox="0 0 {WIDTH} {height}" font-family="sans-serif" font-size="12">"#
    );
    let _ = writeln!(svg, r#"<rect width="100%" height="100%" fill="white"/>"#);
    let _ = writeln!(
        svg,
        r##"<text x="{LEFT}" y="20" fill="#555">shaded: from the median of the first flights to the threshold that marks a flight; red: flights beyond it; hollow: baseline flights</text>"##
    );
    // Flight ticks: whole flights, at most about ten.
    let step = nice_step(d1 - d0, 10.0).max(1.0);
    let x_ticks: Vec<usize> = ticks(d0.max(1.0), n, (d1 - d0) / step)
        .into_iter()
        .filter(|d| d.fract() == 0.0 && *d >= 1.0)
        .map(|d| d as usize)
        .collect();
    for (k, p) in panels.iter().enumerate() {
        let area = Area {
            left: LEFT,
            top: TOP + k as f64 * (PANEL_HEIGHT + PANEL_GAP) + 16.0,
            width: PLOT_WIDTH,
            height: PANEL_HEIGHT,
        };
        let values = p
            .points
            .iter()
            .map(|x| x.2)
            .chain(p.band.iter().flat_map(|b| [b.0, b.1]))
            .chain(p.reference.iter().map(|r| r.0));
        let (vlo, vhi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(v), b.max(v))
        });
        let range = axis_range(vlo, vhi, 0.08, 0.02);
        let y_of = |v: f64| area.y_of(v, range);
        let _ = writeln!(svg, r#"<g class="panel" data-panel="{}">"#, p.figure);
        area.title(&mut svg, p.title);
        area.frame(&mut svg);
        area.y_grid(&mut svg, range, 4.0);
        let last = k == panels.len() - 1;
        for &flight in &x_ticks {
            let number = flight.to_string();
            let date = s.flights.get(flight - 1).map_or_else(String::new, |f| {
                Utc::from_unix_ns(f.run_start_unix_ns).date()
            });
            let labels: &[&str] = if last { &[&number, &date] } else { &[&number] };
            area.x_tick(&mut svg, x_of(flight), labels);
        }
        if last {
            let _ = writeln!(
                svg,
                r##"<text x="{:.1}" y="{:.1}" text-anchor="middle" fill="#555">flight (in date order; a point's tooltip gives its date and time)</text>"##,
                LEFT + PLOT_WIDTH / 2.0,
                area.bottom() + 48.0
            );
        }
        if let Some((a, b)) = p.band {
            let (ya, yb) = (y_of(a), y_of(b));
            let _ = writeln!(
                svg,
                r##"<rect class="band" x="{LEFT}" y="{:.1}" width="{PLOT_WIDTH}" height="{:.1}" fill="#2ca02c" fill-opacity="0.12"><title>baseline {a:.3} to threshold {b:.3}</title></rect><line x1="{LEFT}" y1="{ya:.1}" x2="{:.1}" y2="{ya:.1}" stroke="#2ca02c" stroke-dasharray="4 3"/>"##,
                ya.min(yb),
                (ya - yb).abs().max(1.0),
                LEFT + PLOT_WIDTH
            );
        }
        if let Some((v, label)) = p.reference {
            area.reference_line(&mut svg, y_of(v), "#d62728", label);
        }
        if p.points.is_empty() {
            area.no_data(&mut svg);
        } else {
            polyline(
                &mut svg,
                &format!(r#"fill="none" stroke="{}" stroke-width="1.2""#, p.color),
                p.points.iter().map(|&(n, _, v, _)| (x_of(n), y_of(v))),
            );
        }
        for &(n, ns, v, cross) in &p.points {
            let baseline = s.flights.get(n - 1).is_some_and(|f| f.baseline);
            let (class, fill, stroke) = if cross {
                ("crossed", "#d62728", "#d62728")
            } else if baseline {
                ("baseline", "white", p.color)
            } else {
                ("flight", p.color, p.color)
            };
            let _ = writeln!(
                svg,
                r#"<circle class="{class}" data-figure="{}" data-flight="{n}" cx="{:.1}" cy="{:.1}" r="{}" fill="{fill}" stroke="{stroke}" stroke-width="1.5"><title>flight {n}, {}: {v:.3}</title></circle>"#,
                p.figure,
                x_of(n),
                y_of(v),
                if cross { 4.5 } else { 3.5 },
                Utc::from_unix_ns(ns).minute()
            );
        }
        let _ = writeln!(svg, "</g>");
    }
    let _ = writeln!(svg, "</svg>");
    svg
}

/// The page: the table of every servo and its figures' pictures.
pub fn trend_page(t: &Trend) -> String {
    let mut html = String::with_capacity(128 * 1024);
    let _ = writeln!(html, "<!DOCTYPE html>");
    let _ = writeln!(html, r#"<html lang="en"><head><meta charset="utf-8">"#);
    let _ = writeln!(html, "<title>Servo wear across flights</title>");
    let _ = writeln!(
        html,
        "<style>body{{font-family:sans-serif;margin:1em 2em}}pre{{overflow-x:auto}}\
         svg{{max-width:100%;height:auto;border:1px solid #ccc;cursor:grab}}\
         .inspect{{color:#d62728}}.watch{{color:#ff7f0e}}</style>"
    );
    let _ = writeln!(html, "</head><body>");
    let _ = writeln!(html, "<h1>Servo wear across flights</h1>");
    let _ = writeln!(
        html,
        "<p>Each servo's figures flight by flight, in date order (a point's tooltip gives its \
         date and time). Wheel: zoom; drag: pan; double click: all flights.</p>"
    );
    let _ = writeln!(html, "<pre>{}</pre>", escape(&t.to_string()));
    for s in &t.servos {
        let _ = writeln!(
            html,
            "<section data-servo=\"{}\" data-verdict=\"{}\"><h2>{}{} — bus {}, ID {}: <span class=\"{}\">{}</span></h2>\n{}</section>",
            escape(&s.servo.name),
            s.verdict,
            s.servo
                .aircraft
                .as_ref()
                .map(|a| format!("{}: ", escape(a)))
                .unwrap_or_default(),
            escape(&s.servo.name),
            escape(&s.servo.bus),
            s.servo.id,
            s.verdict,
            s.verdict,
            servo_trend_svg(s)
        );
    }
    let _ = writeln!(html, "<script>{ZOOM_SCRIPT}</script>");
    let _ = writeln!(html, "</body></html>");
    html
}

/// Write the page to `path`.
pub fn write_trend_page(t: &Trend, path: &Path) -> io::Result<()> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)?;
    }
    std::fs::write(path, trend_page(t))
}

//! `record trend` on synthetic flights of one servo whose figures are set one by one: each
//! trigger alone, each verdict, and the page.

mod tempdir;
mod trend_support;

use lj9da_bridge::bus::Health;
use lj9da_bridge::protocol::{Celsius, Ma10, MmCenti, Ms10, Mv10, ReplyFlags, Telemetry};
use lj9da_bridge::record::format::{RecordHeader, RecordServo, encode_header, encode_record};
use lj9da_bridge::record::trend::{Verdict, trend};
use lj9da_bridge::record::trend_html::trend_page;
use lj9da_bridge::record::{Record, RecordBody};
use std::path::{Path, PathBuf};
use tempdir::TempDir;
use trend_support::{FIRST_FLIGHT_NS, NS_PER_DAY, files_of};

// ---------------------------------------------------------------------------------------------
// Each trigger alone, and each verdict: synthetic flights whose figures are set one by one.

/// What one synthetic flight of the servo "flap" draws and how warm it gets.
#[derive(Debug, Clone, Copy)]
struct Synth {
    /// Current while the rod moves, A.
    moving_a: f64,
    /// Current while it holds still, A.
    holding_a: f64,
    /// Temperature at the start, °C.
    start_c: i16,
    /// Temperature rise over the flight, °C (linear in time).
    rise_c: i16,
}

/// A healthy flap: 0.30 A moving at 10 mm/s (some 30 mA per mm/s), 0.07 A holding, 4 °C warmer
/// at the end of a flight.
const HEALTHY: Synth = Synth {
    moving_a: 0.30,
    holding_a: 0.07,
    start_c: 30,
    rise_c: 4,
};

/// Flight `n` (0-based) of "flap", one a day: 60 s of a 10 mm/s triangle (0 → +10 → −10 →
/// 0 mm, 4 s), then 2 s holding at 0, again and again; telemetry every 20 ms. The current is
/// `moving_a` for a sample whose position changed since the one before, else `holding_a`. The
/// ambient temperature (the start) differs by up to 2 °C from flight to flight. Every request
/// was answered.
fn synth_flight(dir: &Path, n: usize, s: Synth) -> PathBuf {
    synth_flight_at(dir, n, FIRST_FLIGHT_NS + n as i64 * NS_PER_DAY, s)
}

/// [`synth_flight`] starting at `start_ns`.
fn synth_flight_at(dir: &Path, n: usize, start_ns: i64, s: Synth) -> PathBuf {
    let table = vec![RecordServo::new("flap", "wing", 5, 7)];
    let mut bytes = encode_header(&RecordHeader::new(start_ns, table));
    let mut put = |t_us: u64, body: RecordBody| {
        encode_record(&Record { t_us, body }, &mut bytes);
    };
    put(
        0,
        RecordBody::Health {
            servo: 0,
            health: Health::Online,
            stalled: false,
        },
    );
    let start_c = s.start_c + (n % 3) as i16;
    let mut previous = 0i16;
    for k in 0..3000u64 {
        let t_s = k as f64 * 0.02;
        let phase = t_s % 6.0;
        let mm = match phase {
            p if p < 1.0 => 10.0 * p,
            p if p < 3.0 => 10.0 - 10.0 * (p - 1.0),
            p if p < 4.0 => -10.0 + 10.0 * (p - 3.0),
            _ => 0.0,
        };
        let centi = (mm * 100.0).round() as i16;
        let amps = if centi != previous {
            s.moving_a
        } else {
            s.holding_a
        };
        previous = centi;
        let celsius = start_c + (f64::from(s.rise_c) * t_s / 60.0).round() as i16;
        put(
            k * 20_000,
            RecordBody::Telemetry {
                servo: 0,
                telemetry: Telemetry {
                    present_position: MmCenti(centi),
                    present_time: Ms10(0),
                    present_load: Ma10((amps * 100.0).round() as u16),
                    present_temperature: Celsius(celsius),
                    present_voltage: Mv10(1200),
                },
                flags: ReplyFlags(0),
            },
        );
    }
    put(
        60_000_000,
        RecordBody::Replies {
            servo: 0,
            answered: 3000,
            missed: 0,
        },
    );
    put(60_000_000, RecordBody::End { continued: false });
    let path = dir.join(format!("flap{:02}.lj9rec", n + 1));
    std::fs::write(&path, &bytes).unwrap();
    path
}

/// `count` flights of "flap", healthy but for those numbered (1-based) in `worn`, which fly
/// `wear`; judged.
fn flap_trend(
    count: usize,
    worn: &[usize],
    wear: Synth,
) -> (lj9da_bridge::record::trend::ServoTrend, String) {
    let dir = TempDir::new("trend-synth");
    for n in 0..count {
        let s = if worn.contains(&(n + 1)) {
            wear
        } else {
            HEALTHY
        };
        synth_flight(dir.path(), n, s);
    }
    let (t, notes) = trend(&files_of(dir.path()), &[]);
    assert!(
        notes.errors.is_empty() && notes.notes.is_empty(),
        "{notes:?}"
    );
    let text = t.to_string();
    assert_eq!(t.servos.len(), 1, "{text}");
    (t.servos.into_iter().next().unwrap(), text)
}

/// The figures that marked each flight (1-based), for the flights that were marked.
fn marks(s: &lj9da_bridge::record::trend::ServoTrend) -> Vec<(usize, Vec<&'static str>)> {
    s.flights
        .iter()
        .enumerate()
        .filter(|(_, f)| !f.findings.is_empty())
        .map(|(i, f)| (i + 1, f.findings.iter().map(|x| x.figure).collect()))
        .collect()
}

/// Flights 9 and 10 of ten fly `wear`: the servo is "inspect" since flight 9, marked by
/// `figure` and by nothing else, on those flights only.
fn only_this_trigger(figure: &'static str, wear: Synth) -> lj9da_bridge::record::trend::ServoTrend {
    let (s, text) = flap_trend(10, &[9, 10], wear);
    assert_eq!(s.verdict, Verdict::Inspect, "{text}");
    assert_eq!(s.marked_since, Some(9), "{text}");
    let triggers: Vec<&str> = s.triggers.iter().map(|f| f.figure).collect();
    assert_eq!(triggers, [figure], "{text}");
    assert_eq!(marks(&s), [(9, vec![figure]), (10, vec![figure])], "{text}");
    assert!(
        text.contains(&format!("flap (bus wing, ID 5): INSPECT — {figure} ")),
        "{text}"
    );
    s
}

#[test]
fn friction_alone_marks_a_flight_and_no_other_figure_does() {
    // +50 % current while moving, the same holding current and temperatures.
    let s = only_this_trigger(
        "friction",
        Synth {
            moving_a: 0.45,
            ..HEALTHY
        },
    );
    let base = s.baseline.friction_ma_per_mm_s.unwrap();
    assert!((base - 30.0).abs() < 3.0, "{base}");
    let f = &s.triggers[0];
    assert!((f.change - 0.5).abs() < 0.05, "{f:?}");
    assert_eq!(f.baseline, base);
    // The other figures stayed where they were.
    let last = s.flights.last().unwrap();
    assert!((last.holding_a.unwrap() - s.baseline.holding_a.unwrap()).abs() < 0.005);
    assert_eq!(last.rise_c, s.baseline.rise_c);
}

#[test]
fn holding_current_alone_marks_a_flight_and_no_other_figure_does() {
    // 0.07 → 0.12 A holding: +71 %, 50 mA; moving and temperatures as before.
    let s = only_this_trigger(
        "holding current",
        Synth {
            holding_a: 0.12,
            ..HEALTHY
        },
    );
    let f = &s.triggers[0];
    // (A few samples right after a move still count as holding: a little over 0.07 A.)
    assert!((f.baseline - 0.07).abs() < 0.005, "{f:?}");
    assert!((f.value - f.baseline - 0.05).abs() < 0.003, "{f:?}");
    let last = s.flights.last().unwrap();
    let friction = last.friction_ma_per_mm_s.unwrap() / s.baseline.friction_ma_per_mm_s.unwrap();
    assert!((friction - 1.0).abs() < 0.05, "{friction}");
}

#[test]
fn a_holding_current_rise_under_20_ma_does_not_mark_a_flight() {
    // 0.07 → 0.08 A: +14 %; 0.03 → 0.04 A: +33 %, but one 10 mA step of the register: neither
    // is a finding.
    for (base, worn) in [(0.07, 0.08), (0.03, 0.04)] {
        let wear = Synth {
            holding_a: worn,
            ..HEALTHY
        };
        let dir = TempDir::new("trend-synth-hold");
        for n in 0..10 {
            let s = if n >= 8 {
                wear
            } else {
                Synth {
                    holding_a: base,
                    ..HEALTHY
                }
            };
            synth_flight(dir.path(), n, s);
        }
        let (t, _) = trend(&files_of(dir.path()), &[]);
        let s = &t.servos[0];
        assert_eq!(s.verdict, Verdict::Ok, "{base} → {worn}: {t}");
        assert!(marks(s).is_empty(), "{t}");
    }
}

#[test]
fn heating_alone_marks_a_flight_and_no_other_figure_does() {
    // 10 °C warmer at the end instead of 4: +150 % per minute moving, 6 °C more rise; the peak
    // is 6 °C higher, less than the 10 °C the margin allows.
    let s = only_this_trigger(
        "heating",
        Synth {
            rise_c: 10,
            ..HEALTHY
        },
    );
    let f = &s.triggers[0];
    assert!((f.change - 1.5).abs() < 0.1, "{f:?}");
    let last = s.flights.last().unwrap();
    assert!(s.baseline.margin_c.unwrap() - last.margin_c.unwrap() < 10.0);
}

#[test]
fn heating_with_a_rise_under_2_c_more_does_not_mark_a_flight() {
    // 1 °C of rise in the baseline, 2 °C in the last flights: +100 % per minute, but one
    // degree more: the register's whole degrees, not a finding.
    let cool = Synth {
        rise_c: 1,
        ..HEALTHY
    };
    let dir = TempDir::new("trend-synth-heat");
    for n in 0..10 {
        let s = if n >= 8 {
            Synth { rise_c: 2, ..cool }
        } else {
            cool
        };
        synth_flight(dir.path(), n, s);
    }
    let (t, _) = trend(&files_of(dir.path()), &[]);
    let s = &t.servos[0];
    let last = s.flights.last().unwrap();
    assert!(
        last.heating_c_per_min.unwrap() > 1.9 * s.baseline.heating_c_per_min.unwrap(),
        "{t}"
    );
    assert_eq!(s.verdict, Verdict::Ok, "{t}");
}

#[test]
fn temperature_margin_alone_marks_a_flight_and_no_other_figure_does() {
    // A 15 °C warmer start with the same rise: the peak is 15 °C nearer the alarm, the
    // heating per minute the same.
    let s = only_this_trigger(
        "temperature margin",
        Synth {
            start_c: 45,
            ..HEALTHY
        },
    );
    let f = &s.triggers[0];
    assert!(f.change < -10.0 && f.change > -20.0, "{f:?}");
    // Flight 10 starts at 45 °C (its ambient: + 9 % 3) and peaks 4 °C higher.
    assert_eq!(f.value, 75.0 - 49.0);
    let last = s.flights.last().unwrap();
    let heating = last.heating_c_per_min.unwrap() / s.baseline.heating_c_per_min.unwrap();
    assert!((heating - 1.0).abs() < 0.05, "{heating}");
}

#[test]
fn five_flights_are_a_baseline_and_are_not_judged_however_worn_the_last() {
    let worst = Synth {
        moving_a: 0.9,
        holding_a: 0.5,
        start_c: 50,
        rise_c: 20,
    };
    let (s, text) = flap_trend(5, &[5], worst);
    assert_eq!(s.verdict, Verdict::Baseline, "{text}");
    assert!(s.triggers.is_empty() && s.marked_since.is_none(), "{text}");
    assert!(marks(&s).is_empty(), "{text}");
    assert!(s.flights.iter().all(|f| f.baseline), "{text}");
    assert!(
        text.contains("flap (bus wing, ID 5): BASELINE — flights are judged from the 6th on"),
        "{text}"
    );
    assert_eq!(serde_json::to_value(&s).unwrap()["verdict"], "baseline");
}

#[test]
fn healthy_flights_are_ok() {
    let (s, text) = flap_trend(10, &[], HEALTHY);
    assert_eq!(s.verdict, Verdict::Ok, "{text}");
    assert!(s.triggers.is_empty() && s.marked_since.is_none(), "{text}");
    assert!(marks(&s).is_empty(), "{text}");
    assert_eq!(s.flights.iter().filter(|f| f.baseline).count(), 5);
    assert!(text.contains("flap (bus wing, ID 5): OK\n"), "{text}");
    assert_eq!(serde_json::to_value(&s).unwrap()["verdict"], "ok");
}

#[test]
fn a_marked_flight_followed_by_healthy_ones_is_watch() {
    let wear = Synth {
        moving_a: 0.45,
        ..HEALTHY
    };
    let (s, text) = flap_trend(10, &[6, 7], wear);
    assert_eq!(s.verdict, Verdict::Watch, "{text}");
    // The last marked flight, and its findings.
    assert_eq!(s.marked_since, Some(7), "{text}");
    let triggers: Vec<&str> = s.triggers.iter().map(|f| f.figure).collect();
    assert_eq!(triggers, ["friction"], "{text}");
    assert_eq!(
        marks(&s),
        [(6, vec!["friction"]), (7, vec!["friction"])],
        "{text}"
    );
    assert!(
        text.contains("flap (bus wing, ID 5): WATCH — flight 7 was marked\n"),
        "{text}"
    );
    assert_eq!(serde_json::to_value(&s).unwrap()["verdict"], "watch");
}

#[test]
fn inspect_counts_the_marked_flights_since_the_last_healthy_one() {
    let wear = Synth {
        moving_a: 0.45,
        ..HEALTHY
    };
    let (s, text) = flap_trend(10, &[6, 8, 9, 10], wear);
    assert_eq!(s.verdict, Verdict::Inspect, "{text}");
    assert_eq!(s.marked_since, Some(8), "{text}");
    assert_eq!(marks(&s).len(), 4, "{text}");
    assert!(text.contains("since flight 8\n"), "{text}");
    assert_eq!(serde_json::to_value(&s).unwrap()["verdict"], "inspect");
}

// ---------------------------------------------------------------------------------------------
// The page

/// The value of attribute `name` in the tag `tag`.
fn attribute<'a>(tag: &'a str, name: &str) -> Option<&'a str> {
    let at = tag.find(&format!(" {name}=\""))? + name.len() + 3;
    tag[at..].split('"').next()
}

/// The `<g class="panel">` of `figure` in `svg`.
fn panel<'a>(svg: &'a str, figure: &str) -> &'a str {
    let start = svg
        .find(&format!(r#"<g class="panel" data-panel="{figure}">"#))
        .unwrap_or_else(|| panic!("no panel {figure}"));
    let end = svg[start..].find("</g>").unwrap() + start;
    &svg[start..end]
}

/// The labels of the panel's value axis (its grid lines' texts, at the left of the frame).
fn y_labels(panel: &str) -> Vec<String> {
    panel
        .split("<text ")
        .skip(1)
        .filter(|t| t.contains(r#"text-anchor="end""#) && !t.contains("fill="))
        .map(|t| t[t.find('>').unwrap() + 1..t.find("</text>").unwrap()].to_string())
        .collect()
}

/// Ten flights on one day, ten minutes apart: each at its own x, in flight order, its date and
/// time in its tooltip.
#[test]
fn the_page_plots_flights_by_number_so_that_flights_of_one_day_do_not_stack() {
    let dir = TempDir::new("trend-one-day");
    for n in 0..10 {
        synth_flight_at(
            dir.path(),
            n,
            FIRST_FLIGHT_NS + n as i64 * 600_000_000_000,
            HEALTHY,
        );
    }
    let (t, _) = trend(&files_of(dir.path()), &[]);
    let page = trend_page(&t);
    let friction = panel(&page, "friction");
    let circles: Vec<(usize, f64, &str)> = friction
        .split("<circle ")
        .skip(1)
        .map(|c| {
            let n: usize = attribute(c, "data-flight").unwrap().parse().unwrap();
            let cx: f64 = attribute(c, "cx").unwrap().parse().unwrap();
            let title = &c[c.find("<title>").unwrap() + 7..c.find("</title>").unwrap()];
            (n, cx, title)
        })
        .collect();
    assert_eq!(circles.len(), 10, "{friction}");
    for (k, w) in circles.windows(2).enumerate() {
        assert_eq!(w[0].0, k + 1);
        // At least a few pixels apart, in order.
        assert!(w[1].1 > w[0].1 + 20.0, "{circles:?}");
    }
    // Evenly spaced: flight numbers, not times.
    let gaps: Vec<f64> = circles.windows(2).map(|w| w[1].1 - w[0].1).collect();
    assert!(gaps.iter().all(|g| (g - gaps[0]).abs() < 0.2), "{gaps:?}");
    assert!(
        circles[3].2.starts_with("flight 4, 2026-01-01 08:30:"),
        "{circles:?}"
    );
    assert!(
        page.contains(">flight</text>") || page.contains(">flight ("),
        "{page}"
    );
}

/// Nothing but zeros (no bad reply in any flight): an axis from 0 up with round labels, not
/// one a few millionths wide.
#[test]
fn a_series_of_zeros_gets_an_axis_that_reads_well() {
    let (s, text) = flap_trend(6, &[], HEALTHY);
    assert!(
        s.flights.iter().all(|f| f.bad_replies == Some(0.0)),
        "{text}"
    );
    let svg = lj9da_bridge::record::trend_html::servo_trend_svg(&s);
    let bad = panel(&svg, "bad replies");
    let labels = y_labels(bad);
    assert_eq!(labels, ["0.0", "0.2", "0.4", "0.6", "0.8", "1.0"], "{bad}");
    // The points sit on the 0 line, inside the frame.
    let frame = &bad[bad.find("<rect ").unwrap()..];
    let top: f64 = attribute(frame, "y").unwrap().parse().unwrap();
    let height: f64 = attribute(frame, "height").unwrap().parse().unwrap();
    for c in bad.split("<circle ").skip(1) {
        let cy: f64 = attribute(c, "cy").unwrap().parse().unwrap();
        assert!(
            cy > top + 2.0 && cy < top + height - 2.0,
            "{cy} in {top}+{height}"
        );
    }
    // A constant series that is not zero: its value ± 10 %, labelled at round values.
    let labels = y_labels(panel(&svg, "holding current"));
    assert!(labels.len() >= 3, "{labels:?}");
    for l in &labels {
        let v: f64 = l.parse().unwrap();
        assert!(l.len() <= 5 && v > 0.0 && v < 0.2, "{labels:?}");
    }
}

//! Looking at a record: the summary's figures against a synthetic run whose figures are
//! known, the CSV export, the SVG pictures, and the `record` subcommand.

mod flag_records;
mod tempdir;

use flag_records::{ALARM_AT_US, FLASH_ERROR_AT_US, flag_records};
use lj9da_bridge::bus::{Goal, Health};
use lj9da_bridge::protocol::{Celsius, Ma10, MmCenti, Ms10, Mv10, ReplyFlags, Telemetry};
use lj9da_bridge::record::cli::{RecordCommand, run};
use lj9da_bridge::record::csv::{CSV_HEADER, write_csv};
use lj9da_bridge::record::format::{RecordHeader, RecordServo, encode_header, encode_record};
use lj9da_bridge::record::page::flight_page;
use lj9da_bridge::record::plot::plot;
use lj9da_bridge::record::{Record, RecordBody, Recording, summary};
use std::process::ExitCode;
use tempdir::TempDir;

/// One sample of the synthetic run.
struct Sample {
    t_s: f64,
    position: i16,
    load: u16,
    temperature: i16,
    voltage: u16,
    flags: u8,
}

/// The synthetic run: servo 0 ("left") is polled every 0.1 s from 0.1 s to 3.0 s except
/// 2.3–2.7 s (offline); it gets a 10 mm goal at 0.95 s and reaches it from 1.5 s with
/// ±0.05 mm of jitter; it stalls from 1.6 s to 2.1 s; its temperature alarm goes on twice
/// (2.0 s, 2.8 s) and its temperature error once (2.8 s); its goal is held at 2.0 s and
/// switched off at 2.6 s. Servo 1 ("right") is never heard from.
fn samples() -> Vec<Sample> {
    (1..=30)
        .filter(|k| !(23..=27).contains(k))
        .map(|k: i32| {
            let t_s = f64::from(k) / 10.0;
            let position = match k {
                ..=10 => 0,
                11..=14 => (k as i16 - 10) * 200,
                _ => 1000 + if k % 2 == 0 { 5 } else { -5 },
            };
            Sample {
                t_s,
                position,
                load: if k == 15 { 250 } else { 50 + k as u16 },
                temperature: 30 + (k % 3) as i16,
                voltage: if k == 20 { 1150 } else { 1200 },
                flags: match k {
                    20 | 21 | 29 => ReplyFlags::TEMPERATURE_ALARM,
                    28 => ReplyFlags::TEMPERATURE_ALARM | ReplyFlags::TEMPERATURE_ERROR,
                    _ => 0x02, // undefined bit 1 only: no alarm
                },
            }
        })
        .collect()
}

fn us(t_s: f64) -> u64 {
    (t_s * 1e6).round() as u64
}

fn synthetic_records() -> Vec<Record> {
    let mut records = vec![
        Record {
            t_us: 0,
            body: RecordBody::Health {
                servo: 0,
                health: Health::Starting,
                stalled: false,
            },
        },
        Record {
            t_us: 0,
            body: RecordBody::Goal {
                servo: 0,
                goal: Goal::Position(MmCenti(0)),
            },
        },
        Record {
            t_us: us(0.1),
            body: RecordBody::Health {
                servo: 0,
                health: Health::Online,
                stalled: false,
            },
        },
        Record {
            t_us: us(0.95),
            body: RecordBody::Goal {
                servo: 0,
                goal: Goal::Position(MmCenti(1000)),
            },
        },
        Record {
            t_us: us(1.6),
            body: RecordBody::Health {
                servo: 0,
                health: Health::Online,
                stalled: true,
            },
        },
        Record {
            t_us: us(2.0),
            body: RecordBody::Goal {
                servo: 0,
                goal: Goal::Hold,
            },
        },
        Record {
            t_us: us(2.1),
            body: RecordBody::Health {
                servo: 0,
                health: Health::Online,
                stalled: false,
            },
        },
        Record {
            t_us: us(2.25),
            body: RecordBody::Health {
                servo: 0,
                health: Health::Offline,
                stalled: false,
            },
        },
        Record {
            t_us: us(2.6),
            body: RecordBody::Goal {
                servo: 0,
                goal: Goal::Off,
            },
        },
        Record {
            t_us: us(2.75),
            body: RecordBody::Health {
                servo: 0,
                health: Health::Online,
                stalled: false,
            },
        },
        Record {
            t_us: us(2.3),
            body: RecordBody::Event {
                servo: Some(0),
                severity: 2,
                text: "left: servo lost".into(),
            },
        },
        Record {
            t_us: us(1.0),
            body: RecordBody::Event {
                servo: None,
                severity: 4,
                text: "a text, with a comma and \"quotes\"".into(),
            },
        },
        Record {
            t_us: us(1.2),
            body: RecordBody::Dropped { count: 3 },
        },
    ];
    for s in samples() {
        records.push(Record {
            t_us: us(s.t_s),
            body: RecordBody::Telemetry {
                servo: 0,
                telemetry: Telemetry {
                    present_position: MmCenti(s.position),
                    present_time: Ms10(0),
                    present_load: Ma10(s.load),
                    present_temperature: Celsius(s.temperature),
                    present_voltage: Mv10(s.voltage),
                },
                flags: ReplyFlags(s.flags),
            },
        });
    }
    records.sort_by_key(|r| r.t_us);
    records.push(Record {
        t_us: us(3.0),
        body: RecordBody::End { continued: false },
    });
    records
}

fn synthetic() -> Recording {
    let mut bytes = encode_header(&RecordHeader::new(
        1_763_769_600_000_000_000,
        vec![
            RecordServo::new("left", "wing", 1, 3),
            RecordServo::new("right", "wing", 2, 4),
        ],
    ));
    for r in synthetic_records() {
        encode_record(&r, &mut bytes);
    }
    Recording::from_bytes(&bytes).unwrap()
}

fn us_to_s(t_us: u64) -> f64 {
    t_us as f64 / 1e6
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() < 1e-9
}

#[test]
fn summary_figures_match_the_known_run() {
    let rec = synthetic();
    assert!(rec.notes.is_empty(), "{:?}", rec.notes);
    let sum = summary(&rec);
    let s = &sum.servos[0];
    let all = samples();

    // Expected figures, computed from the samples directly.
    let temps: Vec<f64> = all.iter().map(|x| f64::from(x.temperature)).collect();
    let mean_temp = temps.iter().sum::<f64>() / temps.len() as f64;
    let volts: Vec<f64> = all.iter().map(|x| f64::from(x.voltage) / 100.0).collect();
    let goal_at = |t: f64| -> Option<f64> {
        match t {
            t if t < 0.95 => Some(0.0),
            t if t < 2.6 => Some(10.0),
            _ => None,
        }
    };
    let errors: Vec<(f64, f64)> = all
        .iter()
        .filter_map(|x| goal_at(x.t_s).map(|g| (x.t_s, (g - f64::from(x.position) / 100.0).abs())))
        .collect();
    let max_error = errors.iter().map(|e| e.1).fold(0.0, f64::max);
    let settled = errors
        .iter()
        .filter(|(t, _)| *t >= 0.95 + 1.0)
        .map(|e| e.1)
        .fold(0.0, f64::max);

    assert_eq!(s.servo.name, "left");
    assert_eq!(s.samples, 25);
    assert!(close(s.duration_s(), 2.9));
    let t = s.temperature_c.unwrap();
    assert_eq!((t.min, t.max), (30.0, 32.0));
    assert!(close(t.mean, mean_temp));
    assert!(close(s.peak_current_a().unwrap(), 2.5));
    let v = s.voltage_v.unwrap();
    assert!(close(v.min, 11.5));
    assert!(close(
        v.mean,
        volts.iter().sum::<f64>() / volts.len() as f64
    ));
    assert!(close(s.stalled_s, 0.5));
    assert!(close(s.offline_s, 0.5));
    assert!(close(s.max_error_mm.unwrap(), max_error));
    assert!(close(s.max_error_mm.unwrap(), 10.0));
    assert!(close(s.max_error_at_s.unwrap(), 1.0));
    assert!(close(s.max_settled_error_mm.unwrap(), settled));
    assert!(close(settled, 0.05));
    assert_eq!(s.temperature_alarms, 2);
    assert_eq!(s.temperature_errors, 1);
    assert_eq!(s.flash_errors, 0);
    assert_eq!(s.alarms(), 3);
    assert_eq!(s.goals, 4);
    assert_eq!(s.events, 1);

    let quiet = &sum.servos[1];
    assert_eq!(quiet.samples, 0);
    assert_eq!(quiet.temperature_c, None);
    assert_eq!(quiet.max_error_mm, None);
    assert_eq!(quiet.alarms(), 0);

    assert!(close(sum.duration_s, 3.0));
    assert_eq!(sum.dropped, 3);
    assert!(sum.closed);
}

#[test]
fn the_summary_table_is_aligned_and_names_each_servo() {
    let text = summary(&synthetic()).to_string();
    let lines: Vec<&str> = text.lines().collect();
    assert!(lines[0].starts_with("run started 2025-11-22 00:00:00.000 UTC: 3.0 s"));
    assert!(lines[1].contains("3 records were dropped"));
    let table: Vec<&str> = lines[2..5].to_vec();
    assert!(table[0].starts_with("servo"));
    assert!(table[1].starts_with("left "));
    assert!(table[2].starts_with("right "));
    let width = table[0].chars().count();
    assert!(table.iter().all(|l| l.chars().count() == width), "{text}");
    assert!(table[1].contains(" 25 "), "{text}");
    assert!(table[1].contains("10.00"), "{text}");
    assert!(table[1].contains("2.50"), "{text}");
    assert!(lines[5].starts_with("left: 2 × temperature alarm, 1 × temperature error"));
    assert!(!text.contains("-0.0"), "{text}");
}

#[test]
fn csv_has_a_header_and_one_row_per_record() {
    let rec = synthetic();
    let mut out = Vec::new();
    let rows = write_csv(&rec, &mut out).unwrap();
    let text = String::from_utf8(out).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines[0], CSV_HEADER);
    assert_eq!(rows as usize, rec.records.len());
    assert_eq!(lines.len(), rec.records.len() + 1);
    let columns = CSV_HEADER.split(',').count();
    assert_eq!(columns, 15);

    let telemetry = lines
        .iter()
        .find(|l| l.starts_with("1.500000,left,telemetry,"))
        .unwrap();
    assert_eq!(
        *telemetry,
        "1.500000,left,telemetry,,,9.95,2.50,30,12.00,0,ok,,,,"
    );
    assert!(lines.contains(&"0.950000,left,goal,position,10.00,,,,,,,,,,"));
    assert!(lines.contains(&"2.600000,left,goal,off,,,,,,,,,,,"));
    assert!(lines.contains(&"2.250000,left,health,,,,,,,,,offline,0,,"));
    assert!(
        lines.contains(
            &"1.000000,,event,,,,,,,,,,,warning,\"a text, with a comma and \"\"quotes\"\"\""
        ),
        "{text}"
    );
    assert!(lines.contains(&"1.200000,,dropped,,,,,,,,,,,,records dropped: 3"));
    assert!(lines.contains(&"3.000000,,end,,,,,,,,,,,,end of run"));
    let flagged = lines
        .iter()
        .find(|l| l.starts_with("2.800000,left,telemetry,"))
        .unwrap();
    assert!(flagged.contains("\"temperature error (force off), temperature alarm\""));
}

fn count(svg: &str, needle: &str) -> usize {
    svg.matches(needle).count()
}

#[test]
fn pictures_show_every_series_with_alarms_marked() {
    let rec = synthetic();
    let dir = TempDir::new("plot");
    let files = plot(&rec, dir.path(), "run").unwrap();
    assert_eq!(
        files,
        vec![
            dir.path().join("run-left.svg"),
            dir.path().join("run-right.svg")
        ]
    );
    let left = std::fs::read_to_string(&files[0]).unwrap();
    assert!(left.starts_with("<?xml"));
    assert!(left.trim_end().ends_with("</svg>"));
    for panel in ["position", "current", "temperature", "voltage"] {
        assert_eq!(count(&left, &format!("data-panel=\"{panel}\"")), 1);
    }
    // The gap while offline (2.2 s → 2.8 s) breaks each telemetry line in two.
    for series in ["position", "current", "temperature", "voltage"] {
        assert_eq!(
            count(&left, &format!("<polyline data-series=\"{series}\"")),
            2,
            "{series}"
        );
    }
    // One goal line: from the first goal until it is switched off.
    assert_eq!(count(&left, "<polyline data-series=\"goal\""), 1);
    // Three flag alarms, marked in each of the four panels.
    assert_eq!(count(&left, "class=\"alarm\""), 12);
    assert_eq!(count(&left, "data-alarm=\"temperature alarm\""), 8);
    assert_eq!(count(&left, "data-alarm=\"temperature error\""), 4);
    assert_eq!(count(&left, "class=\"stalled\""), 4);
    assert_eq!(count(&left, "class=\"offline\""), 4);
    assert!(left.contains(">alarm 75 °C<") && left.contains(">limit 85 °C<"));
    for label in [
        "goal",
        "present position",
        "current",
        "temperature",
        "voltage",
    ] {
        assert!(left.contains(&format!(">{label}</text>")), "{label}");
    }

    let right = std::fs::read_to_string(&files[1]).unwrap();
    assert!(!right.is_empty());
    assert_eq!(count(&right, "<polyline"), 0);
    assert_eq!(count(&right, ">no data<"), 4);
}

#[test]
fn long_runs_are_thinned_but_keep_their_peaks() {
    let mut bytes = encode_header(&RecordHeader::new(
        0,
        vec![RecordServo::new("s", "b", 1, 1)],
    ));
    let n = 100_000u64;
    for k in 0..n {
        encode_record(
            &Record {
                t_us: k * 10_000,
                body: RecordBody::Telemetry {
                    servo: 0,
                    telemetry: Telemetry {
                        present_load: Ma10(if k == 54_321 { 999 } else { 50 }),
                        ..Telemetry::default()
                    },
                    flags: ReplyFlags(0),
                },
            },
            &mut bytes,
        );
    }
    let rec = Recording::from_bytes(&bytes).unwrap();
    let svg = lj9da_bridge::record::plot::servo_svg(&rec, 0, "long");
    assert!(svg.len() < 400_000, "{} bytes", svg.len());
    let current = svg
        .lines()
        .find(|l| l.starts_with("<polyline data-series=\"current\""))
        .unwrap();
    let ys: Vec<f64> = current
        .split("points=\"")
        .nth(1)
        .unwrap()
        .trim_end_matches("\"/>")
        .split(' ')
        .map(|p| p.split(',').nth(1).unwrap().parse().unwrap())
        .collect();
    assert!(ys.len() < 3000, "{} points", ys.len());
    // The single 9.99 A sample is the panel's top: the smallest y of the line.
    let top = ys.iter().copied().fold(f64::INFINITY, f64::min);
    assert_eq!(ys.iter().filter(|y| **y == top).count(), 1);
}

#[test]
fn the_record_subcommand_reads_plots_and_exports() {
    let dir = TempDir::new("cli");
    let mut bytes = encode_header(&RecordHeader::new(
        1_763_769_600_000_000_000,
        vec![
            RecordServo::new("left", "wing", 1, 3),
            RecordServo::new("right", "wing", 2, 4),
        ],
    ));
    for r in synthetic_records() {
        encode_record(&r, &mut bytes);
    }
    let file = dir.path().join("20251122T000000Z.lj9rec");
    std::fs::write(&file, &bytes).unwrap();

    assert_eq!(
        run(RecordCommand::Summary { file: file.clone() }),
        ExitCode::SUCCESS
    );
    let out = dir.path().join("pictures");
    assert_eq!(
        run(RecordCommand::Plot {
            file: file.clone(),
            out: out.clone()
        }),
        ExitCode::SUCCESS
    );
    assert!(out.join("20251122T000000Z-left.svg").is_file());
    assert!(out.join("20251122T000000Z-right.svg").is_file());
    let csv = dir.path().join("run.csv");
    assert_eq!(
        run(RecordCommand::Csv {
            file: file.clone(),
            out: Some(csv.clone())
        }),
        ExitCode::SUCCESS
    );
    assert_eq!(
        std::fs::read_to_string(&csv).unwrap().lines().count(),
        synthetic_records().len() + 1
    );
    assert_eq!(
        run(RecordCommand::Summary {
            file: dir.path().join("missing.lj9rec")
        }),
        ExitCode::FAILURE
    );
}

#[test]
fn position_records_count_in_the_error_and_the_exports_but_not_as_samples() {
    let mut bytes = encode_header(&RecordHeader::new(
        1_763_769_600_000_000_000,
        vec![RecordServo::new("left", "wing", 1, 3)],
    ));
    let records = [
        (
            0.0,
            RecordBody::Goal {
                servo: 0,
                goal: Goal::Position(MmCenti(1000)),
            },
        ),
        (
            1.0,
            RecordBody::Telemetry {
                servo: 0,
                telemetry: Telemetry {
                    present_position: MmCenti(990),
                    present_time: Ms10(0),
                    present_load: Ma10(30),
                    present_temperature: Celsius(35),
                    present_voltage: Mv10(1480),
                },
                flags: ReplyFlags(0),
            },
        ),
        // A read of the position alone, 2 s after the goal: 3.00 mm short of it.
        (
            2.0,
            RecordBody::Position {
                servo: 0,
                position: MmCenti(700),
                flags: ReplyFlags(0),
            },
        ),
        (3.0, RecordBody::End { continued: false }),
    ];
    for (t, body) in &records {
        encode_record(
            &Record {
                t_us: us(*t),
                body: body.clone(),
            },
            &mut bytes,
        );
    }
    let rec = Recording::from_bytes(&bytes).unwrap();
    assert!(rec.notes.is_empty(), "{:?}", rec.notes);
    let s = &summary(&rec).servos[0];
    assert_eq!(s.samples, 1, "a position read is not a telemetry sample");
    assert!(close(s.max_error_mm.unwrap(), 3.0), "{:?}", s.max_error_mm);
    assert!(close(s.max_error_at_s.unwrap(), 2.0));
    assert!(close(s.max_settled_error_mm.unwrap(), 3.0));

    let mut csv = Vec::new();
    write_csv(&rec, &mut csv).unwrap();
    let csv = String::from_utf8(csv).unwrap();
    let row = csv
        .lines()
        .find(|l| l.split(',').nth(2) == Some("position"))
        .unwrap();
    assert!(
        row.starts_with("2.000000,") && row.contains(",7.00,"),
        "{row}"
    );
}

/// A flag that comes and goes between two full reads is seen only by the reads of position (and
/// current) in between: it counts, at the time of the read that first carried it.
#[test]
fn a_flag_seen_only_between_two_full_reads_counts_as_an_alarm() {
    let mut bytes = encode_header(&RecordHeader::new(
        1_763_769_600_000_000_000,
        vec![RecordServo::new("left", "wing", 1, 3)],
    ));
    for (t_us, body) in flag_records() {
        encode_record(&Record { t_us, body }, &mut bytes);
    }
    let rec = Recording::from_bytes(&bytes).unwrap();
    assert!(rec.notes.is_empty(), "{:?}", rec.notes);
    let s = &summary(&rec).servos[0];
    assert_eq!(
        (s.temperature_alarms, s.temperature_errors, s.flash_errors),
        (1, 0, 1)
    );
    let at = summary::flag_alarms(&rec, 0);
    assert_eq!(at.len(), 2, "{at:?}");
    assert!(
        close(at[0].0, us_to_s(ALARM_AT_US)) && at[0].1 == "temperature alarm",
        "{at:?}"
    );
    assert!(
        close(at[1].0, us_to_s(FLASH_ERROR_AT_US)) && at[1].1 == "flash write error",
        "{at:?}"
    );
}

#[test]
fn one_page_shows_every_servo_of_a_flight_with_nothing_to_fetch() {
    let rec = synthetic();
    let page = flight_page(&rec, "run");
    assert!(page.starts_with("<!DOCTYPE html>"));
    assert!(page.trim_end().ends_with("</html>"));
    for servo in ["left", "right"] {
        assert_eq!(
            count(&page, &format!("<section data-servo=\"{servo}\">")),
            1
        );
    }
    // Each servo's whole picture, inline and zoomable: the same series as its SVG file.
    assert_eq!(count(&page, "<svg data-zoom"), 2);
    assert!(
        !page.contains("<?xml"),
        "inline SVG takes no XML declaration"
    );
    for servo in 0..2 {
        let svg = lj9da_bridge::record::plot::servo_svg(&rec, servo, "run");
        let body = &svg[svg.find("<svg ").unwrap() + "<svg ".len()..];
        assert!(
            page.contains(body),
            "servo {servo}'s picture is in the page whole"
        );
    }
    let svgs: String = (0..2)
        .map(|servo| lj9da_bridge::record::plot::servo_svg(&rec, servo, "run"))
        .collect();
    for series in ["goal", "position", "current", "temperature", "voltage"] {
        let needle = format!("data-series=\"{series}\"");
        assert!(count(&page, &needle) >= 1, "{series}");
        assert_eq!(count(&page, &needle), count(&svgs, &needle), "{series}");
    }
    // The flight's summary, and nothing loaded from elsewhere.
    assert!(page.contains("left: 2 × temperature alarm, 1 × temperature error"));
    for outside in ["src=", "<link", "@import", "https:"] {
        assert!(!page.contains(outside), "{outside}");
    }
}

#[test]
fn record_plot_also_writes_the_flights_page() {
    let dir = TempDir::new("page");
    let mut bytes = encode_header(&RecordHeader::new(
        1_763_769_600_000_000_000,
        vec![
            RecordServo::new("left", "wing", 1, 3),
            RecordServo::new("right", "wing", 2, 4),
        ],
    ));
    for r in synthetic_records() {
        encode_record(&r, &mut bytes);
    }
    let file = dir.path().join("20251122T000000Z.lj9rec");
    std::fs::write(&file, &bytes).unwrap();
    let out = dir.path().join("pictures");
    assert_eq!(
        run(RecordCommand::Plot {
            file,
            out: out.clone()
        }),
        ExitCode::SUCCESS
    );
    let page = std::fs::read_to_string(out.join("20251122T000000Z.html")).unwrap();
    assert_eq!(count(&page, "<svg data-zoom"), 2);
}

/// `record summary` and `record trend` fold a servo's records with the same code: on the same
/// file they agree on every figure they both report.
#[test]
fn summary_and_trend_agree_on_the_figures_they_share() {
    let dir = TempDir::new("summary-trend");
    let flags: Vec<Record> = flag_records()
        .into_iter()
        .map(|(t_us, body)| Record { t_us, body })
        .collect();
    for (name, records) in [("synthetic", synthetic_records()), ("flags", flags)] {
        let mut bytes = encode_header(&RecordHeader::new(
            1_763_769_600_000_000_000,
            vec![
                RecordServo::new("left", "wing", 1, 3),
                RecordServo::new("right", "wing", 2, 4),
            ],
        ));
        for r in &records {
            encode_record(r, &mut bytes);
        }
        let path = dir.path().join(format!("{name}.lj9rec"));
        std::fs::write(&path, &bytes).unwrap();
        let s = &summary(&Recording::from_bytes(&bytes).unwrap()).servos[0];
        let (t, notes) = lj9da_bridge::record::trend::trend(&[path], &[]);
        assert!(notes.errors.is_empty(), "{notes:?}");
        // "right" is never heard from: no flight.
        assert_eq!(t.servos.len(), 1, "{name}");
        let f = &t.servos[0].flights[0];
        assert_eq!(f.alarms, s.alarms(), "{name}");
        assert_eq!(f.stalled_s, s.stalled_s, "{name}");
        assert_eq!(f.peak_a, s.peak_current_a(), "{name}");
        assert_eq!(f.peak_c, s.temperature_c.map(|r| r.max), "{name}");
        assert_eq!(f.mean_c, s.temperature_c.map(|r| r.mean), "{name}");
        assert!(f.alarms > 0, "{name}: {f:?}");
    }
}

/// `lj9da-bridge record … | head`: a reader that has gone before the command writes is no
/// error, for every command that prints to stdout. (A `print!` panics there: exit 101 and a
/// backtrace on stderr.)
#[test]
fn a_reader_that_stopped_reading_is_no_error() {
    let fixture = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/src/record/fixtures/x86_64.lj9rec"
    );
    for args in [
        vec!["summary", fixture],
        vec!["csv", fixture],
        vec!["trend", fixture],
    ] {
        let (reader, writer) = std::io::pipe().unwrap();
        drop(reader);
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_lj9da-bridge"))
            .arg("record")
            .args(&args)
            .stdout(writer)
            .stderr(std::process::Stdio::piped())
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(
            out.status.success() && !stderr.contains("panicked"),
            "record {args:?}: {}\n{stderr}",
            out.status
        );
    }
}

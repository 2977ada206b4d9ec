//! `record trend` on flights with a known answer: ten flights of four simulated servos (the
//! `lj9da-sim` servo model in virtual time, its registers recorded as the bridge records
//! telemetry), one of which wears from flight six on; and one real run through a pseudo-terminal,
//! the bus master and the recorder, with the simulator's wear knob turned on one servo.

mod flag_records;
mod tempdir;
mod trend_support;

use flag_records::flag_records;
use lj9da_bridge::bus::{BusConfig, Goal, Health, ServoSetup, ShutdownForce, spawn_bus_observed};
use lj9da_bridge::protocol::{
    BaudRate, Celsius, Ma10, MmCenti, Ms10, Mv10, ReplyFlags, ServoId, Telemetry,
};
use lj9da_bridge::record::cli::{RecordCommand, run};
use lj9da_bridge::record::format::{RecordHeader, RecordServo, encode_header, encode_record};
use lj9da_bridge::record::trend::{Since, Trend, Verdict, record_files, trend};
use lj9da_bridge::record::trend_html::trend_page;
use lj9da_bridge::record::{Record, RecordBody, RecordLimits, Recorder, StatusFeed};
use lj9da_sim::{FrictionSpot, SimBus, SimConfig, Wear};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};
use tempdir::TempDir;
use trend_support::flight::{Flight, four_servos as servos};
use trend_support::{FIRST_FLIGHT_NS, NS_PER_DAY, files_of};

/// Seconds of each virtual flight.
const FLIGHT_S: u64 = 40;

/// Friction wear of `k` A per mm/s, both ways and over the whole stroke.
fn friction(k: f64) -> Wear {
    Wear {
        friction_a_per_mm_s: k,
        ..Wear::default()
    }
}

const NO_WEAR: [Wear; 4] = [Wear {
    friction_a_per_mm_s: 0.0,
    friction_extend_a_per_mm_s: 0.0,
    friction_spot: None,
    stiff_spot: None,
}; 4];

/// Flight `n` (0-based) of the four servos, with the given wear on each, written as a record
/// file in `dir` ([`trend_support::flight`]): one a day from 2026-01-01.
fn fly(dir: &Path, n: usize, wear: [Wear; 4]) -> PathBuf {
    fly_as(dir, n, wear, None)
}

/// As [`fly`], on the aircraft the header names.
fn fly_as(dir: &Path, n: usize, wear: [Wear; 4], aircraft: Option<&str>) -> PathBuf {
    let path = dir.join(format!("flight{:02}.lj9rec", n + 1));
    Flight {
        n,
        start_ns: FIRST_FLIGHT_NS + n as i64 * NS_PER_DAY,
        seconds: FLIGHT_S,
        servos: servos(),
        wear: wear.to_vec(),
        aircraft: aircraft.map(str::to_string),
        ambient_offset_c: 0.0,
    }
    .write(&path);
    path
}

fn servo<'a>(t: &'a Trend, name: &str) -> &'a lj9da_bridge::record::trend::ServoTrend {
    t.servos.iter().find(|s| s.servo.name == name).unwrap()
}

#[test]
fn the_servo_whose_friction_rises_is_marked_from_the_flight_it_passes_the_threshold() {
    let worn_dir = TempDir::new("trend-worn");
    let new_dir = TempDir::new("trend-new");
    // The first five flights of both sets: no wear anywhere.
    for n in 0..5 {
        fly(worn_dir.path(), n, NO_WEAR);
        fly(new_dir.path(), n, NO_WEAR);
    }
    let files = record_files(&[worn_dir.path().to_path_buf()]).unwrap();
    let (first, notes) = trend(&files, &[]);
    assert!(
        notes.errors.is_empty() && notes.notes.is_empty(),
        "{notes:?}"
    );
    assert!(first.servos.iter().all(|s| s.verdict == Verdict::Baseline));
    // The elevator's friction from flight six on, as a share of its baseline friction figure:
    // +8 %, +16 % (below the +25 % threshold), then +40 %, +60 %, +80 %.
    let base = servo(&first, "elevator")
        .baseline
        .friction_ma_per_mm_s
        .unwrap()
        / 1000.0;
    let rises = [0.08, 0.16, 0.40, 0.60, 0.80];
    for (k, rise) in rises.iter().enumerate() {
        let mut wear = NO_WEAR;
        wear[2] = friction(rise * base);
        fly(worn_dir.path(), 5 + k, wear);
        fly(new_dir.path(), 5 + k, NO_WEAR);
    }

    let files = record_files(&[worn_dir.path().to_path_buf()]).unwrap();
    assert_eq!(files.len(), 10);
    let (worn, _) = trend(&files, &[]);
    let text = worn.to_string();
    let elevator = servo(&worn, "elevator");
    assert_eq!(elevator.verdict, Verdict::Inspect, "{text}");
    assert_eq!(elevator.marked_since, Some(8), "{text}");
    assert!(
        elevator.triggers.iter().any(|f| f.figure == "friction"),
        "{text}"
    );
    let marked: Vec<usize> = elevator
        .flights
        .iter()
        .enumerate()
        .filter(|(_, f)| !f.findings.is_empty())
        .map(|(i, _)| i + 1)
        .collect();
    assert_eq!(marked, [8, 9, 10], "{text}");
    // The figure follows the knob: each flight's friction over the baseline by about its rise.
    for (k, rise) in rises.iter().enumerate() {
        let f = &elevator.flights[5 + k];
        let change =
            f.friction_ma_per_mm_s.unwrap() / elevator.baseline.friction_ma_per_mm_s.unwrap() - 1.0;
        assert!(
            (change - rise).abs() < 0.06,
            "flight {}: {change} for {rise}",
            6 + k
        );
    }
    // More friction, more heat: the most worn flight heats faster than the baseline.
    let heating = |i: usize| elevator.flights[i].heating_c_per_min.unwrap();
    assert!(
        heating(9) > elevator.baseline.heating_c_per_min.unwrap(),
        "{text}"
    );
    for other in ["aileron_left", "aileron_right", "rudder"] {
        let s = servo(&worn, other);
        assert_eq!(s.verdict, Verdict::Ok, "{other}: {text}");
        assert!(s.flights.iter().all(|f| f.findings.is_empty()), "{text}");
    }
    assert!(
        text.contains("elevator (bus tail, ID 3): INSPECT — friction +"),
        "{text}"
    );
    assert!(text.contains("since flight 8"), "{text}");

    // The figures of a flight: ±10 mm sines at 0.5 Hz, 4 s of every 6, for 40 s.
    let f = &servo(&worn, "aileron_left").flights[0];
    assert!((f.force_on_s - 40.0).abs() < 0.1, "{f:?}");
    // Two sine periods of 40 mm each per 6 s, and the move to the holding point: about 560 mm.
    assert!(f.travel_mm > 500.0 && f.travel_mm < 650.0, "{f:?}");
    // Per 6 s: four turns of the sines, and two around the holding point.
    assert!((36..=42).contains(&f.reversals), "{f:?}");
    assert!(f.motion_s > 20.0 && f.motion_s < 30.0, "{f:?}");
    assert!((f.holding_a.unwrap() - 0.07).abs() < 0.015, "{f:?}");
    assert_eq!(f.stalled_s, 0.0);
    assert_eq!(f.bad_replies, Some(0.0));
    let rudder = &servo(&worn, "rudder").flights[0];
    assert!((rudder.bad_replies.unwrap() - 40.0 / 3116.0).abs() < 1e-3);

    // The same flights without wear: nothing marked.
    let files = record_files(&[new_dir.path().to_path_buf()]).unwrap();
    let (new, _) = trend(&files, &[]);
    for s in &new.servos {
        assert_eq!(s.verdict, Verdict::Ok, "{}", new);
        assert!(s.flights.iter().all(|f| f.findings.is_empty()), "{new}");
    }

    // A new baseline after the elevator was replaced on the day of flight eight: nothing to
    // judge yet for it; the others keep theirs.
    let since: Since = "elevator=2026-01-08".parse().unwrap();
    let (replaced, _) = trend(&files_of(worn_dir.path()), &[since]);
    let elevator = servo(&replaced, "elevator");
    assert_eq!(elevator.left_out, 7);
    assert_eq!(elevator.verdict, Verdict::Baseline);
    assert_eq!(servo(&replaced, "rudder").flights.len(), 10);

    // JSON and the page say the same.
    let json = serde_json::to_value(&worn).unwrap();
    let elevator = json["servos"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["servo"]["name"] == "elevator")
        .unwrap();
    assert_eq!(elevator["verdict"], "inspect");
    assert_eq!(elevator["triggers"][0]["figure"], "friction");
    assert_eq!(json["thresholds"]["rise_limit"], 0.25);
    let page = trend_page(&worn);
    assert!(page.starts_with("<!DOCTYPE html>") && page.trim_end().ends_with("</html>"));
    assert_eq!(page.matches("<svg data-zoom").count(), 4);
    assert_eq!(
        page.matches(r#"class="crossed" data-figure="friction""#)
            .count(),
        3
    );
    assert!(page.contains(r#"data-servo="elevator" data-verdict="inspect""#));
    assert!(page.matches(r#"class="band""#).count() >= 4 * 3);
    for outside in ["src=", "<link", "@import", "https:"] {
        assert!(!page.contains(outside), "{outside}");
    }

    // The subcommand: text, JSON, page.
    let html = worn_dir.path().join("out/trend.html");
    for json in [false, true] {
        assert_eq!(
            run(RecordCommand::Trend {
                paths: vec![worn_dir.path().to_path_buf()],
                json,
                since: vec![],
                html: Some(html.clone()),
            }),
            ExitCode::SUCCESS
        );
    }
    assert!(std::fs::read_to_string(&html).unwrap().contains("elevator"));
    assert_eq!(
        run(RecordCommand::Trend {
            paths: vec![worn_dir.path().join("nothing-here")],
            json: false,
            since: vec![],
            html: None,
        }),
        ExitCode::FAILURE
    );
}

/// Two aircraft with servos of the same names, flown at the same times, one elevator wearing:
/// given at once, each aircraft's servos are judged on their own flights.
#[test]
fn a_fleets_folders_at_once_keep_each_aircrafts_servos_apart() {
    let a = TempDir::new("trend-plane-a");
    let b = TempDir::new("trend-plane-b");
    for n in 0..5 {
        fly_as(a.path(), n, NO_WEAR, Some("plane-a"));
        fly_as(b.path(), n, NO_WEAR, Some("plane-b"));
    }
    let (first, _) = trend(&record_files(&[a.path().to_path_buf()]).unwrap(), &[]);
    let base = servo(&first, "elevator")
        .baseline
        .friction_ma_per_mm_s
        .unwrap()
        / 1000.0;
    for n in 5..10 {
        let mut wear = NO_WEAR;
        wear[2] = friction(0.8 * base);
        fly_as(a.path(), n, wear, Some("plane-a"));
        fly_as(b.path(), n, NO_WEAR, Some("plane-b"));
    }
    let files = record_files(&[a.path().to_path_buf(), b.path().to_path_buf()]).unwrap();
    assert_eq!(files.len(), 20);
    let (fleet, notes) = trend(&files, &[]);
    assert!(notes.errors.is_empty(), "{notes:?}");
    let text = fleet.to_string();
    assert_eq!(fleet.servos.len(), 8, "{text}");
    for s in &fleet.servos {
        assert_eq!(s.flights.len(), 10, "{text}");
        // Runs of the two aircraft that began at the same instant are two flights, each of
        // its own file.
        assert!(
            s.flights.iter().all(|f| f.files.len() == 1),
            "{:?}",
            s.servo
        );
        let worn = s.servo.aircraft.as_deref() == Some("plane-a") && s.servo.name == "elevator";
        let want = if worn { Verdict::Inspect } else { Verdict::Ok };
        assert_eq!(s.verdict, want, "{:?}: {text}", s.servo);
    }
    assert!(
        text.contains("plane-a: elevator (bus tail, ID 3): INSPECT"),
        "{text}"
    );
    assert!(
        text.contains("plane-b: elevator (bus tail, ID 3): OK"),
        "{text}"
    );
}

#[test]
fn the_parts_of_one_run_make_one_flight_and_older_formats_read() {
    // One run in two parts, the second a format 1.1 file (no replies records): one flight.
    let dir = TempDir::new("trend-parts");
    let table = vec![RecordServo::new("flap", "wing", 5, 7)];
    let start = FIRST_FLIGHT_NS;
    for part in 0..2u16 {
        let mut header = RecordHeader::new(start, table.clone());
        header.part = part;
        header.version = (1, 1);
        let mut bytes = encode_header(&header);
        for k in 0..500u64 {
            let t_us = (u64::from(part) * 500 + k) * 20_000;
            // 10 mm/s up and down over 1 s, 20 ms apart.
            let mm = ((t_us / 20_000) % 100) as i16;
            let centi = if mm < 50 { mm * 20 } else { (100 - mm) * 20 };
            encode_record(
                &Record {
                    t_us,
                    body: RecordBody::Telemetry {
                        servo: 0,
                        telemetry: Telemetry {
                            present_position: MmCenti(centi),
                            present_time: Ms10(0),
                            present_load: Ma10(30),
                            present_temperature: Celsius(30 + (part as i16) * 2),
                            present_voltage: Mv10(1200),
                        },
                        flags: ReplyFlags(0),
                    },
                },
                &mut bytes,
            );
        }
        encode_record(
            &Record {
                t_us: (u64::from(part) + 1) * 500 * 20_000,
                body: RecordBody::End {
                    continued: part == 0,
                },
            },
            &mut bytes,
        );
        std::fs::write(dir.path().join(format!("run-{part}.lj9rec")), bytes).unwrap();
    }
    let (t, notes) = trend(&files_of(dir.path()), &[]);
    assert!(notes.errors.is_empty(), "{notes:?}");
    let flap = &t.servos[0];
    assert_eq!(flap.flights.len(), 1);
    let f = &flap.flights[0];
    assert_eq!(f.files.len(), 2);
    // 20 s of samples, 10 sweeps of 10 mm each way: 200 mm and 19 reversals.
    assert!((f.force_on_s - 19.98).abs() < 0.01, "{f:?}");
    assert!((f.travel_mm - 198.0).abs() < 2.1, "{f:?}");
    assert_eq!(f.reversals, 19, "{f:?}");
    // 0.30 A at 10 mm/s: 30 mA per mm/s (a little more: the speed over a span across a
    // reversal is lower).
    assert!(
        (f.friction_ma_per_mm_s.unwrap() - 30.0).abs() < 1.5,
        "{f:?}"
    );
    assert_eq!(f.peak_c, Some(32.0));
    assert_eq!(f.bad_replies, None);
    assert_eq!(flap.verdict, Verdict::Baseline);
}

/// A flag that comes and goes between two full reads is carried only by the reads of position
/// (and current) in between: the flight counts it.
#[test]
fn a_flag_seen_only_between_two_full_reads_counts_as_an_alarm() {
    let dir = TempDir::new("trend-flags");
    let mut bytes = encode_header(&RecordHeader::new(
        FIRST_FLIGHT_NS,
        vec![RecordServo::new("flap", "wing", 5, 7)],
    ));
    for (t_us, body) in flag_records() {
        encode_record(&Record { t_us, body }, &mut bytes);
    }
    std::fs::write(dir.path().join("run.lj9rec"), bytes).unwrap();
    let (t, notes) = trend(&files_of(dir.path()), &[]);
    assert!(notes.errors.is_empty(), "{notes:?}");
    let flights = &t.servos[0].flights;
    assert_eq!(flights.len(), 1);
    assert_eq!(flights[0].alarms, 2, "{:?}", flights[0]);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_simulators_wear_knob_shows_in_a_recorded_run() {
    let sim = SimBus::spawn_pty(SimConfig {
        ids: vec![1, 2],
        ..SimConfig::default()
    })
    .unwrap();
    assert!(sim.handle().set_wear(2, friction(0.01)));
    let table = vec![
        RecordServo::new("new", "sim", 1, 1),
        RecordServo::new("worn", "sim", 2, 2),
    ];
    let setups = table
        .iter()
        .map(|s| ServoSetup::new(ServoId::new(s.id).unwrap(), &s.name))
        .collect();
    let mut bus_cfg = BusConfig::new("sim", BaudRate::B115200, setups);
    bus_cfg.turnaround = Duration::from_millis(20);
    bus_cfg.offline_after_timeouts = 50;
    bus_cfg.stale_after = Duration::from_secs(2);
    let dir = TempDir::new("trend-sim");
    let record = Recorder::start(dir.path(), &table, RecordLimits::default()).unwrap();
    let mut feed = StatusFeed::new(record.clone(), &table);
    let bus = spawn_bus_observed(bus_cfg, sim.path(), Box::new(move |s| feed.observe(s)));
    let deadline = Instant::now() + Duration::from_secs(10);
    while !bus
        .status()
        .servos
        .iter()
        .all(|s| s.health == Health::Online)
    {
        assert!(Instant::now() < deadline, "servos did not come online");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    // Sweeps of ±8 mm at 0.5 Hz for 6 s, goals at 50 Hz.
    let began = Instant::now();
    while began.elapsed() < Duration::from_secs(6) {
        let t = began.elapsed().as_secs_f64();
        let centi = (800.0 * (std::f64::consts::PI * t).sin()).round() as i16;
        for (index, s) in table.iter().enumerate() {
            let goal = Goal::Position(MmCenti(centi));
            bus.set_goal(ServoId::new(s.id).unwrap(), goal);
            record.goal(index, goal);
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    bus.shutdown(ShutdownForce::AsIs).await;
    let stats = record.finish();
    sim.shutdown();

    let (t, notes) = trend(&stats.files, &[]);
    assert!(notes.errors.is_empty(), "{notes:?}");
    let text = t.to_string();
    let new = &servo(&t, "new").flights[0];
    let worn = &servo(&t, "worn").flights[0];
    assert!(new.travel_mm > 60.0 && worn.travel_mm > 60.0, "{text}");
    let (a, b) = (
        new.friction_ma_per_mm_s.unwrap(),
        worn.friction_ma_per_mm_s.unwrap(),
    );
    // 10 mA per mm/s of friction on top of the new servo's figure.
    assert!(b > a + 6.0, "{text}");
    // The run wrote its reply counts (format 1.2): a clean line.
    assert!(new.bad_replies.unwrap() < 0.05, "{text}");
    assert!(worn.peak_a.unwrap() > new.peak_a.unwrap(), "{text}");
}

/// Wear whose signature is not the friction figure's: friction that drags one way only, and
/// friction over a 2 mm spot of the stroke only. The figure (Σ current / Σ speed while moving)
/// sees the first at half its size — the same as friction half as strong both ways — and the
/// second at the share of the travel that passes over the spot (some 14 % in these flights).
/// docs/wear.md gives the figures.
#[test]
fn one_way_friction_shows_at_half_its_size_and_a_friction_spot_at_its_share_of_the_travel() {
    let dir = TempDir::new("trend-signature");
    for n in 0..5 {
        fly(dir.path(), n, NO_WEAR);
    }
    let (first, _) = trend(&files_of(dir.path()), &[]);
    // Each servo's friction figure, A per mm/s.
    let base = |name: &str| servo(&first, name).baseline.friction_ma_per_mm_s.unwrap() / 1000.0;
    let spot = |k: f64| Wear {
        friction_spot: Some(FrictionSpot {
            from_mm: 2.0,
            to_mm: 4.0,
            a_per_mm_s: k,
        }),
        ..Wear::default()
    };
    let wear = [
        // While extending only, 80 % of the figure.
        Wear {
            friction_extend_a_per_mm_s: 0.8 * base("aileron_left"),
            ..Wear::default()
        },
        // Over 2–4 mm only, 100 % of the figure.
        spot(base("aileron_right")),
        // Both ways, 40 %: as much friction work as the aileron's one way.
        friction(0.4 * base("elevator")),
        // Over 2–4 mm only, 300 %.
        spot(3.0 * base("rudder")),
    ];
    for n in 5..10 {
        fly(dir.path(), n, wear);
    }
    let (t, _) = trend(&files_of(dir.path()), &[]);
    let text = t.to_string();
    // Each worn flight's friction figure over the baseline, as a share of the wear's own size.
    let seen = |name: &str, size: f64| -> Vec<f64> {
        let s = servo(&t, name);
        let b = s.baseline.friction_ma_per_mm_s.unwrap();
        s.flights[5..]
            .iter()
            .map(|f| (f.friction_ma_per_mm_s.unwrap() / b - 1.0) / size)
            .collect()
    };
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let one_way = seen("aileron_left", 0.8);
    let both_ways = seen("elevator", 0.4);
    let small_spot = seen("aileron_right", 1.0);
    let big_spot = seen("rudder", 3.0);
    eprintln!(
        "friction figure's rise as a share of the wear: one way {:.3}, both ways {:.3}, \
         2 mm spot {:.3} and {:.3}",
        mean(&one_way),
        mean(&both_ways),
        mean(&small_spot),
        mean(&big_spot)
    );
    // One way: half, flight by flight the same as the same work both ways.
    assert!((mean(&one_way) - 0.5).abs() < 0.05, "{one_way:?}");
    for (a, b) in one_way.iter().zip(&both_ways) {
        assert!(
            (a * 0.8 - b * 0.4).abs() < 0.02,
            "{one_way:?} {both_ways:?}"
        );
    }
    // A spot: the share of the travel over it, whatever the friction there.
    assert!(
        mean(&small_spot) > 0.08 && mean(&small_spot) < 0.18,
        "{small_spot:?}"
    );
    assert!(
        (mean(&big_spot) - mean(&small_spot)).abs() < 0.03,
        "{big_spot:?}"
    );
    // So: one-way friction of 80 % is marked, as 40 % both ways is; a spot as strong as the
    // servo's whole friction figure is not (+13 %), one three times as strong is.
    for (name, verdict) in [
        ("aileron_left", Verdict::Inspect),
        ("elevator", Verdict::Inspect),
        ("aileron_right", Verdict::Ok),
        ("rudder", Verdict::Inspect),
    ] {
        let s = servo(&t, name);
        assert_eq!(s.verdict, verdict, "{name}: {text}");
        if verdict == Verdict::Inspect {
            assert!(
                s.triggers.iter().any(|f| f.figure == "friction"),
                "{name}: {text}"
            );
        }
    }
}

//! `record trend` on flights with a known answer: ten flights of four simulated servos (the
//! `lj9da-sim` servo model in virtual time, its registers recorded as the bridge records
//! telemetry), one of which wears from flight six on; and one real run through a pseudo-terminal,
//! the bus master and the recorder, with the simulator's wear knob turned on one servo.

mod flag_records;
mod tempdir;

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
use lj9da_sim::servo::memory_map::{FACTORY_ROM, ROM_START, reg};
use lj9da_sim::servo::{Servo, ServoConfig};
use lj9da_sim::{FrictionSpot, HostPacket, ShortPacket, SimBus, SimConfig, Wear};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};
use tempdir::TempDir;

const NS_PER_DAY: i64 = 86_400 * 1_000_000_000;
/// 2026-01-01T08:00:00Z.
const FIRST_FLIGHT_NS: i64 = 1_767_254_400 * 1_000_000_000;
/// Seconds of each virtual flight.
const FLIGHT_S: u64 = 40;

fn servos() -> Vec<RecordServo> {
    vec![
        RecordServo::new("aileron_left", "wing", 1, 1),
        RecordServo::new("aileron_right", "wing", 2, 2),
        RecordServo::new("elevator", "tail", 3, 3),
        RecordServo::new("rudder", "tail", 4, 4),
    ]
}

fn write(servo: &mut Servo, now: Instant, id: u8, address: usize, data: &[u8]) {
    let packet = HostPacket::Short(ShortPacket::write(id, address as u8, data, 0));
    servo.receive(now, &packet);
}

fn u16_at(registers: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([registers[at], registers[at + 1]])
}

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
/// file in `dir`. The flight: a sine sweep of ±10 mm (its amplitude a little different each
/// flight) for 4 s, then 2 s holding at 5 mm, again and again; telemetry every 13 ms; the
/// ambient temperature differs from flight to flight.
fn fly(dir: &Path, n: usize, wear: [Wear; 4]) -> PathBuf {
    let start = Instant::now();
    let table = servos();
    let ambient = 20.0 + (n * 7 % 10) as f64;
    let amplitude_centi = 1000.0 * (1.0 + 0.04 * (((n * 3) % 5) as f64 - 2.0) / 2.0);
    let mut sim: Vec<Servo> = table
        .iter()
        .zip(wear)
        .map(|(s, wear)| {
            let mut servo = Servo::new(
                ServoConfig {
                    id: s.id,
                    baud_code: FACTORY_ROM[reg::BAUD_RATE - ROM_START],
                    voltage_v: 12.0,
                    ambient_c: ambient,
                },
                start,
            );
            write(&mut servo, start, s.id, reg::FORCE_ENABLE, &[1]);
            servo.set_wear(start, wear);
            servo
        })
        .collect();
    let mut bytes = encode_header(&RecordHeader::new(
        FIRST_FLIGHT_NS + n as i64 * NS_PER_DAY,
        table.clone(),
    ));
    let mut put = |t_us: u64, body: RecordBody| {
        encode_record(&Record { t_us, body }, &mut bytes);
    };
    for index in 0..table.len() {
        put(
            0,
            RecordBody::Health {
                servo: index as u8,
                health: Health::Online,
                stalled: false,
            },
        );
    }
    let mut goals = vec![i16::MIN; table.len()];
    // Goals every 20 ms, each to be reached in 20 ms (a goal time, as a mapping may set);
    // telemetry every 13 ms, so that samples fall anywhere in a goal's period.
    for ms in 0..FLIGHT_S * 1000 {
        let now = start + Duration::from_millis(ms);
        let phase = (ms % 6000) as f64 / 1000.0;
        let goal_centi = if phase < 4.0 {
            (amplitude_centi * (std::f64::consts::PI * phase).sin()).round() as i16
        } else {
            500
        };
        for (index, (servo, s)) in sim.iter_mut().zip(&table).enumerate() {
            if ms.is_multiple_of(20) && goals[index] != goal_centi {
                let mut data = goal_centi.to_le_bytes().to_vec();
                data.extend_from_slice(&2u16.to_le_bytes());
                write(servo, now, s.id, reg::GOAL_POSITION, &data);
                goals[index] = goal_centi;
                put(
                    ms * 1000,
                    RecordBody::Goal {
                        servo: index as u8,
                        goal: Goal::Position(MmCenti(goal_centi)),
                    },
                );
            }
            if !(ms + index as u64 * 3).is_multiple_of(13) {
                continue;
            }
            servo.update(now);
            let r = servo.registers();
            put(
                ms * 1000 + 500,
                RecordBody::Telemetry {
                    servo: index as u8,
                    telemetry: Telemetry {
                        present_position: MmCenti(u16_at(r, reg::PRESENT_POSITION) as i16),
                        present_time: Ms10(u16_at(r, reg::PRESENT_TIME)),
                        present_load: Ma10(u16_at(r, reg::PRESENT_LOAD)),
                        present_temperature: Celsius(u16_at(r, reg::PRESENT_TEMPERATURE) as i16),
                        present_voltage: Mv10(u16_at(r, reg::PRESENT_VOLTAGE)),
                    },
                    flags: ReplyFlags(servo.status_flags()),
                },
            );
        }
    }
    let end_us = FLIGHT_S * 1_000_000 + 10_000;
    for index in 0..table.len() {
        put(
            end_us,
            RecordBody::Replies {
                servo: index as u8,
                answered: (FLIGHT_S * 1000 / 13) as u32,
                missed: if index == 3 { 40 } else { 0 },
            },
        );
    }
    put(end_us, RecordBody::End { continued: false });
    let path = dir.join(format!("flight{:02}.lj9rec", n + 1));
    std::fs::write(&path, &bytes).unwrap();
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

fn files_of(dir: &Path) -> Vec<PathBuf> {
    record_files(&[dir.to_path_buf()]).unwrap()
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

//! `record trend` over a folder of synthesised flights: how long reading and judging takes.
//!
//! Each flight is one record file of `TREND_BENCH_MINUTES` minutes (default 3) of
//! `TREND_BENCH_SERVOS` servos (default 4) at the rates a busy bus gives: per servo 90
//! telemetry samples/s (full polls and position-and-current reads), 10 position-only reads/s,
//! 50 goals/s and a replies record each second. `TREND_BENCH_FILES` flights (default 100) are
//! written to a temporary folder, then read by `record trend`'s reader on every core, twice
//! (both from the page cache: the files were just written).
//!
//! Printed: the files' size and record count, each read's wall time, throughput in MB/s and
//! records/s, and the time 100 one-hour flights of 4 servos would take at the best throughput.
//! `TREND_BENCH_KEEP=1` keeps the folder.

use lj9da_bridge::bus::{Goal, Health};
use lj9da_bridge::protocol::{Celsius, Ma10, MmCenti, Ms10, Mv10, ReplyFlags, Telemetry};
use lj9da_bridge::record::format::{RecordHeader, RecordServo, encode_header, encode_record};
use lj9da_bridge::record::trend::{record_files, trend};
use lj9da_bridge::record::{Record, RecordBody};
use std::path::Path;
use std::time::Instant;

fn env(name: &str, default: u64) -> u64 {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// Records per second of one servo: telemetry, position reads, goals, replies.
const RATES: [u64; 4] = [90, 10, 50, 1];

fn flight(dir: &Path, n: u64, minutes: u64, servos: u64) -> (u64, u64) {
    let table: Vec<RecordServo> = (0..servos)
        .map(|i| RecordServo::new(format!("servo{i}"), "bus", (i + 1) as u8, (i + 1) as u8))
        .collect();
    let start_ns = 1_767_254_400_000_000_000 + n as i64 * 86_400_000_000_000;
    let mut bytes = encode_header(&RecordHeader::new(start_ns, table));
    let mut records = 0u64;
    let mut put = |t_us: u64, body: RecordBody| {
        encode_record(&Record { t_us, body }, &mut bytes);
        records += 1;
    };
    for s in 0..servos as u8 {
        put(
            0,
            RecordBody::Health {
                servo: s,
                health: Health::Online,
                stalled: false,
            },
        );
    }
    // 1 ms ticks; each kind at its rate, servos a little apart.
    let seconds = minutes * 60;
    for ms in 0..seconds * 1000 {
        let t = ms as f64 / 1000.0;
        let mm = 8.0 * (t * 1.3 + n as f64).sin() + 2.0 * (t * 7.1).sin();
        let centi = (mm * 100.0).round() as i16;
        for s in 0..servos as u8 {
            let t_us = ms * 1000 + u64::from(s) * 100;
            // A record of `rate` per second is due when this millisecond completes one more.
            let due = |rate: u64| ms * rate / 1000 != (ms + 1) * rate / 1000;
            if due(RATES[0]) {
                put(
                    t_us,
                    RecordBody::Telemetry {
                        servo: s,
                        telemetry: Telemetry {
                            present_position: MmCenti(centi),
                            present_time: Ms10(0),
                            present_load: Ma10(7 + (mm.abs() * 3.0) as u16),
                            present_temperature: Celsius(30 + (t / 120.0) as i16),
                            present_voltage: Mv10(1200),
                        },
                        flags: ReplyFlags(0),
                    },
                );
            }
            if due(RATES[1]) {
                put(
                    t_us + 50,
                    RecordBody::Position {
                        servo: s,
                        position: MmCenti(centi),
                        flags: ReplyFlags(0),
                    },
                );
            }
            if due(RATES[2]) {
                put(
                    t_us + 20,
                    RecordBody::Goal {
                        servo: s,
                        goal: Goal::Position(MmCenti(centi)),
                    },
                );
            }
            if due(RATES[3]) {
                put(
                    t_us + 70,
                    RecordBody::Replies {
                        servo: s,
                        answered: (ms / 10) as u32,
                        missed: (ms / 100_000) as u32,
                    },
                );
            }
        }
    }
    put(seconds * 1_000_000, RecordBody::End { continued: false });
    let path = dir.join(format!("flight{n:03}.lj9rec"));
    std::fs::write(&path, &bytes).expect("write a flight");
    (bytes.len() as u64, records)
}

fn main() {
    let files = env("TREND_BENCH_FILES", 100);
    let minutes = env("TREND_BENCH_MINUTES", 3);
    let servos = env("TREND_BENCH_SERVOS", 4).clamp(1, 254);
    let dir = std::env::temp_dir().join(format!("lj9da-trend-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("a temporary folder");
    let made = Instant::now();
    let (mut bytes, mut records) = (0u64, 0u64);
    for n in 0..files {
        let (b, r) = flight(&dir, n, minutes, servos);
        bytes += b;
        records += r;
    }
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    println!(
        "record trend bench: {files} flights × {minutes} min × {servos} servos, {:.1} MB, {records} records ({:.1} bytes each), written in {:.1} s; {cores} cores",
        bytes as f64 / 1e6,
        bytes as f64 / records as f64,
        made.elapsed().as_secs_f64()
    );
    let list = record_files(std::slice::from_ref(&dir)).expect("list the flights");
    let mut best = f64::INFINITY;
    for round in 1..=2 {
        let began = Instant::now();
        let (t, notes) = trend(&list, &[]);
        let wall = began.elapsed().as_secs_f64();
        best = best.min(wall);
        assert!(notes.errors.is_empty(), "{:?}", notes.errors);
        assert_eq!(t.servos.len() as u64, servos);
        assert!(t.servos.iter().all(|s| s.flights.len() as u64 == files));
        println!(
            "read {round}: {wall:.2} s, {:.0} MB/s, {:.1} M records/s",
            bytes as f64 / 1e6 / wall,
            records as f64 / 1e6 / wall
        );
    }
    // 100 one-hour flights of 4 servos at these rates.
    let per_hour_records = 4 * 3600 * RATES.iter().sum::<u64>();
    let target_records = 100 * per_hour_records;
    let target_bytes = target_records as f64 * bytes as f64 / records as f64;
    println!(
        "100 one-hour flights of 4 servos: {:.1} GB, {:.0} M records: about {:.0} s at the best rate",
        target_bytes / 1e9,
        target_records as f64 / 1e6,
        best * target_records as f64 / records as f64
    );
    if std::env::var_os("TREND_BENCH_KEEP").is_none() {
        let _ = std::fs::remove_dir_all(&dir);
    } else {
        println!("kept {}", dir.display());
    }
}

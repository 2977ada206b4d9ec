//! The recorder: rotation keeps the total size, the handle never blocks, nothing is lost
//! without being counted, and what was handed over reaches the disk without a clean stop.

mod tempdir;

use lj9da_bridge::bus::Goal;
use lj9da_bridge::protocol::{Celsius, Ma10, MmCenti, Motion, Ms10, Mv10, ReplyFlags, Telemetry};
use lj9da_bridge::record::format::RecordServo;
use lj9da_bridge::record::rotate::list_record_files;
use lj9da_bridge::record::{
    RecordBody, RecordLimits, Recorder, RecorderOptions, Recording, read_record,
};
use std::fs::File;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant, SystemTime};
use tempdir::TempDir;

fn servos() -> Vec<RecordServo> {
    vec![
        RecordServo::new("left", "wing", 1, 1),
        RecordServo::new("right", "wing", 2, 2),
    ]
}

fn sample(k: u64) -> Telemetry {
    Telemetry {
        present_position: MmCenti((k % 5000) as i16 - 2500),
        present_time: Ms10(0),
        present_load: Ma10(40 + (k % 7) as u16),
        present_temperature: Celsius(30),
        present_voltage: Mv10(1200),
    }
}

fn total_size(dir: &Path) -> u64 {
    list_record_files(dir)
        .unwrap()
        .iter()
        .map(|f| f.bytes)
        .sum()
}

/// A record file of `bytes` bytes, last modified `age` ago.
fn old_file(dir: &Path, name: &str, bytes: usize, age: Duration) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, vec![0u8; bytes]).unwrap();
    File::options()
        .write(true)
        .open(&path)
        .unwrap()
        .set_modified(SystemTime::now() - age)
        .unwrap();
    path
}

#[test]
fn start_deletes_the_oldest_record_files_first_to_stay_under_the_total() {
    let dir = TempDir::new("rot");
    let hour = Duration::from_secs(3600);
    // Names sort the other way round: age is what counts.
    let oldest = old_file(dir.path(), "z.lj9rec", 10_000, 3 * hour);
    let middle = old_file(dir.path(), "y.lj9rec", 10_000, 2 * hour);
    let newest = old_file(dir.path(), "x.lj9rec", 10_000, hour);
    let other = old_file(dir.path(), "notes.txt", 50_000, 4 * hour);
    let limits = RecordLimits {
        max_total_bytes: 40_000,
        max_file_bytes: 16_000,
    };
    // The others may take 40 000 − 16 000 = 24 000 bytes: only the oldest must go.
    let handle = Recorder::start(dir.path(), &servos(), limits).unwrap();
    assert!(!oldest.exists());
    assert!(middle.exists() && newest.exists());
    assert!(
        other.exists(),
        "files that are not records are never touched"
    );
    let stats = handle.finish();

    // Tighter: the others may take 4 000 bytes, so both 10 kB files go, oldest first, and
    // the small file of the first run (newest) stays.
    let limits = RecordLimits {
        max_total_bytes: 20_000,
        max_file_bytes: 16_000,
    };
    let handle = Recorder::start(dir.path(), &servos(), limits).unwrap();
    assert!(!middle.exists() && !newest.exists());
    assert!(stats.files[0].exists());
    assert!(total_size(dir.path()) <= 4_000 + 1_000);
    assert!(other.exists());
    handle.finish();
}

#[test]
fn a_long_run_continues_in_new_files_and_keeps_the_total_under_the_limit() {
    let dir = TempDir::new("parts");
    let limits = RecordLimits {
        max_total_bytes: 40_000,
        max_file_bytes: 8_000,
    };
    let handle = Recorder::start(dir.path(), &servos(), limits).unwrap();
    let start = handle.start_instant();
    let n = 6_000u64;
    for k in 0..n {
        let at = start + Duration::from_millis(k);
        handle.telemetry(at, (k % 2) as usize, &sample(k), ReplyFlags(0));
        if k % 500 == 0 {
            // Keep the queue from filling: this test is about files, not drops.
            while handle.stats().accepted > handle.stats().written + 10_000 {
                std::thread::sleep(Duration::from_millis(1));
            }
        }
    }
    let stats = handle.finish();
    assert_eq!(stats.dropped(), 0);
    assert_eq!(stats.written, n);
    assert!(
        stats.files.len() >= 10,
        "{} parts for ~140 kB",
        stats.files.len()
    );

    // What is left: the newest parts, under the total (plus one record of slack).
    let left: Vec<PathBuf> = list_record_files(dir.path())
        .unwrap()
        .into_iter()
        .map(|f| f.path)
        .collect();
    assert!(
        total_size(dir.path()) <= 40_000 + 64,
        "{}",
        total_size(dir.path())
    );
    let kept = &stats.files[stats.files.len() - left.len()..];
    let mut left_sorted = left.clone();
    left_sorted.sort();
    let mut kept_sorted = kept.to_vec();
    kept_sorted.sort();
    assert_eq!(
        left_sorted, kept_sorted,
        "the oldest parts were deleted first"
    );

    let mut previous_t = None;
    for (i, path) in kept.iter().enumerate() {
        let rec = read_record(path).unwrap();
        let part = usize::from(rec.header.part);
        assert_eq!(part, stats.files.len() - kept.len() + i);
        let last = i + 1 == kept.len();
        assert_eq!(
            rec.records.last().unwrap().body,
            RecordBody::End { continued: !last }
        );
        assert!(rec.closed);
        for r in &rec.records {
            if let RecordBody::Telemetry { .. } = r.body {
                assert!(
                    previous_t.is_none_or(|p| r.t_us > p),
                    "time runs on across parts"
                );
                previous_t = Some(r.t_us);
            }
        }
    }
    assert_eq!(previous_t, Some((n - 1) * 1000), "the last sample is kept");
}

#[test]
fn a_flood_never_blocks_and_every_record_is_written_or_counted_as_dropped() {
    let dir = TempDir::new("flood");
    let handle = Recorder::start_with(
        dir.path(),
        &servos(),
        RecordLimits::default(),
        RecorderOptions {
            queue_capacity: 16,
            sync_interval: Duration::from_millis(500),
            ..RecorderOptions::default()
        },
    )
    .unwrap();
    let pushed = 1_000_000u64;
    let start = handle.start_instant();
    for k in 0..pushed {
        handle.telemetry(
            start + Duration::from_micros(k),
            0,
            &sample(k),
            ReplyFlags(0),
        );
    }
    let stats = handle.finish();
    assert_eq!(stats.accepted + stats.dropped_full, pushed);
    assert_eq!(stats.written, stats.accepted);
    assert_eq!(stats.dropped_failed, 0);
    assert!(
        stats.dropped_full > 0,
        "a 16-record queue cannot keep up with a million pushes"
    );

    let mut telemetry = 0u64;
    let mut told = 0u64;
    for path in &stats.files {
        let rec = read_record(path).unwrap();
        assert!(
            rec.notes.iter().all(|n| n.contains("continues")),
            "{:?}",
            rec.notes
        );
        for r in &rec.records {
            match r.body {
                RecordBody::Telemetry { .. } => telemetry += 1,
                RecordBody::Dropped { count } => told += count,
                _ => {}
            }
        }
    }
    assert_eq!(telemetry, stats.written);
    assert_eq!(told, stats.dropped_full, "every drop is told in the file");
    assert_eq!(telemetry + told, pushed);
}

#[test]
fn records_reach_the_disk_without_a_clean_stop() {
    let dir = TempDir::new("crash");
    let handle = Recorder::start(dir.path(), &servos(), RecordLimits::default()).unwrap();
    let path = handle.path().unwrap();
    for k in 0..100 {
        handle.goal(1, Goal::Position(MmCenti(k)));
    }
    // Read the file while the writer still runs, as after a power cut.
    let deadline = Instant::now() + Duration::from_secs(5);
    let rec = loop {
        let rec = read_record(&path).unwrap();
        if rec.records.len() >= 100 || Instant::now() > deadline {
            break rec;
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    assert_eq!(rec.records.len(), 100);
    assert!(!rec.closed);
    assert!(rec.notes.iter().any(|n| n.contains("no end record")));
    let stats = handle.finish();
    assert_eq!(stats.written, 100);
    assert!(read_record(&path).unwrap().closed);
}

#[test]
fn dropping_every_handle_closes_the_file() {
    let dir = TempDir::new("drop");
    let handle = Recorder::start(dir.path(), &servos(), RecordLimits::default()).unwrap();
    let path = handle.path().unwrap();
    let clone = handle.clone();
    std::thread::spawn(move || clone.event(None, 6, "from another thread"))
        .join()
        .unwrap();
    drop(handle);
    let deadline = Instant::now() + Duration::from_secs(5);
    let rec: Recording = loop {
        let rec = read_record(&path).unwrap();
        if rec.closed || Instant::now() > deadline {
            break rec;
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    assert!(rec.closed);
    assert!(
        matches!(&rec.records[0].body, RecordBody::Event { text, .. } if text == "from another thread")
    );
}

#[test]
fn impossible_servo_indices_are_counted_not_recorded() {
    let dir = TempDir::new("idx");
    let handle = Recorder::start(dir.path(), &servos(), RecordLimits::default()).unwrap();
    handle.goal(255, Goal::Hold);
    handle.goal(100_000, Goal::Hold);
    handle.goal(1, Goal::Hold);
    let stats = handle.finish();
    assert_eq!(stats.written, 1);
    assert_eq!(stats.dropped_failed, 2);
    let rec = read_record(&stats.files[0]).unwrap();
    assert_eq!(
        rec.records
            .iter()
            .filter_map(|r| match r.body {
                RecordBody::Dropped { count } => Some(count),
                _ => None,
            })
            .sum::<u64>(),
        2
    );
}

#[test]
fn more_than_255_servos_are_refused_with_a_reason() {
    let dir = TempDir::new("many");
    let many: Vec<RecordServo> = (0..256)
        .map(|i| RecordServo::new(format!("s{i}"), "b", 1, 1))
        .collect();
    let e = Recorder::start(dir.path(), &many, RecordLimits::default()).unwrap_err();
    assert!(e.to_string().contains("at most 255 servos"), "{e}");
}

#[test]
fn file_names_are_the_utc_start_time_and_never_replace_a_file() {
    let dir = TempDir::new("names");
    let a = Recorder::start(dir.path(), &servos(), RecordLimits::default()).unwrap();
    let b = Recorder::start(dir.path(), &servos(), RecordLimits::default()).unwrap();
    let (pa, pb) = (a.path().unwrap(), b.path().unwrap());
    assert_ne!(pa, pb);
    let name = pa.file_name().unwrap().to_string_lossy().into_owned();
    // 20261121T235959Z.lj9rec
    assert_eq!(name.len(), 23, "{name}");
    assert_eq!(&name[8..9], "T");
    assert!(name.ends_with("Z.lj9rec"));
    let year: i32 = name[..4].parse().unwrap();
    assert!(year >= 2024);
    a.finish();
    b.finish();
}

/// Not a test of speed (nothing is asserted about it): prints how many records per second
/// one writer thread takes, for the documentation. Run with
/// `cargo test --release --test record_writer -- --ignored --nocapture`.
#[test]
#[ignore]
fn writer_throughput() {
    let dir = TempDir::new("speed");
    let handle = Recorder::start_with(
        dir.path(),
        &servos(),
        RecordLimits::default(),
        RecorderOptions {
            queue_capacity: 1 << 20,
            sync_interval: Duration::from_millis(500),
            ..RecorderOptions::default()
        },
    )
    .unwrap();
    let n = 2_000_000u64;
    let t0 = Instant::now();
    let start = handle.start_instant();
    for k in 0..n {
        handle.telemetry(
            start + Duration::from_micros(k * 10),
            0,
            &sample(k),
            ReplyFlags(0),
        );
    }
    let pushed = t0.elapsed();
    let stats = handle.finish();
    let all = t0.elapsed();
    println!(
        "{n} pushes in {pushed:?} ({:.0} ns each); {} written, {} dropped, {} bytes in {all:?}: \
         {:.0} records/s, {:.1} bytes per telemetry record",
        pushed.as_nanos() as f64 / n as f64,
        stats.written,
        stats.dropped(),
        stats.bytes,
        stats.written as f64 / all.as_secs_f64(),
        stats.bytes as f64 / stats.written as f64
    );
}

/// Servo `id` of the bus "wing", online, with nothing read yet.
fn online_servo(id: u8, name: &str) -> lj9da_bridge::bus::ServoStatus {
    use lj9da_bridge::bus::{ForceState, Health, ServoStatus};
    ServoStatus {
        id: lj9da_bridge::protocol::ServoId::new(id).unwrap(),
        name: name.into(),
        health: Health::Online,
        telemetry: None,
        telemetry_at: None,
        position_at: None,
        motion_at: None,
        age: None,
        flags: ReplyFlags(0),
        goal: None,
        force: ForceState::On,
        stalled: false,
        identity: Default::default(),
        consecutive_timeouts: 0,
        telemetry_count: 0,
        answered: 0,
        timeouts: 0,
        degraded: None,
    }
}

/// The bus "wing" with `servo` alone, at `at`.
fn wing(servo: lj9da_bridge::bus::ServoStatus, at: Instant) -> lj9da_bridge::bus::BusStatus {
    lj9da_bridge::bus::BusStatus {
        name: "wing".into(),
        port_open: true,
        servos: vec![servo],
        counters: Default::default(),
        at,
        telemetry_asked_hz: None,
        thread: Default::default(),
    }
}

#[test]
fn reads_between_full_polls_are_recorded_once_as_position_and_motion_records() {
    use lj9da_bridge::bus::ServoStatus;
    use lj9da_bridge::record::StatusFeed;

    let dir = TempDir::new("pos");
    let handle = Recorder::start(dir.path(), &servos(), RecordLimits::default()).unwrap();
    let mut feed = StatusFeed::new(handle.clone(), &servos());
    let t0 = Instant::now();
    let status = |telemetry: Telemetry, telemetry_at, position_at, motion_at| {
        let servo = ServoStatus {
            telemetry: Some(telemetry),
            telemetry_at: Some(telemetry_at),
            position_at,
            motion_at,
            flags: ReplyFlags(0x20),
            telemetry_count: 1,
            answered: 1,
            ..online_servo(2, "right")
        };
        wing(servo, t0 + Duration::from_millis(30))
    };
    let full = sample(100);
    let mut moved = full;
    moved.present_position = MmCenti(-1234);
    let mut pulling = moved;
    pulling.present_position = MmCenti(-1300);
    pulling.present_time = Ms10(12);
    pulling.present_load = Ma10(250);
    let polled_at = t0 + Duration::from_millis(10);
    let read_at = t0 + Duration::from_millis(20);
    let motion_at = t0 + Duration::from_millis(30);
    feed.observe(&status(full, polled_at, None, None));
    // The position read replaces the position of the latest telemetry; the same status seen
    // again (a refresh) records nothing more.
    feed.observe(&status(moved, polled_at, Some(read_at), None));
    feed.observe(&status(moved, polled_at, Some(read_at), None));
    // A read of position and current replaces both: its current is recorded too.
    feed.observe(&status(
        pulling,
        polled_at,
        Some(motion_at),
        Some(motion_at),
    ));
    feed.observe(&status(
        pulling,
        polled_at,
        Some(motion_at),
        Some(motion_at),
    ));
    let path = handle.path().unwrap();
    handle.finish();

    let rec = read_record(&path).unwrap();
    let bodies: Vec<&RecordBody> = rec
        .records
        .iter()
        .map(|r| &r.body)
        .filter(|b| {
            matches!(
                b,
                RecordBody::Telemetry { .. }
                    | RecordBody::Position { .. }
                    | RecordBody::Motion { .. }
            )
        })
        .collect();
    assert_eq!(
        bodies,
        [
            &RecordBody::Telemetry {
                servo: 1,
                telemetry: full,
                flags: ReplyFlags(0x20),
            },
            &RecordBody::Position {
                servo: 1,
                position: MmCenti(-1234),
                flags: ReplyFlags(0x20),
            },
            &RecordBody::Motion {
                servo: 1,
                motion: Motion {
                    present_position: MmCenti(-1300),
                    present_time: Ms10(12),
                    present_load: Ma10(250),
                },
                flags: ReplyFlags(0x20),
            },
        ]
    );
    let times: Vec<u64> = rec
        .records
        .iter()
        .filter(|r| {
            matches!(
                r.body,
                RecordBody::Position { .. } | RecordBody::Motion { .. }
            )
        })
        .map(|r| r.t_us)
        .collect();
    let telemetry_t = rec
        .records
        .iter()
        .find(|r| matches!(r.body, RecordBody::Telemetry { .. }))
        .map(|r| r.t_us)
        .unwrap();
    // Stamped with the instant each read's reply arrived: 10 and 20 ms after the full poll's.
    assert_eq!(times.len(), 2);
    for (t, after) in times.iter().zip([10_000, 20_000]) {
        assert!(
            (t - telemetry_t).abs_diff(after) <= 1,
            "{times:?} vs {telemetry_t}"
        );
    }
}

#[test]
fn reply_counts_are_recorded_when_they_change_at_most_once_a_second() {
    use lj9da_bridge::bus::ServoStatus;
    use lj9da_bridge::record::StatusFeed;

    let dir = TempDir::new("replies");
    let handle = Recorder::start(dir.path(), &servos(), RecordLimits::default()).unwrap();
    let mut feed = StatusFeed::new(handle.clone(), &servos());
    let t0 = handle.start_instant();
    let status = |ms: u64, answered: u64, timeouts: u64| {
        let servo = ServoStatus {
            answered,
            timeouts,
            ..online_servo(1, "left")
        };
        wing(servo, t0 + Duration::from_millis(ms))
    };
    // Nothing asked yet: no record. Then the first counts; changes within a second wait; the
    // same counts a second later are not written again.
    for (ms, answered, timeouts) in [
        (0, 0, 0),
        (100, 5, 1),
        (600, 50, 1),
        (1_100, 90, 2),
        (1_200, 95, 2),
        (3_000, 95, 2),
        (4_000, 95, 2),
    ] {
        feed.observe(&status(ms, answered, timeouts));
    }
    let path = handle.path().unwrap();
    handle.finish();
    let rec = read_record(&path).unwrap();
    let replies: Vec<(u64, u32, u32)> = rec
        .records
        .iter()
        .filter_map(|r| match r.body {
            RecordBody::Replies {
                servo: 0,
                answered,
                missed,
            } => Some((r.t_us / 1000, answered, missed)),
            _ => None,
        })
        .collect();
    assert_eq!(replies, [(100, 5, 1), (1_100, 90, 2), (3_000, 95, 2)]);
}

#[test]
fn telemetry_samples_the_feed_never_saw_are_counted_and_said_in_the_record() {
    use lj9da_bridge::bus::ServoStatus;
    use lj9da_bridge::record::StatusFeed;

    let dir = TempDir::new("missed");
    let handle = Recorder::start(dir.path(), &servos(), RecordLimits::default()).unwrap();
    let mut feed = StatusFeed::new(handle.clone(), &servos());
    let t0 = handle.start_instant();
    let status = |ms: u64, count: u64| {
        let servo = ServoStatus {
            telemetry: Some(sample(100)),
            telemetry_at: Some(t0 + Duration::from_millis(ms)),
            telemetry_count: count,
            ..online_servo(1, "left")
        };
        wing(servo, t0 + Duration::from_millis(ms))
    };
    // Samples 1, 2 and 5 seen: 3 and 4 were replaced before the feed looked.
    for (ms, count) in [(10, 1), (30, 2), (90, 5)] {
        feed.observe(&status(ms, count));
    }
    assert_eq!(feed.missed_samples(), 2);
    let path = handle.path().unwrap();
    handle.finish();
    let rec = read_record(&path).unwrap();
    let warnings: Vec<&str> = rec
        .records
        .iter()
        .filter_map(|r| match &r.body {
            RecordBody::Event {
                servo: Some(0),
                severity: 4,
                text,
            } => Some(text.as_str()),
            _ => None,
        })
        .collect();
    assert_eq!(
        warnings,
        ["2 telemetry samples not recorded (replaced before the record saw them)"]
    );
    let samples = rec
        .records
        .iter()
        .filter(|r| matches!(r.body, RecordBody::Telemetry { servo: 0, .. }))
        .count();
    assert_eq!(samples, 3);
}

//! A fleet's flight records, from the folder to the servos to inspect: `record trend` against
//! `record parquet` once and DuckDB (and Spark local, when asked), at 10, 30 and 100
//! flight-hours.
//!
//! The fleet: `FLEET_BENCH_AIRCRAFT` aircraft (default 3) of four servos each, flights of 10,
//! 15, 20, 25 and 30 minutes in turn (20 on average), one a day per aircraft, flown through the
//! simulator's servo model in virtual time as `record trend`'s tests fly them
//! (`tests/trend_support/flight.rs`), with its wear shapes: on the first aircraft the
//! elevator's friction grows from its sixth flight on, on the second the rudder drags one way
//! from its sixth flight on, the third wears nothing. The records are made on every core, faster
//! than real time, once per size and kept in `target/fleet-bench/` (`FLEET_BENCH_REMAKE=1`
//! makes them again).
//!
//! Timed, each from the records or the export on disk, warm in the page cache (each step run
//! once before it is timed):
//! - `record trend --json` over the folder: the verdicts;
//! - `record parquet` of the folder: the export, its throughput (MB of records per second) and
//!   the Parquet's size against the records';
//! - DuckDB: the verdicts (`docs/fleet/verdicts.sql`) and an ad-hoc question over every sample
//!   (`docs/fleet/adhoc.sql`: each servo's minutes above 70 °C per aircraft and month), inside
//!   Python (the interpreter's start is not counted);
//! - with `FLEET_BENCH_SPARK=1`, the same two SQL files in Spark local (`pyspark`, Java from
//!   Debian's `openjdk-17-jre-headless`), timed inside its session.
//!
//! `FLEET_BENCH_HOURS=10,30` runs only those sizes. Figures and method: benches/README.md and
//! docs/fleet.md.

#[path = "../tests/common/python.rs"]
#[allow(dead_code)]
mod python;
#[path = "../tests/trend_support/mod.rs"]
mod trend_support;

use lj9da_sim::Wear;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;
use trend_support::flight::{Flight, four_servos};
use trend_support::{FIRST_FLIGHT_NS, NS_PER_DAY};

/// Flight lengths, minutes, in turn.
const MINUTES: [u64; 5] = [10, 15, 20, 25, 30];
/// The flight of each worn aircraft from which its wear grows.
const WEAR_FROM: usize = 5;

fn env_list(name: &str, default: &[u64]) -> Vec<u64> {
    std::env::var(name).map_or_else(
        |_| default.to_vec(),
        |v| v.split(',').filter_map(|h| h.trim().parse().ok()).collect(),
    )
}

/// The wear of aircraft `a`'s servos on its flight `k`.
fn wear(a: usize, k: usize) -> Vec<Wear> {
    let mut wear = vec![Wear::default(); 4];
    let grown = k.saturating_sub(WEAR_FROM) as f64;
    match a {
        0 => wear[2].friction_a_per_mm_s = 0.0004 * grown,
        1 => wear[3].friction_extend_a_per_mm_s = 0.0008 * grown,
        _ => {}
    }
    wear
}

/// The fleet's flights: `hours` flight-hours over `aircraft` aircraft.
fn plan(hours: u64, aircraft: usize) -> Vec<(PathBuf, Flight)> {
    let mut flights = Vec::new();
    let mut seconds = 0;
    let mut per_aircraft = vec![0usize; aircraft];
    while seconds < hours * 3600 {
        let i = flights.len();
        let a = i % aircraft;
        let k = per_aircraft[a];
        per_aircraft[a] += 1;
        let length = MINUTES[i % MINUTES.len()] * 60;
        seconds += length;
        let name = format!("LJ9-{:02}", a + 1);
        flights.push((
            PathBuf::from(&name).join(format!("flight{k:04}.lj9rec")),
            Flight {
                n: i,
                start_ns: FIRST_FLIGHT_NS + k as i64 * NS_PER_DAY + a as i64 * 3_600_000_000_000,
                seconds: length,
                servos: four_servos(),
                wear: wear(a, k),
                aircraft: Some(name),
                ambient_offset_c: 0.0,
            },
        ));
    }
    flights
}

/// Make the fleet's records in `dir` on every core, unless they are there; their bytes.
fn make_fleet(dir: &Path, hours: u64, aircraft: usize) -> u64 {
    let flights = plan(hours, aircraft);
    // The marker names the plan: a folder made for another is made again.
    let done = dir.join("complete");
    let marker = format!(
        "{hours} h, {aircraft} aircraft, {} flights\n",
        flights.len()
    );
    if std::fs::read_to_string(&done).is_ok_and(|m| m == marker)
        && std::env::var_os("FLEET_BENCH_REMAKE").is_none()
    {
        return bytes_under(dir);
    }
    let _ = std::fs::remove_dir_all(dir);
    let began = Instant::now();
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    std::thread::scope(|scope| {
        for core in 0..cores {
            let flights = &flights;
            scope.spawn(move || {
                for (path, flight) in flights.iter().skip(core).step_by(cores) {
                    let path = dir.join(path);
                    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
                    flight.write(&path);
                }
            });
        }
    });
    std::fs::write(&done, marker).unwrap();
    let bytes = bytes_under(dir);
    println!(
        "  made {} flights, {:.0} MB, in {:.1} s on {cores} cores",
        flights.len(),
        bytes as f64 / 1e6,
        began.elapsed().as_secs_f64()
    );
    bytes
}

fn bytes_under(dir: &Path) -> u64 {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return 0;
    };
    entries
        .filter_map(Result::ok)
        .map(|e| {
            let p = e.path();
            if p.is_dir() {
                bytes_under(&p)
            } else {
                e.metadata().map_or(0, |m| m.len())
            }
        })
        .sum()
}

/// Run `cmd` and return its wall time, s, and stdout; panics with its stderr if it fails.
fn timed(cmd: &mut Command) -> (f64, String) {
    let began = Instant::now();
    let out = cmd.output().unwrap_or_else(|e| panic!("{cmd:?}: {e}"));
    let took = began.elapsed().as_secs_f64();
    assert!(
        out.status.success(),
        "{cmd:?}: {:?}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    (took, String::from_utf8_lossy(&out.stdout).into_owned())
}

fn main() {
    let hours = env_list("FLEET_BENCH_HOURS", &[10, 30, 100]);
    let aircraft = env_list("FLEET_BENCH_AIRCRAFT", &[3])[0].max(1) as usize;
    let spark = std::env::var_os("FLEET_BENCH_SPARK").is_some();
    let bin = env!("CARGO_BIN_EXE_lj9da-bridge");
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let sql = [
        root.join("docs/fleet/verdicts.sql"),
        root.join("docs/fleet/adhoc.sql"),
    ];
    let data_python = python::data_python();
    let spark_python = spark.then(python::spark_python);
    let base = root.join("target/fleet-bench");
    println!(
        "fleet bench: {aircraft} aircraft × 4 servos, flights of {MINUTES:?} min in turn; {} cores",
        std::thread::available_parallelism().map_or(1, |n| n.get())
    );
    println!(
        "| flight-hours | records MB | trend s | export s | export MB/s | Parquet MB | Parquet ÷ records | DuckDB verdicts s | export + DuckDB s | DuckDB ad-hoc s | Spark verdicts s | Spark ad-hoc s |"
    );
    let mut rows = Vec::new();
    for &h in &hours {
        let dir = base.join(format!("{h}h"));
        println!("{h} flight-hours:");
        let records_mb = make_fleet(&dir.join("records"), h, aircraft) as f64 / 1e6;
        let out = dir.join("export");
        // The records are in a folder per aircraft; both commands take the folders' files.
        let mut folders: Vec<PathBuf> = std::fs::read_dir(dir.join("records"))
            .expect("the fleet's records")
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.is_dir())
            .collect();
        folders.sort();
        let trend = || {
            let mut c = Command::new(bin);
            c.args(["record", "trend", "--json"]).args(&folders);
            timed(&mut c)
        };
        let export = || {
            let _ = std::fs::remove_dir_all(&out);
            let mut c = Command::new(bin);
            c.args(["record", "parquet"])
                .args(&folders)
                .arg("--out")
                .arg(&out);
            timed(&mut c)
        };
        trend();
        let (trend_s, _) = trend();
        export();
        let (export_s, _) = export();
        let parquet_mb = bytes_under(&out) as f64 / 1e6;
        // The scripts of `docs/fleet.md`, each query's second run timed (warm).
        let query = |python: &Path, script: &str| {
            let mut c = Command::new(python);
            c.arg(root.join("benches/fleet").join(script)).arg(&out);
            for file in &sql {
                c.arg("--sql").arg(file);
            }
            c.args(["--runs", "2", "--timing"]);
            let (_, stdout) = timed(&mut c);
            let s: Vec<f64> = stdout
                .lines()
                .filter_map(|l| l.split_whitespace().next()?.parse().ok())
                .collect();
            assert_eq!(s.len(), 2, "{stdout}");
            (s[0], s[1])
        };
        let (duck_verdicts, duck_adhoc) = query(&data_python, "duckdb_verdicts.py");
        let (spark_verdicts, spark_adhoc) = spark_python
            .as_ref()
            .map_or((f64::NAN, f64::NAN), |p| query(p, "spark_verdicts.py"));
        let row = format!(
            "| {h} | {records_mb:.0} | {trend_s:.2} | {export_s:.2} | {:.0} | {parquet_mb:.0} | {:.2} | {duck_verdicts:.3} | {:.2} | {duck_adhoc:.3} | {spark_verdicts:.2} | {spark_adhoc:.2} |",
            records_mb / export_s,
            parquet_mb / records_mb,
            export_s + duck_verdicts,
        );
        println!("{row}");
        rows.push(row);
    }
    println!(
        "\n| flight-hours | records MB | trend s | export s | export MB/s | Parquet MB | Parquet ÷ records | DuckDB verdicts s | export + DuckDB s | DuckDB ad-hoc s | Spark verdicts s | Spark ad-hoc s |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
    for row in rows {
        println!("{row}");
    }
}

//! A fleet's wear as a query: `docs/fleet/verdicts.sql`, run by DuckDB over the Parquet export
//! of a simulated fleet, gives every servo the verdict `record trend` gives it — the same
//! verdict, the same figures marking it, from the same flight, against the same baseline. And
//! `docs/fleet/adhoc.sql` (minutes above 70 °C per aircraft, month and servo) adds up to the
//! flights' own `hot_min`.
//!
//! The fleet: four aircraft of four servos each, flown through the simulator's servo model in
//! virtual time (`tests/trend_support/flight.rs`, as in `tests/record_trend.rs`), flights of
//! 30, 40 and 50 s ten days apart (so over several months), with the simulator's wear shapes:
//! friction on one aircraft's elevator from its sixth flight on; on another, friction on an aileron for two flights
//! only, then none, and a stiff spot where the rudder holds; a third aircraft with four
//! flights only; a fourth flown in the heat from its sixth flight on; a fifth with wear close
//! to the thresholds, so that a threshold of the SQL a little off changes a verdict.

mod common;
mod tempdir;
mod trend_support;

use lj9da_bridge::record::format::RecordServo;
use lj9da_sim::{StiffSpot, Wear};
use serde_json::Value;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::Command;
use tempdir::TempDir;
use trend_support::flight::Flight;
use trend_support::{FIRST_FLIGHT_NS, NS_PER_DAY};

fn servos() -> Vec<RecordServo> {
    vec![
        RecordServo::new("aileron_left", "wing", 1, 1),
        RecordServo::new("aileron_right", "wing", 2, 2),
        RecordServo::new("elevator", "tail", 3, 3),
        RecordServo::new("rudder", "tail", 4, 4),
    ]
}

const NO_WEAR: Wear = Wear {
    friction_a_per_mm_s: 0.0,
    friction_extend_a_per_mm_s: 0.0,
    friction_spot: None,
    stiff_spot: None,
};

fn friction(k: f64) -> Wear {
    Wear {
        friction_a_per_mm_s: k,
        ..NO_WEAR
    }
}

/// The fleet's aircraft and their flights: one every ten days from 2026-01-01 (each aircraft at
/// its own hour), of 30, 40 or 50 s in turn.
fn fleet() -> Vec<(&'static str, Vec<Flight>)> {
    let flight =
        |aircraft: &str, hour: i64, n: usize, ambient_offset_c: f64, wear: [Wear; 4]| Flight {
            n,
            start_ns: FIRST_FLIGHT_NS + n as i64 * 10 * NS_PER_DAY + hour * 3_600_000_000_000,
            seconds: 30 + 10 * (n as u64 % 3),
            servos: servos(),
            wear: wear.to_vec(),
            aircraft: Some(aircraft.to_string()),
            ambient_offset_c,
        };
    // Elevator friction from the sixth flight: some +50 % of its figure (and heating, but in
    // its shortest flights).
    let alpha = (0..11)
        .map(|n| {
            let mut wear = [NO_WEAR; 4];
            if n >= 5 {
                wear[2] = friction(0.006);
            }
            flight("alpha", 0, n, 0.0, wear)
        })
        .collect();
    // Friction on the right aileron on flights six and seven only (then fixed); a stiff spot
    // where the rudder holds (5 mm) from flight six on.
    let bravo = (0..9)
        .map(|n| {
            let mut wear = [NO_WEAR; 4];
            if n == 5 || n == 6 {
                wear[1] = friction(0.004);
            }
            if n >= 5 {
                wear[3] = Wear {
                    stiff_spot: Some(StiffSpot {
                        from_mm: 4.0,
                        to_mm: 6.0,
                        load_n: 5.0,
                    }),
                    ..NO_WEAR
                };
            }
            flight("bravo", 1, n, 0.0, wear)
        })
        .collect();
    // Four flights: a baseline still forming.
    let charlie = (0..4)
        .map(|n| flight("charlie", 2, n, 0.0, [NO_WEAR; 4]))
        .collect();
    // Flown in the heat from its sixth flight on: above 70 °C, with less margin to the alarm.
    let delta = (0..8)
        .map(|n| {
            let hot = if n >= 5 { 48.0 } else { 25.0 };
            flight("delta", 3, n, hot, [NO_WEAR; 4])
        })
        .collect();
    // Close to the thresholds: the elevator's friction a little under, over, then under the
    // +25 % that marks a flight (some +22 %, +27 %, +23 %); the rudder holding against a stiff
    // spot on the latest flight only, its holding current some 30 mA (+40 %) over its baseline.
    let echo = (0..8)
        .map(|n| {
            let mut wear = [NO_WEAR; 4];
            wear[2] = friction(match n {
                5 => 0.0021,
                6 => 0.0034,
                7 => 0.0024,
                _ => 0.0,
            });
            if n == 7 {
                wear[3] = Wear {
                    stiff_spot: Some(StiffSpot {
                        from_mm: 4.0,
                        to_mm: 6.0,
                        load_n: 3.0,
                    }),
                    ..NO_WEAR
                };
            }
            flight("echo", 4, n, 0.0, wear)
        })
        .collect();
    vec![
        ("alpha", alpha),
        ("bravo", bravo),
        ("charlie", charlie),
        ("delta", delta),
        ("echo", echo),
    ]
}

fn bridge() -> Command {
    Command::new(env!("CARGO_BIN_EXE_lj9da-bridge"))
}

/// Run one of the scripts of `benches/fleet/` (`duckdb_verdicts.py`, `spark_verdicts.py`) with
/// `python` over the export, with an SQL file of `docs/fleet/`; its rows.
fn query(python: &Path, script: &str, export: &Path, sql: &str) -> Vec<Value> {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut cmd = Command::new(python);
    cmd.arg(repo.join("benches/fleet").join(script))
        .arg(export)
        .arg("--sql")
        .arg(repo.join("docs/fleet").join(sql))
        .arg("--json");
    if script.starts_with("spark") {
        cmd.args(["--runs", "1"]);
    }
    let out = cmd.output().expect("the Python runs");
    assert!(
        out.status.success(),
        "{script} --sql {sql}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).expect("a JSON row"))
        .collect()
}

/// Run `cmd` (the bridge with its arguments), which must succeed; its stdout.
fn succeeds(cmd: &mut Command) -> Vec<u8> {
    let out = cmd.output().unwrap();
    assert!(
        out.status.success(),
        "{cmd:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    out.stdout
}

/// `record trend --json` over one aircraft's folder.
fn trend(dir: &Path) -> Value {
    let stdout = succeeds(bridge().args(["record", "trend", "--json"]).arg(dir));
    serde_json::from_slice(&stdout).unwrap()
}

/// The name a finding's figure has among the SQL's boolean columns.
fn column_of(figure: &str) -> &'static str {
    match figure {
        "friction" => "friction",
        "holding current" => "holding_current",
        "heating" => "heating",
        "temperature margin" => "temperature_margin",
        other => panic!("a figure the SQL does not know: {other}"),
    }
}

/// The SQL's change column of a rising figure.
fn change_of(figure: &str) -> Option<&'static str> {
    match figure {
        "friction" => Some("friction_change"),
        "holding current" => Some("holding_change"),
        "heating" => Some("heating_change"),
        _ => None,
    }
}

/// The fleet: each aircraft's records in a folder of its own, all exported into one folder.
struct Fleet {
    _dir: TempDir,
    /// Each aircraft's record folder.
    records: Vec<(&'static str, PathBuf)>,
    export: PathBuf,
}

fn make_fleet() -> Fleet {
    let dir = TempDir::new("fleet-sql");
    let export = dir.path().join("export");
    let mut records = Vec::new();
    for (aircraft, flights) in fleet() {
        let folder = dir.path().join(aircraft);
        std::fs::create_dir_all(&folder).unwrap();
        for flight in &flights {
            flight.write(&folder.join(format!("flight{:02}.lj9rec", flight.n + 1)));
        }
        // Each aircraft exported on its own, into one fleet folder.
        succeeds(
            bridge()
                .args(["record", "parquet"])
                .arg(&folder)
                .arg("--out")
                .arg(&export),
        );
        records.push((aircraft, folder));
    }
    Fleet {
        _dir: dir,
        records,
        export,
    }
}

/// Every servo of the fleet has in `rows` (the rows of `docs/fleet/verdicts.sql`) the verdict
/// `record trend` gives it over its aircraft's folder: the same verdict, flights, first marked
/// flight, figures marking it and their changes, and baseline; and the fleet needs every rule.
fn assert_verdicts_are_trends(engine: &str, fleet: &Fleet, rows: &[Value]) {
    let mut seen_verdicts = BTreeSet::new();
    let mut seen_figures = BTreeSet::new();
    let mut compared = 0;
    for (aircraft, folder) in &fleet.records {
        let trend = trend(folder);
        let servos = trend["servos"].as_array().unwrap();
        let sql: Vec<&Value> = rows.iter().filter(|r| r["aircraft"] == *aircraft).collect();
        assert_eq!(sql.len(), servos.len(), "{engine}: {aircraft}: servos");
        for servo in servos {
            let key = &servo["servo"];
            let who = format!("{engine}: {aircraft} {}", key["name"]);
            let row = sql
                .iter()
                .find(|r| {
                    r["servo"] == key["name"] && r["bus"] == key["bus"] && r["id"] == key["id"]
                })
                .unwrap_or_else(|| panic!("{who}: no row"));
            let verdict = servo["verdict"].as_str().unwrap();
            assert_eq!(row["verdict"], verdict, "{who}: verdict\n{row}\n{servo}");
            seen_verdicts.insert(verdict.to_string());
            assert_eq!(
                row["flights"].as_u64(),
                Some(servo["flights"].as_array().unwrap().len() as u64),
                "{who}: flights"
            );
            assert_eq!(
                row["marked_since"], servo["marked_since"],
                "{who}: marked since"
            );
            // The same figures marked it, named in the same order.
            let figures: Vec<&str> = servo["triggers"]
                .as_array()
                .unwrap()
                .iter()
                .map(|f| f["figure"].as_str().unwrap())
                .collect();
            assert_eq!(
                row["triggers"].as_str().unwrap_or_default(),
                figures.join(", "),
                "{who}: triggers"
            );
            for figure in [
                "friction",
                "holding current",
                "heating",
                "temperature margin",
            ] {
                assert_eq!(
                    row[column_of(figure)].as_bool(),
                    Some(figures.contains(&figure)),
                    "{who}: {figure}"
                );
            }
            // Each finding's change over the baseline, as trend computed it.
            for finding in servo["triggers"].as_array().unwrap() {
                let figure = finding["figure"].as_str().unwrap();
                seen_figures.insert(figure.to_string());
                if let Some(column) = change_of(figure) {
                    assert_eq!(
                        row[column].as_f64(),
                        finding["change"].as_f64(),
                        "{who}: {figure}"
                    );
                }
            }
            // The same baseline: the median of the first five flights.
            let baseline = &servo["baseline"];
            for (column, field) in [
                ("baseline_friction_ma_per_mm_s", "friction_ma_per_mm_s"),
                ("baseline_holding_a", "holding_a"),
                ("baseline_heating_c_per_min", "heating_c_per_min"),
                ("baseline_rise_c", "rise_c"),
                ("baseline_margin_c", "margin_c"),
            ] {
                assert_eq!(
                    row[column].as_f64(),
                    baseline[field].as_f64(),
                    "{who}: {column}"
                );
            }
            compared += 1;
        }
    }
    assert_eq!(
        compared,
        rows.len(),
        "{engine} has servos record trend has not"
    );
    // The fleet is built to need every rule: each verdict and each figure occurs.
    assert_eq!(
        seen_verdicts,
        ["baseline", "inspect", "ok", "watch"]
            .map(String::from)
            .into(),
        "the fleet no longer shows every verdict"
    );
    assert_eq!(
        seen_figures,
        [
            "friction",
            "heating",
            "holding current",
            "temperature margin"
        ]
        .map(String::from)
        .into(),
        "the fleet no longer shows every figure"
    );
}

/// The rows of `docs/fleet/adhoc.sql` (minutes above 70 °C per aircraft, month and servo) add
/// up to the flights' `hot_min` as `record trend` computed them.
fn assert_hot_minutes_are_trends(engine: &str, fleet: &Fleet, rows: &[Value]) {
    let mut want: BTreeMap<(String, String, String), f64> = BTreeMap::new();
    for (aircraft, folder) in &fleet.records {
        for servo in trend(folder)["servos"].as_array().unwrap() {
            for flight in servo["flights"].as_array().unwrap() {
                let month = flight["date"].as_str().unwrap()[..7].to_string();
                *want
                    .entry((
                        aircraft.to_string(),
                        month,
                        servo["servo"]["name"].as_str().unwrap().to_string(),
                    ))
                    .or_default() += flight["hot_min"].as_f64().unwrap();
            }
        }
    }
    let got: BTreeMap<(String, String, String), f64> = rows
        .iter()
        .map(|r| {
            (
                (
                    r["aircraft"].as_str().unwrap().to_string(),
                    r["month"].as_str().unwrap()[..7].to_string(),
                    r["servo"].as_str().unwrap().to_string(),
                ),
                r["minutes_above_70c"].as_f64().unwrap(),
            )
        })
        .collect();
    assert_eq!(
        got.keys().collect::<Vec<_>>(),
        want.keys().collect::<Vec<_>>(),
        "{engine}: aircraft, months and servos"
    );
    assert!(
        want.values().filter(|&&m| m > 0.0).count() >= 4,
        "the fleet no longer has hot flights: {want:?}"
    );
    for (key, minutes) in &want {
        // Sums of the same spans in another order: equal to rounding.
        assert!(
            (got[key] - minutes).abs() <= 1e-9 * minutes.max(1.0),
            "{engine}: {key:?}: {} minutes, {minutes} in record trend",
            got[key]
        );
    }
}

#[test]
fn duckdb_gives_every_servo_of_the_fleet_the_verdict_record_trend_gives_it() {
    let fleet = make_fleet();
    let python = common::python::data_python();
    let rows = query(&python, "duckdb_verdicts.py", &fleet.export, "verdicts.sql");
    assert_verdicts_are_trends("DuckDB", &fleet, &rows);
    let rows = query(&python, "duckdb_verdicts.py", &fleet.export, "adhoc.sql");
    assert_hot_minutes_are_trends("DuckDB", &fleet, &rows);
}

/// The same SQL files in Spark (local mode) give the same answers. Run by hand, not by
/// `cargo test` (Spark takes a JVM and some 450 MB of PySpark, `common::python::spark_python`):
/// `cargo test --test fleet_sql -- --ignored`.
#[test]
#[ignore = "needs PySpark (450 MB) and Java 17: cargo test --test fleet_sql -- --ignored"]
fn spark_gives_every_servo_of_the_fleet_the_verdict_record_trend_gives_it() {
    let python = common::python::spark_python();
    let fleet = make_fleet();
    let rows = query(&python, "spark_verdicts.py", &fleet.export, "verdicts.sql");
    assert_verdicts_are_trends("Spark", &fleet, &rows);
    let rows = query(&python, "spark_verdicts.py", &fleet.export, "adhoc.sql");
    assert_hot_minutes_are_trends("Spark", &fleet, &rows);
}

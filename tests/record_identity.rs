//! What a flight record says about where and when it was flown, from a real `sitl` run: the
//! aircraft's name in its header (the mapping's `[record] aircraft`, else the host name), and
//! the autopilot's boot clock as its output messages carried it, once a second.

mod common;
mod tempdir;

use common::sitl::sitl_records;
use lj9da_bridge::record::{RecordBody, Recording, read_record};
use std::path::Path;
use tempdir::TempDir;

/// Run `sitl` for `seconds` in `work` with `args`; the one record it wrote.
fn sitl_record(work: &Path, seconds: &str, args: &[&str]) -> Recording {
    let files = sitl_records(work, seconds, args);
    assert_eq!(files.len(), 1, "{files:?}");
    read_record(&files[0]).unwrap()
}

#[test]
fn a_record_names_the_host_and_keeps_the_autopilots_clock_once_a_second() {
    let dir = TempDir::new("identity-host");
    let rec = sitl_record(dir.path(), "4", &[]);
    let host = std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap();
    assert_eq!(rec.header.aircraft.as_deref(), Some(host.trim()));

    let clocks: Vec<(u64, u64, u8)> = rec
        .records
        .iter()
        .filter_map(|r| match r.body {
            RecordBody::AutopilotClock { time_usec, bits } => Some((r.t_us, time_usec, bits)),
            _ => None,
        })
        .collect();
    // The simulated autopilot sends SERVO_OUTPUT_RAW with its clock at 50 Hz for 4 s: the
    // first message's clock, then one a second.
    assert!(
        (3..=5).contains(&clocks.len()),
        "{} autopilot clock records: {clocks:?}",
        clocks.len()
    );
    assert!(clocks.iter().all(|&(_, _, bits)| bits == 32), "{clocks:?}");
    for pair in clocks.windows(2) {
        let gap_us = pair[1].0 - pair[0].0;
        assert!(
            (1_000_000..1_500_000).contains(&gap_us),
            "records {gap_us} µs apart: {clocks:?}"
        );
    }
    // Each is the clock of the message it was taken from, stamped when the bridge took it:
    // the autopilot's clock less the record's time is the same in every one but for the
    // messages' transit, and near 0, as `sitl`'s autopilot starts its clock as the record
    // starts (within a millisecond on an idle machine).
    let offsets: Vec<i64> = clocks
        .iter()
        .map(|&(t_us, time_usec, _)| time_usec as i64 - t_us as i64)
        .collect();
    let spread = offsets.iter().max().unwrap() - offsets.iter().min().unwrap();
    assert!(
        spread < 300_000,
        "autopilot clock less record time varies by {spread} µs: {offsets:?}"
    );
    assert!(
        offsets.iter().all(|o| o.abs() < 300_000),
        "autopilot clock less record time, µs: {offsets:?}"
    );
}

#[test]
fn a_record_names_the_aircraft_the_mapping_names() {
    let dir = TempDir::new("identity-named");
    let mapping = dir.path().join("plane.toml");
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/mappings/sitl-default.toml"
    ))
    .unwrap();
    std::fs::write(
        &mapping,
        format!("{text}\n[record]\naircraft = \"VH-LJ9 #2\"\n"),
    )
    .unwrap();
    let rec = sitl_record(dir.path(), "1", &["--config", mapping.to_str().unwrap()]);
    assert_eq!(rec.header.aircraft.as_deref(), Some("VH-LJ9 #2"));
}

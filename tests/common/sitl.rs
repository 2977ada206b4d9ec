//! `lj9da-bridge sitl` run as a user runs it, for the tests that read what it leaves behind.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

/// Run `sitl --plain --seconds SECONDS ARGS…` in the folder `work` (stdin closed); panics with
/// its stderr if it fails. The record files it left in `work/records/`, sorted.
pub fn sitl_records(work: &Path, seconds: &str, args: &[&str]) -> Vec<PathBuf> {
    let out = Command::new(env!("CARGO_BIN_EXE_lj9da-bridge"))
        .args(["sitl", "--plain", "--seconds", seconds])
        .args(args)
        .current_dir(work)
        .stdin(Stdio::null())
        .output()
        .expect("lj9da-bridge sitl runs");
    assert!(
        out.status.success(),
        "{:?}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    let mut files: Vec<PathBuf> = std::fs::read_dir(work.join("records"))
        .expect("records/ in the current folder")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "lj9rec"))
        .collect();
    files.sort();
    files
}

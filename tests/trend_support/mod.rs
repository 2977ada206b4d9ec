//! What the `record trend` tests share: the flights' calendar (the first on 2026-01-01 at 08:00
//! UTC) and the record files of a folder.

// Each test binary uses some of these, and the fleet bench others.
#![allow(dead_code)]

pub mod flight;

use lj9da_bridge::record::trend::record_files;
use std::path::{Path, PathBuf};

pub const NS_PER_DAY: i64 = 86_400 * 1_000_000_000;
/// 2026-01-01T08:00:00Z.
pub const FIRST_FLIGHT_NS: i64 = 1_767_254_400 * 1_000_000_000;

pub fn files_of(dir: &Path) -> Vec<PathBuf> {
    record_files(&[dir.to_path_buf()]).unwrap()
}

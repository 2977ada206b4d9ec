//! Record files on disk: their names, and keeping their total size under a limit.
//!
//! A record file is named by the UTC time it was opened, `20261121T235959Z.lj9rec`, with
//! `-2`, `-3`, … added if that name is taken (a companion computer without a real-time clock
//! may boot with the same time twice; a long run may open parts in quick succession).
//! Rotation deletes the oldest record files first — oldest by modification time, then by
//! name and number — and never touches any other file, nor a file it is told to keep.

use super::clock::Utc;
use super::format::FILE_EXTENSION;
use std::fs::{File, OpenOptions};
use std::io;
use std::path::{Path, PathBuf};
use std::time::SystemTime;

/// One record file in a record directory.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecordFile {
    pub path: PathBuf,
    pub bytes: u64,
    pub modified: SystemTime,
}

/// Whether `path` has the record files' extension.
pub fn is_record_file(path: &Path) -> bool {
    path.extension().is_some_and(|e| e == FILE_EXTENSION)
}

/// The record files directly in `dir`, oldest first.
pub fn list_record_files(dir: &Path) -> io::Result<Vec<RecordFile>> {
    let mut files = Vec::new();
    for entry in std::fs::read_dir(dir)? {
        let Ok(entry) = entry else { continue };
        let path = entry.path();
        if !is_record_file(&path) {
            continue;
        }
        let Ok(meta) = entry.metadata() else { continue };
        if !meta.is_file() {
            continue;
        }
        files.push(RecordFile {
            path,
            bytes: meta.len(),
            modified: meta.modified().unwrap_or(SystemTime::UNIX_EPOCH),
        });
    }
    files.sort_by(|a, b| {
        a.modified
            .cmp(&b.modified)
            .then_with(|| name_order(&a.path).cmp(&name_order(&b.path)))
    });
    Ok(files)
}

/// A file's place among files of the same modification time (a coarse clock can give files
/// written in quick succession the same one): its name without a `-<n>` suffix, then `n` (1
/// without a suffix), so `…Z-10` comes after `…Z-9`.
fn name_order(path: &Path) -> (String, u64) {
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    match stem.rsplit_once('-') {
        Some((base, n)) if !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()) => {
            (base.to_string(), n.parse().unwrap_or(u64::MAX))
        }
        _ => (stem, 1),
    }
}

/// Delete the oldest record files in `dir`, except those in `keep`, until their total size is
/// at most `budget` bytes. Returns the files deleted, oldest first. A file that cannot be
/// deleted is logged and counted as still there.
pub fn rotate(dir: &Path, budget: u64, keep: &[&Path]) -> io::Result<Vec<PathBuf>> {
    let files = list_record_files(dir)?;
    let mut total: u64 = files.iter().map(|f| f.bytes).sum();
    let mut deleted = Vec::new();
    for file in files {
        if total <= budget {
            break;
        }
        if keep.iter().any(|k| *k == file.path) {
            continue;
        }
        match std::fs::remove_file(&file.path) {
            Ok(()) => {
                tracing::info!(
                    file = %file.path.display(),
                    bytes = file.bytes,
                    "deleted the oldest flight record to stay under {budget} bytes"
                );
                total = total.saturating_sub(file.bytes);
                deleted.push(file.path);
            }
            Err(e) => tracing::warn!(
                file = %file.path.display(),
                "cannot delete an old flight record: {e}"
            ),
        }
    }
    Ok(deleted)
}

/// Create a new, empty record file in `dir` named by `unix_ns` (UTC), never replacing an
/// existing file. `after`, the part written before it: a part named in the same second gets a
/// higher suffix than that one, even when the older one was rotated away meanwhile, so that a
/// name is never used twice in a run and the name order stays the order of writing.
pub fn create_record_file(
    dir: &Path,
    unix_ns: i64,
    after: Option<&Path>,
) -> io::Result<(PathBuf, File)> {
    let stamp = Utc::from_unix_ns(unix_ns).file_stamp();
    let first = after
        .map(name_order)
        .filter(|(base, _)| *base == stamp)
        .map_or(1, |(_, n)| {
            u32::try_from(n).unwrap_or(u32::MAX).saturating_add(1)
        });
    let mut last_error = None;
    for n in first..=first.saturating_add(1000) {
        let name = if n == 1 {
            format!("{stamp}.{FILE_EXTENSION}")
        } else {
            format!("{stamp}-{n}.{FILE_EXTENSION}")
        };
        let path = dir.join(name);
        match OpenOptions::new().write(true).create_new(true).open(&path) {
            Ok(file) => return Ok((path, file)),
            Err(e) if e.kind() == io::ErrorKind::AlreadyExists => last_error = Some(e),
            Err(e) => return Err(e),
        }
    }
    Err(last_error.unwrap_or_else(|| io::Error::other("no free record file name")))
}

/// Make a new file's directory entry durable (best effort: not every file system can).
pub fn sync_dir(dir: &Path) {
    if let Ok(d) = File::open(dir) {
        let _ = d.sync_all();
    }
}

#[cfg(test)]
mod tests {
    use super::{create_record_file, name_order};
    use std::path::Path;

    #[test]
    fn a_part_of_the_same_second_never_takes_the_name_of_one_rotated_away() {
        let dir = std::env::temp_dir().join(format!("lj9da-rotate-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let t = 1_763_769_599_000_000_000i64;
        let (first, _) = create_record_file(&dir, t, None).unwrap();
        let (second, _) = create_record_file(&dir, t, Some(&first)).unwrap();
        // Both parts of that second are rotated away; the next one still follows them.
        std::fs::remove_file(&first).unwrap();
        std::fs::remove_file(&second).unwrap();
        let (third, _) = create_record_file(&dir, t, Some(&second)).unwrap();
        let name = |p: &Path| p.file_name().unwrap().to_string_lossy().into_owned();
        assert!(name(&second).ends_with("Z-2.lj9rec"), "{}", name(&second));
        assert!(name(&third).ends_with("Z-3.lj9rec"), "{}", name(&third));
        assert!(name_order(&third) > name_order(&second));
        // A new second starts again without a suffix.
        let (next, _) = create_record_file(&dir, t + 1_000_000_000, Some(&third)).unwrap();
        assert!(!name(&next).contains('-'), "{}", name(&next));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn files_of_the_same_second_sort_by_their_number() {
        let mut names = vec![
            "20261121T235959Z-10.lj9rec",
            "20261121T235960Z.lj9rec",
            "20261121T235959Z-2.lj9rec",
            "20261121T235959Z.lj9rec",
            "20261121T235959Z-9.lj9rec",
        ];
        names.sort_by_key(|n| name_order(Path::new(n)));
        assert_eq!(
            names,
            [
                "20261121T235959Z.lj9rec",
                "20261121T235959Z-2.lj9rec",
                "20261121T235959Z-9.lj9rec",
                "20261121T235959Z-10.lj9rec",
                "20261121T235960Z.lj9rec",
            ]
        );
    }
}

//! Reading a record file back: every whole record, and notes on whatever was not one.
//!
//! Only a file whose header cannot be read is an error (not a record file, a format this
//! build does not know, a header cut or damaged). Everything after the header is read as far
//! as it goes:
//! - a record the file ends in the middle of (the writer was cut off by a power loss or a
//!   crash) ends the reading with a note saying where and how much;
//! - a tail of zeros (a file system that kept the file's length but not its last data) ends
//!   it with a note;
//! - damaged bytes between whole records (a bad CRC, an impossible length) are skipped to
//!   the next position where a whole record with a correct CRC starts, with a note saying
//!   which bytes were skipped, as a frame decoder retries a bad candidate from its next byte;
//! - records of a later format's kinds are skipped, counted in a note;
//! - a file without an end record gets a note that the bridge did not close it.
//!
//! The reader never panics, whatever the bytes.

use super::format::{
    self, Decoded, HeaderError, MAX_RECORD_LEN, Record, RecordBody, RecordHeader, decode_header,
    decode_record,
};
use std::collections::BTreeMap;
use std::io;
use std::path::{Path, PathBuf};
use thiserror::Error;

/// Why a record file cannot be read at all.
#[derive(Debug, Error)]
pub enum RecordError {
    #[error("cannot read {}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: io::Error,
    },
    #[error("{}: {reason}", path.display())]
    Header { path: PathBuf, reason: HeaderError },
}

/// A record file as read back.
#[derive(Debug, Clone, PartialEq)]
pub struct Recording {
    pub header: RecordHeader,
    /// Every whole record, in file order.
    pub records: Vec<Record>,
    /// What was skipped or missing, one sentence each (empty for a file closed cleanly).
    pub notes: Vec<String>,
    /// Whether the file ends with the writer's end record.
    pub closed: bool,
}

/// Read the record file at `path`.
pub fn read_record(path: &Path) -> Result<Recording, RecordError> {
    let bytes = std::fs::read(path).map_err(|source| RecordError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    Recording::from_bytes(&bytes).map_err(|reason| RecordError::Header {
        path: path.to_path_buf(),
        reason,
    })
}

/// What reading a file's bytes found besides its records (see [`scan_bytes`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Scan {
    pub header: RecordHeader,
    /// What was skipped or missing, one sentence each (empty for a file closed cleanly).
    pub notes: Vec<String>,
    /// Whether the file ends with the writer's end record.
    pub closed: bool,
    /// Whole records handed on.
    pub records: usize,
}

/// Read the record file at `path` without keeping its records: each is handed to `on_record`
/// in file order, as [`read_record`] would have kept it (for reading many files quickly).
pub fn scan_record(path: &Path, on_record: impl FnMut(Record)) -> Result<Scan, RecordError> {
    let bytes = std::fs::read(path).map_err(|source| RecordError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    scan_bytes(&bytes, on_record).map_err(|reason| RecordError::Header {
        path: path.to_path_buf(),
        reason,
    })
}

/// Read a record file's bytes, handing each whole record to `on_record` in file order; the
/// notes and the end are those [`Recording::from_bytes`] gives.
pub fn scan_bytes(bytes: &[u8], mut on_record: impl FnMut(Record)) -> Result<Scan, HeaderError> {
    let (header, header_len) = decode_header(bytes)?;
    let mut notes = Vec::new();
    let mut unsupported: BTreeMap<String, u64> = BTreeMap::new();
    let mut count = 0usize;
    let mut outside = 0usize;
    // The last record's end mark: `Some(continued)` if it is an end record.
    let mut last_end: Option<bool> = None;
    let mut pos = header_len;
    while let Some(rest) = bytes.get(pos..).filter(|r| !r.is_empty()) {
        match decode_record(rest) {
            Decoded::Record { record, len } => {
                if record
                    .body
                    .servo()
                    .is_some_and(|s| usize::from(s) >= header.servos.len())
                {
                    outside += 1;
                }
                last_end = match record.body {
                    RecordBody::End { continued } => Some(continued),
                    _ => None,
                };
                count += 1;
                on_record(record);
                pos += len;
            }
            Decoded::Unsupported { what, len } => {
                *unsupported.entry(what).or_default() += 1;
                pos += len;
            }
            failure => match resync(bytes, pos + 1) {
                Some(next) => {
                    let why = match failure {
                        Decoded::Invalid { why } => why,
                        _ => "a record that overlaps the next one".to_string(),
                    };
                    notes.push(format!(
                        "bytes {pos} to {} ({} bytes) are not a record ({why}): skipped, \
                         reading resumed at offset {next}",
                        next - 1,
                        next - pos
                    ));
                    pos = next;
                }
                None => {
                    notes.push(tail_note(pos, rest, &failure, count));
                    break;
                }
            },
        }
    }
    for (what, count) in unsupported {
        notes.push(format!(
            "skipped {count} {what}, unknown to this lj9da-bridge (written by a newer one?)"
        ));
    }
    if outside > 0 {
        notes.push(format!(
            "{outside} records name a servo index beyond the header's {} servos: they are \
             shown without a servo",
            header.servos.len()
        ));
    }
    let closed = match last_end {
        Some(false) => true,
        Some(true) => {
            notes.push(format!(
                "the run continues in the next record file (part {})",
                u32::from(header.part) + 1
            ));
            true
        }
        None => {
            notes.push(
                "the file has no end record: the bridge stopped without closing it (crash, \
                 kill or power loss); up to the last ~0.3 s before the stop may be missing"
                    .to_string(),
            );
            false
        }
    };
    Ok(Scan {
        header,
        notes,
        closed,
        records: count,
    })
}

impl Recording {
    /// Read a record file's bytes.
    pub fn from_bytes(bytes: &[u8]) -> Result<Recording, HeaderError> {
        let mut records = Vec::with_capacity((bytes.len() / 24).min(1 << 20));
        let scan = scan_bytes(bytes, |r| records.push(r))?;
        Ok(Recording {
            header: scan.header,
            records,
            notes: scan.notes,
            closed: scan.closed,
        })
    }

    /// The name of servo `servo` (its index), or `#<index>` if the table has no such servo.
    pub fn servo_name(&self, servo: u8) -> String {
        self.header
            .servos
            .get(usize::from(servo))
            .map_or_else(|| format!("#{servo}"), |s| s.name.clone())
    }

    /// The time of the latest record, µs since the run's start (0 without records).
    pub fn end_t_us(&self) -> u64 {
        self.records.iter().map(|r| r.t_us).max().unwrap_or(0)
    }

    /// The time of the earliest record, µs since the run's start (0 without records).
    pub fn start_t_us(&self) -> u64 {
        self.records.iter().map(|r| r.t_us).min().unwrap_or(0)
    }

    /// Records the writer could not take, as its `dropped` records count them.
    pub fn dropped(&self) -> u64 {
        self.records
            .iter()
            .map(|r| match r.body {
                RecordBody::Dropped { count } => count,
                _ => 0,
            })
            .fold(0u64, u64::saturating_add)
    }
}

/// The first position at or after `from` where a whole record of a known kind with a correct
/// CRC starts.
fn resync(bytes: &[u8], from: usize) -> Option<usize> {
    let known = format::kind::KNOWN;
    (from..bytes.len()).find(|&p| {
        let Some(&[l0, l1, kind]) = bytes.get(p..p + 3) else {
            return false;
        };
        let len = usize::from(u16::from_le_bytes([l0, l1]));
        known.contains(&kind)
            && (2..=MAX_RECORD_LEN).contains(&len)
            && matches!(
                bytes.get(p..).map(decode_record),
                Some(Decoded::Record { .. })
            )
    })
}

fn tail_note(pos: usize, rest: &[u8], failure: &Decoded, intact: usize) -> String {
    if rest.iter().all(|&b| b == 0) {
        return format!(
            "the last {} bytes, from offset {pos}, are zeros, not records: the file system kept \
             the file's length but not its last data (power loss?); the {intact} records before \
             them are intact",
            rest.len()
        );
    }
    match failure {
        Decoded::Incomplete { needed } => format!(
            "the file ends {} bytes into a record at offset {pos} (a whole one would be {needed} \
             bytes): the last record was cut (power loss?); the {intact} records before it are \
             intact",
            rest.len()
        ),
        Decoded::Invalid { why } => format!(
            "the last {} bytes, from offset {pos}, are not a record ({why}) and no whole record \
             follows: skipped; the {intact} records before them are intact",
            rest.len()
        ),
        _ => format!(
            "the last {} bytes, from offset {pos}, could not be read",
            rest.len()
        ),
    }
}

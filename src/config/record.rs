//! The `[record]` table: where the flight record goes and how much disk it may take.

use super::error::{ConfigError, Scope};
use super::raw::RawRecord;
use std::path::{Path, PathBuf};

/// The `[record]` table.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecordSection {
    /// Whether `run` and `sitl` keep a flight record (default true).
    pub enabled: bool,
    /// The folder for record files; relative paths are relative to the mapping file's folder.
    /// `None`: a `records/` folder beside the mapping file.
    pub dir: Option<PathBuf>,
    /// The most all record files in the folder may take together, in MiB (default 512); the
    /// oldest files are deleted to stay under it.
    pub max_total_mb: u64,
    /// The aircraft's name, kept in every record file's header so that a fleet's records can
    /// be told apart (`None`: the computer's host name, which the runtime reads).
    pub aircraft: Option<String>,
}

impl RecordSection {
    pub const DEFAULT_MAX_TOTAL_MB: u64 = 512;
    /// Files of at least 64 KiB each, four to the total: 1 MiB is the smallest useful total.
    pub const MIN_TOTAL_MB: u64 = 1;
    pub const MAX_TOTAL_MB: u64 = 1 << 20;
    /// The longest aircraft name a record file keeps, in bytes.
    pub const MAX_AIRCRAFT_LEN: usize = 64;

    /// The record folder for a mapping file at `config_path`.
    pub fn dir_for(&self, config_path: Option<&Path>) -> PathBuf {
        let base = config_path
            .and_then(Path::parent)
            .map(Path::to_path_buf)
            .unwrap_or_default();
        match &self.dir {
            Some(dir) if dir.is_absolute() => dir.clone(),
            Some(dir) => base.join(dir),
            None => base.join("records"),
        }
    }

    /// The total size limit in bytes.
    pub fn max_total_bytes(&self) -> u64 {
        self.max_total_mb << 20
    }

    pub(crate) fn from_raw(raw: &RawRecord, scope: &Scope<'_>) -> Result<Self, ConfigError> {
        let max_total_mb = match &raw.max_total_mb {
            None => Self::DEFAULT_MAX_TOTAL_MB,
            Some(v) => {
                let mb = *v.get_ref();
                if !(Self::MIN_TOTAL_MB as i64..=Self::MAX_TOTAL_MB as i64).contains(&mb) {
                    return Err(scope.error_on(
                        v,
                        "max_total_mb",
                        format!(
                            "{mb} is outside {}–{} (MiB)",
                            Self::MIN_TOTAL_MB,
                            Self::MAX_TOTAL_MB
                        ),
                    ));
                }
                mb as u64
            }
        };
        let dir = match &raw.dir {
            None => None,
            Some(d) if d.get_ref().trim().is_empty() => {
                return Err(scope.error_on(
                    d,
                    "dir",
                    "is empty; leave the key out for records/ beside this file",
                ));
            }
            Some(d) => Some(PathBuf::from(d.get_ref())),
        };
        let aircraft = match &raw.aircraft {
            None => None,
            Some(a) => {
                let name = a.get_ref();
                if name.trim().is_empty() {
                    return Err(scope.error_on(
                        a,
                        "aircraft",
                        "is empty; leave the key out for the computer's host name",
                    ));
                }
                if name.len() > Self::MAX_AIRCRAFT_LEN || name.chars().any(char::is_control) {
                    return Err(scope.error_on(
                        a,
                        "aircraft",
                        format!(
                            "{name:?} is not a name: at most {} bytes, no control characters",
                            Self::MAX_AIRCRAFT_LEN
                        ),
                    ));
                }
                Some(name.clone())
            }
        };
        Ok(RecordSection {
            enabled: raw.enabled.unwrap_or(true),
            dir,
            max_total_mb,
            aircraft,
        })
    }
}

impl Default for RecordSection {
    fn default() -> Self {
        RecordSection {
            enabled: true,
            dir: None,
            max_total_mb: Self::DEFAULT_MAX_TOTAL_MB,
            aircraft: None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_record_folder_is_beside_the_mapping_file_unless_given() {
        let r = RecordSection::default();
        assert_eq!(
            r.dir_for(Some(Path::new("/etc/lj9da/plane.toml"))),
            PathBuf::from("/etc/lj9da/records")
        );
        let r = RecordSection {
            dir: Some("logs".into()),
            ..RecordSection::default()
        };
        assert_eq!(
            r.dir_for(Some(Path::new("/etc/lj9da/plane.toml"))),
            PathBuf::from("/etc/lj9da/logs")
        );
        let r = RecordSection {
            dir: Some("/var/lib/lj9da-bridge/records".into()),
            ..RecordSection::default()
        };
        assert_eq!(
            r.dir_for(Some(Path::new("plane.toml"))),
            PathBuf::from("/var/lib/lj9da-bridge/records")
        );
        assert_eq!(RecordSection::default().max_total_bytes(), 512 << 20);
    }
}

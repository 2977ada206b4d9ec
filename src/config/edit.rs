//! Changing a mapping file from the running bridge (MAVLink parameters, see
//! [`crate::mavlink::params`]) without losing its comments or layout.
//!
//! A change is applied to the file's text with `toml_edit`, and the whole new text is read
//! again with [`Config::parse`]: a value the file would refuse is refused here with the same
//! reason, and nothing is written. An accepted change is saved by writing a temporary file
//! beside the mapping file, syncing it and renaming it over the old one, so a power cut leaves
//! either the old file or the new one, never a torn one.
//!
//! A bridge started without a file of its own (`sitl` on its built-in airframe) keeps the
//! changes in memory for the run.

use super::{Config, ConfigError};
use std::io::Write;
use std::path::{Path, PathBuf};
use thiserror::Error;
use toml_edit::{DocumentMut, Item, Table, Value};

/// A table of the mapping file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Section {
    Mavlink,
    Telemetry,
    /// The n-th `[[servo]]` table (from 0), in file order.
    Servo(usize),
}

impl Section {
    fn describe(self) -> String {
        match self {
            Section::Mavlink => "[mavlink]".into(),
            Section::Telemetry => "[telemetry]".into(),
            Section::Servo(i) => format!("[[servo]] number {}", i + 1),
        }
    }
}

/// One end of a servo's travel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TravelEnd {
    Min,
    Max,
}

/// A change to a mapping file.
#[derive(Debug, Clone)]
pub enum Edit {
    /// Set `key` of a table to `value` (an inline comment after the old value is kept).
    Set {
        section: Section,
        key: &'static str,
        value: Value,
    },
    /// Remove `key` from a table (its default applies).
    Remove { section: Section, key: &'static str },
    /// Set one end of a servo's travel, in whichever form the file uses (`travel_mm = [min,
    /// max]`, or `min_mm` / `max_mm`).
    Travel {
        servo: usize,
        end: TravelEnd,
        mm: f64,
    },
}

/// Why a change was not made. Nothing was written in any case.
#[derive(Debug, Error)]
pub enum EditError {
    /// The file would not be valid with the change: the reason the file reader gives.
    #[error("{0}")]
    Invalid(ConfigError),
    /// The file is not laid out so that the change can be made (e.g. `[[servo]]` written as an
    /// inline array).
    #[error("cannot change {0}")]
    Layout(String),
    /// The new file could not be written; the old one is unchanged.
    #[error("cannot save {}: {source}", .path.display())]
    Save {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
}

impl EditError {
    /// The reason alone, short enough for a STATUSTEXT where possible.
    pub fn reason(&self) -> String {
        match self {
            EditError::Invalid(e) => e.reason(),
            EditError::Layout(what) => format!("cannot change {what}"),
            EditError::Save { source, .. } => format!("not saved: {source}"),
        }
    }
}

/// A mapping file as text, with what the running bridge has changed in it.
#[derive(Debug, Clone)]
pub struct MappingFile {
    doc: DocumentMut,
    origin: String,
    /// Where changes are saved; `None`: in memory only.
    path: Option<PathBuf>,
}

impl MappingFile {
    /// The file at `path`; changes are saved there.
    pub fn open(path: &Path) -> Result<MappingFile, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        let mut file = Self::in_memory(&text, &path.display().to_string())?;
        file.path = Some(path.to_path_buf());
        Ok(file)
    }

    /// A mapping held in memory (`origin` names it in errors); changes last for the run.
    pub fn in_memory(text: &str, origin: &str) -> Result<MappingFile, ConfigError> {
        // `Config::parse` gives the located error for anything `toml_edit` would refuse.
        Config::parse(text, origin)?;
        let doc = text
            .parse::<DocumentMut>()
            .map_err(|e| ConfigError::Invalid {
                origin: origin.to_string(),
                location: None,
                scope: None,
                key: None,
                reason: e.to_string(),
            })?;
        Ok(MappingFile {
            doc,
            origin: origin.to_string(),
            path: None,
        })
    }

    /// Where changes are saved, if anywhere.
    pub fn path(&self) -> Option<&Path> {
        self.path.as_deref()
    }

    /// The file's text as it is now.
    pub fn text(&self) -> String {
        self.doc.to_string()
    }

    /// Make `edits` together: check the new file as the bridge would read it, save it, and
    /// return what it says. On any error nothing changes, in memory or on disk.
    pub fn apply(&mut self, edits: &[Edit]) -> Result<Config, EditError> {
        let mut doc = self.doc.clone();
        for edit in edits {
            apply_one(&mut doc, edit)?;
        }
        let text = doc.to_string();
        let cfg = Config::parse(&text, &self.origin).map_err(EditError::Invalid)?;
        if let Some(path) = &self.path {
            write_atomically(path, &text).map_err(|source| EditError::Save {
                path: path.clone(),
                source,
            })?;
        }
        self.doc = doc;
        Ok(cfg)
    }
}

fn apply_one(doc: &mut DocumentMut, edit: &Edit) -> Result<(), EditError> {
    match edit {
        Edit::Set {
            section,
            key,
            value,
        } => {
            set(table_mut(doc, *section)?, key, value.clone());
        }
        Edit::Remove { section, key } => {
            table_mut(doc, *section)?.remove(key);
        }
        Edit::Travel { servo, end, mm } => {
            let table = table_mut(doc, Section::Servo(*servo))?;
            let at = match end {
                TravelEnd::Min => 0,
                TravelEnd::Max => 1,
            };
            match table.get_mut("travel_mm").and_then(Item::as_array_mut) {
                Some(pair) if pair.len() == 2 => {
                    let old = pair.get(at).map(|v| v.decor().clone());
                    let mut value = Value::from(*mm);
                    if let Some(decor) = old {
                        *value.decor_mut() = decor;
                    }
                    pair.replace(at, value);
                }
                Some(_) => {
                    return Err(EditError::Layout(format!(
                        "travel_mm of {}: it is not a pair [min, max]",
                        Section::Servo(*servo).describe()
                    )));
                }
                None => {
                    let key = match end {
                        TravelEnd::Min => "min_mm",
                        TravelEnd::Max => "max_mm",
                    };
                    set(table, key, Value::from(*mm));
                }
            }
        }
    }
    Ok(())
}

/// Set `key` to `value`, keeping the decoration (spacing, comment) of the value it replaces.
fn set(table: &mut Table, key: &str, mut value: Value) {
    if let Some(old) = table.get(key).and_then(Item::as_value) {
        *value.decor_mut() = old.decor().clone();
    }
    table[key] = Item::Value(value);
}

fn table_mut(doc: &mut DocumentMut, section: Section) -> Result<&mut Table, EditError> {
    let layout = || EditError::Layout(section.describe());
    match section {
        Section::Mavlink | Section::Telemetry => {
            let name = if section == Section::Mavlink {
                "mavlink"
            } else {
                "telemetry"
            };
            if doc.get(name).is_none() {
                doc.insert(name, Item::Table(Table::new()));
            }
            doc.get_mut(name)
                .and_then(Item::as_table_mut)
                .ok_or_else(layout)
        }
        Section::Servo(i) => doc
            .get_mut("servo")
            .and_then(Item::as_array_of_tables_mut)
            .and_then(|servos| servos.get_mut(i))
            .ok_or_else(layout),
    }
}

/// Replace `path` with `text` so that a crash leaves the old file or the new one: write a
/// temporary file in the same directory, sync it, rename it over `path`, sync the directory.
/// The old file's permissions are kept.
pub fn write_atomically(path: &Path, text: &str) -> std::io::Result<()> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "mapping".into());
    let tmp = dir.join(format!(".{name}.{}.tmp", std::process::id()));
    let result = (|| {
        let mut file = std::fs::File::create(&tmp)?;
        if let Ok(meta) = std::fs::metadata(path) {
            file.set_permissions(meta.permissions())?;
        }
        file.write_all(text.as_bytes())?;
        file.sync_all()?;
        std::fs::rename(&tmp, path)?;
        // The rename itself is durable only once the directory is.
        std::fs::File::open(dir)?.sync_all()
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

#[cfg(test)]
mod tests {
    use super::*;

    const FILE: &str = r#"# An airframe.
[mavlink]
connection = "udpin:0.0.0.0:14560"   # where the autopilot is
failsafe_timeout_ms = 500

[[bus]]
name = "wing"
port = "/dev/ttyUSB0"

[[servo]]
name = "aileron_left"   # left wing
bus = "wing"
id = 1
channel = 1
pwm_trim_us = 1500      # measured on the bench
travel_mm = [-20.0, 20.0]

[[servo]]
name = "rudder"
bus = "wing"
id = 2
channel = 4
"#;

    fn trim(value: i64) -> Edit {
        Edit::Set {
            section: Section::Servo(0),
            key: "pwm_trim_us",
            value: Value::from(value),
        }
    }

    #[test]
    fn a_change_keeps_every_comment_and_the_rest_of_the_text() {
        let mut file = MappingFile::in_memory(FILE, "plane.toml").unwrap();
        let cfg = file.apply(&[trim(1510)]).unwrap();
        assert_eq!(cfg.servos[0].pwm.trim_us, 1510);
        assert_eq!(
            file.text(),
            FILE.replace(
                "pwm_trim_us = 1500      # measured",
                "pwm_trim_us = 1510      # measured"
            )
        );
    }

    #[test]
    fn a_value_the_file_would_refuse_is_refused_with_the_files_reason_and_nothing_changes() {
        let mut file = MappingFile::in_memory(FILE, "plane.toml").unwrap();
        let err = file.apply(&[trim(3000)]).unwrap_err();
        let EditError::Invalid(e) = &err else {
            panic!("{err:?}")
        };
        assert_eq!(e.key(), Some("pwm_trim_us"));
        assert!(err.reason().contains("3000"), "{}", err.reason());
        assert_eq!(file.text(), FILE);
    }

    #[test]
    fn travel_is_changed_in_the_form_the_file_uses() {
        let mut file = MappingFile::in_memory(FILE, "plane.toml").unwrap();
        let cfg = file
            .apply(&[
                Edit::Travel {
                    servo: 0,
                    end: TravelEnd::Max,
                    mm: 18.5,
                },
                Edit::Travel {
                    servo: 1,
                    end: TravelEnd::Min,
                    mm: -10.0,
                },
            ])
            .unwrap();
        assert!(file.text().contains("travel_mm = [-20.0, 18.5]"));
        assert!(file.text().contains("min_mm = -10.0"));
        assert_eq!(cfg.servos[0].travel.plus().mm(), 18.5);
        assert_eq!(cfg.servos[1].travel.minus().mm(), -10.0);
        // Beyond the stroke: the file's own refusal.
        let err = file
            .apply(&[Edit::Travel {
                servo: 1,
                end: TravelEnd::Max,
                mm: 26.0,
            }])
            .unwrap_err();
        assert!(err.reason().contains("beyond the stroke"), "{err}");
    }

    #[test]
    fn a_missing_telemetry_table_is_added_and_a_removed_key_takes_its_default() {
        let mut file = MappingFile::in_memory(FILE, "plane.toml").unwrap();
        let cfg = file
            .apply(&[
                Edit::Set {
                    section: Section::Telemetry,
                    key: "rate_hz",
                    value: Value::from(4.0),
                },
                Edit::Remove {
                    section: Section::Mavlink,
                    key: "failsafe_timeout_ms",
                },
            ])
            .unwrap();
        assert_eq!(cfg.telemetry.rate_hz, 4.0);
        assert_eq!(
            cfg.mavlink.failsafe_timeout_ms,
            super::super::mavlink::DEFAULT_FAILSAFE_TIMEOUT_MS
        );
        assert!(
            Config::parse(&file.text(), "again").is_ok(),
            "{}",
            file.text()
        );
    }

    #[test]
    fn a_saved_change_replaces_the_file_and_leaves_no_temporary_file() {
        let dir = std::env::temp_dir().join(format!("lj9da-edit-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("plane.toml");
        std::fs::write(&path, FILE).unwrap();
        let mut file = MappingFile::open(&path).unwrap();
        file.apply(&[trim(1490)]).unwrap();
        let on_disk = std::fs::read_to_string(&path).unwrap();
        assert!(on_disk.contains("pwm_trim_us = 1490      # measured on the bench"));
        assert_eq!(Config::load(&path).unwrap().servos[0].pwm.trim_us, 1490);
        // Refused: the file on disk is untouched.
        assert!(file.apply(&[trim(100)]).is_err());
        assert_eq!(std::fs::read_to_string(&path).unwrap(), on_disk);
        let left: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(left, vec![std::ffi::OsString::from("plane.toml")]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_file_that_cannot_be_written_refuses_the_change_and_keeps_the_old_values() {
        let dir = std::env::temp_dir().join(format!("lj9da-edit-ro-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("plane.toml");
        std::fs::write(&path, FILE).unwrap();
        let mut file = MappingFile::open(&path).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        let err = file.apply(&[trim(1490)]).unwrap_err();
        assert!(matches!(err, EditError::Save { .. }), "{err:?}");
        assert!(err.reason().starts_with("not saved"), "{}", err.reason());
        assert_eq!(file.text(), FILE);
    }
}

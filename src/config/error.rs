//! What can be wrong with a mapping file, and where.
//!
//! Every refusal names the file, the line and column, the table (`servo "aileron_left"`,
//! `bus "wing"`, `[mavlink]`), the key and the reason, in the form editors and terminals
//! recognise: `mappings/plane.toml:14:6: servo "aileron_left": key "id": 200 is outside 1–127`.
//! TOML syntax and type errors come from the `toml` crate's byte span; semantic errors from the
//! span of the offending value, kept with [`toml::Spanned`] while the file is read.

use serde::Deserialize;
use serde::de::IgnoredAny;
use std::fmt;
use std::ops::Range;
use std::path::PathBuf;
use thiserror::Error;
use toml::Spanned;

/// A position in a mapping file, both counted from 1; the column counts characters.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Location {
    pub line: usize,
    pub column: usize,
}

impl Location {
    /// The line and column of byte `offset` in `text` (clamped to the text, never panics).
    pub fn of_offset(text: &str, offset: usize) -> Location {
        let mut at = offset.min(text.len());
        while !text.is_char_boundary(at) {
            at -= 1;
        }
        let before = &text[..at];
        let line = before.matches('\n').count() + 1;
        let column = before.rsplit('\n').next().unwrap_or("").chars().count() + 1;
        Location { line, column }
    }
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}:{}", self.line, self.column)
    }
}

/// A mapping file that cannot be used.
#[derive(Debug, Error)]
pub enum ConfigError {
    /// The file could not be read at all.
    #[error("{}: cannot read the mapping file: {source}", .path.display())]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The file was read but is malformed or asks for something impossible.
    #[error("{origin}{}: {}{reason}", location_suffix(.location), context_prefix(.scope, .key))]
    Invalid {
        /// The file name (or the name given to [`Config::parse`](super::Config::parse)).
        origin: String,
        /// Where the offending key or value is; `None` only if the TOML parser gave no position.
        location: Option<Location>,
        /// The table: `servo "aileron_left"`, `bus "wing"`, `[mavlink]`, …
        scope: Option<String>,
        /// The offending key.
        key: Option<String>,
        /// Why it is refused, and what to do instead.
        reason: String,
    },
}

fn location_suffix(location: &Option<Location>) -> String {
    location.map(|l| format!(":{l}")).unwrap_or_default()
}

fn context_prefix(scope: &Option<String>, key: &Option<String>) -> String {
    let mut out = String::new();
    if let Some(scope) = scope {
        out.push_str(scope);
        out.push_str(": ");
    }
    if let Some(key) = key {
        out.push_str(&format!("key \"{key}\": "));
    }
    out
}

impl ConfigError {
    /// The file name the error refers to.
    pub fn origin(&self) -> String {
        match self {
            ConfigError::Read { path, .. } => path.display().to_string(),
            ConfigError::Invalid { origin, .. } => origin.clone(),
        }
    }

    /// The line (from 1) of the offending key or value, if known.
    pub fn line(&self) -> Option<usize> {
        match self {
            ConfigError::Read { .. } => None,
            ConfigError::Invalid { location, .. } => location.map(|l| l.line),
        }
    }

    /// The column (from 1, in characters) of the offending key or value, if known.
    pub fn column(&self) -> Option<usize> {
        match self {
            ConfigError::Read { .. } => None,
            ConfigError::Invalid { location, .. } => location.map(|l| l.column),
        }
    }

    /// The offending key, if the error is about one.
    pub fn key(&self) -> Option<&str> {
        match self {
            ConfigError::Read { .. } => None,
            ConfigError::Invalid { key, .. } => key.as_deref(),
        }
    }

    /// The table the error is in (`servo "aileron_left"`, `bus "wing"`, `[mavlink]`), if any.
    pub fn scope(&self) -> Option<&str> {
        match self {
            ConfigError::Read { .. } => None,
            ConfigError::Invalid { scope, .. } => scope.as_deref(),
        }
    }

    /// Why the file is refused.
    pub fn reason(&self) -> String {
        match self {
            ConfigError::Read { source, .. } => source.to_string(),
            ConfigError::Invalid { reason, .. } => reason.clone(),
        }
    }
}

/// The text being read and its name, for building located errors.
#[derive(Clone, Copy)]
pub(crate) struct Doc<'a> {
    pub text: &'a str,
    pub origin: &'a str,
}

impl<'a> Doc<'a> {
    pub fn new(text: &'a str, origin: &'a str) -> Self {
        Doc { text, origin }
    }

    /// An error at byte `offset`.
    pub fn error_at(
        &self,
        offset: Option<usize>,
        scope: Option<&str>,
        key: Option<&str>,
        reason: impl Into<String>,
    ) -> ConfigError {
        ConfigError::Invalid {
            origin: self.origin.to_string(),
            location: offset.map(|o| Location::of_offset(self.text, o)),
            scope: scope.map(str::to_string),
            key: key.map(str::to_string),
            reason: reason.into(),
        }
    }

    /// Errors inside one table.
    pub fn scope(&self, scope: impl Into<String>) -> Scope<'a> {
        Scope {
            doc: *self,
            name: scope.into(),
        }
    }

    /// A syntax or type error reported by the TOML parser, with the key and table it concerns.
    pub fn toml_error(&self, error: &toml::de::Error) -> ConfigError {
        let span = error.span();
        let offset = span.as_ref().map(|s| s.start);
        let message = match error.message().trim() {
            "" => "malformed TOML here (a value or a closing bracket or quote is missing?)"
                .to_string(),
            m => plain_type_names(&m.replace('\n', "; ")),
        };
        let (key, reason) = match quoted_after(&message, "unknown field `") {
            Some(key) => {
                let rest = message
                    .split_once("`, ")
                    .map(|(_, rest)| rest.to_string())
                    .unwrap_or_default();
                let reason = if rest.is_empty() {
                    "unknown key".to_string()
                } else {
                    format!("unknown key (a typo?); {rest}")
                };
                (Some(key), reason)
            }
            None => {
                if let Some(key) = quoted_after(&message, "missing field `") {
                    (Some(key), "required key is missing".to_string())
                } else if let Some(key) = quoted_after(&message, "duplicate key `") {
                    (Some(key), message.clone())
                } else {
                    (
                        offset.and_then(|o| key_before(self.text, o)),
                        message.clone(),
                    )
                }
            }
        };
        let scope = offset.and_then(|o| scope_of_offset(self.text, o));
        ConfigError::Invalid {
            origin: self.origin.to_string(),
            location: offset.map(|o| Location::of_offset(self.text, o)),
            scope,
            key,
            reason,
        }
    }
}

/// A table of the file (`servo "aileron_left"`, `[mavlink]`) in which errors are reported.
#[derive(Clone)]
pub(crate) struct Scope<'a> {
    doc: Doc<'a>,
    name: String,
}

impl Scope<'_> {
    /// An error about `key`, whose value is at `span`.
    pub fn error(&self, span: Range<usize>, key: &str, reason: impl Into<String>) -> ConfigError {
        self.doc
            .error_at(Some(span.start), Some(&self.name), Some(key), reason)
    }

    /// An error about `key`, whose value is `value`.
    pub fn error_on<T>(
        &self,
        value: &Spanned<T>,
        key: &str,
        reason: impl Into<String>,
    ) -> ConfigError {
        self.error(value.span(), key, reason)
    }
}

/// The parser's Rust type names in words a user of the file knows.
fn plain_type_names(message: &str) -> String {
    [
        ("expected i64", "expected an integer"),
        ("expected f64", "expected a number"),
        ("expected a sequence", "expected an array [ … ]"),
        ("expected struct ", "expected a table "),
    ]
    .iter()
    .fold(message.to_string(), |m, (from, to)| m.replace(from, to))
}

/// The text between `prefix` and the next backtick in `message`.
fn quoted_after(message: &str, prefix: &str) -> Option<String> {
    let rest = message.split_once(prefix)?.1;
    let key = rest.split_once('`')?.0;
    Some(key.to_string())
}

/// The key whose value holds byte `offset`: the bare or quoted key before the last `=` that
/// precedes `offset` on its line (`id = "x"` → `id`; `{ name = "a", id = "x" }` → `id`).
fn key_before(text: &str, offset: usize) -> Option<String> {
    let mut at = offset.min(text.len());
    while !text.is_char_boundary(at) {
        at -= 1;
    }
    let line_start = text[..at].rfind('\n').map_or(0, |i| i + 1);
    let before = &text[line_start..at];
    let eq = before.rfind('=')?;
    let lhs = before[..eq].trim_end();
    let start = lhs
        .char_indices()
        .rev()
        .find(|(_, c)| !(c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.' | '"' | '\'')))
        .map_or(0, |(i, c)| i + c.len_utf8());
    let key = lhs[start..].trim_matches(|c| c == '"' || c == '\'');
    (!key.is_empty()).then(|| key.to_string())
}

/// The outline of a mapping file: where each table is and what each entry is called. Used only
/// to say in which table a parser error lies, so it accepts anything the real reader accepts.
#[derive(Deserialize)]
struct Outline {
    #[serde(default)]
    mavlink: Option<Spanned<IgnoredAny>>,
    #[serde(default)]
    telemetry: Option<Spanned<IgnoredAny>>,
    #[serde(default)]
    bridge: Option<Spanned<IgnoredAny>>,
    #[serde(default)]
    bus: Vec<Spanned<NamedEntry>>,
    #[serde(default)]
    servo: Vec<Spanned<NamedEntry>>,
}

#[derive(Deserialize)]
struct NamedEntry {
    #[serde(default)]
    name: Option<toml::Value>,
}

/// `servo "aileron_left"`, `bus #2` or `[mavlink]` for the table that holds byte `offset`.
fn scope_of_offset(text: &str, offset: usize) -> Option<String> {
    let outline: Outline = toml::from_str(text).ok()?;
    let inside = |span: Range<usize>| span.contains(&offset);
    for (table, section) in [
        ("[mavlink]", &outline.mavlink),
        ("[telemetry]", &outline.telemetry),
        ("[bridge]", &outline.bridge),
    ] {
        if section.as_ref().is_some_and(|s| inside(s.span())) {
            return Some(table.to_string());
        }
    }
    for (kind, entries) in [("bus", &outline.bus), ("servo", &outline.servo)] {
        for (index, entry) in entries.iter().enumerate() {
            if inside(entry.span()) {
                return Some(entry_scope(
                    kind,
                    index,
                    entry.get_ref().name.as_ref().and_then(|v| v.as_str()),
                ));
            }
        }
    }
    None
}

/// `servo "aileron_left"`, or `servo #3` (counted from 1) for an entry without a usable name.
pub(crate) fn entry_scope(kind: &str, index: usize, name: Option<&str>) -> String {
    match name {
        Some(name) if !name.is_empty() => format!("{kind} \"{name}\""),
        _ => format!("{kind} #{}", index + 1),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn offsets_become_lines_and_character_columns() {
        let text = "a = 1\nµ = \"x\"\n";
        assert_eq!(
            Location::of_offset(text, 0),
            Location { line: 1, column: 1 }
        );
        assert_eq!(
            Location::of_offset(text, 6),
            Location { line: 2, column: 1 }
        );
        // "µ" is two bytes but one column.
        assert_eq!(
            Location::of_offset(text, 10),
            Location { line: 2, column: 4 }
        );
        // Inside a multi-byte character and past the end: clamped, no panic.
        assert_eq!(Location::of_offset(text, 7).line, 2);
        assert_eq!(Location::of_offset(text, 10_000).line, 3);
    }

    #[test]
    fn the_key_of_a_value_is_found_on_its_line() {
        let text = "[[servo]]\nid = \"x\"\nservo = [{ name = \"a\", id = \"y\" }]\n";
        let first = text.find("\"x\"").unwrap();
        let second = text.find("\"y\"").unwrap();
        assert_eq!(key_before(text, first).as_deref(), Some("id"));
        assert_eq!(key_before(text, second).as_deref(), Some("id"));
        assert_eq!(key_before(text, 3), None);
    }

    #[test]
    fn the_table_of_an_offset_is_named_after_its_entry() {
        let text =
            "[mavlink]\nconnection = 3\n[[servo]]\nname = \"ail\"\nid = 1\n[[servo]]\nid = 2\n";
        assert_eq!(scope_of_offset(text, 12).as_deref(), Some("[mavlink]"));
        let ail = text.find("id = 1").unwrap();
        assert_eq!(scope_of_offset(text, ail).as_deref(), Some("servo \"ail\""));
        let unnamed = text.find("id = 2").unwrap();
        assert_eq!(scope_of_offset(text, unnamed).as_deref(), Some("servo #2"));
    }

    #[test]
    fn the_message_reads_file_line_column_table_key_reason() {
        let doc = Doc::new("[[servo]]\nid = 200\n", "plane.toml");
        let e = doc
            .scope("servo \"aileron_left\"")
            .error(15..18, "id", "200 is outside 1–127");
        assert_eq!(
            e.to_string(),
            "plane.toml:2:6: servo \"aileron_left\": key \"id\": 200 is outside 1–127"
        );
        assert_eq!(e.line(), Some(2));
        assert_eq!(e.column(), Some(6));
        assert_eq!(e.key(), Some("id"));
        assert_eq!(e.scope(), Some("servo \"aileron_left\""));
    }
}

//! The mapping a chain test runs: the texts every one of them starts from, here, and what a
//! test changes said at its call site.
//!
//! ```ignore
//! let text = Mapping::four_servos()
//!     .with("[mavlink]", "output_rate_hz = 40")
//!     .with("[telemetry]", "rate_hz = 10")
//!     .servo_with("elevator", "failsafe = 4.0")
//!     .to_string();
//! ```
//!
//! A test whose subject is the mapping text itself (a comment kept through a parameter write,
//! an odd key) keeps its own text.

use std::fmt;

/// What every chain's mapping starts from: the autopilot's link (the chain puts a free port in
/// its place) and one bus of simulated servos (the chain gives it a pseudo-terminal).
const BASE: &str = r#"
[mavlink]
connection = "udpin:127.0.0.1:14560"

[[bus]]
name = "wing"
port = "sim"
# Several chains share two cores while the tests run: allow for a scheduler's hiccup.
turnaround_ms = 20
"#;

/// A small airplane's four servos on bus "wing".
const FOUR_SERVOS: &str = r#"
[[servo]]
name = "aileron_left"
label = "ail_l"
bus = "wing"
id = 1
channel = 1

[[servo]]
name = "aileron_right"
label = "ail_r"
bus = "wing"
id = 2
channel = 2

[[servo]]
name = "elevator"
label = "elev"
bus = "wing"
id = 3
channel = 3

[[servo]]
name = "rudder"
bus = "wing"
id = 4
channel = 4
"#;

/// Two servos on bus "wing": the left aileron on channel 1, the rudder on channel 4.
const AILERON_AND_RUDDER: &str = r#"
[[servo]]
name = "aileron_left"
label = "ail_l"
bus = "wing"
id = 1
channel = 1

[[servo]]
name = "rudder"
bus = "wing"
id = 2
channel = 4
"#;

/// A mapping's text, table by table: `[mavlink]` and the other tables first, then each
/// `[[bus]]`, then each `[[servo]]`. Its [`fmt::Display`] is the TOML the chain is given.
#[derive(Clone, Debug)]
pub struct Mapping {
    /// Each table as its header line (`[mavlink]`, `[[servo]]`, …) and the lines under it.
    tables: Vec<(String, Vec<String>)>,
}

impl Mapping {
    /// [`BASE`]: the autopilot's link and bus "wing", no servo yet.
    pub fn new() -> Mapping {
        Mapping { tables: Vec::new() }.append(BASE)
    }

    /// [`BASE`] with [`FOUR_SERVOS`].
    pub fn four_servos() -> Mapping {
        Mapping::new().append(FOUR_SERVOS)
    }

    /// [`BASE`] with [`AILERON_AND_RUDDER`].
    pub fn aileron_and_rudder() -> Mapping {
        Mapping::new().append(AILERON_AND_RUDDER)
    }

    /// Add a servo `name` on bus "wing", its bus `id`, driven by `channel`.
    pub fn servo(self, name: &str, id: u8, channel: u16) -> Mapping {
        self.append(&format!(
            "[[servo]]\nname = \"{name}\"\nbus = \"wing\"\nid = {id}\nchannel = {channel}\n"
        ))
    }

    /// Set the keys of `lines` (TOML, one `key = value` a line; a comment line is kept as it
    /// is) in `table`: `[mavlink]`, `[telemetry]` or any single table (made after the others
    /// when missing), or `[[bus]]` for the one bus. A key already there takes the new value in
    /// its place.
    pub fn with(mut self, table: &str, lines: &str) -> Mapping {
        let at = self.table(table);
        set(&mut self.tables[at].1, lines);
        self
    }

    /// Set the keys of `lines` (as in [`Mapping::with`]) in the servo called `name`.
    pub fn servo_with(mut self, name: &str, lines: &str) -> Mapping {
        let name_line = format!("name = \"{name}\"");
        let servo = self
            .tables
            .iter_mut()
            .find(|(header, keys)| header == "[[servo]]" && keys.contains(&name_line))
            .unwrap_or_else(|| panic!("no servo {name} in the test mapping"));
        set(&mut servo.1, lines);
        self
    }

    /// Take `key` (and a comment line just above it) out of `table` (as in [`Mapping::with`]).
    pub fn without(mut self, table: &str, key: &str) -> Mapping {
        let at = self.table(table);
        let lines = &mut self.tables[at].1;
        let i = lines
            .iter()
            .position(|l| key_of(l) == Some(key))
            .unwrap_or_else(|| panic!("no {key} in {table} of the test mapping"));
        lines.remove(i);
        if i > 0 && lines[i - 1].starts_with('#') {
            lines.remove(i - 1);
        }
        self
    }

    /// The index of `table`; a single table that is missing is made after the others.
    fn table(&mut self, table: &str) -> usize {
        let found: Vec<usize> = (0..self.tables.len())
            .filter(|&i| self.tables[i].0 == table)
            .collect();
        match found[..] {
            [one] => one,
            [] if !table.starts_with("[[") => {
                let at = self
                    .tables
                    .iter()
                    .position(|(header, _)| header.starts_with("[["))
                    .unwrap_or(self.tables.len());
                self.tables.insert(at, (table.to_string(), Vec::new()));
                at
            }
            _ => panic!("{} {table} in the test mapping", found.len()),
        }
    }

    /// Add the tables of `text` (TOML) after those there.
    fn append(mut self, text: &str) -> Mapping {
        for line in text.lines().map(str::trim).filter(|l| !l.is_empty()) {
            if line.starts_with('[') {
                self.tables.push((line.to_string(), Vec::new()));
            } else {
                self.tables
                    .last_mut()
                    .expect("a table before the first key")
                    .1
                    .push(line.to_string());
            }
        }
        self
    }
}

impl Default for Mapping {
    fn default() -> Self {
        Mapping::new()
    }
}

/// The key a `key = value` line sets (`None` for a comment).
fn key_of(line: &str) -> Option<&str> {
    if line.starts_with('#') {
        return None;
    }
    line.split_once('=').map(|(key, _)| key.trim())
}

/// Set each key of `lines` in `table`: in the place of the same key's line, else at the end.
fn set(table: &mut Vec<String>, lines: &str) {
    for line in lines.lines().map(str::trim).filter(|l| !l.is_empty()) {
        let same = key_of(line).and_then(|key| table.iter().position(|l| key_of(l) == Some(key)));
        match same {
            Some(i) => table[i] = line.to_string(),
            None => table.push(line.to_string()),
        }
    }
}

impl fmt::Display for Mapping {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (header, lines) in &self.tables {
            writeln!(f)?;
            writeln!(f, "{header}")?;
            for line in lines {
                writeln!(f, "{line}")?;
            }
        }
        Ok(())
    }
}

//! `lj9da-bridge record …`: looking at a flight record after the flight.
//!
//! Notes about a damaged or unclosed file go to stderr as `note: …`; the output itself
//! (table, CSV, file list) goes to stdout or the files asked for. Exit status 0 on success,
//! 1 if the record cannot be read or the output cannot be written.

use super::csv::write_csv;
use super::page::write_page;
use super::plot::plot;
use super::reader::{Recording, read_record};
use super::summary::summary;
use super::trend::{Since, record_files, trend};
use super::trend_html::write_trend_page;
use super::ulog;
use clap::Subcommand;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// What to do with a record file.
#[derive(Debug, Clone, PartialEq, Eq, Subcommand)]
pub enum RecordCommand {
    /// Print per servo: duration, samples, temperatures, peak current, time stalled and
    /// offline, max goal-to-position error, alarms.
    Summary {
        /// A record file (`*.lj9rec`, in the records folder).
        file: PathBuf,
    },
    /// Write one SVG picture per servo (goal and position, current, temperature and voltage
    /// against time, with alarms marked) and one HTML page with every servo's picture,
    /// zoomable, and the flight's summary.
    Plot {
        file: PathBuf,
        /// The folder to write the pictures into (created if missing).
        #[arg(long)]
        out: PathBuf,
    },
    /// Each servo's wear across flights: per flight its time with force on, travel,
    /// reversals, time in motion, friction (current per speed), holding and peak current, time
    /// stalled, temperatures, heating, bad replies and alarms; a verdict ("inspect" when a
    /// figure rose beyond its threshold over the servo's first flights).
    Trend {
        /// Record files, or folders of them (their `*.lj9rec` files).
        #[arg(required = true)]
        paths: Vec<PathBuf>,
        /// Print JSON (the same figures and verdicts) for a fleet tool.
        #[arg(long)]
        json: bool,
        /// Start a new baseline on this date (UTC, `2026-11-21` or `2026-11-21T08:30`): flights
        /// before it are left out. `SERVO=DATE` for one servo (after it was replaced); may be
        /// given more than once.
        #[arg(long, value_name = "[SERVO=]DATE")]
        since: Vec<Since>,
        /// Also write a page with each figure flight by flight (in date order).
        #[arg(long, value_name = "FILE")]
        html: Option<PathBuf>,
    },
    /// Export every flight as Parquet for a fleet's tools (DuckDB, Spark): per flight
    /// `DIR/samples/<aircraft>_<run start>.parquet` (one row per record) and
    /// `DIR/flights/<aircraft>_<run start>.parquet` (one row per servo with the figures of
    /// `record trend`). Exporting again overwrites the same files.
    Parquet {
        /// Record files, or folders of them (their `*.lj9rec` files).
        #[arg(required = true)]
        paths: Vec<PathBuf>,
        /// The export's folder (its `samples/` and `flights/` are created if missing).
        #[arg(long)]
        out: PathBuf,
        /// The aircraft of records that do not name one (written before record format 1.4);
        /// a record that names its aircraft keeps it.
        #[arg(long, value_name = "NAME")]
        aircraft: Option<String>,
    },
    /// Export every record as CSV (one row per record) for a spreadsheet.
    Csv {
        file: PathBuf,
        /// Write to this file instead of stdout.
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Export each record as a ULog file (PX4's log format: `<name>.ulg`, beside the record)
    /// for PlotJuggler, PX4 Flight Review, Foxglove or pyulog, to be looked at beside the
    /// autopilot's own log; prints the files written.
    Ulog {
        /// Record files (`*.lj9rec`).
        #[arg(required = true)]
        files: Vec<PathBuf>,
        /// Write the ULog files into this folder (created if missing) instead.
        #[arg(long, value_name = "DIR")]
        out: Option<PathBuf>,
    },
}

/// Write `text` to stdout. A reader that stopped early (`| head`) is no error: what it did not
/// read is left unwritten, quietly, where `print!` would panic.
fn print_out(text: &str) -> ExitCode {
    let stdout = std::io::stdout();
    let mut lock = stdout.lock();
    match lock.write_all(text.as_bytes()).and_then(|()| lock.flush()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: cannot write to stdout: {e}");
            ExitCode::FAILURE
        }
    }
}

fn load(file: &Path) -> Result<Recording, ExitCode> {
    match read_record(file) {
        Ok(rec) => {
            for note in &rec.notes {
                eprintln!("note: {}: {note}", file.display());
            }
            Ok(rec)
        }
        Err(e) => {
            eprintln!("error: {e}");
            Err(ExitCode::FAILURE)
        }
    }
}

/// Run a `record` subcommand.
pub fn run(cmd: RecordCommand) -> ExitCode {
    match cmd {
        RecordCommand::Summary { file } => {
            let rec = match load(&file) {
                Ok(rec) => rec,
                Err(code) => return code,
            };
            print_out(&format!("{}\n{}", file.display(), summary(&rec)))
        }
        RecordCommand::Plot { file, out } => {
            let rec = match load(&file) {
                Ok(rec) => rec,
                Err(code) => return code,
            };
            let stem = file.file_stem().map_or_else(
                || "record".to_string(),
                |s| s.to_string_lossy().into_owned(),
            );
            match plot(&rec, &out, &stem)
                .and_then(|files| Ok([files, vec![write_page(&rec, &out, &stem)?]].concat()))
            {
                Ok(files) => print_out(
                    &files
                        .iter()
                        .map(|f| format!("{}\n", f.display()))
                        .collect::<String>(),
                ),
                Err(e) => {
                    eprintln!(
                        "error: cannot write the pictures into {}: {e}",
                        out.display()
                    );
                    ExitCode::FAILURE
                }
            }
        }
        RecordCommand::Trend {
            paths,
            json,
            since,
            html,
        } => run_trend(&paths, json, &since, html.as_deref()),
        RecordCommand::Parquet {
            paths,
            out,
            aircraft,
        } => super::parquet::run(&paths, &out, aircraft.as_deref()),
        RecordCommand::Csv { file, out } => {
            let rec = match load(&file) {
                Ok(rec) => rec,
                Err(code) => return code,
            };
            let result = match &out {
                Some(path) => std::fs::File::create(path)
                    .and_then(|f| write_csv(&rec, &mut std::io::BufWriter::new(f))),
                None => {
                    let stdout = std::io::stdout();
                    let mut lock = stdout.lock();
                    write_csv(&rec, &mut lock).and_then(|n| lock.flush().map(|()| n))
                }
            };
            match result {
                Ok(_) => ExitCode::SUCCESS,
                Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => ExitCode::SUCCESS,
                Err(e) => {
                    let to = out.map_or_else(|| "stdout".to_string(), |p| p.display().to_string());
                    eprintln!("error: cannot write the CSV to {to}: {e}");
                    ExitCode::FAILURE
                }
            }
        }
        RecordCommand::Ulog { files, out } => run_ulog(&files, out.as_deref()),
    }
}

/// `record ulog`: each record's ULog file, written whole or not at all (through a `.part` file
/// renamed at the end). A record that cannot be read, or a file that cannot be written, is an
/// error and the others are still exported; the exit status is then 1.
fn run_ulog(files: &[PathBuf], out: Option<&Path>) -> ExitCode {
    if let Some(dir) = out
        && let Err(e) = std::fs::create_dir_all(dir)
    {
        eprintln!("error: cannot create the folder {}: {e}", dir.display());
        return ExitCode::FAILURE;
    }
    let mut failed = false;
    let mut targets = std::collections::BTreeSet::new();
    for file in files {
        let target = match out {
            Some(dir) => dir
                .join(file.file_name().unwrap_or(std::ffi::OsStr::new("record")))
                .with_extension(ulog::FILE_EXTENSION),
            None => file.with_extension(ulog::FILE_EXTENSION),
        };
        if target == *file {
            eprintln!(
                "error: {}: its ULog file would replace it: rename the record to *.lj9rec",
                file.display()
            );
            failed = true;
            continue;
        }
        if !targets.insert(target.clone()) {
            eprintln!(
                "error: {}: its ULog file {} is an earlier record's too: export records of the \
                 same name from different folders one by one",
                file.display(),
                target.display()
            );
            failed = true;
            continue;
        }
        let Ok(rec) = load(file) else {
            failed = true;
            continue;
        };
        let part = target.with_extension(format!("{}.part", ulog::FILE_EXTENSION));
        let written = std::fs::write(&part, ulog::encode_ulog(&rec))
            .and_then(|()| std::fs::rename(&part, &target));
        match written {
            Ok(()) => {
                if print_out(&format!("{}\n", target.display())) != ExitCode::SUCCESS {
                    failed = true;
                }
            }
            Err(e) => {
                let _ = std::fs::remove_file(&part);
                eprintln!("error: cannot write {}: {e}", target.display());
                failed = true;
            }
        }
    }
    if failed {
        ExitCode::FAILURE
    } else {
        ExitCode::SUCCESS
    }
}

fn run_trend(paths: &[PathBuf], json: bool, since: &[Since], html: Option<&Path>) -> ExitCode {
    let files = match record_files(paths) {
        Ok(files) => files,
        Err(e) => {
            eprintln!("error: cannot list the record files: {e}");
            return ExitCode::FAILURE;
        }
    };
    if files.is_empty() {
        eprintln!("error: no record files (*.lj9rec) in what was given");
        return ExitCode::FAILURE;
    }
    let (found, notes) = trend(&files, since);
    for note in &notes.notes {
        eprintln!("note: {note}");
    }
    for error in &notes.errors {
        eprintln!("error: {error} (left out)");
    }
    if notes.errors.len() == files.len() {
        return ExitCode::FAILURE;
    }
    let text = if json {
        match serde_json::to_string_pretty(&found) {
            Ok(text) => text + "\n",
            Err(e) => {
                eprintln!("error: {e}");
                return ExitCode::FAILURE;
            }
        }
    } else {
        found.to_string()
    };
    let printed = print_out(&text);
    if printed != ExitCode::SUCCESS {
        return printed;
    }
    if let Some(page) = html {
        if let Err(e) = write_trend_page(&found, page) {
            eprintln!("error: cannot write {}: {e}", page.display());
            return ExitCode::FAILURE;
        }
        eprintln!("wrote {}", page.display());
    }
    ExitCode::SUCCESS
}

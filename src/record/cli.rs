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
    /// Export every record as CSV (one row per record) for a spreadsheet.
    Csv {
        file: PathBuf,
        /// Write to this file instead of stdout.
        #[arg(long)]
        out: Option<PathBuf>,
    },
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
            println!("{}", file.display());
            print!("{}", summary(&rec));
            ExitCode::SUCCESS
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
                Ok(files) => {
                    for f in files {
                        println!("{}", f.display());
                    }
                    ExitCode::SUCCESS
                }
                Err(e) => {
                    eprintln!(
                        "error: cannot write the pictures into {}: {e}",
                        out.display()
                    );
                    ExitCode::FAILURE
                }
            }
        }
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
    }
}

//! The flight record: everything the bridge did and heard, kept on the companion computer.
//!
//! While `run` or `sitl` runs, every goal handed to the buses, every telemetry sample, every
//! health or stall change and every event (STATUSTEXT, bus events) is appended to one file
//! per run, in the compact, versioned, CRC-checked format of [`format`](mod@format). Recording never
//! blocks the bus or MAVLink paths and never loses a record silently; a crash or a power cut
//! loses at most the last ~0.3 s, and a file cut anywhere reads back up to its last whole
//! record. Old files are deleted, oldest first, to keep a configured total size.
//!
//! One file per idea:
//! - [`format`](mod@format): the file format, byte by byte, and its pure encoder and decoder;
//! - [`writer`]: [`Recorder`] and [`RecordHandle`], the non-blocking handle and the writer
//!   thread (batching, sync, drop accounting, file parts);
//! - [`rotate`]: file names and deleting the oldest files;
//! - [`feed`]: [`StatusFeed`], bus statuses and events → records;
//! - [`reader`]: [`read_record`], a file back into a [`Recording`], with notes on damage;
//! - [`analysis`]: [`analysis::ServoFold`], one servo's records folded into its state and
//!   counts (alarms, stalled and offline spans, temperature and current), shared by the summary,
//!   the pictures and the trend;
//! - [`summary`](mod@summary), [`csv`], [`plot`], [`page`]: what `lj9da-bridge record summary|csv|plot`
//!   show;
//! - `svg`: the SVG drawing the pictures and the trend's page share (escaping, ticks, axes,
//!   grid, reference lines, polylines);
//! - [`trend`](mod@trend): each servo's wear across flights, what `lj9da-bridge record trend` shows;
//! - [`parquet`](mod@parquet): flights as Parquet for a fleet's tools, what `lj9da-bridge record
//!   parquet` writes (the only user of the `parquet` crate);
//! - [`ulog`]: a recording as a ULog file (PX4's log format), what `lj9da-bridge record ulog`
//!   writes, for PlotJuggler, Flight Review and `pyulog` beside the autopilot's own log;
//! - [`cli`]: [`RecordCommand`] and [`cli::run`], the `record` subcommand;
//! - `crc` and `clock`: CRC-32 and UTC dates (through `crc32fast` and `time`).
//!
//! # Wiring it into a run
//! ```no_run
//! use lj9da_bridge::bus::Goal;
//! use lj9da_bridge::protocol::MmCenti;
//! use lj9da_bridge::record::{RecordLimits, RecordServo, Recorder, StatusFeed};
//! # fn wire(cfg: &lj9da_bridge::config::Config) -> std::io::Result<()> {
//! let servos = RecordServo::from_config(cfg);
//! let record = Recorder::start("records".as_ref(), &servos, RecordLimits::default())?;
//! // Where the bridge hands a goal to a bus (servo index in mapping order):
//! record.goal(0, Goal::Position(MmCenti(1250)));
//! // Per bus status (as the bus's status observer, or from `BusHandle::watch_status`).
//! let mut feed = StatusFeed::new(record.clone(), &servos);
//! // feed.observe(&status);
//! // Per event the ground station is told: record.bridge_event(&event, servo_name);
//! let stats = record.finish();
//! # let _ = stats; Ok(()) }
//! ```

pub mod analysis;
pub mod cli;
mod clock;
mod crc;
#[cfg(test)]
mod cross_arch;
pub mod csv;
pub mod feed;
pub mod format;
pub mod page;
pub mod parquet;
pub mod plot;
pub mod reader;
pub mod rotate;
pub mod summary;
mod svg;
pub mod trend;
pub mod trend_html;
pub mod ulog;
pub mod writer;

pub use cli::RecordCommand;
pub use clock::{Utc, unix_ns_now};
pub use crc::crc32;
pub use feed::StatusFeed;
pub use format::{Record, RecordBody, RecordHeader, RecordServo};
pub use reader::{RecordError, Recording, Scan, read_record, scan_bytes, scan_record};
pub use summary::{ServoSummary, Summary, summary};
pub use writer::{RecordHandle, RecordLimits, RecordStats, Recorder, RecorderOptions};

use std::path::{Path, PathBuf};

/// The default record folder: `records/` beside the mapping file at `config_path`.
pub fn default_dir(config_path: &Path) -> PathBuf {
    config_path
        .parent()
        .map_or_else(|| PathBuf::from("records"), |p| p.join("records"))
}

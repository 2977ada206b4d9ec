//! The recorder: a handle that never blocks, and a writer thread that owns the file.
//!
//! [`RecordHandle`]'s methods stamp a record with the time and push it into a bounded queue;
//! they never wait, never touch the disk, never wake another thread and never fail. A
//! dedicated thread takes the queued records every 50 ms, encodes them into a buffer, writes
//! the buffer out when it holds 64 KiB and, at least every [`RecorderOptions::sync_interval`]
//! (0.25 s by default) while there is something to write, writes it out and asks the disk to
//! keep it (`File::sync_data`). So a crash or power cut loses at most the last ~0.3 s of
//! records (the interval and one 50 ms drain, plus what the disk takes to sync), and a file
//! cut in the middle of a write reads back up to its last whole record.
//!
//! Nothing is lost silently. When the queue is full (the disk stalls) a record is counted as
//! dropped instead of queued; the writer writes a `dropped` record with the count as soon as
//! it takes the next record. Records that could not be written because the disk failed are
//! counted the same way, and the writer opens a new file (after rotation) every few seconds
//! until it can write again. [`RecordHandle::stats`] keeps the accounts: every record handed
//! to the handle is either written or dropped.
//!
//! Files: one per run in the record directory, named by the UTC time it was opened (see
//! [`super::rotate`]). At start, and whenever a new file is opened, the oldest record files
//! are deleted until the others leave room for a whole new file under `max_total_bytes`. A
//! file that reaches `max_file_bytes` is closed with an end record saying the run continues,
//! and the run goes on in a new file (part 1, 2, …) with the same time base.

use super::clock::unix_ns_now;
use super::format::{
    MAX_SERVOS, NO_SERVO, Record, RecordBody, RecordHeader, RecordServo, encode_header,
    encode_record,
};
use super::rotate::{create_record_file, rotate, sync_dir};
use crate::bus::{Goal, Health};
use crate::mavlink::BridgeEvent;
use crate::protocol::{MmCenti, Motion, ReplyFlags, Telemetry};
use std::fs::File;
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{self, Receiver, SyncSender, TryRecvError, TrySendError};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// How much disk the flight records may use.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RecordLimits {
    /// The most all record files in the directory may take together. Before a file is opened
    /// the oldest are deleted until the others leave room for `max_file_bytes` under it.
    pub max_total_bytes: u64,
    /// A file that reaches this size is closed, and the run continues in a new file.
    pub max_file_bytes: u64,
}

impl RecordLimits {
    /// 512 MiB: about 6 hours of four servos polled at 100 Hz each.
    pub const DEFAULT_TOTAL_BYTES: u64 = 512 << 20;
    /// The smallest file size the writer uses, whatever the limits say.
    pub const MIN_FILE_BYTES: u64 = 4 << 10;
    /// The largest file size [`RecordLimits::with_total`] picks (a file is read whole).
    pub const MAX_FILE_BYTES: u64 = 64 << 20;

    /// Limits for a total size: files of a quarter of it, between 64 KiB and 64 MiB.
    pub fn with_total(max_total_bytes: u64) -> Self {
        RecordLimits {
            max_total_bytes,
            max_file_bytes: (max_total_bytes / 4).clamp(64 << 10, Self::MAX_FILE_BYTES),
        }
    }

    fn file_bytes(&self) -> u64 {
        self.max_file_bytes.max(Self::MIN_FILE_BYTES)
    }

    /// What the other files may take before a new file is opened.
    fn budget_for_others(&self) -> u64 {
        self.max_total_bytes.saturating_sub(self.file_bytes())
    }
}

impl Default for RecordLimits {
    fn default() -> Self {
        Self::with_total(Self::DEFAULT_TOTAL_BYTES)
    }
}

/// How the writer works; the defaults suit the bridge.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecorderOptions {
    /// Records the queue holds before new ones are dropped (counted).
    pub queue_capacity: usize,
    /// The longest a record waits in memory before it is written and synced to the disk.
    pub sync_interval: Duration,
    /// The aircraft the header names (`None`: none).
    pub aircraft: Option<String>,
}

impl Default for RecorderOptions {
    /// 16 384 records (several seconds of a busy bridge), 0.25 s: a power cut loses at most
    /// the last ~0.3 s, within the half second the service promises.
    fn default() -> Self {
        RecorderOptions {
            queue_capacity: 16_384,
            sync_interval: Duration::from_millis(250),
            aircraft: None,
        }
    }
}

/// The recorder's accounts. Every record handed to a [`RecordHandle`] is `accepted` into the
/// queue or `dropped_full`; every accepted record is, once the writer is done with it,
/// `written` (and synced) or `dropped_failed`.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct RecordStats {
    pub accepted: u64,
    /// Dropped because the queue was full.
    pub dropped_full: u64,
    /// Taken from the queue but not written: the disk failed (or the writer had stopped).
    pub dropped_failed: u64,
    /// Written to a file and synced (or handed to the OS, for the last ones before a crash).
    pub written: u64,
    /// Bytes written to files, headers included.
    pub bytes: u64,
    /// The files written, oldest first.
    pub files: Vec<PathBuf>,
    /// The latest write error, if any.
    pub last_error: Option<String>,
}

impl RecordStats {
    pub fn dropped(&self) -> u64 {
        self.dropped_full + self.dropped_failed
    }
}

/// The recorder's entry point.
pub struct Recorder;

impl Recorder {
    /// Start recording a run into a new file in `dir` (created if missing), for the servos of
    /// `servos` (their positions are the servo indices of the handle's methods). Rotates old
    /// files first. Fails if the directory or the file cannot be created or written, or if
    /// there are more than 255 servos.
    pub fn start(
        dir: &Path,
        servos: &[RecordServo],
        limits: RecordLimits,
    ) -> io::Result<RecordHandle> {
        Self::start_with(dir, servos, limits, RecorderOptions::default())
    }

    /// [`Recorder::start`] with other writer options.
    pub fn start_with(
        dir: &Path,
        servos: &[RecordServo],
        limits: RecordLimits,
        options: RecorderOptions,
    ) -> io::Result<RecordHandle> {
        if servos.len() > MAX_SERVOS {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!(
                    "a flight record holds at most {MAX_SERVOS} servos, not {}",
                    servos.len()
                ),
            ));
        }
        std::fs::create_dir_all(dir)?;
        let start = Instant::now();
        let run_start_unix_ns = unix_ns_now();
        let shared = Arc::new(Shared::default());
        let mut writer = Writer {
            dir: dir.to_path_buf(),
            header: RecordHeader::new(run_start_unix_ns, servos.to_vec())
                .with_aircraft(options.aircraft.as_deref()),
            limits,
            start,
            shared: Arc::clone(&shared),
            file: None,
            part_bytes: 0,
            buffer: Vec::with_capacity(BUFFER_BYTES + 2048),
            buffered_records: 0,
            retry_at: None,
            unsynced: false,
        };
        writer.open_part(run_start_unix_ns)?;
        let (tx, rx) = mpsc::sync_channel(options.queue_capacity.max(1));
        let interval = options.sync_interval.max(Duration::from_millis(1));
        let thread = std::thread::Builder::new()
            .name("flight record".into())
            .spawn(move || writer.run(rx, interval))?;
        *lock(&shared.thread) = Some(thread);
        Ok(RecordHandle { tx, shared, start })
    }
}

/// The bytes gathered before they are written out.
const BUFFER_BYTES: usize = 64 << 10;
/// How often the writer takes what is queued (and at least every sync interval).
const DRAIN_PERIOD: Duration = Duration::from_millis(50);
/// How long the writer waits before it opens a new file after a write error.
const RETRY_AFTER_ERROR: Duration = Duration::from_secs(5);

enum Message {
    Record(Record),
    Finish(mpsc::Sender<()>),
}

#[derive(Default)]
struct Shared {
    accepted: AtomicU64,
    dropped_full: AtomicU64,
    dropped_failed: AtomicU64,
    /// Drops not yet told in a `dropped` record.
    unreported: AtomicU64,
    written: AtomicU64,
    bytes: AtomicU64,
    files: Mutex<Vec<PathBuf>>,
    last_error: Mutex<Option<String>>,
    thread: Mutex<Option<JoinHandle<()>>>,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// The running recorder. Cheap to clone and to send to other threads; its recording methods
/// never block. Call [`RecordHandle::finish`] once at the end of the run; if every clone is
/// dropped instead, the writer also closes the file.
#[derive(Clone)]
pub struct RecordHandle {
    tx: SyncSender<Message>,
    shared: Arc<Shared>,
    start: Instant,
}

impl std::fmt::Debug for RecordHandle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RecordHandle")
            .field("start", &self.start)
            .field("stats", &self.stats())
            .finish()
    }
}

impl RecordHandle {
    /// Time 0 of the run's records.
    pub fn start_instant(&self) -> Instant {
        self.start
    }

    /// Record `body` as having happened at `at` (clamped to the run's start). Never blocks.
    pub fn record_at(&self, at: Instant, body: RecordBody) {
        let t_us =
            u64::try_from(at.saturating_duration_since(self.start).as_micros()).unwrap_or(u64::MAX);
        match self.tx.try_send(Message::Record(Record { t_us, body })) {
            Ok(()) => {
                self.shared.accepted.fetch_add(1, Ordering::Relaxed);
            }
            Err(TrySendError::Full(_)) => {
                self.shared.dropped_full.fetch_add(1, Ordering::Relaxed);
                self.shared.unreported.fetch_add(1, Ordering::Relaxed);
            }
            Err(TrySendError::Disconnected(_)) => {
                self.shared.dropped_failed.fetch_add(1, Ordering::Relaxed);
            }
        }
    }

    /// The servo index as recorded, or `None` (counted as dropped) if it cannot be one.
    fn servo_index(&self, servo: usize) -> Option<u8> {
        let index = u8::try_from(servo).ok().filter(|s| *s != NO_SERVO);
        if index.is_none() {
            self.shared.dropped_failed.fetch_add(1, Ordering::Relaxed);
            self.shared.unreported.fetch_add(1, Ordering::Relaxed);
        }
        index
    }

    /// The goal handed to the bus for servo `servo` (its index in the mapping file), now.
    pub fn goal(&self, servo: usize, goal: Goal) {
        self.goal_at(Instant::now(), servo, goal);
    }

    /// As [`RecordHandle::goal`], at `at`.
    pub fn goal_at(&self, at: Instant, servo: usize, goal: Goal) {
        if let Some(servo) = self.servo_index(servo) {
            self.record_at(at, RecordBody::Goal { servo, goal });
        }
    }

    /// The autopilot's boot clock (`time_usec`, from a field of `bits` bits) as an output
    /// message handled at `at` carried it.
    pub fn autopilot_clock(&self, at: Instant, time_usec: u64, bits: u8) {
        self.record_at(at, RecordBody::AutopilotClock { time_usec, bits });
    }

    /// One telemetry reply of servo `servo`, received at `at`.
    pub fn telemetry(&self, at: Instant, servo: usize, telemetry: &Telemetry, flags: ReplyFlags) {
        if let Some(servo) = self.servo_index(servo) {
            self.record_at(
                at,
                RecordBody::Telemetry {
                    servo,
                    telemetry: *telemetry,
                    flags,
                },
            );
        }
    }

    /// One reply of servo `servo`'s position alone (registers 42–43), received at `at`.
    pub fn position(&self, at: Instant, servo: usize, position: MmCenti, flags: ReplyFlags) {
        if let Some(servo) = self.servo_index(servo) {
            self.record_at(
                at,
                RecordBody::Position {
                    servo,
                    position,
                    flags,
                },
            );
        }
    }

    /// One reply of servo `servo`'s position, present time and current (registers 42–49),
    /// received at `at`.
    pub fn motion(&self, at: Instant, servo: usize, motion: Motion, flags: ReplyFlags) {
        if let Some(servo) = self.servo_index(servo) {
            self.record_at(
                at,
                RecordBody::Motion {
                    servo,
                    motion,
                    flags,
                },
            );
        }
    }

    /// Servo `servo`'s reply counts at `at`: requests answered well, and answered garbled or not
    /// at all, since its bus started (saturated at `u32::MAX`).
    pub fn replies(&self, at: Instant, servo: usize, answered: u64, missed: u64) {
        if let Some(servo) = self.servo_index(servo) {
            self.record_at(
                at,
                RecordBody::Replies {
                    servo,
                    answered: u32::try_from(answered).unwrap_or(u32::MAX),
                    missed: u32::try_from(missed).unwrap_or(u32::MAX),
                },
            );
        }
    }

    /// Servo `servo`'s health or stall state, as it became at `at`.
    pub fn health(&self, at: Instant, servo: usize, health: Health, stalled: bool) {
        if let Some(servo) = self.servo_index(servo) {
            self.record_at(
                at,
                RecordBody::Health {
                    servo,
                    health,
                    stalled,
                },
            );
        }
    }

    /// An event now: `servo` is `None` for the bridge as a whole; `severity` is a MAVLink
    /// MAV_SEVERITY (see [`super::format::severity`]). Texts over 1000 bytes are cut.
    pub fn event(&self, servo: Option<usize>, severity: u8, text: impl Into<String>) {
        let servo = match servo {
            None => None,
            Some(s) => match self.servo_index(s) {
                Some(s) => Some(s),
                None => return,
            },
        };
        self.record_at(
            Instant::now(),
            RecordBody::Event {
                servo,
                severity,
                text: text.into(),
            },
        );
    }

    /// A bridge event as the ground station is told it (STATUSTEXT severity and text), now.
    /// `servo_name` names the servo of a servo event.
    pub fn bridge_event(&self, event: &BridgeEvent, servo_name: &str) {
        let (severity, text) = crate::mavlink::statustext::describe(event, servo_name);
        let servo = match event {
            BridgeEvent::Servo { servo, .. } => Some(*servo),
            _ => None,
        };
        self.event(servo, severity as u8, text);
    }

    /// The accounts so far (see [`RecordStats`]).
    pub fn stats(&self) -> RecordStats {
        let s = &self.shared;
        RecordStats {
            accepted: s.accepted.load(Ordering::Relaxed),
            dropped_full: s.dropped_full.load(Ordering::Relaxed),
            dropped_failed: s.dropped_failed.load(Ordering::Relaxed),
            written: s.written.load(Ordering::Relaxed),
            bytes: s.bytes.load(Ordering::Relaxed),
            files: lock(&s.files).clone(),
            last_error: lock(&s.last_error).clone(),
        }
    }

    /// The file being written now.
    pub fn path(&self) -> Option<PathBuf> {
        lock(&self.shared.files).last().cloned()
    }

    /// Write everything queued, close the file with an end record, stop the writer, and
    /// return the accounts. Waits for the writer (call it at the end of a run, not on the bus
    /// or MAVLink paths). Records handed to other clones afterwards are counted as dropped.
    pub fn finish(self) -> RecordStats {
        let (done_tx, done_rx) = mpsc::channel();
        if self.tx.send(Message::Finish(done_tx)).is_ok() {
            if let Some(thread) = lock(&self.shared.thread).as_ref() {
                thread.thread().unpark();
            }
            let _ = done_rx.recv();
        }
        let thread = lock(&self.shared.thread).take();
        if let Some(thread) = thread {
            let _ = thread.join();
        }
        self.stats()
    }
}

/// The writer thread's state.
struct Writer {
    dir: PathBuf,
    header: RecordHeader,
    limits: RecordLimits,
    start: Instant,
    shared: Arc<Shared>,
    /// `None` after a write error, until a new file is opened.
    file: Option<File>,
    part_bytes: u64,
    buffer: Vec<u8>,
    buffered_records: u64,
    /// When to try a new file after a write error.
    retry_at: Option<Instant>,
    /// Whether bytes were written since the last sync.
    unsynced: bool,
}

impl Writer {
    fn run(mut self, rx: Receiver<Message>, interval: Duration) {
        let mut next_sync = Instant::now() + interval;
        loop {
            let mut finish = None;
            loop {
                match rx.try_recv() {
                    Ok(Message::Record(record)) => self.take(record),
                    Ok(Message::Finish(done)) => {
                        finish = Some(Some(done));
                        break;
                    }
                    Err(TryRecvError::Empty) => break,
                    Err(TryRecvError::Disconnected) => {
                        finish = Some(None);
                        break;
                    }
                }
            }
            if let Some(done) = finish {
                self.close();
                if let Some(done) = done {
                    let _ = done.send(());
                }
                return;
            }
            let now = Instant::now();
            if now >= next_sync {
                self.report_drops();
                self.sync();
                if self.file.is_none() && self.retry_at.is_some_and(|t| now >= t) {
                    self.reopen();
                }
                next_sync = now + interval;
            }
            // Senders never wake the writer (a record costs its sender no thread switch);
            // `finish` does.
            std::thread::park_timeout(DRAIN_PERIOD.min(next_sync.saturating_duration_since(now)));
        }
    }

    fn now_us(&self) -> u64 {
        u64::try_from(self.start.elapsed().as_micros()).unwrap_or(u64::MAX)
    }

    /// Encode one record from the queue (after telling of any drops).
    fn take(&mut self, record: Record) {
        self.report_drops();
        if self.file.is_none() {
            self.count_failed(1);
            return;
        }
        self.push(&record, true);
    }

    /// Write a `dropped` record for the drops not yet told, if there are any and a file.
    fn report_drops(&mut self) {
        if self.file.is_none() {
            return;
        }
        let count = self.shared.unreported.swap(0, Ordering::Relaxed);
        if count > 0 {
            let t_us = self.now_us();
            self.push(
                &Record {
                    t_us,
                    body: RecordBody::Dropped { count },
                },
                false,
            );
        }
    }

    /// Encode `record` into the buffer; `handed` says whether it came from a handle (and is
    /// counted in the accounts) or is the writer's own (`dropped`, `end`).
    fn push(&mut self, record: &Record, handed: bool) {
        encode_record(record, &mut self.buffer);
        self.buffered_records += u64::from(handed);
        if self.buffer.len() >= BUFFER_BYTES {
            self.write_out();
        }
        if self.part_bytes + self.buffer.len() as u64 >= self.limits.file_bytes()
            && !matches!(record.body, RecordBody::End { .. })
        {
            self.next_part();
        }
    }

    fn count_failed(&self, n: u64) {
        if n > 0 {
            self.shared.dropped_failed.fetch_add(n, Ordering::Relaxed);
            self.shared.unreported.fetch_add(n, Ordering::Relaxed);
        }
    }

    /// Hand the buffer to the file. On failure its records are counted as dropped and the
    /// file is given up until a new one can be opened.
    fn write_out(&mut self) {
        if self.buffer.is_empty() {
            return;
        }
        let Some(file) = self.file.as_mut() else {
            self.count_failed(self.buffered_records);
            self.buffered_records = 0;
            self.buffer.clear();
            return;
        };
        match file.write_all(&self.buffer) {
            Ok(()) => {
                let n = self.buffer.len() as u64;
                self.part_bytes += n;
                self.shared.bytes.fetch_add(n, Ordering::Relaxed);
                self.shared
                    .written
                    .fetch_add(self.buffered_records, Ordering::Relaxed);
                self.unsynced = true;
            }
            Err(e) => {
                self.count_failed(self.buffered_records);
                self.fail("writing", e);
            }
        }
        self.buffered_records = 0;
        self.buffer.clear();
    }

    /// Write out and make the disk keep it.
    fn sync(&mut self) {
        self.write_out();
        if !self.unsynced {
            return;
        }
        if let Some(file) = &self.file {
            match file.sync_data() {
                Ok(()) => self.unsynced = false,
                Err(e) => self.fail("syncing", e),
            }
        }
    }

    fn fail(&mut self, doing: &str, e: io::Error) {
        let path = self.path();
        let message = format!("{doing} the flight record {} failed: {e}", path.display());
        tracing::error!("{message}; records are counted as dropped until a new file can be opened");
        *lock(&self.shared.last_error) = Some(message);
        self.file = None;
        self.retry_at = Some(Instant::now() + RETRY_AFTER_ERROR);
    }

    fn path(&self) -> PathBuf {
        lock(&self.shared.files).last().cloned().unwrap_or_default()
    }

    /// Rotate, then open the next file and write its header.
    fn open_part(&mut self, unix_ns: i64) -> io::Result<()> {
        if let Err(e) = rotate(&self.dir, self.limits.budget_for_others(), &[]) {
            tracing::warn!(dir = %self.dir.display(), "cannot rotate the flight records: {e}");
        }
        let previous = lock(&self.shared.files).last().cloned();
        let (path, mut file) = create_record_file(&self.dir, unix_ns, previous.as_deref())?;
        self.header.part_start_unix_ns = unix_ns;
        let header = encode_header(&self.header);
        file.write_all(&header)?;
        file.sync_data()?;
        sync_dir(&self.dir);
        tracing::info!(file = %path.display(), part = self.header.part, "flight record open");
        self.shared
            .bytes
            .fetch_add(header.len() as u64, Ordering::Relaxed);
        lock(&self.shared.files).push(path);
        self.part_bytes = header.len() as u64;
        self.file = Some(file);
        self.retry_at = None;
        self.unsynced = false;
        Ok(())
    }

    /// Close this file with an end record saying the run goes on, and open the next part.
    fn next_part(&mut self) {
        let t_us = self.now_us();
        self.push(
            &Record {
                t_us,
                body: RecordBody::End { continued: true },
            },
            false,
        );
        self.sync();
        self.reopen();
    }

    /// Open the next part (after the current one was closed or failed).
    fn reopen(&mut self) {
        self.file = None;
        self.header.part = self.header.part.saturating_add(1);
        if let Err(e) = self.open_part(unix_ns_now()) {
            let message = format!(
                "cannot open a new flight record in {}: {e}",
                self.dir.display()
            );
            tracing::error!("{message}; records are counted as dropped until it can");
            *lock(&self.shared.last_error) = Some(message);
            self.retry_at = Some(Instant::now() + RETRY_AFTER_ERROR);
        }
    }

    /// The end of the run: drops told, end record, out to the disk.
    fn close(&mut self) {
        self.report_drops();
        let t_us = self.now_us();
        if self.file.is_some() {
            encode_record(
                &Record {
                    t_us,
                    body: RecordBody::End { continued: false },
                },
                &mut self.buffer,
            );
        }
        self.sync();
        if let Some(file) = self.file.take() {
            tracing::info!(file = %self.path().display(), "flight record closed");
            drop(file);
        }
    }
}

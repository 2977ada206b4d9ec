//! The thin tokio shell around one [`BusMaster`]: a serial port, a timer, goals in, status and
//! events out.
//!
//! The bus master and the write side of the port sit together behind one mutex (the *core*).
//! Packets that became due are written before the lock is let go: by
//! [`BusHandle::set_goals`] in the caller's thread (the goals of one autopilot message reach the
//! port within one system call, with no thread to wake first), and by the driver task when a
//! reply completes (in the same turn that read its last byte), when a deadline passes, or when
//! [`BusHandle::set_goal`] woke it (goals set one by one meanwhile share one long packet). Order on the wire
//! is the order of the lock; the bus master alone decides what may be sent (never while a reply
//! is pending).
//!
//! The driver task (one per bus) reads the port, keeps the bus master's deadline (a caller wakes
//! it only when that deadline moved), publishes the status (when it changed, at least every
//! 100 ms) and the events, and reopens a port that fails or disappears with back-off
//! (`port_reopen_backoff`, 100 ms doubling to 2 s by default); goals keep being accepted
//! meanwhile.
//!
//! This file must never decide what to send or when: it only carries bytes and time between the
//! port and the bus master. It never panics: a port error is a lost port, a poisoned lock is
//! taken over, a runtime that cannot start is logged.

use super::config::BusConfig;
use super::event::BusEvent;
use super::goal::{Goal, ShutdownForce};
use super::master::BusMaster;
use super::status::BusStatus;
use crate::protocol::{BaudRate, ServoId};
use std::fs::File;
use std::io::Write;
use std::os::fd::{FromRawFd, IntoRawFd};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};
use tokio::io::AsyncReadExt;
use tokio::sync::{Notify, broadcast, watch};
use tokio_serial::{DataBits, FlowControl, Parity, SerialStream, StopBits};

/// Events kept for a slow subscriber before it starts missing them.
const EVENT_CAPACITY: usize = 256;
/// The status is published when it changes, and at least this often (ages grow).
const STATUS_REFRESH: Duration = Duration::from_millis(100);

/// The bus master and the port's write side, changed only together.
struct Core {
    master: BusMaster,
    /// The write side of the open port (`None` while the port is away).
    writer: Option<File>,
    /// Why the last write failed; the driver then treats the port as lost.
    write_error: Option<String>,
    /// The bus master's deadline the driver is sleeping on.
    armed: Option<Instant>,
}

impl Core {
    /// Write every packet the bus master has due now. A write that fails (or would block: the
    /// bus master never queues more than about two frames, so a full output buffer means the
    /// port is stuck) closes the write side and leaves the reason for the driver.
    fn flush(&mut self) {
        let Some(writer) = self.writer.as_mut() else {
            return;
        };
        while let Some(tx) = self.master.poll_transmit(Instant::now()) {
            if let Err(e) = writer.write_all(&tx.bytes) {
                self.write_error = Some(format!("write failed: {e}"));
                self.writer = None;
                return;
            }
        }
    }

    /// Whether the driver must wake up: its deadline moved (e.g. a request now awaits a reply)
    /// or the port failed.
    fn driver_must_wake(&self) -> bool {
        self.write_error.is_some() || self.master.poll_timeout() != self.armed
    }
}

/// What the driver task and every [`BusHandle`] share.
struct Shared {
    core: Mutex<Core>,
    /// Tells the driver that the bus master changed (its deadline may have moved).
    wake: Notify,
}

impl Shared {
    fn core(&self) -> MutexGuard<'_, Core> {
        self.core
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
    }
}

/// Dropped with the last [`BusHandle`]: the bus then shuts down, leaving the servos as they are.
struct Owners {
    shared: Arc<Shared>,
}

impl Drop for Owners {
    fn drop(&mut self) {
        let mut core = self.shared.core();
        core.master.shutdown(ShutdownForce::AsIs);
        core.flush();
        drop(core);
        self.shared.wake.notify_one();
    }
}

/// The rest of the bridge's hold on one running bus: goals in, status and events out. Cheap to
/// clone; the bus keeps running until [`BusHandle::shutdown`] or until every clone is dropped
/// (which leaves the servos as they are).
#[derive(Clone)]
pub struct BusHandle {
    name: String,
    owners: Arc<Owners>,
    status: watch::Receiver<BusStatus>,
    events: broadcast::Sender<BusEvent>,
    finished: watch::Receiver<bool>,
}

impl std::fmt::Debug for BusHandle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BusHandle")
            .field("name", &self.name)
            .field("finished", &self.is_finished())
            .finish()
    }
}

impl BusHandle {
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The newest goal for servo `id`; the driver writes it as soon as it wakes (goals set one
    /// after another meanwhile share one long packet). Ignored after shutdown and for IDs not
    /// on this bus. For the goals of one autopilot message, [`BusHandle::set_goals`] is faster.
    pub fn set_goal(&self, id: ServoId, goal: Goal) {
        let shared = &self.owners.shared;
        shared.core().master.set_goal(id, goal, Instant::now());
        shared.wake.notify_one();
    }

    /// The newest goals of several servos at once (e.g. every channel of one autopilot
    /// message). When no reply is pending and the wire is free, the one long packet carrying
    /// them is written before this returns, from the caller's thread.
    pub fn set_goals(&self, goals: impl IntoIterator<Item = (ServoId, Goal)>) {
        let shared = &self.owners.shared;
        let mut core = shared.core();
        let now = Instant::now();
        for (id, goal) in goals {
            core.master.set_goal(id, goal, now);
        }
        core.flush();
        let wake = core.driver_must_wake();
        drop(core);
        // The write is done; the driver (another thread) is woken only when it must re-arm.
        if wake {
            shared.wake.notify_one();
        }
    }

    /// The latest status the driver published.
    pub fn status(&self) -> BusStatus {
        self.status.borrow().clone()
    }

    /// A receiver that is told about every new status.
    pub fn watch_status(&self) -> watch::Receiver<BusStatus> {
        self.status.clone()
    }

    /// Every event from now on.
    pub fn events(&self) -> broadcast::Receiver<BusEvent> {
        self.events.subscribe()
    }

    /// Stop the bus: wait for a pending reply, write the final packets, let them leave the
    /// wire, close the port. Returns when the driver has stopped.
    pub async fn shutdown(&self, leave: ShutdownForce) {
        let shared = &self.owners.shared;
        {
            let mut core = shared.core();
            core.master.shutdown(leave);
            core.flush();
        }
        shared.wake.notify_one();
        let mut finished = self.finished.clone();
        let _ = finished.wait_for(|done| *done).await;
    }

    /// Whether the driver has stopped.
    pub fn is_finished(&self) -> bool {
        *self.finished.borrow() || self.finished.has_changed().is_err()
    }
}

/// Start a driver for `cfg` on the serial port at `port`. Runs on the current tokio runtime,
/// or on a thread of its own when called outside one.
pub fn spawn_bus(cfg: BusConfig, port: PathBuf) -> BusHandle {
    let name = cfg.name.clone();
    let master = BusMaster::new(cfg, Instant::now());
    let (status_tx, status_rx) = watch::channel(master.status());
    let (event_tx, _) = broadcast::channel(EVENT_CAPACITY);
    let (finished_tx, finished_rx) = watch::channel(false);
    let shared = Arc::new(Shared {
        core: Mutex::new(Core {
            master,
            writer: None,
            write_error: None,
            armed: None,
        }),
        wake: Notify::new(),
    });
    let driver = Driver {
        name: name.clone(),
        shared: Arc::clone(&shared),
        path: port,
        status: status_tx,
        events: event_tx.clone(),
        finished: finished_tx,
        published_at: Instant::now(),
    };
    match tokio::runtime::Handle::try_current() {
        Ok(runtime) => {
            runtime.spawn(driver.run());
        }
        Err(_) => {
            let spawned = std::thread::Builder::new()
                .name(format!("bus {name}"))
                .spawn(move || {
                    match tokio::runtime::Builder::new_current_thread()
                        .enable_all()
                        .build()
                    {
                        Ok(rt) => rt.block_on(driver.run()),
                        Err(e) => tracing::error!("bus driver cannot start a runtime: {e}"),
                    }
                });
            if let Err(e) = spawned {
                tracing::error!("bus driver thread cannot start: {e}");
            }
        }
    }
    BusHandle {
        name,
        owners: Arc::new(Owners { shared }),
        status: status_rx,
        events: event_tx,
        finished: finished_rx,
    }
}

/// Open `path` at `baud`, 8N1, no flow control, not exclusive (a pseudo-terminal in tests):
/// the async read side, and a duplicate of the same open port for plain `write(2)` calls. The
/// write side never waits: the open port is non-blocking (the read side makes it so, and the
/// duplicate shares that setting).
fn open_port(path: &Path, baud: BaudRate) -> Result<(SerialStream, File), tokio_serial::Error> {
    let mut native = tokio_serial::new(path.to_string_lossy(), baud.bits_per_second())
        .data_bits(DataBits::Eight)
        .parity(Parity::None)
        .stop_bits(StopBits::One)
        .flow_control(FlowControl::None)
        .open_native()?;
    let _ = native.set_exclusive(false);
    let duplicate = native.try_clone_native()?;
    // SAFETY: `into_raw_fd` hands over a valid, open descriptor that nothing else owns or
    // closes any more (the duplicate made by `try_clone_native`); the `File` becomes its only
    // owner.
    let writer = unsafe { File::from_raw_fd(duplicate.into_raw_fd()) };
    let reader = SerialStream::try_from(native)?;
    Ok((reader, writer))
}

enum Exit {
    Shutdown,
    PortLost(String),
}

struct Driver {
    name: String,
    shared: Arc<Shared>,
    path: PathBuf,
    status: watch::Sender<BusStatus>,
    events: broadcast::Sender<BusEvent>,
    finished: watch::Sender<bool>,
    published_at: Instant,
}

impl Driver {
    async fn run(mut self) {
        let name = self.name.clone();
        let (baud, reopen) = {
            let core = self.shared.core();
            let cfg = core.master.config();
            (cfg.baud, cfg.port_reopen_backoff)
        };
        let mut backoff = Duration::ZERO;
        loop {
            match open_port(&self.path, baud) {
                Ok((reader, writer)) => {
                    backoff = Duration::ZERO;
                    tracing::info!(bus = %name, port = %self.path.display(), "serial port open at {baud}");
                    {
                        let mut core = self.shared.core();
                        core.master.handle_port_back(Instant::now());
                        core.write_error = None;
                        core.writer = Some(writer);
                    }
                    let exit = self.serve(reader).await;
                    let mut core = self.shared.core();
                    core.writer = None;
                    match exit {
                        Exit::Shutdown => break,
                        Exit::PortLost(reason) => {
                            core.master.handle_port_lost(reason, Instant::now());
                        }
                    }
                }
                Err(e) => {
                    self.shared.core().master.handle_port_lost(
                        format!("cannot open {}: {e}", self.path.display()),
                        Instant::now(),
                    );
                }
            }
            self.publish(false);
            if self.shared.core().master.is_shut_down() || self.shutdown_requested() {
                break;
            }
            backoff = reopen.after(backoff);
            if self.wait_offline(backoff).await {
                break;
            }
        }
        self.publish(true);
        let _ = self.finished.send(true);
    }

    /// A shutdown was asked for (it cannot complete without a port).
    fn shutdown_requested(&self) -> bool {
        self.shared.core().master.shutdown_requested()
    }

    /// Wait `wait` with the port closed, still taking goals. True when a shutdown arrived.
    async fn wait_offline(&mut self, wait: Duration) -> bool {
        let until = tokio::time::Instant::now() + wait;
        loop {
            tokio::select! {
                _ = tokio::time::sleep_until(until) => return false,
                _ = self.shared.wake.notified() => {}
            }
            self.shared.core().master.handle_timeout(Instant::now());
            self.publish(false);
            if self.shutdown_requested() {
                return true;
            }
        }
    }

    /// Publish the status (when it changed, or every [`STATUS_REFRESH`]), then the events:
    /// whoever reacts to an event finds a status at least as new as the event.
    fn publish(&mut self, force: bool) {
        let now = Instant::now();
        let mut events = Vec::new();
        let status = {
            let mut core = self.shared.core();
            while let Some(event) = core.master.poll_event() {
                events.push(event);
            }
            let due = core.master.take_changed()
                || force
                || now.saturating_duration_since(self.published_at) >= STATUS_REFRESH;
            due.then(|| core.master.status_at(now))
        };
        if let Some(status) = status {
            self.published_at = now;
            self.status.send_replace(status);
        }
        for event in events {
            let bus = &self.name;
            match &event {
                BusEvent::ServoOnline { .. }
                | BusEvent::ServoBack { .. }
                | BusEvent::PortBack
                | BusEvent::TemperatureAlarm { on: false, .. }
                | BusEvent::Stalled { on: false, .. } => tracing::info!(bus = %bus, "{event}"),
                _ => tracing::warn!(bus = %bus, "{event}"),
            }
            let _ = self.events.send(event);
        }
    }

    /// Run the bus over an open port until shutdown or until the port fails.
    async fn serve(&mut self, mut port: SerialStream) -> Exit {
        let mut buf = [0u8; 512];
        loop {
            let (deadline, wire_idle_at) = {
                let mut core = self.shared.core();
                core.flush();
                if let Some(reason) = core.write_error.take() {
                    return Exit::PortLost(reason);
                }
                let done = core.master.is_shut_down();
                let deadline = (!done).then(|| core.master.poll_timeout()).flatten();
                core.armed = deadline;
                (deadline, done.then(|| core.master.wire_idle_at()))
            };
            self.publish(false);
            if let Some(idle) = wire_idle_at {
                // Let the final packets leave the wire before the port closes.
                tokio::time::sleep_until(idle.into()).await;
                return Exit::Shutdown;
            }
            // Wake at least every STATUS_REFRESH: goals set by other threads change the status
            // without waking the driver.
            let refresh = tokio::time::Instant::now() + STATUS_REFRESH;
            let sleep_to = deadline
                .map(tokio::time::Instant::from_std)
                .map_or(refresh, |d| d.min(refresh));
            tokio::select! {
                biased;
                read = port.read(&mut buf) => match read {
                    Ok(0) => return Exit::PortLost("end of file".into()),
                    Ok(n) => {
                        let now = Instant::now();
                        let mut core = self.shared.core();
                        core.master.handle_input(buf.get(..n).unwrap_or_default(), now);
                        // A completed reply frees the bus: write what is due in this turn.
                        core.flush();
                    }
                    Err(e) if matches!(e.kind(), std::io::ErrorKind::Interrupted | std::io::ErrorKind::WouldBlock) => {}
                    Err(e) => return Exit::PortLost(format!("read failed: {e}")),
                },
                _ = self.shared.wake.notified() => {}
                _ = tokio::time::sleep_until(sleep_to) => {}
            }
            self.shared.core().master.handle_timeout(Instant::now());
        }
    }
}

//! The thin tokio shell around one [`BusMaster`]: a serial port, a timer, goals in, status and
//! events out.
//!
//! One task per bus. Each turn of its loop writes every packet the bus master has due, then
//! waits for whichever comes first: bytes from the port (a reply is acted on in the same turn
//! that completes it), a new goal (written at once when no reply is pending), or the bus
//! master's deadline. A port that fails or disappears is reopened with back-off
//! (`port_reopen_backoff`, 100 ms doubling to 2 s by default); goals keep being accepted
//! meanwhile.
//!
//! All protocol decisions belong to the bus master; this file must never decide what to send
//! or when, only carry bytes and time between the port and the bus master. It never panics: a
//! port error is a lost port, a closed channel is a shutdown.

use super::config::BusConfig;
use super::event::BusEvent;
use super::goal::{Goal, ShutdownForce};
use super::master::BusMaster;
use super::status::BusStatus;
use crate::protocol::{BaudRate, ServoId};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::sync::{broadcast, mpsc, watch};
use tokio_serial::{DataBits, FlowControl, Parity, SerialStream, StopBits};

/// Events kept for a slow subscriber before it starts missing them.
const EVENT_CAPACITY: usize = 256;
/// The status is published when it changes, and at least this often (ages grow).
const STATUS_REFRESH: Duration = Duration::from_millis(100);

enum Command {
    Goal(ServoId, Goal),
    Shutdown(ShutdownForce),
}

/// The rest of the bridge's hold on one running bus: goals in, status and events out. Cheap to
/// clone; the bus keeps running until [`BusHandle::shutdown`] or until every clone is dropped
/// (which leaves the servos as they are).
#[derive(Debug, Clone)]
pub struct BusHandle {
    name: String,
    commands: mpsc::UnboundedSender<Command>,
    status: watch::Receiver<BusStatus>,
    events: broadcast::Sender<BusEvent>,
    finished: watch::Receiver<bool>,
}

impl std::fmt::Debug for Command {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Command::Goal(id, g) => write!(f, "Goal({id}, {g:?})"),
            Command::Shutdown(l) => write!(f, "Shutdown({l:?})"),
        }
    }
}

impl BusHandle {
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The newest goal for servo `id`; written at once when the bus is free. Ignored after
    /// shutdown and for IDs not on this bus.
    pub fn set_goal(&self, id: ServoId, goal: Goal) {
        let _ = self.commands.send(Command::Goal(id, goal));
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
        let _ = self.commands.send(Command::Shutdown(leave));
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
    let (command_tx, command_rx) = mpsc::unbounded_channel();
    let (status_tx, status_rx) = watch::channel(master.status());
    let (event_tx, _) = broadcast::channel(EVENT_CAPACITY);
    let (finished_tx, finished_rx) = watch::channel(false);
    let driver = Driver {
        master,
        path: port,
        commands: command_rx,
        commands_open: true,
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
            let thread_name = format!("bus {name}");
            let spawned = std::thread::Builder::new()
                .name(thread_name)
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
        commands: command_tx,
        status: status_rx,
        events: event_tx,
        finished: finished_rx,
    }
}

/// Open `path` at `baud`, 8N1, no flow control, not exclusive (a pseudo-terminal in tests).
fn open_port(path: &Path, baud: BaudRate) -> Result<SerialStream, tokio_serial::Error> {
    let builder = tokio_serial::new(path.to_string_lossy(), baud.bits_per_second())
        .data_bits(DataBits::Eight)
        .parity(Parity::None)
        .stop_bits(StopBits::One)
        .flow_control(FlowControl::None);
    #[allow(unused_mut)]
    let mut port = SerialStream::open(&builder)?;
    #[cfg(unix)]
    let _ = port.set_exclusive(false);
    Ok(port)
}

enum Exit {
    Shutdown,
    PortLost(String),
}

struct Driver {
    master: BusMaster,
    path: PathBuf,
    commands: mpsc::UnboundedReceiver<Command>,
    commands_open: bool,
    status: watch::Sender<BusStatus>,
    events: broadcast::Sender<BusEvent>,
    finished: watch::Sender<bool>,
    published_at: Instant,
}

impl Driver {
    async fn run(mut self) {
        let name = self.master.config().name.clone();
        let baud = self.master.config().baud;
        let reopen = self.master.config().port_reopen_backoff;
        let mut backoff = Duration::ZERO;
        loop {
            match open_port(&self.path, baud) {
                Ok(port) => {
                    backoff = Duration::ZERO;
                    tracing::info!(bus = %name, port = %self.path.display(), "serial port open at {baud}");
                    self.master.handle_port_back(Instant::now());
                    match self.serve(port).await {
                        Exit::Shutdown => break,
                        Exit::PortLost(reason) => {
                            self.master.handle_port_lost(reason, Instant::now());
                        }
                    }
                }
                Err(e) => {
                    self.master.handle_port_lost(
                        format!("cannot open {}: {e}", self.path.display()),
                        Instant::now(),
                    );
                }
            }
            self.publish(false);
            if self.shutdown_requested() {
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

    fn shutdown_requested(&self) -> bool {
        self.master.is_shut_down() || !self.commands_open
    }

    /// Wait `wait` with the port closed, still taking goals. True when a shutdown arrived
    /// (nothing can be written without a port, so the driver stops).
    async fn wait_offline(&mut self, wait: Duration) -> bool {
        let until = tokio::time::Instant::now() + wait;
        loop {
            tokio::select! {
                _ = tokio::time::sleep_until(until) => return false,
                cmd = self.commands.recv(), if self.commands_open => {
                    match cmd {
                        Some(Command::Shutdown(leave)) => {
                            self.master.shutdown(leave);
                            return true;
                        }
                        Some(c) => self.apply(c),
                        None => {
                            self.commands_open = false;
                            return true;
                        }
                    }
                }
            }
            self.master.handle_timeout(Instant::now());
            self.publish(false);
        }
    }

    /// Hand every goal waiting in the channel to the bus master.
    fn drain_commands(&mut self) {
        loop {
            match self.commands.try_recv() {
                Ok(c) => self.apply(c),
                Err(mpsc::error::TryRecvError::Empty) => return,
                Err(mpsc::error::TryRecvError::Disconnected) => {
                    if self.commands_open {
                        self.commands_open = false;
                        self.master.shutdown(ShutdownForce::AsIs);
                    }
                    return;
                }
            }
        }
    }

    fn apply(&mut self, command: Command) {
        match command {
            Command::Goal(id, goal) => self.master.set_goal(id, goal, Instant::now()),
            Command::Shutdown(leave) => self.master.shutdown(leave),
        }
    }

    /// Publish the status, then the events: whoever reacts to an event finds a status at
    /// least as new as the event.
    fn publish(&mut self, force: bool) {
        let now = Instant::now();
        if self.master.take_changed()
            || force
            || now.saturating_duration_since(self.published_at) >= STATUS_REFRESH
        {
            self.published_at = now;
            self.status.send_replace(self.master.status_at(now));
        }
        while let Some(event) = self.master.poll_event() {
            let bus = &self.master.config().name;
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
            // Goals that arrived meanwhile (e.g. while the reply just read was on the wire)
            // count before the next packet is chosen.
            self.drain_commands();
            while let Some(tx) = self.master.poll_transmit(Instant::now()) {
                if let Err(e) = port.write_all(&tx.bytes).await {
                    return Exit::PortLost(format!("write failed: {e}"));
                }
            }
            self.publish(false);
            if self.master.is_shut_down() {
                let _ = port.flush().await;
                tokio::time::sleep_until(self.master.wire_idle_at().into()).await;
                return Exit::Shutdown;
            }
            let sleep_to = self
                .master
                .poll_timeout()
                .map(tokio::time::Instant::from_std)
                .unwrap_or_else(|| tokio::time::Instant::now() + Duration::from_secs(3600));
            tokio::select! {
                biased;
                read = port.read(&mut buf) => match read {
                    Ok(0) => return Exit::PortLost("end of file".into()),
                    Ok(n) => {
                        let now = Instant::now();
                        self.master.handle_input(buf.get(..n).unwrap_or_default(), now);
                    }
                    Err(e) if matches!(e.kind(), std::io::ErrorKind::Interrupted | std::io::ErrorKind::WouldBlock) => {}
                    Err(e) => return Exit::PortLost(format!("read failed: {e}")),
                },
                cmd = self.commands.recv(), if self.commands_open => match cmd {
                    Some(c) => self.apply(c),
                    None => {
                        self.commands_open = false;
                        self.master.shutdown(ShutdownForce::AsIs);
                    }
                },
                _ = tokio::time::sleep_until(sleep_to) => {}
            }
            self.master.handle_timeout(Instant::now());
        }
    }
}

//! A running simulated bus: one OS thread per bus, serving a pty or a TCP socket in real time.
//!
//! Timing: tokio timers tick in milliseconds, but one byte at 115 200 bit/s lasts 86.8 µs. The bus thread
//! therefore sleeps in `ppoll(2)` (nanosecond timeout, timer slack lowered to 1 µs) on the host descriptor
//! until the next deadline of the [`BusModel`], and wakes at once when the host writes. Host bytes are
//! stamped with the instant `read()` returned, before anything else is done with them.
//!
//! A thread woken from `ppoll` runs some tens of µs after its timeout on a loaded or virtual machine. The
//! last byte of a reply is what the host waits for, so the thread wakes `SPIN_AHEAD` before it is due
//! and spins until the instant, as a UART would hand it over when its stop bit ends. The first byte of
//! a reply is written at its own instant and the bytes between with the last
//! ([`BusModel::next_wake`]): the host waits for the whole reply, not for each byte, and a wake-up per
//! byte cost the simulator a third of a core for four servos.

pub mod link;
pub mod pty;

use std::io;
use std::net::SocketAddr;
use std::os::fd::AsFd;
use std::os::unix::net::UnixStream;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, Receiver, Sender};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use nix::poll::{PollFd, PollFlags, ppoll};
use nix::sys::time::TimeSpec;

use crate::bus::BusModel;
use crate::config::SimConfig;
use crate::events::{BusEvent, BusStats};
use crate::fault::{Fault, FaultKind};
use crate::servo::ServoSnapshot;
use link::{Link, PtyLink, TcpLink};

/// The bus thread wakes at least this often, even with nothing due.
const HOUSEKEEPING_PERIOD: Duration = Duration::from_millis(20);
/// How early the bus thread wakes to hand over the last byte of a reply on time (see the module docs):
/// above the usual wake-up latency of a virtual machine, and at most about one byte time of spinning per
/// reply.
const SPIN_AHEAD: Duration = Duration::from_micros(100);
/// A write toward the host later than this after its last byte was due is reported
/// ([`BusEvent::HandedLate`]): the host then saw the simulator's lateness, not the model's line.
pub const LATE_REPORT: Duration = Duration::from_micros(200);
/// How long `disconnect_port` / `reconnect_port` wait for the bus thread.
const COMMAND_TIMEOUT: Duration = Duration::from_secs(5);

enum Command {
    Disconnect(Sender<()>),
    Reconnect(Sender<io::Result<PathBuf>>),
}

struct Shared {
    model: Mutex<BusModel>,
    subscribers: Mutex<Vec<Sender<BusEvent>>>,
    commands: Mutex<Vec<Command>>,
    path: Mutex<PathBuf>,
    local_addr: Option<SocketAddr>,
    host_baud_override: Mutex<Option<u32>>,
    stop: AtomicBool,
    waker: UnixStream,
    /// The bus thread's scheduling: 0 not set yet, 1 real-time, 2 refused.
    realtime: std::sync::atomic::AtomicU8,
}

impl Shared {
    fn model(&self) -> MutexGuard<'_, BusModel> {
        self.model
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    fn wake(&self) {
        use std::io::Write;
        let _ = (&self.waker).write(&[1]);
    }
}

fn lock<T>(mutex: &Mutex<T>) -> MutexGuard<'_, T> {
    mutex
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// A running simulated bus. Stops (and removes its symlink) on [`SimBus::shutdown`] or when dropped.
pub struct SimBus {
    shared: Arc<Shared>,
    thread: Option<JoinHandle<()>>,
}

/// A cheap, cloneable handle to a running bus: inspect servos, inject faults, watch events.
#[derive(Clone)]
pub struct SimHandle {
    shared: Arc<Shared>,
}

impl SimBus {
    /// Start a bus on a new pseudo-terminal; open [`SimBus::path`] like a serial port.
    pub fn spawn_pty(config: SimConfig) -> io::Result<SimBus> {
        config
            .validate()
            .map_err(|error| io::Error::new(io::ErrorKind::InvalidInput, error))?;
        let link = PtyLink::open(config.baud, config.link.clone())?;
        Self::spawn(config, Link::Pty(link))
    }

    /// Start a bus serving one TCP client at a time on `addr` (port 0 picks a free port; see
    /// [`SimBus::local_addr`]). TCP has no bit rate: the host is taken to be at the bus's configured rate
    /// unless [`SimHandle::set_host_baud`] says otherwise.
    pub fn spawn_tcp(config: SimConfig, addr: SocketAddr) -> io::Result<SimBus> {
        config
            .validate()
            .map_err(|error| io::Error::new(io::ErrorKind::InvalidInput, error))?;
        let link = TcpLink::bind(addr)?;
        Self::spawn(config, Link::Tcp(link))
    }

    fn spawn(config: SimConfig, link: Link) -> io::Result<SimBus> {
        let (waker, wake_reader) = UnixStream::pair()?;
        waker.set_nonblocking(true)?;
        wake_reader.set_nonblocking(true)?;
        let shared = Arc::new(Shared {
            model: Mutex::new(BusModel::new(&config, Instant::now())),
            subscribers: Mutex::new(Vec::new()),
            commands: Mutex::new(Vec::new()),
            path: Mutex::new(link.path()),
            local_addr: link.local_addr(),
            host_baud_override: Mutex::new(None),
            stop: AtomicBool::new(false),
            waker,
            realtime: std::sync::atomic::AtomicU8::new(0),
        });
        let thread_shared = Arc::clone(&shared);
        let thread = std::thread::Builder::new()
            .name("lj9da-sim-bus".into())
            .spawn(move || run_bus(thread_shared, link, wake_reader))?;
        Ok(SimBus {
            shared,
            thread: Some(thread),
        })
    }

    /// The path a host should open: the symlink if one was asked for, else the pty slave (after
    /// `reconnect_port` without a symlink this changes). For TCP, the listening address.
    /// Whether the simulated bus's thread runs with real-time scheduling: `None` until it has
    /// started, then `Some(false)` where the system refused it.
    pub fn realtime(&self) -> Option<bool> {
        match self.shared.realtime.load(Ordering::SeqCst) {
            0 => None,
            state => Some(state == 1),
        }
    }

    pub fn path(&self) -> PathBuf {
        lock(&self.shared.path).clone()
    }

    /// The TCP address actually bound (`None` for a pty bus).
    pub fn local_addr(&self) -> Option<SocketAddr> {
        self.shared.local_addr
    }

    /// A handle to this bus.
    pub fn handle(&self) -> SimHandle {
        SimHandle {
            shared: Arc::clone(&self.shared),
        }
    }

    /// Stop the bus thread and close the device.
    pub fn shutdown(mut self) {
        self.stop();
    }

    fn stop(&mut self) {
        self.shared.stop.store(true, Ordering::SeqCst);
        self.shared.wake();
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

impl Drop for SimBus {
    fn drop(&mut self) {
        self.stop();
    }
}

impl std::fmt::Debug for SimBus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SimBus")
            .field("path", &self.path())
            .finish()
    }
}

impl std::fmt::Debug for SimHandle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SimHandle")
            .field("path", &lock(&self.shared.path))
            .finish()
    }
}

impl SimHandle {
    fn with_model<T>(&self, action: impl FnOnce(&mut BusModel, Instant) -> T) -> T {
        let result = {
            let mut model = self.shared.model();
            let now = Instant::now();
            action(&mut model, now)
        };
        self.shared.wake();
        result
    }

    /// The current path of the device (see [`SimBus::path`]).
    pub fn path(&self) -> PathBuf {
        lock(&self.shared.path).clone()
    }

    /// State of the servo answering to `id` now (or, if none does, the one configured with `id`).
    pub fn snapshot(&self, id: u8) -> Option<ServoSnapshot> {
        self.with_model(|model, now| model.snapshot(now, id))
    }

    /// State of every servo, in configuration order.
    pub fn snapshots(&self) -> Vec<ServoSnapshot> {
        self.with_model(|model, now| model.snapshots(now))
    }

    /// Inject a fault into servo `id`, or with `None` into every servo / the bus. False if `id` is unknown.
    pub fn inject(&self, id: Option<u8>, fault: Fault) -> bool {
        self.with_model(|model, now| model.inject(now, id, fault))
    }

    /// Remove a fault from servo `id`, or with `None` from every servo and the bus.
    pub fn clear(&self, id: Option<u8>, kind: FaultKind) -> bool {
        self.with_model(|model, now| model.clear(now, id, kind))
    }

    /// Remove every fault and plug every servo back in.
    pub fn clear_all(&self) {
        self.with_model(|model, now| model.clear_all(now));
    }

    /// Unplug a servo: silent, ignores everything.
    pub fn unplug(&self, id: u8) -> bool {
        self.with_model(|model, now| model.unplug(now, id))
    }

    /// Plug a servo back in: power-on state from flash (deaf for 50 ms while it boots).
    pub fn plug(&self, id: u8) -> bool {
        self.with_model(|model, now| model.plug(now, id))
    }

    /// Power a servo off and on: RAM lost, registers from flash, force off.
    pub fn power_cycle(&self, id: u8) -> bool {
        self.with_model(|model, now| model.power_cycle(now, id))
    }

    /// Make the adapter echo every host byte back to the host.
    pub fn set_echo(&self, on: bool) {
        self.with_model(|model, _| model.set_echo(on));
    }

    /// External load opposing servo `id`'s rod, newtons (0 = none).
    pub fn set_load_n(&self, id: u8, newtons: f32) -> bool {
        self.with_model(|model, now| model.set_load_n(now, id, newtons))
    }

    /// Wear servo `id`: friction current in proportion to its speed, a stiff spot over part of
    /// its stroke (`Wear::default()`: a new servo again).
    pub fn set_wear(&self, id: u8, wear: crate::servo::physics::Wear) -> bool {
        self.with_model(|model, now| model.set_wear(now, id, wear))
    }

    /// Block servo `id`'s rod (or free it).
    pub fn set_stalled(&self, id: u8, stalled: bool) -> bool {
        self.with_model(|model, now| model.set_stalled(now, id, stalled))
    }

    /// Make servo `id` heat up quickly until `clear(Some(id), FaultKind::Overheat)`.
    pub fn overheat(&self, id: u8) -> bool {
        self.with_model(|model, now| model.overheat(now, id))
    }

    /// Registers 0–1 of servo `id` report `model_number`.
    pub fn set_model_number(&self, id: u8, model_number: u16) -> bool {
        self.with_model(|model, now| model.set_model_number(now, id, model_number))
    }

    /// Supply voltage of servo `id` or (with `None`) of every servo.
    pub fn set_voltage(&self, id: Option<u8>, voltage_v: f32) -> bool {
        self.with_model(|model, now| model.set_voltage_v(now, id, voltage_v))
    }

    /// Ambient temperature of servo `id` or (with `None`) of every servo.
    pub fn set_ambient(&self, id: Option<u8>, ambient_c: f32) -> bool {
        self.with_model(|model, now| model.set_ambient_c(now, id, ambient_c))
    }

    /// Set servo `id`'s temperature now (it then follows the heat model again).
    pub fn set_temperature(&self, id: u8, temperature_c: f32) -> bool {
        self.with_model(|model, now| model.set_temperature_c(now, id, temperature_c))
    }

    /// Move servo `id`'s rod by hand to a physical position, mm.
    pub fn move_rod(&self, id: u8, position_mm: f32) -> bool {
        self.with_model(|model, now| model.move_rod(now, id, position_mm))
    }

    /// Override the host's bit rate (`None`: read it from the pty; for TCP, the configured rate).
    pub fn set_host_baud(&self, baud: Option<u32>) {
        *lock(&self.shared.host_baud_override) = baud;
        self.shared.wake();
    }

    /// The device disappears: the pty is closed (the host reads EOF/EIO) and the symlink removed; for TCP
    /// the client and the listener are closed. Waits until done.
    pub fn disconnect_port(&self) {
        let (done, wait) = mpsc::channel();
        self.send_command(Command::Disconnect(done));
        let _ = wait.recv_timeout(COMMAND_TIMEOUT);
    }

    /// The device reappears (a new pty; the symlink points at it). Errors are logged; see
    /// [`SimHandle::try_reconnect_port`] to get them.
    pub fn reconnect_port(&self) {
        if let Err(error) = self.try_reconnect_port() {
            tracing::error!(%error, "could not recreate the simulated serial device");
        }
    }

    /// The device reappears; returns the path to open.
    pub fn try_reconnect_port(&self) -> io::Result<PathBuf> {
        let (done, wait) = mpsc::channel();
        self.send_command(Command::Reconnect(done));
        wait.recv_timeout(COMMAND_TIMEOUT).map_err(|_| {
            io::Error::new(
                io::ErrorKind::TimedOut,
                "the simulated bus thread did not answer",
            )
        })?
    }

    fn send_command(&self, command: Command) {
        lock(&self.shared.commands).push(command);
        self.shared.wake();
    }

    /// Every event from now on (host packets, bad sums, garbage, replies, collisions, damage, …). Drop the
    /// receiver to unsubscribe.
    pub fn subscribe(&self) -> Receiver<BusEvent> {
        let (sender, receiver) = mpsc::channel();
        lock(&self.shared.subscribers).push(sender);
        receiver
    }

    /// Running counters.
    pub fn stats(&self) -> BusStats {
        self.shared.model().stats()
    }
}

/// The bus thread.
fn run_bus(shared: Arc<Shared>, mut link: Link, wake_reader: UnixStream) {
    // Precise sleeps: the default 50 µs timer slack is more than half a byte time at 115 200 bit/s.
    // SAFETY: PR_SET_TIMERSLACK takes an integer argument and only affects the calling thread.
    unsafe {
        libc::prctl(
            libc::PR_SET_TIMERSLACK,
            1_000 as libc::c_ulong,
            0 as libc::c_ulong,
            0 as libc::c_ulong,
            0 as libc::c_ulong,
        );
    }
    let realtime = request_realtime();
    if !realtime {
        request_short_slice();
    }
    shared
        .realtime
        .store(if realtime { 1 } else { 2 }, Ordering::SeqCst);
    let mut buffer = vec![0u8; 4096];
    let mut wake_buffer = [0u8; 64];
    while !shared.stop.load(Ordering::SeqCst) {
        run_commands(&shared, &mut link);

        let now = Instant::now();
        let (deadline, reply_ends) = {
            let model = shared.model();
            (model.next_wake(), model.reply_end_due())
        };
        let wake_at = reply_ends.map_or(deadline, |at| at.checked_sub(SPIN_AHEAD));
        let timeout = wake_at.map_or(HOUSEKEEPING_PERIOD, |at| at.saturating_duration_since(now));
        let timeout = timeout.min(HOUSEKEEPING_PERIOD);
        let mut input = false;
        if !timeout.is_zero() {
            let mut fds = vec![PollFd::new(wake_reader.as_fd(), PollFlags::POLLIN)];
            if let Some(fd) = link.poll_fd() {
                fds.push(PollFd::new(fd, PollFlags::POLLIN));
            }
            input = ppoll(&mut fds, Some(TimeSpec::from_duration(timeout)), None)
                .is_ok_and(|ready| ready > 0);
        }
        // Spin only inside the last SPIN_AHEAD: a ppoll that ended at the housekeeping period
        // (a reply due after a long return delay) goes round the loop again.
        if let Some(at) = reply_ends
            && !input
            && at.saturating_duration_since(Instant::now()) <= SPIN_AHEAD
        {
            while Instant::now() < at {
                std::hint::spin_loop();
            }
        }
        {
            use std::io::Read;
            while matches!((&wake_reader).read(&mut wake_buffer), Ok(n) if n > 0) {}
        }

        let baud_override = *lock(&shared.host_baud_override);
        let is_tcp = link.local_addr().is_some();
        let mut chunks: Vec<(Instant, Vec<u8>)> = Vec::new();
        link.read_available(&mut buffer, |read_at, bytes| {
            chunks.push((read_at, bytes.to_vec()))
        });
        let host_baud = baud_override.or_else(|| if is_tcp { None } else { link.host_baud() });

        let now = Instant::now();
        let (transmit, mut events) = {
            let mut model = shared.model();
            let host_baud = host_baud.or_else(|| is_tcp.then(|| model.default_baud()));
            for (read_at, bytes) in &chunks {
                model.receive(*read_at, bytes, host_baud);
            }
            model.observe_host_baud(host_baud);
            model.advance(now);
            (model.poll_transmit(now), model.drain_events())
        };
        if !transmit.is_empty() {
            let bytes: Vec<u8> = transmit.iter().map(|tx| tx.byte).collect();
            link.write(&bytes);
            let handed_at = Instant::now();
            if let Some(due) = transmit.last().map(|tx| tx.at)
                && handed_at.saturating_duration_since(due) > LATE_REPORT
            {
                let mut model = shared.model();
                model.record_late_handover(due, handed_at, bytes.len());
                events.extend(model.drain_events());
            }
        }
        for event in &events {
            tracing::debug!(?event, "bus");
        }
        if !events.is_empty() {
            let mut subscribers = lock(&shared.subscribers);
            subscribers.retain(|subscriber| {
                events
                    .iter()
                    .all(|event| subscriber.send(event.clone()).is_ok())
            });
        }
    }
    link.close();
}

/// The real-time priority the simulated bus asks for (SCHED_FIFO): modest, above every normal
/// thread, below the kernel's own real-time threads.
pub const REALTIME_PRIORITY: i32 = 10;

/// Ask for real-time scheduling (SCHED_FIFO at [`REALTIME_PRIORITY`]) so that the simulated
/// servos answer on time beside busy programs; false where the system refuses it (no
/// CAP_SYS_NICE, no RLIMIT_RTPRIO). The thread sleeps between bytes and spins only within
/// 100 µs of one, so it never holds a core for long.
fn request_realtime() -> bool {
    let result = lj9da_realtime::request_fifo(REALTIME_PRIORITY);
    if let Err(error) = &result {
        tracing::debug!(%error, "no real-time scheduling for the simulated bus");
    }
    result.is_ok()
}

/// Ask Linux (≥ 6.12, EEVDF) to run the bus thread in 100 µs slices, so that when it wakes for a
/// byte it may preempt a thread running a longer slice instead of waiting for that slice to end.
/// Unprivileged; older kernels refuse it and nothing else changes. The thread's nice value is
/// set to 0 with it.
fn request_short_slice() {
    if let Err(error) = lj9da_realtime::request_slice(Duration::from_micros(100), 0) {
        tracing::debug!(%error, "scheduler slice stays at its default");
    }
}

fn run_commands(shared: &Shared, link: &mut Link) {
    let commands: Vec<Command> = lock(&shared.commands).drain(..).collect();
    for command in commands {
        match command {
            Command::Disconnect(done) => {
                link.disconnect();
                shared.model().reset_link();
                let _ = done.send(());
            }
            Command::Reconnect(done) => {
                let result = link.reconnect();
                if let Ok(path) = &result {
                    *lock(&shared.path) = path.clone();
                }
                let _ = done.send(result);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn assert_shareable<T: Send + Sync + Clone + 'static>() {}
    fn assert_sendable<T: Send + 'static>() {}

    #[test]
    fn the_handle_can_be_shared_between_threads_and_the_bus_moved() {
        assert_shareable::<SimHandle>();
        assert_sendable::<SimBus>();
        assert_sendable::<BusEvent>();
    }

    #[test]
    fn an_invalid_config_is_refused_before_anything_starts() {
        let error = SimBus::spawn_pty(SimConfig {
            ids: vec![],
            ..SimConfig::default()
        })
        .unwrap_err();
        assert_eq!(error.kind(), io::ErrorKind::InvalidInput);
        assert!(error.to_string().contains("no servos"));
    }
}

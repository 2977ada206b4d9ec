//! The thin shell around one [`BusMaster`]: a serial port, a clock, goals in, status and events
//! out. One OS thread per bus.
//!
//! The bus master and the port sit together behind one mutex (the *core*). Packets that became
//! due are written before the lock is let go: by [`BusHandle::output_message`] in the caller's
//! thread (the goals of one autopilot message reach the port within one system call, with no
//! thread to wake first), and by the bus thread when a reply completes, when a deadline
//! passes, or when [`BusHandle::set_goal`] woke it (goals set one by one meanwhile share one
//! long packet). Order on the wire is the order of the lock; the bus master alone decides what
//! may be sent (never while a reply is pending). A caller whose writes make the bus master's
//! next deadline come sooner (a request written behind the frame, whose reply is to be read)
//! sets the bus thread's timer (a timerfd) instead of waking it; the thread wakes once, then.
//!
//! The bus thread reads the port when the bus master says a reply should be there, not on every
//! byte: it sleeps until the bus master's next deadline or until the awaited reply should be
//! (nearly) whole ([`BusMaster::reply_look_at`]), reads whatever has arrived without blocking (the
//! tty may hold that read until bytes its kernel worker has queued are passed on; the count of
//! bytes it held before the read then tells the bus master that the look came early, see
//! [`BusMaster::note_reply_incomplete`]), and if part of the reply is still missing, waits on the
//! port with the tty's read threshold (termios `VMIN`) set to the bytes missing
//! ([`BusMaster::bytes_awaited`]), so the kernel wakes it once they are all in. A reply costs about
//! one wake-up, not one per byte (at 115 200 bit/s a telemetry reply is 26 bytes; the bridge's CPU
//! time is mostly wake-ups). The port is in no event loop, so bytes arriving otherwise wake nothing
//! (a tty wakes whoever polls it at every chunk it receives, whatever the threshold). The thread
//! also publishes the status (when it changed, at least every 100 ms) and the events, and reopens a
//! port that fails or disappears with back-off (`port_reopen_backoff`, 100 ms doubling to 2 s by
//! default); goals keep being accepted meanwhile. A port that fails while idle is noticed within
//! 100 ms (the thread reads at least that often).
//!
//! The thread goes round its loop at least every 100 ms, port open or not, and counts its turns
//! ([`BusHandle::turns`]): the service's watchdog is fed only while every bus thread turns.
//!
//! This file must never decide what to send or when: it only carries bytes and time between the
//! port and the bus master. It never panics: a port error is a lost port, a poisoned lock is
//! taken over, a thread that cannot start is logged.

mod port;
mod realtime;

use super::config::BusConfig;
use super::event::BusEvent;
use super::goal::{Goal, ShutdownForce};
use super::master::BusMaster;
use super::status::{BusStatus, ThreadUsage};
use crate::protocol::ServoId;
use crate::serial::rs485::Rs485Request;
use nix::poll::{PollFd, PollFlags, ppoll};
use nix::sys::eventfd::{EfdFlags, EventFd};
use nix::sys::termios::tcdrain;
use nix::sys::time::TimeSpec;
use nix::sys::timer::{Expiration, TimerSetTimeFlags};
use nix::sys::timerfd::{ClockId, TimerFd, TimerFlags};
use port::{ReplyWaiter, Waited, bytes_in, open_port};
pub use realtime::{REALTIME_PRIORITY, lock_memory};
use realtime::{request_realtime, request_short_slice, warn_not_realtime};
use std::fs::File;
use std::io::{Read, Write};
use std::os::fd::AsFd;
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};
use tokio::sync::{broadcast, watch};

/// Events kept for a slow subscriber before it starts missing them.
const EVENT_CAPACITY: usize = 256;
/// The status is published when it changes, and at least this often (ages grow). The port is
/// read at least this often too.
const STATUS_REFRESH: Duration = Duration::from_millis(100);
/// Timer slack of the bus thread: the default 50 µs is more than half a byte time at
/// 115 200 bit/s.
const TIMER_SLACK_NS: u64 = 1_000;

/// A wake-up this long after the instant slept until is counted as late
/// ([`super::BusCounters::late_wakeups`]).
const LATE_WAKEUP: Duration = Duration::from_micros(500);

/// When the bytes a reply still misses take at most this long on the wire, the bus thread
/// reads the port in a loop for them instead of sleeping until the kernel wakes it: a wake-up
/// costs some tens of µs, a byte at 460 800 bit/s lasts 22 µs. At 115 200 bit/s (87 µs a
/// byte) it always sleeps.
const SPIN_LIMIT: Duration = Duration::from_micros(50);

/// How the bus thread waits for the last bytes of a reply.
struct ReplyWait {
    bytes: usize,
    deadline: Instant,
    spin: bool,
}

/// Called in the bus thread with every status it publishes (see [`spawn_bus_observed`]).
pub type StatusObserver = Box<dyn FnMut(&BusStatus) + Send>;

/// The bus master and the port, changed only together.
struct Core {
    master: BusMaster,
    /// The open port, read and written without blocking (`None` while the port is away).
    port: Option<File>,
    /// Why the last write failed; the bus thread then treats the port as lost.
    write_error: Option<String>,
    /// The instant the bus thread next looks at the bus master unless the bell wakes it
    /// first: the end of its own wait, or [`Wakers::timer`] where another thread brought it
    /// forward. `None` from a wake-up until the thread has looked at the bus master again.
    armed: Option<Instant>,
    /// The end of the bus thread's own wait (`None` with `armed`): the timer can bring a
    /// look forward of it, never push one past it.
    waits_until: Option<Instant>,
    /// [`Wakers::timer`] is set (by a thread that wrote and moved `armed`).
    timer_set: bool,
    late_wakeups: LateWakeups,
}

/// Late wake-ups of the bus thread, for the operator: the first one is a warning, the ones
/// after it are only counted ([`super::BusCounters::late_wakeups`], shown in the bus row of
/// the live view) and logged at debug level. On a busy computer they come by the thousand; a
/// warning for each, or a summary every minute, would bury the other lines of the log.
#[derive(Debug, Default)]
struct LateWakeups {
    warned: bool,
}

impl LateWakeups {
    /// A wake-up `late`: the warning to give now, if any.
    fn note(&mut self, late: Duration) -> Option<String> {
        if std::mem::replace(&mut self.warned, true) {
            return None;
        }
        Some(format!(
            "bus thread woke {:.1} ms late: the computer did not run it in time, and a goal may \
             have waited as long (said once; later ones are only counted)",
            late.as_secs_f64() * 1e3
        ))
    }
}

impl Core {
    /// Write every packet the bus master has due now, in one write (a tick's frame and the
    /// read behind it cost one system call, and leave back to back). A write that fails (or
    /// would block: the bus master never queues more than about two frames, so a full output
    /// buffer means the port is stuck) closes the port and leaves the reason for the bus
    /// thread.
    fn flush(&mut self) {
        let Some(port) = self.port.as_mut() else {
            return;
        };
        let mut due: Option<Vec<u8>> = None;
        while let Some(tx) = self.master.poll_transmit(Instant::now()) {
            // The bytes cannot start on the wire before the write does (a few microseconds
            // after this, for every packet of the write).
            self.master.handle_written(Instant::now());
            match due.as_mut() {
                None => due = Some(tx.bytes),
                Some(bytes) => bytes.extend_from_slice(&tx.bytes),
            }
        }
        if let Some(bytes) = due
            && let Err(e) = port.write_all(&bytes)
        {
            self.write_error = Some(format!("write failed: {e}"));
            self.port = None;
        }
    }

    /// Read everything that has arrived and hand it to the bus master, with the instant each
    /// read returned. `Err` when the port failed (end of file: the other side hung up; or an
    /// error other than "would block").
    fn read_input(&mut self, buf: &mut [u8]) -> Result<(), String> {
        let Some(port) = self.port.as_mut() else {
            return Ok(());
        };
        // A first look at an awaited reply that finds fewer of its bytes than it misses came
        // early, even when the read below waits for the kernel's worker to pass them on. (Later
        // reads of the same reply, after the wait for its last bytes, need not ask.)
        if let Some(missing) = self.master.bytes_awaited_at_first_look()
            && bytes_in(port).is_some_and(|held| held < missing)
        {
            self.master.note_reply_incomplete();
        }
        loop {
            match port.read(buf) {
                Ok(0) => return Err("end of file".into()),
                Ok(n) => {
                    self.master
                        .handle_input(buf.get(..n).unwrap_or_default(), Instant::now());
                    if n < buf.len() {
                        // The tty had no more (a later byte is read at the next look).
                        return Ok(());
                    }
                }
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => return Ok(()),
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(format!("read failed: {e}")),
            }
        }
    }

    /// The bus thread ran `late` after the instant it slept until: counted, logged at debug
    /// level (with the instant, for whoever lines it up with the traffic), and told to the
    /// operator as a warning the first time ([`LateWakeups`]).
    fn late_wakeup(&mut self, late: Duration) {
        self.master.note_late_wakeup();
        let bus = &self.master.config().name;
        tracing::debug!(
            bus = %bus,
            late_us = u64::try_from(late.as_micros()).unwrap_or(u64::MAX),
            "bus thread woke late"
        );
        if let Some(warning) = self.late_wakeups.note(late) {
            tracing::warn!(bus = %bus, "{warning}");
        }
    }

    /// After another thread wrote: whether the bus thread must be woken now (the port failed).
    /// Otherwise the bus thread is left asleep, and the timer set so that it wakes at the bus
    /// master's next deadline (or the look at a reply it now awaits), not before:
    /// - a deadline before the instant armed brings the wake-up forward;
    /// - a deadline after it pushes back a wake-up that an earlier write brought forward (a
    ///   tick's first message opens a window for the rest of its goals; the message that
    ///   closes it writes the frame, and the thread then has nothing to do before the look at
    ///   the reply), up to the end of the thread's own wait.
    ///
    /// (A goal's frame is written by the caller; waking the thread as well would take a CPU
    /// from the simulator, or the kernel's tty worker, that should pass the frame on.)
    fn after_write(&mut self, timer: &TimerFd) -> bool {
        if self.write_error.is_some() {
            return true;
        }
        let (Some(armed), Some(own)) = (self.armed, self.waits_until) else {
            // Awake: the thread looks at the bus master before it sleeps again.
            return false;
        };
        let next = [self.master.poll_timeout(), self.master.reply_look_at()]
            .into_iter()
            .flatten()
            .min();
        let (set, armed) = match rearm(armed, own, next) {
            Rearm::Keep => return false,
            Rearm::Set(at) => {
                // A zero expiry would disarm the timer.
                let left = at.saturating_duration_since(Instant::now());
                let left = TimeSpec::from_duration(left.max(Duration::from_nanos(1)));
                let set = timer.set(Expiration::OneShot(left), TimerSetTimeFlags::empty());
                (set, at)
            }
            Rearm::Unset => (timer.unset(), own),
        };
        if set.is_err() {
            // Never seen; the bell does the timer's work, a wake-up sooner.
            return true;
        }
        self.armed = Some(armed);
        self.timer_set = armed < own;
        false
    }

    /// The bus thread is about to wait until `until`: armed for it, or for the earlier instant
    /// another thread's timer keeps.
    fn arm(&mut self, until: Instant) {
        self.waits_until = Some(until);
        self.armed = Some(self.armed.map_or(until, |armed| armed.min(until)));
    }

    /// The bus thread woke: the instant it was armed for.
    fn woke(&mut self) -> Option<Instant> {
        self.waits_until = None;
        self.armed.take()
    }
}

/// What a write does to the timer of the sleeping bus thread ([`Core::after_write`]).
#[derive(Debug, PartialEq)]
enum Rearm {
    /// The thread wakes when it should already.
    Keep,
    /// Set the timer to fire then.
    Set(Instant),
    /// Unset the timer: the thread's own wait ends first.
    Unset,
}

/// The thread sleeps until `armed` (its own wait ends at `own`; the timer is set exactly when
/// `armed` is before `own`), and the bus master's next deadline is now `next`: wake it then,
/// never after `own`, and never just because a deadline an earlier write brought forward has
/// gone.
fn rearm(armed: Instant, own: Instant, next: Option<Instant>) -> Rearm {
    let next = next.map_or(own, |next| next.min(own));
    if next == armed {
        Rearm::Keep
    } else if next < own {
        Rearm::Set(next)
    } else {
        Rearm::Unset
    }
}

/// What the bus thread and every [`BusHandle`] share.
struct Shared {
    core: Mutex<Core>,
    /// The bus thread's wake-ups (`None`: they could not be made, and the thread never ran).
    wakers: Option<Wakers>,
    /// Turns of the bus thread's loops since its first attempt to open the port (0 before):
    /// the evidence that the thread runs (see [`BusHandle::turns`]).
    turns: AtomicU64,
}

/// What ends the bus thread's wait besides the port, without the core.
struct Wakers {
    /// Rung when the bus thread must look at once (a goal set alone, a shutdown, a failed
    /// write): an eventfd.
    bell: EventFd,
    /// Fires at [`Core::armed`] when a thread that wrote brought it forward: a timerfd, set
    /// without waking the bus thread.
    timer: TimerFd,
}

impl Wakers {
    fn new() -> nix::Result<Self> {
        Ok(Wakers {
            bell: EventFd::from_flags(EfdFlags::EFD_NONBLOCK | EfdFlags::EFD_CLOEXEC)?,
            timer: TimerFd::new(
                ClockId::CLOCK_MONOTONIC,
                TimerFlags::TFD_NONBLOCK | TimerFlags::TFD_CLOEXEC,
            )?,
        })
    }
}

impl Shared {
    fn core(&self) -> MutexGuard<'_, Core> {
        self.core
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    /// Wake the bus thread, letting go of the core it is handed.
    fn ring(&self, core: MutexGuard<'_, Core>) {
        drop(core);
        if let Some(wakers) = &self.wakers {
            // An eventfd write fails only when its counter would overflow: it is rung already.
            let _ = wakers.bell.write(1);
        }
    }

    /// After another thread wrote: ring the bell when the port failed, otherwise see that the
    /// bus thread looks in time without waking it now ([`Core::after_write`]).
    fn after_write(&self, mut core: MutexGuard<'_, Core>) {
        let Some(wakers) = &self.wakers else {
            return;
        };
        if core.after_write(&wakers.timer) {
            self.ring(core);
        }
    }

    /// Sleep until `until` (or the instant a thread that wrote armed the timer for), until the
    /// bell rings or until the timer fires; returns the core locked again (it is not held
    /// meanwhile). A wake-up more than [`LATE_WAKEUP`] after the instant armed is counted.
    fn sleep<'a>(
        &'a self,
        wakers: &Wakers,
        mut core: MutexGuard<'a, Core>,
        until: Instant,
    ) -> MutexGuard<'a, Core> {
        // A timer set since `until` was chosen fires before it (a write pushing it past
        // `until` unsets it); the thread's own wait ends at `until`, so that a later write can
        // still push the timer back.
        core.arm(until);
        drop(core);
        let mut fds = [
            PollFd::new(wakers.bell.as_fd(), PollFlags::POLLIN),
            PollFd::new(wakers.timer.as_fd(), PollFlags::POLLIN),
        ];
        let mut rung = false;
        let mut slept = false;
        if let Some(left) = until
            .checked_duration_since(Instant::now())
            .filter(|d| !d.is_zero())
        {
            slept = true;
            let _ = ppoll(&mut fds, Some(TimeSpec::from_duration(left)), None);
            rung = fds[0].revents().is_some_and(|r| !r.is_empty());
            if rung {
                let _ = wakers.bell.read();
            }
        }
        let now = Instant::now();
        let mut core = self.core();
        // Awake: the thread looks at the bus master before it sleeps again.
        let armed = core.woke().unwrap_or(until);
        let late = now.saturating_duration_since(armed);
        if slept && !rung && late > LATE_WAKEUP {
            core.late_wakeup(late);
        }
        core
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
        self.shared.ring(core);
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
    /// A subscription made before the thread started, for the first caller of
    /// [`BusHandle::events`] (of any clone): a port refused at once is reported before anyone
    /// could subscribe.
    first_events: Arc<Mutex<Option<broadcast::Receiver<BusEvent>>>>,
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

    /// The newest goal for servo `id`; the bus thread writes it as soon as it wakes (goals set
    /// one after another meanwhile share one long packet). Ignored after shutdown and for IDs
    /// not on this bus. It is no tick of the autopilot's rhythm: the goals of an autopilot
    /// message go through [`BusHandle::output_message`], which is also faster.
    pub fn set_goal(&self, id: ServoId, goal: Goal) {
        let shared = &self.owners.shared;
        let mut core = shared.core();
        core.master.set_goal(id, goal, Instant::now());
        shared.ring(core);
    }

    /// One output message of the autopilot arrived, with the goals it changed (none when it
    /// repeated the last ones: it is still a tick of the autopilot's rhythm). When no reply is
    /// pending, the wire is free and no message of the same tick is expected within a frame's
    /// time, the one long packet carrying the goals is written before this returns, from the
    /// caller's thread.
    pub fn output_message(&self, goals: impl IntoIterator<Item = (ServoId, Goal)>) {
        self.write_goals(true, goals);
    }

    /// The newest goals of several servos at once that no autopilot message brought (a
    /// failsafe position, a parameter change), written like [`BusHandle::output_message`]'s.
    pub fn set_goals(&self, goals: impl IntoIterator<Item = (ServoId, Goal)>) {
        self.write_goals(false, goals);
    }

    fn write_goals(&self, output_message: bool, goals: impl IntoIterator<Item = (ServoId, Goal)>) {
        self.pass_goals([(output_message, goals)]);
    }

    /// Several batches of goals that arrived together, in order, under one lock: each is an
    /// autopilot output message (`true`, as [`BusHandle::output_message`]) or goals no message
    /// brought (`false`, as [`BusHandle::set_goals`]). What each makes due is written before
    /// the next is taken (a request due soon goes out behind the tick's long packet); then,
    /// when the bus master's next deadline came sooner, the bus thread's timer is set to it,
    /// and the thread is woken only when the port failed.
    pub fn pass_goals<G>(&self, batches: impl IntoIterator<Item = (bool, G)>)
    where
        G: IntoIterator<Item = (ServoId, Goal)>,
    {
        let shared = &self.owners.shared;
        let mut core = shared.core();
        for (output_message, goals) in batches {
            let now = Instant::now();
            if output_message {
                core.master.output_message(now);
            }
            for (id, goal) in goals {
                core.master.set_goal(id, goal, now);
            }
            core.flush();
        }
        // The writes are done; the bus thread is woken only when the port failed.
        shared.after_write(core);
    }

    /// How many turns the bus thread has made through its loops since it first tried to open
    /// the port: 0 until that first attempt is over (the port opened or was found missing).
    /// A running thread turns at least every 100 ms, port open or not; a count that stands
    /// still means a thread that is stuck (or has stopped after a shutdown).
    pub fn turns(&self) -> u64 {
        self.owners.shared.turns.load(Ordering::Relaxed)
    }

    /// The latest status the bus thread published.
    pub fn status(&self) -> BusStatus {
        self.status.borrow().clone()
    }

    /// A receiver that is told about every new status.
    pub fn watch_status(&self) -> watch::Receiver<BusStatus> {
        self.status.clone()
    }

    /// Every event: the first call since the bus started (the thread may have reported a
    /// refused port already), later calls from then on.
    pub fn events(&self) -> broadcast::Receiver<BusEvent> {
        let first = self
            .first_events
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .take();
        first.unwrap_or_else(|| self.events.subscribe())
    }

    /// Stop the bus: wait for a pending reply, write the final packets, let them leave the
    /// wire, close the port. Returns when the bus thread has stopped.
    pub async fn shutdown(&self, leave: ShutdownForce) {
        let shared = &self.owners.shared;
        {
            // In a block: the guard is not held across the await below.
            let mut core = shared.core();
            core.master.shutdown(leave);
            core.flush();
            shared.ring(core);
        }
        let mut finished = self.finished.clone();
        let _ = finished.wait_for(|done| *done).await;
    }

    /// Whether the bus thread has stopped.
    pub fn is_finished(&self) -> bool {
        *self.finished.borrow() || self.finished.has_changed().is_err()
    }
}

/// Start a bus thread for `cfg` on the serial port at `port`.
pub fn spawn_bus(cfg: BusConfig, port: PathBuf) -> BusHandle {
    spawn_bus_observed(cfg, port, Box::new(|_| {}))
}

/// [`spawn_bus`], with `observe` called in the bus thread with every status published (after
/// the packets due were written, before the status is sent to watchers). It sees every
/// telemetry sample, which a [`watch`] receiver cannot promise; it must be quick.
pub fn spawn_bus_observed(cfg: BusConfig, port: PathBuf, observe: StatusObserver) -> BusHandle {
    let name = cfg.name.clone();
    let rs485 = cfg.rs485;
    let master = BusMaster::new(cfg, Instant::now());
    let (status_tx, status_rx) = watch::channel(master.status());
    let (event_tx, first_events) = broadcast::channel(EVENT_CAPACITY);
    let (finished_tx, finished_rx) = watch::channel(false);
    let wakers = Wakers::new();
    if let Err(e) = &wakers {
        tracing::error!(bus = %name, "bus thread cannot start: no eventfd or timerfd: {e}");
    }
    let shared = Arc::new(Shared {
        core: Mutex::new(Core {
            master,
            port: None,
            write_error: None,
            armed: None,
            waits_until: None,
            timer_set: false,
            late_wakeups: LateWakeups::default(),
        }),
        wakers: wakers.ok(),
        turns: AtomicU64::new(0),
    });
    let driver = Driver {
        name: name.clone(),
        shared: Arc::clone(&shared),
        path: port,
        rs485: rs485.map(|mode| Rs485Request::new(name.clone(), mode)),
        status: status_tx,
        observe,
        events: event_tx.clone(),
        finished: finished_tx,
        published_at: Instant::now(),
        started: Instant::now(),
    };
    if shared.wakers.is_some() {
        let spawned = std::thread::Builder::new()
            .name(format!("bus {name}"))
            .spawn(move || driver.run());
        if let Err(e) = spawned {
            tracing::error!(bus = %name, "bus thread cannot start: {e}");
        }
    }
    BusHandle {
        name,
        owners: Arc::new(Owners { shared }),
        status: status_rx,
        events: event_tx,
        first_events: Arc::new(Mutex::new(Some(first_events))),
        finished: finished_rx,
    }
}

enum Exit {
    Shutdown,
    PortLost(String),
}

/// When [`Driver::publish`] publishes the status.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Publish {
    /// When something changed, at most every [`publish_spacing`]; at once with an event; and
    /// every [`STATUS_REFRESH`] in any case.
    IfDue,
    /// Now (the driver's last status).
    Now,
    /// Now, because the reply about to be read would replace a reading that the spacing held
    /// back (e.g. one read just after an event's status). The spacing counts on from the status
    /// before, so that the reply's own reading goes out as it would have.
    BeforeReplacing,
}

struct Driver {
    name: String,
    shared: Arc<Shared>,
    path: PathBuf,
    /// The RS485 mode the port is put in each time it opens.
    rs485: Option<Rs485Request>,
    status: watch::Sender<BusStatus>,
    observe: StatusObserver,
    events: broadcast::Sender<BusEvent>,
    finished: watch::Sender<bool>,
    published_at: Instant,
    /// When the thread started (for the fault switch of test builds).
    #[cfg_attr(not(feature = "fault-switch"), allow(dead_code))]
    started: Instant,
}

impl Driver {
    /// One turn of the thread's loops: counted for [`BusHandle::turns`]. In a test build, the
    /// place where the thread hangs when the fault switch asks it to.
    fn turn(&self) {
        #[cfg(feature = "fault-switch")]
        super::fault_switch::hang_if_asked(&self.name, self.started);
        self.shared.turns.fetch_add(1, Ordering::Relaxed);
    }

    fn run(mut self) {
        let shared = Arc::clone(&self.shared);
        let Some(wakers) = shared.wakers.as_ref() else {
            return;
        };
        if let Err(e) = nix::sys::prctl::set_timerslack(TIMER_SLACK_NS) {
            tracing::debug!(bus = %self.name, "timer slack stays at its default: {e}");
        }
        match request_realtime() {
            Ok(()) => {
                tracing::debug!(bus = %self.name, "bus thread runs at SCHED_FIFO {REALTIME_PRIORITY}")
            }
            Err(e) => {
                warn_not_realtime(&e);
                if let Err(e) = request_short_slice() {
                    tracing::debug!(bus = %self.name, "scheduler slice stays at its default: {e}");
                }
            }
        }
        let (baud, reopen) = {
            let core = self.shared.core();
            let cfg = core.master.config();
            (cfg.baud, cfg.port_reopen_backoff)
        };
        #[cfg(feature = "fault-switch")]
        super::fault_switch::announce(&self.name);
        let mut backoff = Duration::ZERO;
        loop {
            let opened = open_port(&self.path, baud, self.rs485.as_mut());
            match opened {
                Ok((port, waiter)) => {
                    self.turn();
                    backoff = Duration::ZERO;
                    tracing::info!(bus = %self.name, port = %self.path.display(), "serial port open at {baud}");
                    {
                        let mut core = self.shared.core();
                        core.master.handle_port_back(Instant::now());
                        core.write_error = None;
                        core.port = Some(port);
                    }
                    let exit = self.serve(wakers, waiter);
                    let mut core = self.shared.core();
                    core.port = None;
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
                    // Counted once the status says so: the first turn tells the service that
                    // this port was tried, and what it says of the bus must be the outcome.
                    self.publish(Publish::Now);
                    self.turn();
                }
            }
            self.publish(Publish::IfDue);
            if self.shared.core().master.is_shut_down() || self.shutdown_requested() {
                break;
            }
            backoff = reopen.after(backoff);
            if self.wait_offline(wakers, backoff) {
                break;
            }
        }
        self.publish(Publish::Now);
        let _ = self.finished.send(true);
    }

    /// A shutdown was asked for (it cannot complete without a port).
    fn shutdown_requested(&self) -> bool {
        self.shared.core().master.shutdown_requested()
    }

    /// Wait `wait` with the port closed, still taking goals, and turning at least every
    /// [`STATUS_REFRESH`]. True when a shutdown arrived.
    fn wait_offline(&mut self, wakers: &Wakers, wait: Duration) -> bool {
        let until = Instant::now() + wait;
        loop {
            self.turn();
            {
                let core = self.shared.core();
                let step = until.min(Instant::now() + STATUS_REFRESH);
                let mut core = self.shared.sleep(wakers, core, step);
                core.master.handle_timeout(Instant::now());
                if core.master.shutdown_requested() {
                    return true;
                }
            }
            self.publish(Publish::IfDue);
            if Instant::now() >= until {
                return false;
            }
        }
    }

    /// Publish the status (see [`Publish`]), then the events: whoever reacts to an event finds
    /// a status at least as new as the event.
    fn publish(&mut self, why: Publish) {
        let now = Instant::now();
        let mut events = Vec::new();
        let status = {
            let mut core = self.shared.core();
            while let Some(event) = core.master.poll_event() {
                events.push(event);
            }
            let since = now.saturating_duration_since(self.published_at);
            let spacing = publish_spacing(core.master.config());
            let due = why != Publish::IfDue
                || !events.is_empty()
                || since >= STATUS_REFRESH
                || (core.master.has_changed() && since >= spacing);
            due.then(|| {
                core.master.take_changed();
                core.master.status_at(now)
            })
        };
        if let Some(mut status) = status {
            status.thread = thread_usage();
            if why != Publish::BeforeReplacing {
                self.published_at = now;
            }
            (self.observe)(&status);
            self.status.send_replace(status);
        }
        // Not logged here: whoever takes the events logs them (the bridge logs every one), and
        // the bus thread does not wait on a log's writer.
        for event in events {
            let _ = self.events.send(event);
        }
    }

    /// Read the port in a loop while the last bytes of a reply are due within [`SPIN_LIMIT`]:
    /// `Ok(None)` once no reply is awaited any more, `Ok(Some(bytes))` with the bytes still
    /// missing when the limit has passed. The core is locked only for each read.
    fn spin_for_reply(&self, buf: &mut [u8]) -> Result<Option<usize>, String> {
        let until = Instant::now() + SPIN_LIMIT;
        loop {
            {
                let mut core = self.shared.core();
                core.read_input(buf)?;
                let missing = core.master.bytes_awaited();
                if missing.is_none() || Instant::now() >= until {
                    return Ok(missing);
                }
            }
            std::hint::spin_loop();
        }
    }

    /// Run the bus over the open port until shutdown or until the port fails.
    fn serve(&mut self, wakers: &Wakers, mut waiter: ReplyWaiter) -> Exit {
        let mut buf = [0u8; 512];
        loop {
            self.turn();
            if self.shared.core().master.awaited_reply_hides_a_reading() {
                self.publish(Publish::BeforeReplacing);
            }
            let (wake_at, reply_wait, wire_idle_at) = {
                let mut core = self.shared.core();
                let now = Instant::now();
                // Before the look at an awaited reply nothing need be read: its bytes wait in
                // the tty (a read then would be a system call for nothing).
                let too_early = core.master.reply_look_at().is_some_and(|at| now < at);
                if !too_early && let Err(reason) = core.read_input(&mut buf) {
                    return Exit::PortLost(reason);
                }
                core.master.handle_timeout(now);
                // A completed reply frees the bus: write what is due in this turn.
                core.flush();
                if let Some(reason) = core.write_error.take() {
                    return Exit::PortLost(reason);
                }
                let done = core.master.is_shut_down();
                let deadline = (!done).then(|| core.master.poll_timeout()).flatten();
                let look_at = core.master.reply_look_at();
                // The awaited reply should be (nearly) whole by now: wait on the port for its
                // last bytes.
                let reply_wait = match (look_at, core.master.bytes_awaited(), deadline) {
                    (Some(at), Some(bytes), Some(deadline)) if now >= at => Some(ReplyWait {
                        bytes,
                        deadline,
                        spin: core.master.config().wire_time(bytes) <= SPIN_LIMIT,
                    }),
                    _ => None,
                };
                let refresh = now + STATUS_REFRESH;
                let wake_at = [deadline, look_at]
                    .into_iter()
                    .flatten()
                    .fold(refresh, Instant::min);
                if std::mem::take(&mut core.timer_set) {
                    // Fired, or to fire at a deadline `wake_at` already holds: a timer left
                    // set would end a later wait for nothing.
                    let _ = wakers.timer.unset();
                }
                core.armed = None;
                core.arm(wake_at);
                (
                    wake_at,
                    reply_wait,
                    // The final packets' wire time, plus the allowance for the adapter and
                    // the servo (a USB adapter may still hold the last bytes).
                    done.then(|| core.master.wire_idle_at() + core.master.config().turnaround),
                )
            };
            self.publish(Publish::IfDue);
            if let Some(idle) = wire_idle_at {
                // Let the final packets leave the wire (and the kernel's output buffer) before
                // the port closes.
                std::thread::sleep(idle.saturating_duration_since(Instant::now()));
                let _ = tcdrain(&waiter.port);
                return Exit::Shutdown;
            }
            if let Some(ReplyWait {
                bytes,
                deadline,
                spin,
            }) = reply_wait
            {
                let bytes = if spin {
                    match self.spin_for_reply(&mut buf) {
                        Ok(Some(missing)) => missing,
                        Ok(None) => continue,
                        Err(reason) => return Exit::PortLost(reason),
                    }
                } else {
                    bytes
                };
                if let Waited::Late(late) = waiter.wait_for(bytes, deadline) {
                    self.shared.core().late_wakeup(late);
                }
                continue;
            }
            let core = self.shared.core();
            drop(self.shared.sleep(wakers, core, wake_at));
        }
    }
}

/// How often at most a changed status is published: building and passing one on costs about
/// as much as a transaction, so a status follows every change only on a bus that reads as
/// often as it can. Half the telemetry interval (at most 5 ms), so that a reading is seldom held
/// back at all. The thread never wakes only to publish: a change held back goes out at its next
/// wake-up (a read, a deadline, or [`STATUS_REFRESH`]), before that wake-up reads a reply that
/// would replace it ([`Publish::BeforeReplacing`]): the flight record keeps every reading.
pub(super) fn publish_spacing(cfg: &BusConfig) -> Duration {
    (cfg.telemetry_min_interval / 2).min(Duration::from_millis(5))
}

/// What the calling thread has used (`getrusage(RUSAGE_THREAD)`; zero where refused).
fn thread_usage() -> ThreadUsage {
    use nix::libc;
    // SAFETY: `usage` is a valid rusage for getrusage to fill; RUSAGE_THREAD is the caller.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    if unsafe { libc::getrusage(libc::RUSAGE_THREAD, &mut usage) } != 0 {
        return ThreadUsage::default();
    }
    let time = |t: libc::timeval| {
        Duration::from_secs(u64::try_from(t.tv_sec).unwrap_or(0))
            + Duration::from_micros(u64::try_from(t.tv_usec).unwrap_or(0))
    };
    ThreadUsage {
        cpu: time(usage.ru_utime) + time(usage.ru_stime),
        wakeups: u64::try_from(usage.ru_nvcsw).unwrap_or(0),
    }
}

#[cfg(test)]
mod tests;

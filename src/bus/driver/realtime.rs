//! What the bus thread asks of the scheduler and of memory: real-time priority, else short
//! time slices; the process's pages locked into RAM.

use std::time::Duration;

/// The real-time priority the bus thread asks for (SCHED_FIFO): modest, above every normal
/// thread (cameras, ROS, loggers), below the kernel's own real-time threads.
pub const REALTIME_PRIORITY: i32 = 10;

/// Ask for real-time scheduling (SCHED_FIFO at [`REALTIME_PRIORITY`]): the bus thread then runs
/// the moment a reply's last byte or a goal's deadline comes, whatever else the computer runs.
/// It sleeps between them (spinning at most [`SPIN_LIMIT`](super::SPIN_LIMIT) for a reply's
/// last bytes), so it never holds a core. Refused without CAP_SYS_NICE or an RLIMIT_RTPRIO of
/// at least the priority (`lj9da-bridge deploy systemd` grants both).
pub(super) fn request_realtime() -> std::io::Result<()> {
    lj9da_realtime::request_fifo(REALTIME_PRIORITY)
}

/// Say once per process, at warning level, that the bus threads run without real-time
/// scheduling, and what to grant.
pub(super) fn warn_not_realtime(error: &std::io::Error) {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        tracing::warn!(
            "bus threads run without real-time scheduling (SCHED_FIFO {REALTIME_PRIORITY} refused: \
             {error}): beside busy programs a goal may wait milliseconds for the CPU. Grant \
             CAP_SYS_NICE or LimitRTPRIO={REALTIME_PRIORITY} (the unit of `lj9da-bridge deploy \
             systemd` does)"
        );
    });
}

/// Lock the process's memory (current and future) into RAM, so that a page the bus threads
/// touch is never fetched back from disk while a reply or a goal waits. Done only where the
/// locked-memory limit is unlimited (root, or `LimitMEMLOCK=infinity` as in the unit of
/// `lj9da-bridge deploy systemd`): under a finite limit, locking future pages would make the
/// process's allocations fail once it is reached. Says once, at warning level, when it is not
/// done.
pub fn lock_memory() {
    use nix::libc;
    let mut limit = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit writes the limit into `limit`, a valid rlimit.
    let unlimited = unsafe { libc::getrlimit(libc::RLIMIT_MEMLOCK, &mut limit) } == 0
        && limit.rlim_cur == libc::RLIM_INFINITY;
    if !unlimited {
        tracing::warn!(
            "memory not locked: the locked-memory limit is {} KiB, not unlimited; a page fault \
             may delay a goal (set LimitMEMLOCK=infinity, as the unit of `lj9da-bridge deploy \
             systemd` does)",
            limit.rlim_cur / 1024
        );
        return;
    }
    // SAFETY: mlockall takes flags only.
    if unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) } != 0 {
        tracing::warn!(
            "memory not locked: {}; a page fault may delay a goal",
            std::io::Error::last_os_error()
        );
    } else {
        tracing::debug!("memory locked");
    }
}

/// The time slice the bus thread asks the scheduler for (the shortest Linux grants).
const SCHED_SLICE: Duration = Duration::from_micros(100);

/// Ask the scheduler to run this thread in short slices (Linux ≥ 6.12, EEVDF: `sched_setattr`
/// with a `sched_runtime` for a normal thread; no privilege needed). A thread with a shorter
/// slice than the one running may preempt it when it wakes, instead of waiting for that
/// thread's slice (a few ms) to end: the bus thread wakes for a reply's last byte or a deadline
/// and has tens of µs of work. Older kernels refuse it; nothing else changes. The thread keeps
/// its nice value (which `sched_setattr` sets too).
pub(super) fn request_short_slice() -> std::io::Result<()> {
    lj9da_realtime::request_slice(SCHED_SLICE, lj9da_realtime::nice()?)
}

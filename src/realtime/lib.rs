//! Scheduling requests for a thread that must wake on time: real-time scheduling (SCHED_FIFO),
//! or, where that is refused, a short time slice (`sched_setattr`). Used by the bridge's bus
//! threads and its MAVLink loop, and by the simulator's bus thread; each caller decides when to
//! ask, and says in its own words what it got.
//!
//! The bridge's bottom layer, a crate of its own so that the simulator (`lj9da-sim`, which the
//! flight binary does not carry) shares it without carrying the bridge: the calling thread and
//! the kernel only (Linux), nothing of either crate.

use std::io;
use std::time::Duration;

/// `SCHED_ATTR_SIZE_VER1` of `<linux/sched/types.h>`: the size of `struct sched_attr` with
/// `sched_util_min` and `sched_util_max` (the first published one, `SCHED_ATTR_SIZE_VER0`, is
/// 48 bytes: it ends at `sched_period`).
pub const SCHED_ATTR_SIZE_VER1: usize = 56;

/// `struct sched_attr` of `SCHED_ATTR_SIZE_VER1`, field for field.
#[repr(C)]
struct SchedAttr {
    size: u32,
    policy: u32,
    flags: u64,
    nice: i32,
    priority: u32,
    runtime: u64,
    deadline: u64,
    period: u64,
    util_min: u32,
    util_max: u32,
}

/// Ask for real-time scheduling of the calling thread: SCHED_FIFO at `priority`, for it alone
/// (`SCHED_RESET_ON_FORK`: a thread or process it starts afterwards runs as a normal one).
/// Refused without CAP_SYS_NICE or an RLIMIT_RTPRIO of at least `priority`; the error is the
/// kernel's.
pub fn request_fifo(priority: i32) -> io::Result<()> {
    let param = libc::sched_param {
        sched_priority: priority,
    };
    let policy = libc::SCHED_FIFO | libc::SCHED_RESET_ON_FORK;
    // SAFETY: pid 0 is the calling thread; the kernel only reads `param`.
    if unsafe { libc::sched_setscheduler(0, policy, &param) } == 0 {
        Ok(())
    } else {
        Err(io::Error::last_os_error())
    }
}

/// Make the calling thread a normal (SCHED_OTHER) one again, at the nice value it had (a real-time
/// thread keeps its nice value, unused, beside its priority). Always allowed: a thread may give
/// up real-time scheduling without privilege.
pub fn request_normal() -> io::Result<()> {
    let param = libc::sched_param { sched_priority: 0 };
    let policy = libc::SCHED_OTHER | libc::SCHED_RESET_ON_FORK;
    // SAFETY: pid 0 is the calling thread; the kernel only reads `param`.
    if unsafe { libc::sched_setscheduler(0, policy, &param) } == 0 {
        Ok(())
    } else {
        Err(io::Error::last_os_error())
    }
}

/// The CPU time the calling thread has used (`CLOCK_THREAD_CPUTIME_ID`: a vDSO read, no system
/// call on the kernels the bridge runs on).
pub fn thread_cpu_time() -> Duration {
    let mut t = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes a timespec into `t`, a valid one; this clock always exists.
    unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut t) };
    Duration::new(t.tv_sec as u64, t.tv_nsec as u32)
}

/// The calling thread's nice value.
pub fn nice() -> io::Result<i32> {
    // getpriority returns -1 both for nice -1 and for an error, so errno tells them apart.
    // SAFETY: __errno_location is the calling thread's errno; getpriority only reads the calling
    // thread's (PRIO_PROCESS, 0) nice value.
    let nice = unsafe {
        *libc::__errno_location() = 0;
        libc::getpriority(libc::PRIO_PROCESS, 0)
    };
    // SAFETY: as above.
    if nice == -1 && unsafe { *libc::__errno_location() } != 0 {
        return Err(io::Error::last_os_error());
    }
    Ok(nice)
}

/// Ask the scheduler to run the calling thread, a normal (SCHED_OTHER) one, in slices of
/// `slice` (Linux ≥ 6.12, EEVDF: `sched_setattr` with a `sched_runtime`; no privilege needed;
/// 100 µs is the shortest granted). A thread with a shorter slice than the one running may
/// preempt it when it wakes, instead of waiting for that thread's slice (a few ms) to end.
/// `sched_setattr` sets the nice value too: `nice` is the one the thread gets (pass [`nice`]
/// to keep its own). Older kernels refuse it; the error is the kernel's.
pub fn request_slice(slice: Duration, nice: i32) -> io::Result<()> {
    let attr = SchedAttr {
        size: std::mem::size_of::<SchedAttr>() as u32,
        policy: libc::SCHED_OTHER as u32,
        flags: 0,
        nice,
        priority: 0,
        runtime: slice.as_nanos() as u64,
        deadline: 0,
        period: 0,
        util_min: 0,
        util_max: 0,
    };
    // SAFETY: `attr` is a valid, fully initialised sched_attr of the size it declares; pid 0 is
    // the calling thread; the kernel only reads it.
    let r = unsafe { libc::syscall(libc::SYS_sched_setattr, 0, &attr as *const SchedAttr, 0) };
    if r == 0 {
        Ok(())
    } else {
        Err(io::Error::last_os_error())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_sched_attr_has_the_kernels_size() {
        assert_eq!(std::mem::size_of::<SchedAttr>(), SCHED_ATTR_SIZE_VER1);
    }

    /// In a thread of its own: the requests change the scheduling of the thread that makes them.
    fn in_a_thread<T: Send + 'static>(f: impl FnOnce() -> T + Send + 'static) -> T {
        std::thread::spawn(f).join().expect("no panic")
    }

    /// The policy of the calling thread (`sched_getscheduler`), without the reset-on-fork flag.
    fn policy() -> i32 {
        // SAFETY: pid 0 is the calling thread; nothing is written.
        unsafe { libc::sched_getscheduler(0) & !libc::SCHED_RESET_ON_FORK }
    }

    /// The calling thread's `struct sched_attr`, as the kernel reports it.
    fn attr() -> SchedAttr {
        let mut attr = SchedAttr {
            size: 0,
            policy: 0,
            flags: 0,
            nice: 0,
            priority: 0,
            runtime: 0,
            deadline: 0,
            period: 0,
            util_min: 0,
            util_max: 0,
        };
        let size = std::mem::size_of::<SchedAttr>() as u32;
        // SAFETY: the kernel writes at most `size` bytes into `attr`, which has that size.
        let r = unsafe {
            libc::syscall(
                libc::SYS_sched_getattr,
                0,
                &mut attr as *mut SchedAttr,
                size,
                0,
            )
        };
        assert_eq!(r, 0, "sched_getattr: {}", io::Error::last_os_error());
        attr
    }

    /// A request that is refused leaves the thread as it was, and the refusal is one the kernel
    /// gives for it; one that is granted is what the kernel then reports. Which of the two
    /// happened is printed (`--nocapture`), so that a run shows what it could check.
    #[test]
    fn a_short_slice_is_the_thread_s_slice_or_refused_as_the_kernel_refuses_it() {
        let slice = Duration::from_micros(300);
        let (result, before, after, attr) = in_a_thread(move || {
            let before = nice().expect("the thread's nice value");
            let result = request_slice(slice, before);
            (
                result,
                before,
                nice().expect("the thread's nice value"),
                attr(),
            )
        });
        assert_eq!(after, before, "the nice value is kept");
        assert_eq!(attr.policy, libc::SCHED_OTHER as u32);
        match result {
            Ok(()) => {
                println!("slice granted: {} ns", attr.runtime);
                assert_eq!(attr.runtime, slice.as_nanos() as u64, "the slice asked for");
            }
            Err(e) => {
                println!("slice refused by this kernel: {e}");
                // EINVAL or E2BIG: a kernel older than EEVDF's custom slices; EPERM: a seccomp or
                // LSM rule.
                assert!(
                    matches!(
                        e.raw_os_error(),
                        Some(libc::EINVAL | libc::E2BIG | libc::EPERM | libc::ENOSYS)
                    ),
                    "an error sched_setattr does not give for this request: {e}"
                );
            }
        }
    }

    /// A thread that gave up real-time scheduling is a normal one, and may ask for it again.
    #[test]
    fn a_real_time_thread_can_become_a_normal_one_and_back() {
        let (granted, normal, again) = in_a_thread(|| {
            let granted = request_fifo(10).is_ok();
            let normal = request_normal().map(|()| policy());
            let again = request_fifo(10).map(|()| policy());
            (granted, normal, again)
        });
        assert_eq!(normal.expect("always allowed"), libc::SCHED_OTHER);
        if granted {
            assert_eq!(
                again.expect("granted once, granted again"),
                libc::SCHED_FIFO
            );
        } else {
            println!("SCHED_FIFO refused here: only the way down was checked");
        }
    }

    #[test]
    fn the_thread_s_cpu_time_grows_with_its_work_and_not_with_its_sleep() {
        let (slept, worked) = in_a_thread(|| {
            let start = thread_cpu_time();
            std::thread::sleep(Duration::from_millis(50));
            let slept = thread_cpu_time() - start;
            let start = thread_cpu_time();
            let spin = std::time::Instant::now();
            while spin.elapsed() < Duration::from_millis(30) {
                std::hint::spin_loop();
            }
            (slept, thread_cpu_time() - start)
        });
        assert!(
            slept < Duration::from_millis(10),
            "asleep 50 ms, used {slept:?}"
        );
        assert!(
            worked > Duration::from_millis(1),
            "spun 30 ms, used {worked:?}"
        );
    }

    #[test]
    fn real_time_scheduling_is_the_thread_s_policy_or_refused_for_want_of_privilege() {
        let (result, policy, priority) = in_a_thread(|| {
            let result = request_fifo(10);
            (result, policy(), attr().priority)
        });
        match result {
            Ok(()) => {
                println!("SCHED_FIFO 10 granted");
                assert_eq!(policy, libc::SCHED_FIFO);
                assert_eq!(priority, 10);
            }
            Err(e) => {
                println!("SCHED_FIFO refused: {e}");
                assert_eq!(e.raw_os_error(), Some(libc::EPERM), "not a refusal: {e}");
                assert_eq!(policy, libc::SCHED_OTHER, "the thread is left as it was");
            }
        }
    }

    #[test]
    fn a_thread_started_by_a_real_time_one_runs_as_a_normal_thread() {
        let (granted, own, child) = in_a_thread(|| {
            let granted = request_fifo(10).is_ok();
            let child = std::thread::spawn(policy).join().expect("no panic");
            (granted, policy(), child)
        });
        if granted {
            assert_eq!(own, libc::SCHED_FIFO, "the thread that asked is real-time");
            assert_eq!(child, libc::SCHED_OTHER, "its new thread is not");
        } else {
            println!("SCHED_FIFO refused: what a real-time thread starts is not checked here");
        }
    }
}

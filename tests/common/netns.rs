//! A network namespace of the test's own, where ArduPilot SITL's multicast CAN (and anything
//! else on its loopback) stays: the calling thread, and every thread and process it starts
//! from then on, move into it.

/// Move the calling thread into a new network namespace with its loopback up and multicast
/// routed on it. Needs root (CAP_SYS_ADMIN), as CI runs; `Err` says why it could not.
pub fn enter() -> Result<(), String> {
    // SAFETY: unshare(2) with CLONE_NEWNET changes only the calling thread's namespace.
    if unsafe { libc::unshare(libc::CLONE_NEWNET) } != 0 {
        return Err(format!(
            "a network namespace of the test's own needs root (CAP_SYS_ADMIN): \
             unshare(CLONE_NEWNET) failed: {}",
            std::io::Error::last_os_error()
        ));
    }
    for args in [
        &["link", "set", "lo", "up"][..],
        &["link", "set", "lo", "multicast", "on"],
        &["route", "add", "224.0.0.0/4", "dev", "lo"],
    ] {
        let status = std::process::Command::new("ip")
            .args(args)
            .status()
            .map_err(|e| format!("the ip command (iproute2): {e}"))?;
        if !status.success() {
            return Err(format!("ip {args:?} failed in the namespace"));
        }
    }
    Ok(())
}

/// [`enter`], or, where it cannot be: under `CI=true` a failure, elsewhere one line saying the
/// test did not run (`false`: return at once).
pub fn enter_or_say() -> bool {
    match enter() {
        Ok(()) => true,
        Err(why) if std::env::var("CI").as_deref() == Ok("true") => panic!("{why}"),
        Err(why) => {
            eprintln!("*** NOT RUN: {why} ***");
            false
        }
    }
}

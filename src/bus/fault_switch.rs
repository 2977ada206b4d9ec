//! The fault switch of test builds (feature `fault-switch`, never in a package): the
//! environment variable [`HANG_SWITCH`], `<bus name>:<seconds>`, makes that bus's thread hang
//! (without the core) once it has run that long, so that a test can see the service's watchdog
//! notice a stuck bus thread. A bridge it is set for says so in its log at the start of that
//! bus. `cargo build` and the Debian package leave this module out: the flight binary has no
//! switch to hang its own threads.

use std::sync::OnceLock;
use std::time::{Duration, Instant};

/// The environment variable of the switch.
pub const HANG_SWITCH: &str = "LJ9DA_TEST_HANG_BUS";

/// The bus named by [`HANG_SWITCH`] and when its thread hangs (`None`: unset or unreadable).
fn hang_switch() -> Option<&'static (String, Duration)> {
    static SWITCH: OnceLock<Option<(String, Duration)>> = OnceLock::new();
    SWITCH
        .get_or_init(|| {
            let value = std::env::var(HANG_SWITCH).ok()?;
            let parsed = value.rsplit_once(':').and_then(|(bus, secs)| {
                let secs = secs.trim().parse::<f64>().ok()?;
                Some((bus.to_string(), Duration::try_from_secs_f64(secs).ok()?))
            });
            if parsed.is_none() {
                tracing::warn!("{HANG_SWITCH}={value:?} ignored: expected <bus name>:<seconds>");
            }
            parsed
        })
        .as_ref()
}

/// Said once at the start of bus `bus` when the switch names it.
pub(super) fn announce(bus: &str) {
    if let Some((_, after)) = hang_switch().filter(|(name, _)| name == bus) {
        tracing::warn!(
            bus,
            "test fault switch {HANG_SWITCH}: this bus thread will hang after {after:?}"
        );
    }
}

/// Hang the calling thread, the thread of bus `bus` started at `started`, for good once the
/// switch's time has come.
pub(super) fn hang_if_asked(bus: &str, started: Instant) {
    if let Some((_, after)) = hang_switch().filter(|(name, _)| name == bus)
        && started.elapsed() >= *after
    {
        tracing::error!(bus, "bus thread hangs now, as {HANG_SWITCH} asks");
        loop {
            std::thread::park();
        }
    }
}

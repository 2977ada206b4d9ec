//! A bridge waiting for its autopilot sleeps. At every boot the companion computer is up before
//! the flight controller, and a link can be down or keyed differently for hours: the bridge
//! must then cost no more than it does while it works.
//!
//! The process's CPU time is read from `/proc/self/stat` over the same stretch of wall time
//! for the same chain (simulated servos on pseudo-terminals, the bridge, a ground station),
//! once with nobody on the autopilot link and once with the simulated autopilot streaming its
//! outputs; the first must not exceed the second by more than a margin for noise, and the second
//! must stay a small share of one core. A bridge that spins uses a whole core, tens of times
//! what it uses running.
//! This file holds one test so that no other test's threads share the process.

mod common;

use common::Chain;
use common::mapping::Mapping;
use std::time::Duration;

/// Two servos; the outputs asked for at 50 Hz.
fn mapping() -> Mapping {
    Mapping::new()
        .with("[mavlink]", "output_rate_hz = 50")
        .servo("aileron", 1, 1)
        .servo("elevator", 2, 2)
}

/// How long each state is measured.
const SPELL: Duration = Duration::from_secs(3);

/// The CPU time (user + system) this process has used, from `/proc/self/stat`.
fn process_cpu() -> Duration {
    let stat = std::fs::read_to_string("/proc/self/stat").expect("/proc/self/stat");
    // The fields after the command name, which is in parentheses and may hold spaces.
    let after = &stat[stat.rfind(')').expect("a command name") + 2..];
    let fields: Vec<&str> = after.split_whitespace().collect();
    // utime and stime are fields 14 and 15 of stat(5), the 12th and 13th after the name.
    let ticks: u64 = fields[11].parse::<u64>().unwrap() + fields[12].parse::<u64>().unwrap();
    let per_second = unsafe { libc::sysconf(libc::_SC_CLK_TCK) } as u64;
    Duration::from_secs_f64(ticks as f64 / per_second as f64)
}

/// The CPU time the process uses over `SPELL` once `chain` is in the state to measure.
async fn cpu_over_a_spell() -> Duration {
    let before = process_cpu();
    tokio::time::sleep(SPELL).await;
    process_cpu() - before
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn waiting_for_the_autopilot_costs_no_more_than_running() {
    let waiting = Chain::start(mapping(), false).await;
    waiting
        .wait_view("the servos read", Duration::from_secs(20), |v| {
            v.servos.iter().all(|s| s.report.position_mm.is_some())
        })
        .await;
    let idle = cpu_over_a_spell().await;
    assert!(
        waiting.view.borrow().autopilot.is_none(),
        "nobody was on the autopilot link"
    );
    waiting.stop().await;

    let running = Chain::start(mapping(), true).await;
    running
        .wait_view(
            "the autopilot's outputs obeyed",
            Duration::from_secs(20),
            |v| v.autopilot.is_some() && v.servos.iter().all(|s| s.goal_mm.is_some()),
        )
        .await;
    let busy = cpu_over_a_spell().await;
    running.stop().await;

    println!("CPU over {SPELL:?}: waiting for the autopilot {idle:?}, running {busy:?}");
    // 50 % and two clock ticks of margin for a noisy machine; a spinning loop costs a whole
    // core (SPELL of CPU time).
    assert!(
        idle <= busy * 3 / 2 + Duration::from_millis(20),
        "waiting for the autopilot used {idle:?} of CPU in {SPELL:?}, running {busy:?}"
    );
    // Nor does it spin while it runs: the whole chain (bridge, simulated servos and autopilot,
    // ground station) used 0.2 s of CPU over the 3 s here, 7 % of a core; a loop that spins
    // uses all of it. A third of a core leaves five times the measured figure for a loaded
    // machine.
    assert!(
        busy <= SPELL / 3,
        "running used {busy:?} of CPU in {SPELL:?}: something spins"
    );
}

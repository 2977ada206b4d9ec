//! Shared helpers of the bus integration tests: a simulated bus on a pseudo-terminal, a bus
//! configuration for it, and waits with a deadline (a test that waits too long fails with what
//! it was waiting for, never hangs).

#![allow(dead_code)]

use lj9da_bridge::bus::{BusConfig, BusEvent, BusHandle, BusStatus, Goal, Health, ServoSetup};
use lj9da_bridge::protocol::{BaudRate, MmCenti, ServoId};
use lj9da_sim::{SimBus, SimConfig};
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;
use tokio::sync::broadcast;

/// How long a test waits for something that should take well under a second.
pub const PATIENCE: Duration = Duration::from_secs(10);

pub fn id(n: u8) -> ServoId {
    ServoId::new(n).unwrap()
}

pub fn sim_config(ids: &[u8], baud: u32) -> SimConfig {
    SimConfig {
        ids: ids.to_vec(),
        baud,
        ..SimConfig::default()
    }
}

pub fn spawn_sim(config: SimConfig) -> SimBus {
    SimBus::spawn_pty(config).expect("simulated bus on a pty")
}

/// The simulated servos run in real time on a thread of their own; on a loaded machine (tests
/// run in parallel, two cores) that thread can read a request several milliseconds late and so
/// answer late. The tests check rules, not timing: they give the bus master a turnaround
/// allowance that covers such stalls. (The bench uses the default and reports timeouts.)
pub const TEST_TURNAROUND: Duration = Duration::from_millis(20);

pub fn bus_config(ids: &[u8], baud: BaudRate) -> BusConfig {
    let mut cfg = BusConfig::new(
        "test bus",
        baud,
        ids.iter()
            .map(|&n| ServoSetup::new(id(n), format!("servo{n}")))
            .collect(),
    );
    cfg.turnaround = TEST_TURNAROUND;
    cfg
}

/// A path for a symlink to the simulated device, unique to this test.
pub fn link_path(test: &str) -> PathBuf {
    static N: AtomicUsize = AtomicUsize::new(0);
    std::env::temp_dir().join(format!(
        "lj9da-bus-{test}-{}-{}",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed)
    ))
}

/// Wait until the bus status satisfies `done`; fail with `what` and the last status otherwise.
pub async fn wait_status(
    bus: &BusHandle,
    what: &str,
    done: impl Fn(&BusStatus) -> bool,
) -> BusStatus {
    let deadline = tokio::time::Instant::now() + PATIENCE;
    let mut watch = bus.watch_status();
    loop {
        let status = watch.borrow_and_update().clone();
        if done(&status) {
            return status;
        }
        if tokio::time::Instant::now() >= deadline {
            panic!("timed out waiting for {what}; last status: {status:#?}");
        }
        let _ = tokio::time::timeout(Duration::from_millis(50), watch.changed()).await;
    }
}

/// Wait until every servo of the bus is online.
pub async fn every_servo_online(bus: &BusHandle) -> BusStatus {
    wait_status(bus, "every servo online", |s| {
        s.servos.iter().all(|s| s.health == Health::Online)
    })
    .await
}

/// Give every servo in `ids` the goal `position` and wait until all hold it with force ON.
pub async fn hold_with_force_on(bus: &BusHandle, ids: &[u8], position: MmCenti) {
    for &n in ids {
        bus.set_goal(id(n), Goal::Position(position));
    }
    wait_status(bus, "force on", all_online_with_force).await;
}

/// Wait for an event matching `want`; fail with `what` otherwise.
pub async fn wait_event(
    events: &mut broadcast::Receiver<BusEvent>,
    what: &str,
    want: impl Fn(&BusEvent) -> bool,
) -> BusEvent {
    let deadline = tokio::time::Instant::now() + PATIENCE;
    loop {
        match tokio::time::timeout_at(deadline, events.recv()).await {
            Ok(Ok(event)) if want(&event) => return event,
            Ok(Ok(_)) | Ok(Err(broadcast::error::RecvError::Lagged(_))) => {}
            Ok(Err(broadcast::error::RecvError::Closed)) => panic!("bus closed waiting for {what}"),
            Err(_) => panic!("timed out waiting for {what}"),
        }
    }
}

/// Every servo of `status` online with force ON.
pub fn all_online_with_force(status: &BusStatus) -> bool {
    status.servos.iter().all(|s| {
        s.health == lj9da_bridge::bus::Health::Online
            && s.force == lj9da_bridge::bus::ForceState::On
    })
}

/// Talk-overs the simulated line saw among `events`, by the servo whose reply was talked over.
pub fn talk_overs(events: &std::sync::mpsc::Receiver<lj9da_sim::BusEvent>) -> BTreeMap<u8, u64> {
    let mut by_servo = BTreeMap::new();
    for event in events.try_iter() {
        if let lj9da_sim::BusEvent::Collision { id, .. } = event {
            *by_servo.entry(id).or_default() += 1;
        }
    }
    by_servo
}

/// The line was never talked over and every request was answered with a good reply, or, where
/// the simulator says it ran late, the bridge only wrote over replies it had already given up
/// on (and its bad sums are those garbled replies).
///
/// When the simulator's thread runs late (a busy machine; it counts each late hand-over in
/// `handed_late`), its servos answer later than their wire time, some after the bridge's reply
/// deadline. The bridge then counts a timeout and carries on, and its next packet may meet the
/// late reply in the model: a talk-over of a reply it had already counted as missing. What it
/// must never do is write over a reply it is still waiting for, so each talked-over reply of a
/// servo must be one of that servo's timeouts.
///
/// Returns whether the line was judged strictly (no talk-over, no reply missed): always where
/// the simulator kept time, and where it ran late without spoiling anything.
pub fn assert_line_kept(
    stats: &lj9da_sim::BusStats,
    status: &BusStatus,
    talk_overs: &BTreeMap<u8, u64>,
) -> bool {
    let c = &status.counters;
    // Judged strictly: where the simulator kept time, or where it ran late and the line was
    // kept all the same (lateness can excuse a talk-over or a lost reply, never require one).
    let kept = stats.collisions == 0 && c.timeouts == 0 && c.bad_sums == 0;
    if stats.handed_late == 0 || kept {
        assert_eq!(stats.collisions, 0, "{stats:?} {c:?}");
        assert_eq!(c.timeouts, 0, "{c:?}");
        assert_eq!(c.bad_sums, 0, "{c:?}");
        return true;
    }
    // A talked-over reply reaches the bridge garbled: its bad sums can be those, no more.
    assert!(
        c.bad_sums <= stats.collisions,
        "{} bad sums but only {} talk-overs to explain them\n{stats:?}\n{c:?}",
        c.bad_sums,
        stats.collisions
    );
    for s in &status.servos {
        let over = talk_overs.get(&s.id.get()).copied().unwrap_or(0);
        assert!(
            over <= s.timeouts,
            "servo {}: {over} replies talked over but only {} given up on\n{stats:?}\n{c:?}",
            s.id,
            s.timeouts
        );
    }
    println!(
        "the simulator ran late {} times: {} talk-overs, all of replies given up on; {} timeouts; \
         not judged: a line never talked over, every request answered",
        stats.handed_late, stats.collisions, c.timeouts
    );
    false
}

//! A run against simulated servos on a pseudo-terminal, recorded the way the bridge records
//! one: goals where they are handed to the bus, telemetry and health from the bus's status
//! watch, bus events from its event channel. Then the summary is checked against what the
//! simulation did.

mod tempdir;

use lj9da_bridge::bus::{BusConfig, Goal, ServoSetup, ShutdownForce, spawn_bus_observed};
use lj9da_bridge::protocol::{BaudRate, MmCenti, ServoId};
use lj9da_bridge::record::format::RecordServo;
use lj9da_bridge::record::{RecordBody, RecordLimits, Recorder, StatusFeed, read_record, summary};
use lj9da_sim::{SimBus, SimConfig};
use std::time::{Duration, Instant};
use tempdir::TempDir;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_simulated_run_is_recorded_and_its_summary_matches_the_simulation() {
    let sim = SimBus::spawn_pty(SimConfig {
        ids: vec![1, 2],
        ..SimConfig::default()
    })
    .unwrap();
    let servos = vec![
        RecordServo::new("left", "sim", 1, 1),
        RecordServo::new("right", "sim", 2, 2),
    ];
    let setups = servos
        .iter()
        .map(|s| ServoSetup::new(ServoId::new(s.id).unwrap(), &s.name))
        .collect();
    // Generous reply allowances: this test is about the record, and a machine busy with other
    // work must not make the servos look lost.
    let mut bus_cfg = BusConfig::new("sim", BaudRate::B115200, setups);
    bus_cfg.turnaround = Duration::from_millis(20);
    bus_cfg.offline_after_timeouts = 50;
    bus_cfg.stale_after = Duration::from_secs(2);
    let dir = TempDir::new("sim");
    let record = Recorder::start(dir.path(), &servos, RecordLimits::default()).unwrap();

    // As the bridge does: the bus thread hands every status it publishes to the feed, which
    // records telemetry and health; the event channel feeds events.
    let feed = std::sync::Arc::new(std::sync::Mutex::new(StatusFeed::new(
        record.clone(),
        &servos,
    )));
    let observed = feed.clone();
    let bus = spawn_bus_observed(
        bus_cfg,
        sim.path(),
        Box::new(move |s| observed.lock().unwrap().observe(s)),
    );
    let events_feed = StatusFeed::new(record.clone(), &servos);
    let mut events = bus.events();
    let event_task = tokio::spawn(async move {
        while let Ok(event) = events.recv().await {
            events_feed.bus_event("sim", &event);
        }
    });

    let deadline = Instant::now() + Duration::from_secs(10);
    while !bus
        .status()
        .servos
        .iter()
        .all(|s| s.health == lj9da_bridge::bus::Health::Online)
    {
        assert!(Instant::now() < deadline, "servos did not come online");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }

    // Goals are recorded where they are handed to the bus, as the bridge does.
    let command = |mm: i16| {
        for (index, servo) in servos.iter().enumerate() {
            let goal = Goal::Position(MmCenti(mm * 100));
            bus.set_goal(ServoId::new(servo.id).unwrap(), goal);
            record.goal(index, goal);
        }
    };
    // The scenario's phases last at least as long as the summary's checks need (the 0.5 s
    // soft start, then settled samples; a stall needs 0.5 s to be called one), and then until
    // what they are about has really happened: a busy machine stretches them, never cuts them.
    let at = |n: usize, centi: i16| {
        move |s: &lj9da_bridge::bus::BusStatus| {
            s.servos[n]
                .telemetry
                .is_some_and(|t| (t.present_position.0 - centi).abs() <= 4)
        }
    };
    command(5);
    tokio::time::sleep(Duration::from_millis(1200)).await;
    wait_for(&bus, "both servos at +5 mm", |s| {
        at(0, 500)(s) && at(1, 500)(s)
    })
    .await;
    // Servo 2's rod is blocked for the second move: it stalls.
    assert!(sim.handle().set_stalled(2, true));
    let second_goal_at = Instant::now();
    command(-5);
    tokio::time::sleep(Duration::from_millis(1500)).await;
    let stalled = wait_for(&bus, "left at −5 mm, right stalled", |s| {
        at(0, -500)(s) && s.servos[1].stalled
    })
    .await;
    // The stall lasts long enough to be recorded as one (> 0.3 s): ten more polls of the
    // blocked servo, and 0.5 s, after the bridge reported it.
    let polls = stalled.servos[1].telemetry_count;
    let reported = Instant::now();
    wait_for(&bus, "ten polls of the stalled servo", |s| {
        s.servos[1].telemetry_count >= polls + 10
            && reported.elapsed() >= Duration::from_millis(500)
    })
    .await;
    let truth = sim.handle().snapshots();

    bus.shutdown(ShutdownForce::AsIs).await;
    let missed = feed.lock().unwrap().missed_samples();
    event_task.abort();
    let start = record.start_instant();
    let stats = record.finish();
    assert_eq!(stats.dropped(), 0);

    let rec = read_record(&stats.files[0]).unwrap();
    assert!(rec.closed);
    assert!(rec.notes.is_empty(), "{:?}", rec.notes);
    let sum = summary(&rec);
    let final_status = bus.status();
    let second_goal_s = second_goal_at.duration_since(start).as_secs_f64();
    let end_s = rec.end_t_us() as f64 / 1e6;

    // Every sample the servos answered was recorded: the feed sees every status the bus
    // thread publishes, and nothing was missed.
    let recorded: u64 = sum.servos.iter().map(|s| s.samples).sum();
    let answered: u64 = final_status.servos.iter().map(|s| s.telemetry_count).sum();
    assert_eq!(missed, 0);
    assert_eq!(
        recorded, answered,
        "{recorded} recorded of {answered} answered"
    );
    // And every read of position (and current) between two full ones that was answered.
    let reads = rec
        .records
        .iter()
        .filter(|r| {
            matches!(
                r.body,
                RecordBody::Motion { .. } | RecordBody::Position { .. }
            )
        })
        .count() as u64;
    let replies = final_status.counters.telemetry_replies;
    assert_eq!(
        recorded + reads,
        replies,
        "{recorded} samples and {reads} reads recorded of {replies} replies"
    );

    for (s, snapshot) in sum.servos.iter().zip(&truth) {
        let name = &s.servo.name;
        assert!(s.samples > 50, "{name}: {} samples", s.samples);
        assert!(s.duration_s() > 2.0, "{name}: {} s", s.duration_s());
        let v = s.voltage_v.unwrap();
        assert!((v.mean - 12.0).abs() < 0.05, "{name}: mean {} V", v.mean);
        assert!((v.mean - f64::from(snapshot.voltage_v)).abs() < 0.05);
        let t = s.temperature_c.unwrap();
        assert!(t.min >= 20.0 && t.max <= 60.0, "{name}: {t:?}");
        assert!(
            (t.max - f64::from(snapshot.temperature_c)).abs() <= 2.0,
            "{name}: {t:?} vs {} °C in the simulation",
            snapshot.temperature_c
        );
        let peak = s.peak_current_a().unwrap();
        assert!(peak > 0.0 && peak < 6.0, "{name}: peak {peak} A");
        // The largest goal step is 10 mm; no error can exceed it (plus quantisation).
        let max_error = s.max_error_mm.unwrap();
        assert!(
            max_error > 4.0 && max_error <= 10.1,
            "{name}: {max_error} mm"
        );
        assert_eq!(s.goals, 2);
        assert_eq!(s.alarms(), 0);
        assert_eq!(s.offline_s, 0.0, "{name}");
    }
    let (left, right) = (&sum.servos[0], &sum.servos[1]);
    // The free servo reached its goal and stayed there.
    assert!(
        left.max_settled_error_mm.unwrap() < 0.2,
        "{:?}",
        left.max_settled_error_mm
    );
    assert_eq!(left.stalled_s, 0.0);
    // The blocked one stalled (500 ms after the goal it could not follow) until the end,
    // and drew stall current.
    assert!(right.stalled_s > 0.3, "{} s stalled", right.stalled_s);
    assert!(
        right.stalled_s <= end_s - second_goal_s - 0.4,
        "{} s stalled of {} s",
        right.stalled_s,
        end_s - second_goal_s
    );
    assert!(right.peak_current_a().unwrap() > 1.5);
    // The reads of position and current between two full ones are recorded with their current:
    // the stall current shows in them too, in every read of the stall's last half second and
    // ten polls at least.
    let stall_motions = rec
        .records
        .iter()
        .filter(|r| {
            matches!(&r.body, RecordBody::Motion { servo: 1, motion, .. }
                if motion.present_load.amps() > 1.5)
        })
        .count();
    assert!(
        stall_motions >= 5,
        "{stall_motions} motion records at stall current"
    );
    assert!(right.max_settled_error_mm.unwrap() > 5.0);
    assert!(rec.records.iter().any(|r| matches!(
        &r.body,
        RecordBody::Event { servo: Some(1), text, .. } if text.contains("stalled")
    )));
    sim.shutdown();
}

/// Wait until the bus status satisfies `done`, checking every 20 ms; fail with `what` after
/// 10 s, far beyond what any of these phases needs.
async fn wait_for(
    bus: &lj9da_bridge::bus::BusHandle,
    what: &str,
    done: impl Fn(&lj9da_bridge::bus::BusStatus) -> bool,
) -> lj9da_bridge::bus::BusStatus {
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        let status = bus.status();
        if done(&status) {
            return status;
        }
        assert!(
            Instant::now() < deadline,
            "timed out waiting for {what}: {status:#?}"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

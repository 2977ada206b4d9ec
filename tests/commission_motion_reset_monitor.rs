//! `move`, `force`, `factory-reset` and `monitor` against the simulated bus.

mod commission_common;

use commission_common::{id, link, link_at, sim, writes};
use lj9da_bridge::commission::CommissionError;
use lj9da_bridge::commission::Setting;
use lj9da_bridge::commission::monitor::{MonitorOptions, MonitorRow, monitor};
use lj9da_bridge::commission::motion::{MoveOptions, move_to, set_force};
use lj9da_bridge::commission::reset::factory_reset;
use lj9da_bridge::commission::set::{SetOptions, set};
use lj9da_bridge::protocol::{BaudRate, ForceMode, MmCenti, Ms10};
use lj9da_sim::Force;
use std::time::Duration;

fn to(mm: f64) -> MoveOptions {
    MoveOptions {
        goal: MmCenti::from_mm(mm).unwrap(),
        time: None,
        force_on: true,
        wait: true,
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn move_is_refused_while_force_is_off_and_writes_nothing() {
    let bus = sim(&[1]);
    let events = bus.handle().subscribe();
    let mut link = link(&bus).await;
    let error = move_to(
        &mut link,
        id(1),
        MoveOptions {
            force_on: false,
            ..to(10.0)
        },
    )
    .await
    .unwrap_err();
    assert!(error.is_refusal(), "{error}");
    assert!(error.to_string().contains("--force-on"), "{error}");
    assert!(writes(&events, &mut link).await.is_empty());
    assert_eq!(bus.handle().snapshot(1).unwrap().force, Force::Off);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn move_with_force_on_reaches_the_position() {
    let bus = sim(&[1]);
    let mut link = link(&bus).await;
    let report = move_to(&mut link, id(1), to(12.5)).await.unwrap();
    assert!(report.switched_force_on);
    assert!(report.arrived, "{report:?}");
    assert_eq!(report.goal.0, 1250);
    assert!(!report.clamped());
    let servo = bus.handle().snapshot(1).unwrap();
    assert_eq!(servo.force, Force::On);
    assert!(
        (servo.position_mm - 12.5).abs() <= 0.1,
        "{}",
        servo.position_mm
    );

    // A second move with a goal time: force is already on.
    let report = move_to(
        &mut link,
        id(1),
        MoveOptions {
            time: Some(Ms10::from_millis(500)),
            force_on: false,
            ..to(-4.0)
        },
    )
    .await
    .unwrap();
    assert!(!report.switched_force_on);
    assert!(report.arrived, "{report:?}");
    assert!(
        report.elapsed >= Duration::from_millis(400),
        "the goal time slows it"
    );
    let servo = bus.handle().snapshot(1).unwrap();
    assert!(
        (servo.position_mm + 4.0).abs() <= 0.1,
        "{}",
        servo.position_mm
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_goal_beyond_the_limits_is_clamped_and_reported() {
    let bus = sim(&[1]);
    let mut link = link(&bus).await;
    set(
        &mut link,
        id(1),
        &Setting::parse_all(&["plus-limit=10"]).unwrap(),
        SetOptions::default(),
    )
    .await
    .unwrap();
    let report = move_to(&mut link, id(1), to(20.0)).await.unwrap();
    assert!(report.clamped());
    assert_eq!(report.goal.0, 1000);
    assert!(report.arrived);
    assert!(lj9da_bridge::commission::print::move_summary(&report).contains("clamped"));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn force_on_off_and_brake() {
    let bus = sim(&[1]);
    let handle = bus.handle();
    let mut link = link(&bus).await;
    for (mode, expected) in [
        (ForceMode::On, Force::On),
        (ForceMode::Brake, Force::Brake),
        (ForceMode::Off, Force::Off),
        (ForceMode::On, Force::On),
    ] {
        let report = set_force(&mut link, id(1), mode).await.unwrap();
        assert_eq!(report.after, mode);
        assert_eq!(handle.snapshot(1).unwrap().force, expected);
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn force_on_refused_by_the_servo_is_explained() {
    let bus = sim(&[1]);
    let handle = bus.handle();
    let mut link = link(&bus).await;
    set(
        &mut link,
        id(1),
        &Setting::parse_all(&["plus-limit=10"]).unwrap(),
        SetOptions::default(),
    )
    .await
    .unwrap();
    assert!(handle.move_rod(1, 20.0));
    let error = set_force(&mut link, id(1), ForceMode::On)
        .await
        .unwrap_err();
    assert!(!error.is_refusal());
    let text = error.to_string();
    assert!(
        text.contains("refused force on") && text.contains("outside the limits"),
        "{text}"
    );
    assert_eq!(handle.snapshot(1).unwrap().force, Force::Off);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn factory_reset_restores_id_1_and_the_defaults() {
    let bus = sim(&[4]);
    let handle = bus.handle();
    let mut link = link(&bus).await;
    set(
        &mut link,
        id(4),
        &Setting::parse_all(&["plus-limit=15", "reverse=1", "baud=57600"]).unwrap(),
        SetOptions::default(),
    )
    .await
    .unwrap();
    assert_eq!(link.baud(), BaudRate::B57600);
    let report = factory_reset(&mut link, id(4)).await.unwrap();
    assert_eq!(report.id_after.get(), 1);
    assert_eq!(report.baud_before, BaudRate::B57600);
    assert_eq!(report.baud_after, BaudRate::B115200);
    assert_eq!(link.baud(), BaudRate::B115200);
    assert!(report.notes.iter().any(|n| n.contains("now ID 1")));
    assert_eq!(report.map_after.plus_limit().0, 2500);
    assert!(!report.map_after.reversed());

    let servo = handle.snapshot(1).unwrap();
    assert_eq!(servo.registers[4], 1);
    assert_eq!(servo.registers[6], 0x07);
    assert_eq!(&servo.registers[8..12], &[0xC4, 0x09, 0x3C, 0xF6]);
    // It survives power-off: flash holds the factory values.
    assert!(handle.power_cycle(1));
    drop(link);
    let mut fresh = link_at(&bus, BaudRate::B115200).await;
    assert!(fresh.wait_for(id(1), Duration::from_secs(1)).await.unwrap());
    assert_eq!(handle.snapshot(1).unwrap().registers[5], 0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn factory_reset_is_refused_while_another_servo_has_id_1() {
    let bus = sim(&[1, 4]);
    let handle = bus.handle();
    let events = handle.subscribe();
    let mut link = link(&bus).await;
    let error = factory_reset(&mut link, id(4)).await.unwrap_err();
    assert!(matches!(error, CommissionError::Refused { .. }), "{error}");
    assert!(error.to_string().contains("ID 1"));
    assert!(writes(&events, &mut link).await.is_empty());
    assert_eq!(handle.snapshot(4).unwrap().registers[4], 4);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn monitor_takes_the_samples_asked_for() {
    let bus = sim(&[1, 2]);
    let events = bus.handle().subscribe();
    let mut link = link(&bus).await;
    let ids = [id(1), id(2), id(9)];
    let mut seen: Vec<(u64, Vec<MonitorRow>)> = Vec::new();
    let taken = monitor(
        &mut link,
        &ids,
        MonitorOptions {
            interval: Duration::from_millis(30),
            count: Some(3),
            duration: None,
        },
        std::future::pending(),
        |n, rows| seen.push((n, rows.to_vec())),
    )
    .await
    .unwrap();
    assert_eq!(taken, 3);
    assert_eq!(seen.iter().map(|(n, _)| *n).collect::<Vec<_>>(), [1, 2, 3]);
    for (_, rows) in &seen {
        assert_eq!(rows.len(), 3);
        for row in &rows[..2] {
            let sample = row.reading.as_ref().unwrap();
            assert_eq!(sample.telemetry.present_voltage.0, 1200);
            assert_eq!(sample.force, Some(ForceMode::Off));
            assert_eq!(sample.max_force_percent, 100);
        }
        assert_eq!(rows[2].reading, Err("no answer".to_string()));
    }
    let table = lj9da_bridge::commission::print::monitor_table(3, &seen[2].1);
    assert!(
        table.contains("12.00 V") && table.contains("no answer"),
        "{table}"
    );
    assert!(
        writes(&events, &mut link).await.is_empty(),
        "monitor writes nothing"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn monitor_stops_when_asked() {
    let bus = sim(&[1]);
    let mut link = link(&bus).await;
    // The stop is asked for as the third sample is handed out: the monitor must end there,
    // before a fourth. Counting samples, not milliseconds, keeps a busy machine out of it.
    let (ask_to_stop, asked) = tokio::sync::oneshot::channel::<()>();
    let mut ask_to_stop = Some(ask_to_stop);
    // With no count and no duration, a monitor that ignores the stop runs forever: fail
    // instead. 10 s is thousands of 20 ms intervals, far beyond any scheduling delay.
    let taken = tokio::time::timeout(
        Duration::from_secs(10),
        monitor(
            &mut link,
            &[id(1)],
            MonitorOptions {
                interval: Duration::from_millis(20),
                count: None,
                duration: None,
            },
            async {
                let _ = asked.await;
            },
            |n, _| {
                if n == 3
                    && let Some(ask) = ask_to_stop.take()
                {
                    let _ = ask.send(());
                }
            },
        ),
    )
    .await
    .expect("the monitor did not stop within 10 s of being asked to")
    .unwrap();
    assert_eq!(taken, 3, "the stop was asked for at the third sample");
}

//! `set` against the simulated bus: read-back, ID and baud changes in the manual's order,
//! `--save` surviving power-off, and refusals that write nothing.

mod commission_common;

use commission_common::{id, link, link_at, sim, writes};
use lj9da_bridge::commission::set::{SetOptions, set};
use lj9da_bridge::commission::{CommissionError, Setting};
use lj9da_bridge::protocol::BaudRate;
use lj9da_sim::HostPacket;
use lj9da_sim::protocol::host_packet::ShortForm;

const SAVE: SetOptions = SetOptions { save: true };
const NO_SAVE: SetOptions = SetOptions { save: false };

fn settings(args: &[&str]) -> Vec<Setting> {
    Setting::parse_all(args).unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn several_keys_are_written_and_read_back() {
    let bus = sim(&[1]);
    let handle = bus.handle();
    let mut link = link(&bus).await;
    let wanted = settings(&[
        "plus-limit=20.0",
        "minus-limit=-20.0",
        "plus-margin=1",
        "minus-margin=1",
        "plus-slope=16",
        "minus-slope=0x10",
        "punch=0x0120",
        "return-delay=1",
        "reverse=1",
        "max-force=80",
    ]);
    let report = set(&mut link, id(1), &wanted, NO_SAVE).await.unwrap();
    assert!(!report.saved);
    assert!(report.notes.iter().any(|n| n.contains("lost at power-off")));
    let keys: Vec<&str> = report.changes.iter().map(|c| c.key).collect();
    assert_eq!(
        keys,
        [
            "reverse",
            "return-delay",
            "plus-limit",
            "minus-limit",
            "plus-margin",
            "minus-margin",
            "plus-slope",
            "minus-slope",
            "punch",
            "max-force"
        ]
    );
    let plus = report
        .changes
        .iter()
        .find(|c| c.key == "plus-limit")
        .unwrap();
    assert_eq!(
        (plus.before.as_str(), plus.after.as_str()),
        ("+25.00 mm", "+20.00 mm")
    );

    let servo = handle.snapshot(1).unwrap();
    let r = &servo.registers;
    assert_eq!(r[5], 1, "reverse");
    assert_eq!(r[7], 1, "return delay");
    assert_eq!(i16::from_le_bytes([r[8], r[9]]), 2000);
    assert_eq!(i16::from_le_bytes([r[10], r[11]]), -2000);
    assert_eq!(&r[24..30], &[1, 1, 0x10, 0x10, 0x20, 0x01]);
    assert_eq!(r[35], 80, "max force");
    // Not saved: flash still holds the factory limits, and power-off loses the values.
    assert_eq!(&servo.flash[8 - 4..10 - 4], &[0xC4, 0x09]);
    assert!(handle.power_cycle(1));
    let servo = handle.snapshot(1).unwrap();
    assert_eq!(
        i16::from_le_bytes([servo.registers[8], servo.registers[9]]),
        2500
    );
    assert_eq!(servo.registers[35], 100);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn saved_settings_survive_power_off_but_max_force_does_not() {
    let bus = sim(&[1]);
    let handle = bus.handle();
    let mut link = link(&bus).await;
    let report = set(
        &mut link,
        id(1),
        &settings(&["plus-limit=15", "punch=0x200", "max-force=60"]),
        SAVE,
    )
    .await
    .unwrap();
    assert!(report.saved);
    assert!(
        report
            .notes
            .iter()
            .any(|n| n.contains("max force lives in RAM"))
    );
    // After the reboot of --save, max force was written again.
    assert_eq!(handle.snapshot(1).unwrap().registers[35], 60);
    assert!(handle.power_cycle(1));
    let servo = handle.snapshot(1).unwrap();
    assert_eq!(
        i16::from_le_bytes([servo.registers[8], servo.registers[9]]),
        1500
    );
    assert_eq!(&servo.registers[28..30], &[0x00, 0x02]);
    assert_eq!(servo.registers[35], 100, "max force is RAM: back to 100 %");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_id_change_without_save_is_lost_at_power_off() {
    let bus = sim(&[1]);
    let handle = bus.handle();
    let mut link = link(&bus).await;
    let report = set(&mut link, id(1), &settings(&["id=5"]), NO_SAVE)
        .await
        .unwrap();
    assert_eq!(report.id_after.get(), 5);
    assert!(link.ping(id(5)).await.unwrap());
    assert!(!link.ping(id(1)).await.unwrap());
    assert!(handle.power_cycle(5));
    assert!(
        link.wait_for(id(1), std::time::Duration::from_secs(1))
            .await
            .unwrap()
    );
    assert!(!link.ping(id(5)).await.unwrap());
    assert_eq!(handle.snapshot(1).unwrap().registers[4], 1);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_id_change_with_save_survives_power_off() {
    let bus = sim(&[1]);
    let handle = bus.handle();
    let events = handle.subscribe();
    let mut link = link(&bus).await;
    let report = set(&mut link, id(1), &settings(&["id=5"]), SAVE)
        .await
        .unwrap();
    assert!(report.saved);
    assert_eq!(handle.snapshot(5).unwrap().flash[0], 5);
    // The manual's order: write the ID, then flash, then reboot, each its own packet.
    let order: Vec<String> = writes(&events, &mut link)
        .await
        .iter()
        .map(|p| match p {
            HostPacket::Short(s) => match s.form() {
                ShortForm::Write { address, data, .. } => {
                    format!("{}: write {address}={data:?}", s.id)
                }
                ShortForm::Special(command) => format!("{}: {command:?}", s.id),
                other => format!("{}: {other:?}", s.id),
            },
            HostPacket::Long(_) => "long".into(),
        })
        .collect();
    assert_eq!(order, ["1: write 4=[5]", "5: WriteFlash", "5: Reboot"]);
    assert!(handle.power_cycle(5));
    assert!(
        link.wait_for(id(5), std::time::Duration::from_secs(1))
            .await
            .unwrap()
    );
    assert!(!link.ping(id(1)).await.unwrap());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_baud_change_end_to_end() {
    let bus = sim(&[1]);
    let handle = bus.handle();
    let mut link = link(&bus).await;
    let report = set(&mut link, id(1), &settings(&["baud=230400"]), SAVE)
        .await
        .unwrap();
    assert_eq!(report.baud_before, BaudRate::B115200);
    assert_eq!(report.baud_after, BaudRate::B230400);
    assert_eq!(link.baud(), BaudRate::B230400);
    let servo = handle.snapshot(1).unwrap();
    assert_eq!(servo.baud, Some(230_400));
    assert_eq!(servo.flash[6 - 4], 0x09);
    drop(link);

    assert!(handle.power_cycle(1));
    let mut slow = link_at(&bus, BaudRate::B115200).await;
    assert!(!slow.ping(id(1)).await.unwrap(), "no longer at 115200");
    drop(slow);
    let mut fast = link_at(&bus, BaudRate::B230400).await;
    assert!(
        fast.wait_for(id(1), std::time::Duration::from_secs(1))
            .await
            .unwrap()
    );
    let report = lj9da_bridge::commission::info::info(&mut fast, id(1))
        .await
        .unwrap();
    assert_eq!(report.map.baud_rate().unwrap(), BaudRate::B230400);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn id_and_baud_change_together_then_back() {
    let bus = sim(&[1]);
    let mut link = link(&bus).await;
    let report = set(
        &mut link,
        id(1),
        &settings(&["baud=460800", "id=9", "plus-limit=24"]),
        NO_SAVE,
    )
    .await
    .unwrap();
    assert_eq!(
        (report.id_after.get(), report.baud_after),
        (9, BaudRate::B460800)
    );
    assert_eq!(report.map_after.plus_limit().0, 2400);
    let back = set(
        &mut link,
        id(9),
        &settings(&["baud=115200", "id=1"]),
        NO_SAVE,
    )
    .await
    .unwrap();
    assert_eq!(
        (back.id_after.get(), back.baud_after),
        (1, BaudRate::B115200)
    );
    assert_eq!(bus.handle().snapshot(1).unwrap().baud, Some(115_200));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn dangerous_values_are_refused_before_anything_is_built() {
    for arg in [
        "plus-limit=25.01",
        "minus-limit=-25.01",
        "baud=921600",
        "baud=0x0B",
        "id=0",
        "id=128",
        "model-number=0x1234",
        "firmware-version=2",
        "temperature-limit=90",
        "present-position=0",
        "reg:12=1",
    ] {
        let error = Setting::parse_all(&["plus-limit=20", arg]).unwrap_err();
        assert!(error.is_refusal(), "{arg}: {error}");
        assert!(error.to_string().contains("nothing was written"), "{error}");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_id_already_on_the_bus_is_refused_and_nothing_is_written() {
    let bus = sim(&[1, 2, 3]);
    let handle = bus.handle();
    let events = handle.subscribe();
    let before = handle.snapshot(1).unwrap();
    let mut link = link(&bus).await;
    let error = set(
        &mut link,
        id(1),
        &settings(&["plus-limit=10", "id=3"]),
        SAVE,
    )
    .await
    .unwrap_err();
    assert!(
        matches!(error, CommissionError::IdTaken { new, .. } if new.get() == 3),
        "{error}"
    );
    assert!(error.is_refusal());
    assert!(
        writes(&events, &mut link).await.is_empty(),
        "no write reached the bus"
    );
    let after = handle.snapshot(1).unwrap();
    assert_eq!(before.registers[..42], after.registers[..42]);
    assert_eq!(before.flash, after.flash);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_servo_that_does_not_answer_gets_nothing_written() {
    let bus = sim(&[1]);
    let events = bus.handle().subscribe();
    let mut link = link(&bus).await;
    let error = set(&mut link, id(4), &settings(&["punch=1"]), SAVE)
        .await
        .unwrap_err();
    assert!(matches!(error, CommissionError::NoServo { .. }), "{error}");
    assert!(writes(&events, &mut link).await.is_empty());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_device_that_is_not_an_lj9da41_is_refused() {
    let bus = sim(&[1]);
    let handle = bus.handle();
    assert!(handle.set_model_number(1, 0x1234));
    let events = handle.subscribe();
    let mut link = link(&bus).await;
    let error = set(&mut link, id(1), &settings(&["plus-limit=10"]), NO_SAVE)
        .await
        .unwrap_err();
    assert!(
        matches!(error, CommissionError::NotLj9da41 { model: 0x1234, .. }),
        "{error}"
    );
    assert!(writes(&events, &mut link).await.is_empty());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn reversing_is_refused_while_force_is_on() {
    let bus = sim(&[1]);
    let handle = bus.handle();
    let mut link = link(&bus).await;
    lj9da_bridge::commission::motion::set_force(
        &mut link,
        id(1),
        lj9da_bridge::protocol::ForceMode::On,
    )
    .await
    .unwrap();
    let events = handle.subscribe();
    let error = set(&mut link, id(1), &settings(&["reverse=1"]), NO_SAVE)
        .await
        .unwrap_err();
    assert!(error.is_refusal(), "{error}");
    assert!(error.to_string().contains("force off first"), "{error}");
    assert!(writes(&events, &mut link).await.is_empty());
    assert_eq!(handle.snapshot(1).unwrap().registers[5], 0);
}

//! `scan` and `info` against the simulated bus, and the link underneath them.

mod commission_common;

use commission_common::{id, is_write, link, packets, sim, writes};
use lj9da_bridge::commission::info::info;
use lj9da_bridge::commission::scan::{ScanOptions, scan};
use lj9da_bridge::commission::set::{SetOptions, set};
use lj9da_bridge::commission::{CommissionError, Link, LinkError, Setting};
use lj9da_bridge::protocol::{BaudRate, ReplyRequest, ServoId, ShortPacket};
use std::time::Duration;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn scan_finds_exactly_the_configured_ids_with_model_0x7510() {
    let bus = sim(&[1, 2, 3]);
    let events = bus.handle().subscribe();
    let mut link = link(&bus).await;
    let report = scan(&mut link, &ScanOptions::new(BaudRate::B115200, false))
        .await
        .unwrap();
    assert_eq!(report.ids(), [1, 2, 3]);
    assert_eq!(report.ids_probed, 127);
    for servo in &report.found {
        assert_eq!(servo.model, Some(0x7510));
        assert_eq!(servo.firmware, Some(0x01));
        assert_eq!(servo.baud, BaudRate::B115200);
        assert_eq!(servo.problem, None);
        let t = servo.telemetry.expect("telemetry of a found servo");
        assert_eq!(t.present_voltage.0, 1200, "12.00 V");
        assert_eq!(t.present_position.0, 0);
    }
    println!(
        "scan of 127 IDs at 115200 bit/s: {:.3} s",
        report.elapsed.as_secs_f64()
    );
    assert!(
        writes(&events, &mut link).await.is_empty(),
        "a scan writes nothing"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_servo_at_another_baud_is_found_only_with_all_bauds() {
    let bus = sim(&[1, 2]);
    let mut link = link(&bus).await;
    // Servo 2 moves to 57 600 bit/s (RAM only).
    set(
        &mut link,
        id(2),
        &[Setting::Baud(BaudRate::B57600)],
        SetOptions::default(),
    )
    .await
    .unwrap();
    link.reopen(BaudRate::B115200).await.unwrap();
    let ids: Vec<ServoId> = (1..=4).map(id).collect();

    let mut one_rate = ScanOptions::new(BaudRate::B115200, false);
    one_rate.ids = ids.clone();
    let report = scan(&mut link, &one_rate).await.unwrap();
    assert_eq!(report.ids(), [1]);

    let mut every_rate = ScanOptions::new(BaudRate::B115200, true);
    every_rate.ids = ids;
    every_rate.ping_margin = Duration::from_millis(15);
    let report = scan(&mut link, &every_rate).await.unwrap();
    let found: Vec<(u8, u32)> = report
        .found
        .iter()
        .map(|f| (f.id.get(), f.baud.bits_per_second()))
        .collect();
    assert_eq!(found, [(2, 57_600), (1, 115_200)]);
    assert_eq!(report.bauds.len(), 11);
    // The link is back at its own rate.
    assert_eq!(link.baud(), BaudRate::B115200);
    assert!(link.ping(id(1)).await.unwrap());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn info_decodes_the_factory_defaults() {
    let bus = sim(&[1]);
    let events = bus.handle().subscribe();
    let mut link = link(&bus).await;
    let report = info(&mut link, id(1)).await.unwrap();
    let m = &report.map;
    assert_eq!(m.model_number(), 0x7510);
    assert_eq!(m.plus_limit().0, 2500);
    assert_eq!(m.minus_limit().0, -2500);
    assert_eq!(m.baud_rate().unwrap(), BaudRate::B115200);
    assert_eq!(m.temperature_limit().0, 85);
    assert_eq!(m.max_force_raw(), 100);
    assert_eq!(m.telemetry().present_voltage.0, 1200);
    assert!(!report.flags.temperature_alarm() && !report.flags.temperature_error());

    let rows = report.registers();
    let reading = |name: &str| {
        rows.iter()
            .find(|(r, _, _)| r.name == name)
            .map(|(_, _, reading)| reading.clone())
            .unwrap()
    };
    assert_eq!(reading("Temperature Limit"), "85 °C");
    assert_eq!(reading("Plus Position Limit"), "+25.00 mm");
    assert_eq!(reading("Minus Position Limit"), "-25.00 mm");
    assert_eq!(reading("Baud Rate"), "115200 bit/s");
    assert!(reading("Model Number").contains("LJ9DA41"));
    assert_eq!(
        rows.iter()
            .map(|(r, _, _)| usize::from(r.size))
            .sum::<usize>(),
        60,
        "every register 0–59 is described"
    );

    let json = report.to_json().pretty();
    for field in [
        "\"temperature_limit_c\": 85",
        "\"plus_limit_mm\": 25.00",
        "\"minus_limit_mm\": -25.00",
        "\"baud\": 115200",
        "\"model_number\": 29968",
        "\"temperature_alarm\": false",
        "\"name\": \"Punch\"",
    ] {
        assert!(json.contains(field), "{field} missing from\n{json}");
    }
    // One look at the line, both checks on it: a second look would start after the first
    // had drained the events and see nothing.
    let asked = packets(&events, &mut link).await;
    assert_eq!(
        asked.len(),
        2,
        "two requests: registers 0–29 and 30–59: {asked:?}"
    );
    let written: Vec<_> = asked.iter().filter(|p| is_write(p)).collect();
    assert!(written.is_empty(), "info writes nothing: {written:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn info_of_a_servo_that_does_not_answer_says_so() {
    let bus = sim(&[1]);
    let mut link = link(&bus).await;
    let error = info(&mut link, id(9)).await.unwrap_err();
    assert!(
        matches!(error, CommissionError::NoServo { id, .. } if id.get() == 9),
        "{error}"
    );
    assert!(error.to_string().contains("servo 9 does not answer"));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_timeout_names_the_servo_what_was_sent_and_the_timeout() {
    let bus = sim(&[1]);
    let mut link = link(&bus).await;
    link.set_retries(1);
    let error = link
        .read(id(5), ReplyRequest::Registers42To59)
        .await
        .unwrap_err();
    let LinkError::Timeout {
        id, attempts, sent, ..
    } = &error
    else {
        panic!("expected a timeout, got {error}");
    };
    assert_eq!((*id, *attempts), (5, 2));
    assert_eq!(sent, "FA AF 05 09 00 00 01 0D");
    let text = error.to_string();
    assert!(text.contains("servo 5 did not answer within"), "{text}");
    assert!(
        text.contains("registers 42–59") && text.contains("2 attempts"),
        "{text}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_timeout_follows_wire_time_and_the_learned_return_delay() {
    let bus = sim(&[1]);
    let mut link = link(&bus).await;
    let request = ShortPacket::request(id(1), ReplyRequest::Registers42To59);
    // 8 + 26 bytes at 115 200 bit/s = 2.95 ms, plus the margin.
    let wire = Duration::from_nanos(BaudRate::B115200.wire_time_ns(8 + 26));
    assert_eq!(link.timeout_for(&request), wire + Link::DEFAULT_MARGIN);
    set(
        &mut link,
        id(1),
        &[Setting::ReturnDelay(30)],
        SetOptions::default(),
    )
    .await
    .unwrap();
    assert_eq!(
        link.timeout_for(&request),
        wire + Duration::from_millis(30) + Link::DEFAULT_MARGIN
    );
    // With a 30 ms return delay and a 5 ms margin the reply still arrives in time.
    link.set_margin(Duration::from_millis(5));
    assert!(
        link.read(id(1), ReplyRequest::Registers42To59)
            .await
            .is_ok()
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn scan_and_info_work_through_an_echoing_adapter() {
    let bus = sim(&[2]);
    bus.handle().set_echo(true);
    let mut link = link(&bus).await;
    let mut options = ScanOptions::new(BaudRate::B115200, false);
    options.ids = (1..=3).map(id).collect();
    let report = scan(&mut link, &options).await.unwrap();
    assert_eq!(report.ids(), [2]);
    let report = info(&mut link, id(2)).await.unwrap();
    assert_eq!(report.map.model_number(), 0x7510);
}

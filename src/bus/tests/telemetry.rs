//! Telemetry polls and what becomes of their readings: full polls round-robin, published, and
//! stale when replies stop; a position read replaces only the position of the latest
//! telemetry; goals faster than the gathering window do not starve the polls; and the
//! driver's publishing, which shows every reading because a reply that would replace an
//! unshown one is announced before it is read.

use super::*;

#[test]
fn telemetry_polls_go_round_robin_and_are_published() {
    let mut rig = Rig::online_with_force_on(full_polls_only(&[1, 2, 3, 4]));
    rig.servo(3).position = 77;
    rig.servo(3).load = 42;
    rig.servo(3).temperature = 51;
    rig.servo(3).voltage = 1111;
    rig.servo(3).flags = 0x20 | 0x02;
    let from = rig.log.len();
    rig.run(ms(200));
    let polled: Vec<u8> = rig
        .sent_since(from)
        .iter()
        .filter_map(|s| match s.tx.kind {
            TxKind::Poll(i) => Some(i.get()),
            _ => None,
        })
        .collect();
    assert!(polled.len() >= 40, "{}", polled.len());
    for w in polled.windows(2) {
        assert_eq!(w[1], w[0] % 4 + 1, "{polled:?}");
    }
    let st = rig.m.status();
    let s3 = st.servo(id(3)).unwrap();
    let t = s3.telemetry.unwrap();
    assert_eq!(t.present_position, MmCenti(77));
    assert_eq!(t.present_load, Ma10(42));
    assert_eq!(t.present_temperature.0, 51);
    assert_eq!(t.present_voltage.0, 1111);
    assert_eq!(s3.flags, ReplyFlags(0x20), "bit 1 ignored");
    assert!(s3.age.unwrap() < ms(20));
    assert_eq!(s3.health, Health::Online);
    // With no replies for longer than stale_after (but fewer timeouts than needed for
    // offline), the servo is stale.
    let mut m = rig.m;
    let later = rig.t + ms(600);
    m.handle_timeout(later);
    assert_eq!(m.status().servo(id(3)).unwrap().health, Health::Stale);
    assert!(m.status().servo(id(3)).unwrap().age.unwrap() >= ms(600));
}

/// A driver's view (see [`Publisher`]) of the readings of servos `ids`, polled at 50 Hz, over
/// 2 s of goals at 50 Hz on two ports, with an event every 13 ms. Returns the readings the servos gave
/// (full, position-and-current, position-only) and the readings the snapshots showed.
fn readings_shown(ids: &[u8], guarded: bool) -> (u64, u64) {
    let mut cfg = config(ids);
    cfg.telemetry_min_interval = ms(20);
    let spacing = driver::publish_spacing(&cfg);
    let mut rig = Rig::online_with_force_on(cfg);
    rig.settle();
    rig.m.take_changed();
    rig.publisher = Some(Publisher {
        spacing,
        event_every: ms(13),
        guarded,
        taken_at: rig.t,
        next_event: rig.t + ms(13),
        snapshots: vec![rig.m.status_at(rig.t)],
        guards: 0,
        early_every: 3,
        looked_early: None,
    });
    let from = rig.log.len();
    let mut position = 0;
    for _ in 0..100 {
        position = (position + 37) % 2000;
        let goals: Vec<(u8, Goal)> = ids
            .iter()
            .map(|&n| (n, Goal::Position(MmCenti(position - 1000))))
            .collect();
        // Two messages a tick, as from an autopilot's two output ports: the second closes
        // the tick's gathering window, and its frame goes out at once.
        rig.message(&goals);
        rig.run(us(100));
        rig.message(&[]);
        rig.run(ms(20) - us(100));
    }
    rig.settle();
    let mut publisher = rig.publisher.take().unwrap();
    publisher.take(&mut rig.m, rig.t);
    assert!(
        !guarded || publisher.guards > 0,
        "no reply would have hidden a reading"
    );
    let given = rig
        .sent_since(from)
        .iter()
        .filter(|s| {
            matches!(
                s.tx.kind,
                TxKind::Poll(_) | TxKind::MotionPoll(_) | TxKind::PositionPoll(_)
            )
        })
        .count() as u64;
    let mut shown = 0;
    for &n in ids {
        let reading = |s: &BusStatus| {
            let servo = s.servo(id(n)).unwrap();
            (servo.telemetry_count, servo.position_at)
        };
        shown += publisher
            .snapshots
            .windows(2)
            .filter(|w| reading(&w[0]) != reading(&w[1]))
            .count() as u64;
    }
    (given, shown)
}

#[test]
fn a_reply_that_would_replace_an_unshown_reading_is_announced_before_it_is_read() {
    for ids in [&[1][..], &[1, 2]] {
        let (given, shown) = readings_shown(ids, true);
        assert!(given >= 90 * ids.len() as u64, "{ids:?}: {given} readings");
        assert_eq!(shown, given, "{ids:?}: readings shown of those given");
        // The same driver without the look before each reply misses readings: the test can
        // tell.
        let (given, shown) = readings_shown(ids, false);
        assert!(shown < given, "{ids:?}: {shown} of {given} shown unguarded");
    }
}

#[test]
fn a_position_read_replaces_only_the_position_of_the_latest_telemetry() {
    let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
    for n in 1..=4 {
        rig.servo(n).stuck = true;
    }
    // Every period the rods stand somewhere else and draw another current: a value read tells
    // the period it was read in.
    let mut periods = Vec::new();
    let position_read = |rig: &Rig, from: usize| {
        rig.sent_since(from)
            .iter()
            .any(|s| matches!(s.tx.kind, TxKind::PositionPoll(_)))
    };
    'stream: for k in 0..80i16 {
        periods.push(rig.t);
        for n in 1..=4u8 {
            rig.servo(n).position = 2000 + k;
            rig.servo(n).load = 100 + k as u16;
        }
        let goals: Vec<_> = (1..=4u8)
            .map(|n| (n, Goal::Position(MmCenti(k * 10 + i16::from(n)))))
            .collect();
        rig.message(&goals);
        // At 55.6 Hz the time left before each goal often fits a position read, not more.
        if k < 40 {
            rig.run(ms(18));
            continue;
        }
        // Then stop at the first position read, once its reply is in.
        let (from, end) = (rig.log.len(), rig.t + ms(18));
        while rig.t < end {
            rig.run(us(50));
            if position_read(&rig, from) {
                break 'stream;
            }
        }
    }
    rig.settle();
    let period_of = |t: Instant| periods.iter().rposition(|p| *p <= t).unwrap() as i16;
    // The fake servo answers with the values of the instant a request is written.
    let last_request = |n: u8, kinds: &[fn(ServoId) -> TxKind]| {
        rig.log
            .iter()
            .rev()
            .find(|s| kinds.iter().any(|k| s.tx.kind == k(id(n))))
            .map(|s| s.at)
            .expect("a request")
    };
    let status = rig.m.status();
    let mut position_only = 0;
    for s in &status.servos {
        let n = s.id.get();
        let t = s.telemetry.expect("telemetry");
        let full = last_request(n, &[TxKind::Poll]);
        let load = last_request(n, &[TxKind::Poll, TxKind::MotionPoll]);
        let position = last_request(n, &[TxKind::Poll, TxKind::MotionPoll, TxKind::PositionPoll]);
        // Temperature and voltage of the last full poll; the load of the last full poll or
        // read of position and current; the position of the last read of any kind.
        assert!(s.telemetry_at.unwrap() > full);
        assert_eq!(t.present_load.0, 100 + period_of(load) as u16, "servo {n}");
        assert_eq!(
            t.present_position.0,
            2000 + period_of(position),
            "servo {n}"
        );
        if position > load {
            position_only += 1;
        }
    }
    assert!(
        position_only > 0,
        "no servo was last read by a position read"
    );
}

#[test]
fn goals_faster_than_the_gathering_do_not_starve_telemetry() {
    let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
    let c0 = *rig.m.counters();
    // A goal every 300 µs for a second: no quiet spell ever opens a gathering window after
    // the first.
    for k in 0..3333i16 {
        rig.set_goal(1 + (k % 4) as u8, Goal::Position(MmCenti(k % 2000)));
        rig.run(us(300));
    }
    let c = rig.m.counters();
    let reads = (c.polls + c.motion_polls) - (c0.polls + c0.motion_polls);
    assert!(reads >= 200, "{reads} telemetry reads in a second");
}

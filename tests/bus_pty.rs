//! The bus driver over a real pseudo-terminal against the simulated LJ9DA41 bus: commands reach
//! the servos, telemetry comes back, the line is never talked over, shutdown leaves the servos
//! as asked.

mod bus_support;

use bus_support::*;
use lj9da_bridge::bus::{ForceState, Goal, ShutdownForce, spawn_bus};
use lj9da_bridge::protocol::{BaudRate, MmCenti};
use lj9da_sim::{BusEvent as SimEvent, Force, HostPacket};
use std::time::Duration;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn servos_reach_their_goals_and_telemetry_is_published() {
    let ids = [1, 2, 3, 4];
    let sim = spawn_sim(sim_config(&ids, 115_200));
    let cfg = bus_config(&ids, BaudRate::B115200);
    let stale_after = cfg.stale_after;
    let bus = spawn_bus(cfg, sim.path());
    let st = every_servo_online(&bus).await;
    for s in &st.servos {
        assert_eq!(s.identity.model, Some(0x7510));
        assert_eq!(s.force, ForceState::Off, "no force before a goal");
    }
    let goals = [(1, 250), (2, -250), (3, 500), (4, -75)];
    for (n, mm_centi) in goals {
        bus.set_goal(id(n), Goal::Position(MmCenti(mm_centi)));
    }
    // The first move is a soft start at 10 mm/s: 5 mm takes 0.5 s.
    let st = wait_status(&bus, "every servo at its goal", |s| {
        goals.iter().all(|&(n, goal)| {
            s.servo(id(n))
                .and_then(|s| s.telemetry)
                .is_some_and(|t| (t.present_position.0 - goal).abs() <= 4)
        })
    })
    .await;
    for (n, goal) in goals {
        let snap = sim.handle().snapshot(n).unwrap();
        assert_eq!(snap.force, Force::On);
        assert!(
            (snap.position_mm - f32::from(goal) / 100.0).abs() < 0.05,
            "servo {n}: {snap:?}"
        );
        let s = st.servo(id(n)).unwrap();
        assert_eq!(s.goal, Some(MmCenti(goal)));
        let t = s.telemetry.unwrap();
        assert!((11.9..=12.1).contains(&t.present_voltage.volts()), "{t:?}");
        assert!(t.present_temperature.0 >= 20, "{t:?}");
        assert!(t.present_load.0 > 0, "{t:?}");
        // Fresh as the bridge defines it: younger than `stale_after` (what makes a servo Online
        // rather than Stale), not a figure of our own that an idle machine happens to meet.
        assert_eq!(s.health, lj9da_bridge::bus::Health::Online, "{s:?}");
        assert!(s.age.unwrap() < stale_after, "fresh: {s:?}");
    }
    // And it stays fresh: every servo is polled again (two more replies each), whatever the
    // machine's load makes of the milliseconds between polls.
    let counts: Vec<u64> = st.servos.iter().map(|s| s.telemetry_count).collect();
    wait_status(&bus, "two more telemetry replies from every servo", |s| {
        s.servos
            .iter()
            .zip(&counts)
            .all(|(s, before)| s.telemetry_count >= before + 2)
    })
    .await;
    // A second, quick move: the long packet carries every servo.
    let events = sim.handle().subscribe();
    bus.set_goal(id(3), Goal::Position(MmCenti(-600)));
    let deadline = std::time::Instant::now() + PATIENCE;
    let long = loop {
        let event = events
            .recv_timeout(deadline.saturating_duration_since(std::time::Instant::now()))
            .expect("a long packet");
        if let SimEvent::Packet(p) = event
            && let HostPacket::Long(_) = p.packet
        {
            break p.packet;
        }
    };
    assert_eq!(
        long.goal_positions(),
        vec![(1, 250), (2, -250), (3, -600), (4, -75)]
    );
    wait_status(&bus, "servo 3 at −6 mm", |s| {
        s.servo(id(3))
            .and_then(|s| s.telemetry)
            .is_some_and(|t| (t.present_position.0 + 600).abs() <= 4)
    })
    .await;
    bus.shutdown(ShutdownForce::AsIs).await;
    assert!(bus.is_finished());
}

/// Attempts at a goal stream the simulator keeps time through: only such a one is judged
/// strictly.
const ATTEMPTS: usize = 3;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_line_is_never_talked_over_and_every_request_is_answered() {
    for attempt in 1..=ATTEMPTS {
        if goal_stream_with_telemetry().await {
            return;
        }
        println!(
            "attempt {attempt}: the simulator ran late: not judged (no talk-over, every request \
             answered); only that the bridge wrote over no reply it waited for"
        );
    }
    panic!(
        "the simulator ran late in each of {ATTEMPTS} attempts: the line was never judged strictly"
    );
}

/// One goal stream with telemetry polled in its gaps; whether the simulator kept time (and the
/// strict checks ran).
async fn goal_stream_with_telemetry() -> bool {
    let ids = [1, 2, 3];
    let sim = spawn_sim(sim_config(&ids, 460_800));
    let bus = spawn_bus(bus_config(&ids, BaudRate::B460800), sim.path());
    let st = every_servo_online(&bus).await;
    let before: Vec<(u64, u64)> = st
        .servos
        .iter()
        .map(|s| (s.telemetry_count, s.timeouts))
        .collect();
    let events = sim.handle().subscribe();
    // Goals at ~500 Hz for a second while telemetry is polled in the gaps.
    for k in 0..500i16 {
        for n in ids {
            bus.set_goal(id(n), Goal::Position(MmCenti((k % 50) * 10 - 250)));
        }
        tokio::time::sleep(Duration::from_millis(2)).await;
    }
    // The last goals (+2.40 mm) reach the wire, then every goal is accounted for.
    let st = wait_status(&bus, "the last goals on the wire", |s| {
        s.servos.iter().all(|s| s.goal == Some(MmCenti(240)))
    })
    .await;
    let stats = sim.handle().stats();
    let c = st.counters;
    let judged = assert_line_kept(&stats, &st, &talk_overs(&events));
    assert!(c.command_frames > 100, "{c:?}");
    // Telemetry was polled in the gaps of the goal stream: counted per servo, not per second,
    // so a longer stream on a busy machine is no excuse and no threat. Where the simulator
    // kept time every poll is answered: at least 20 replies per servo during the 500 goal
    // messages (≈ 90 per servo on an idle machine). Where it ran late, its servos answer late
    // or not at all and the bridge's answer to missing replies is not this test's subject:
    // every servo must still have been polled during the stream, and the attempt is not
    // judged (the caller tries again).
    for (s, (replies, timeouts)) in st.servos.iter().zip(&before) {
        let answered = s.telemetry_count - replies;
        let polled = answered + (s.timeouts - timeouts);
        if stats.handed_late == 0 {
            assert!(
                answered >= 20,
                "servo {}: {answered} telemetry replies during 500 goal messages: {c:?}",
                s.id
            );
        } else {
            assert!(
                polled >= 1,
                "servo {}: never polled during 500 goal messages: {c:?}",
                s.id
            );
        }
    }
    assert_eq!(c.goals_received, 1500);
    assert_eq!(
        c.goals_received,
        c.goals_sent + c.goals_superseded + c.goals_unchanged,
        "every goal sent, superseded or unchanged: {c:?}"
    );
    bus.shutdown(ShutdownForce::AsIs).await;
    judged
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_goals_of_one_message_leave_in_one_long_packet() {
    let ids = [1, 2, 3, 4];
    let sim = spawn_sim(sim_config(&ids, 115_200));
    let mut cfg = bus_config(&ids, BaudRate::B115200);
    // An idle bus: telemetry rarely, so the goals find the line free.
    cfg.telemetry_min_interval = Duration::from_secs(5);
    cfg.verify_interval = Duration::from_secs(5);
    cfg.stale_after = Duration::from_secs(20);
    let cfg_telemetry_interval = cfg.telemetry_min_interval;
    let bus = spawn_bus(cfg, sim.path());
    every_servo_online(&bus).await;
    bus.output_message(ids.map(|n| (id(n), Goal::Position(MmCenti(0)))));
    wait_status(&bus, "force on", all_online_with_force).await;
    let events = sim.handle().subscribe();
    bus.output_message(ids.map(|n| (id(n), Goal::Position(MmCenti(10 * i16::from(n))))));
    // Every long packet from the goals on, until the bus master's next short packet (its next
    // poll, within `telemetry_min_interval`): a goal left behind by a split message would have
    // gone out before it. Waiting for that packet, rather than a fixed 200 ms, means the window
    // has really passed however late the simulator reads the line.
    let deadline = std::time::Instant::now() + cfg_telemetry_interval + PATIENCE;
    let mut longs: Vec<Vec<(u8, i16)>> = Vec::new();
    loop {
        let event = events
            .recv_timeout(deadline.saturating_duration_since(std::time::Instant::now()))
            .unwrap_or_else(|_| panic!("no poll after the goals; long packets so far: {longs:?}"));
        if let SimEvent::Packet(p) = event {
            match p.packet {
                HostPacket::Long(_) => longs.push(p.packet.goal_positions()),
                HostPacket::Short(_) if !longs.is_empty() => break,
                HostPacket::Short(_) => {}
            }
        }
    }
    assert_eq!(longs, vec![vec![(1, 10), (2, 20), (3, 30), (4, 40)]]);
    bus.shutdown(ShutdownForce::AsIs).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shutdown_with_force_off_leaves_every_servo_limp() {
    let ids = [1, 2];
    let sim = spawn_sim(sim_config(&ids, 115_200));
    let bus = spawn_bus(bus_config(&ids, BaudRate::B115200), sim.path());
    every_servo_online(&bus).await;
    hold_with_force_on(&bus, &ids, MmCenti(0)).await;
    assert_eq!(sim.handle().snapshot(1).unwrap().force, Force::On);
    bus.shutdown(ShutdownForce::Off).await;
    assert!(bus.is_finished());
    for n in ids {
        assert_eq!(
            sim.handle().snapshot(n).unwrap().force,
            Force::Off,
            "servo {n}"
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_port_is_left_reading_byte_by_byte_after_shutdown() {
    use nix::sys::termios::{SpecialCharacterIndices, tcgetattr};
    let ids = [1, 2];
    let sim = spawn_sim(sim_config(&ids, 115_200));
    let bus = spawn_bus(bus_config(&ids, BaudRate::B115200), sim.path());
    // Online means replies were awaited with the read threshold raised.
    every_servo_online(&bus).await;
    bus.shutdown(ShutdownForce::AsIs).await;
    let port = std::fs::File::open(sim.path()).expect("the pty is still there");
    let termios = tcgetattr(&port).expect("a tty");
    assert_eq!(
        termios.control_chars[SpecialCharacterIndices::VMIN as usize],
        1
    );
    assert_eq!(
        termios.control_chars[SpecialCharacterIndices::VTIME as usize],
        0
    );
}

/// A servo that answers after its allowance while the bridge runs at its own 2 ms allowance.
/// Every servo has a return delay of 3 ms (the remedy for an adapter slow to release the line);
/// servo 3 answers 1 ms later than that, within its allowance, and every 4th reply of servo 2
/// starts 5.3 ms late: after the bridge gave up on it and wrote servo 3's request, so that it
/// lies in the tty before servo 3's reply. The late reply is never taken for the awaited one:
/// no reply is written over by a packet that follows, within 3 ms, the end of another servo's
/// reply that came while it was awaited (the bridge that took servo 2's late reply for servo
/// 3's wrote its next packet there, 16–19 times in 250 goals). (Servo 2's own late replies
/// may meet a packet written after its allowance ended: that is what an allowance means; and
/// beside busy programs the kernel's pty worker, a normal thread, may pass bytes on so late
/// that a reply on time in the simulator's clock is past the bridge's allowance: such a
/// talk-over is counted and printed, not judged. `src/bus/tests/late_replies.rs` judges the
/// bus master's timing itself, in virtual time.) A talk-over within 20 ms of the
/// pseudo-terminal's visible lateness is the transport's too: the simulator handed bytes late,
/// or read a packet less than the return delay after a read request (every short packet here
/// is one) had ended, which a bridge that waits for replies never writes. Such reads must stay
/// rare: a bridge that did not wait would make them all.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_servo_answering_late_never_gets_the_next_servos_reply_talked_over() {
    const LATE: u8 = 2;
    let ids = [1, 2, 3, 4];
    let sim = spawn_sim(lj9da_sim::SimConfig {
        return_delay_ms: 3,
        ..sim_config(&ids, 115_200)
    });
    let mut cfg = bus_config(&ids, BaudRate::B115200);
    cfg.turnaround = lj9da_bridge::bus::BusConfig::DEFAULT_TURNAROUND;
    let bus = spawn_bus(cfg, sim.path());
    every_servo_online(&bus).await;
    hold_with_force_on(&bus, &ids, MmCenti(0)).await;
    let events = sim.handle().subscribe();
    let late = |delay_us, every| lj9da_sim::Fault::LateReplies { delay_us, every };
    assert!(sim.handle().inject(Some(LATE), late(5_300, 4)));
    assert!(sim.handle().inject(Some(3), late(1_000, 1)));
    let before = bus.status();
    for k in 0..250i16 {
        bus.output_message(ids.map(|n| (id(n), Goal::Position(MmCenti((k % 50) * 10 - 250)))));
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let st = bus.status();
    let timeouts =
        |n: u8| st.servo(id(n)).unwrap().timeouts - before.servo(id(n)).unwrap().timeouts;
    let events: Vec<SimEvent> = events.try_iter().collect();
    let handed_late: Vec<std::time::Instant> = events
        .iter()
        .filter_map(|e| match e {
            SimEvent::HandedLate { at, .. } => Some(*at),
            _ => None,
        })
        .collect();
    let packets: Vec<&lj9da_sim::PacketEvent> = events
        .iter()
        .filter_map(|e| match e {
            SimEvent::Packet(p) => Some(p),
            _ => None,
        })
        .collect();
    let read_bunched: Vec<std::time::Instant> = packets
        .windows(2)
        .filter(|w| {
            matches!(w[0].packet, HostPacket::Short(_))
                && w[1].first_byte_at < w[0].completed_at + Duration::from_millis(3)
        })
        .map(|w| w[1].first_byte_at)
        .collect();
    let transport_late: Vec<std::time::Instant> =
        handed_late.iter().chain(&read_bunched).copied().collect();
    let replies: Vec<&lj9da_sim::ReplyEvent> = events
        .iter()
        .filter_map(|e| match e {
            SimEvent::Reply(r) => Some(r),
            _ => None,
        })
        .collect();
    // Whether servo `id`'s reply met, at `at`, a packet written within 3 ms of the end of
    // another servo's reply that came after `id`'s request ended: the bridge took it for
    // `id`'s.
    let after_anothers_reply = |id: u8, at: std::time::Instant| {
        let Some(request) = packets.iter().rev().find(|p| {
            p.completed_at <= at && matches!(&p.packet, HostPacket::Short(s) if s.id == id)
        }) else {
            return false;
        };
        replies.iter().any(|r| {
            r.id != id
                && r.first_byte_at >= request.completed_at
                && r.last_byte_at <= at
                && at.saturating_duration_since(r.last_byte_at) <= Duration::from_millis(3)
        })
    };
    let (mut late_over, mut unjudged, mut excused, mut over) = (0, 0, 0, Vec::new());
    let mut story = String::new();
    for (k, event) in events.iter().enumerate() {
        let SimEvent::Collision { at, id } = event else {
            continue;
        };
        if *id == LATE {
            late_over += 1;
        } else if !after_anothers_reply(*id, *at) {
            unjudged += 1;
            eprintln!("{}", line_before(&events[..k], *at, *id));
        } else if transport_late
            .iter()
            .any(|h| *h <= *at + Duration::from_millis(1) && *at <= *h + Duration::from_millis(20))
        {
            excused += 1;
        } else {
            over.push(*id);
            story += &line_before(&events[..k], *at, *id);
        }
    }
    println!(
        "servo {LATE}: {} replies given up on, {late_over} of its late replies met a packet; \
         others' replies talked over after another's reply: {over:?}; {unjudged} met otherwise \
         (printed above), {excused} beside the transport's lateness (the simulator handed bytes \
         late {} times, read a packet bunched {} times in {})",
        timeouts(LATE),
        handed_late.len(),
        read_bunched.len(),
        packets.len()
    );
    assert!(timeouts(LATE) > 20, "servo {LATE} answered late: {st:?}");
    assert!(
        read_bunched.len() * 50 <= packets.len(),
        "{} of {} packets read less than the return delay after a read request",
        read_bunched.len(),
        packets.len()
    );
    assert!(
        over.is_empty(),
        "replies of servos {over:?} talked over: {:?}\n{story}",
        st.counters
    );
    bus.shutdown(ShutdownForce::AsIs).await;
}

/// The last dozen packets and replies on the simulated line before the collision at `at`
/// with servo `id`'s reply (`events`: those before it), times in µs before the collision.
fn line_before(events: &[SimEvent], at: std::time::Instant, id: u8) -> String {
    let before = |t: std::time::Instant| at.saturating_duration_since(t).as_micros();
    let lines: Vec<String> = events
        .iter()
        .filter_map(|event| match event {
            SimEvent::Packet(p) => Some(format!(
                "  host {:?} from -{} to -{} µs{}\n",
                p.packet,
                before(p.first_byte_at),
                before(p.completed_at),
                if p.collided { " COLLIDED" } else { "" }
            )),
            SimEvent::Reply(r) => Some(format!(
                "  servo {} replies {} bytes from -{} to -{} µs\n",
                r.id,
                r.bytes.len(),
                before(r.first_byte_at),
                before(r.last_byte_at)
            )),
            _ => None,
        })
        .collect();
    let recent = &lines[lines.len().saturating_sub(12)..];
    format!("servo {id}'s reply talked over:\n{}", recent.concat())
}

//! Injected faults: corrupted and dropped replies, adapter echo, unplugging, stall, load, wrong model.

mod common;

use std::time::Duration;

use common::{VirtualBus, force, goal, read, request};
use lj9da_sim::{BusEvent, Fault, FaultKind, ReturnPacket, SimConfig};

fn status_bytes(bus: &mut VirtualBus, id: u8) -> Vec<u8> {
    bus.transact(&request(id, 0x09))
}

#[test]
fn corrupted_replies_fail_their_check() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.model
        .inject(bus.now, None, Fault::CorruptReplies { probability: 1.0 });
    for _ in 0..50 {
        let answer = status_bytes(&mut bus, 1);
        assert_eq!(answer.len(), 26);
        assert!(ReturnPacket::parse(&answer).is_none(), "{answer:02X?}");
    }
    assert_ne!(
        bus.transact(&request(1, 0x01)),
        [0x07],
        "the ACK byte is corrupted too"
    );
    assert_eq!(bus.model.stats().replies_corrupted, 51);
}

#[test]
fn corruption_with_a_probability_is_seeded_and_repeatable() {
    let run = |seed| {
        let mut bus = VirtualBus::new(SimConfig {
            seed,
            ..SimConfig::default()
        });
        bus.model
            .inject(bus.now, Some(1), Fault::CorruptReplies { probability: 0.3 });
        (0..200)
            .map(|_| ReturnPacket::parse(&status_bytes(&mut bus, 1)).is_none())
            .collect::<Vec<bool>>()
    };
    let first = run(42);
    assert_eq!(first, run(42), "same seed, same corrupted replies");
    let corrupted = first.iter().filter(|&&bad| bad).count();
    assert!(
        (35..=85).contains(&corrupted),
        "{corrupted} of 200 at p = 0.3"
    );
    assert_ne!(first, run(43));
}

#[test]
fn dropped_replies_leave_the_host_waiting_but_the_servo_acts() {
    let mut bus = VirtualBus::with_ids(&[1, 2]);
    bus.model
        .inject(bus.now, Some(1), Fault::DropReplies { probability: 1.0 });
    assert!(
        bus.transact(&common::write_reply(1, 0x23, &[0x40], 0x01))
            .is_empty()
    );
    assert_eq!(
        bus.transact(&request(2, 0x01)),
        [0x07],
        "only servo 1 has the fault"
    );
    bus.model.clear(bus.now, Some(1), FaultKind::DropReplies);
    assert_eq!(
        bus.reply(&read(1, 0x23, 1)).data,
        [0x40],
        "the write was applied"
    );
    assert_eq!(bus.model.stats().replies_dropped, 1);
}

#[test]
fn a_bus_wide_fault_is_overridden_per_servo() {
    let mut bus = VirtualBus::with_ids(&[1, 2]);
    bus.model
        .inject(bus.now, None, Fault::DropReplies { probability: 1.0 });
    bus.model
        .inject(bus.now, Some(2), Fault::DropReplies { probability: 0.0 });
    assert!(bus.transact(&request(1, 0x01)).is_empty());
    assert_eq!(bus.transact(&request(2, 0x01)), [0x07]);
    bus.model.clear_all(bus.now);
    assert_eq!(bus.transact(&request(1, 0x01)), [0x07]);
}

#[test]
fn an_echoing_adapter_returns_every_host_byte_before_the_reply() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.model.inject(bus.now, None, Fault::Echo);
    let packet = request(1, 0x01);
    let answer = bus.transact(&packet);
    assert_eq!(&answer[..packet.len()], packet.as_slice());
    assert_eq!(&answer[packet.len()..], &[0x07]);
    let long = lj9da_sim::LongPacket::write(0x1E, &[(1, &[0, 0])]).encode();
    assert_eq!(bus.transact(&long), long, "even packets nobody answers");
    bus.model.set_echo(false);
    assert_eq!(bus.transact(&packet), [0x07]);
}

#[test]
fn an_unplugged_servo_is_silent_and_comes_back_in_its_power_on_state() {
    let mut bus = VirtualBus::with_ids(&[1, 2]);
    bus.transact(&force(1, 1));
    bus.transact(&goal(1, 500));
    bus.wait(Duration::from_millis(200));
    assert!(bus.model.unplug(bus.now, 1));
    assert!(status_bytes(&mut bus, 1).is_empty());
    bus.transact(&goal(1, -500));
    assert!(!bus.model.snapshot(bus.now, 1).expect("servo").online);
    assert_eq!(
        bus.transact(&request(2, 0x01)),
        [0x07],
        "the others still answer"
    );
    assert!(bus.model.plug(bus.now, 1));
    bus.wait(Duration::from_millis(100));
    let ram = bus.reply(&request(1, 0x0B));
    assert_eq!(ram.i16_at(0x1E), Some(0), "goal back to 0");
    assert_eq!(ram.data[36 - 30], 0, "force off");
    let status = bus.status(1);
    assert_eq!(
        status.i16_at(0x2A),
        Some(500),
        "the rod stayed where it was"
    );
}

#[test]
fn a_stalled_rod_does_not_move_and_draws_several_amps() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.transact(&force(1, 1));
    bus.model.set_stalled(bus.now, 1, true);
    bus.transact(&goal(1, 1000));
    bus.wait(Duration::from_millis(300));
    let status = bus.status(1);
    assert_eq!(status.i16_at(0x2A), Some(0));
    assert!(
        status.u16_at(0x30).expect("load") >= 300,
        "{:?} × 10 mA",
        status.u16_at(0x30)
    );
    bus.model.set_stalled(bus.now, 1, false);
    bus.wait(Duration::from_millis(300));
    assert_eq!(bus.status(1).i16_at(0x2A), Some(1000));
}

#[test]
fn a_load_above_the_thrust_blocks_the_rod_and_a_smaller_one_slows_it() {
    let mut bus = VirtualBus::with_ids(&[1, 2]);
    bus.transact(&force(1, 1));
    bus.transact(&force(2, 1));
    bus.model
        .inject(bus.now, Some(1), Fault::ExternalLoad { newtons: 1000.0 });
    bus.model
        .inject(bus.now, Some(2), Fault::ExternalLoad { newtons: 200.0 });
    bus.transact(&goal(1, 1000));
    bus.transact(&goal(2, 1000));
    bus.wait(Duration::from_millis(100));
    assert_eq!(bus.status(1).i16_at(0x2A), Some(0));
    let slowed = bus.status(2).i16_at(0x2A).expect("position");
    assert!(
        (100..900).contains(&slowed),
        "loaded servo at {slowed} after 150 ms"
    );
    assert!(bus.status(1).u16_at(0x30).expect("load") >= 300);
}

#[test]
fn a_wrong_model_number_is_reported_until_cleared() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.model
        .inject(bus.now, Some(1), Fault::WrongModel(0x7511));
    assert_eq!(bus.reply(&read(1, 0x00, 2)).data, [0x11, 0x75]);
    bus.model.power_cycle(bus.now, 1);
    bus.wait(Duration::from_millis(100));
    assert_eq!(
        bus.reply(&read(1, 0x00, 2)).data,
        [0x11, 0x75],
        "it is the hardware"
    );
    bus.model.clear(bus.now, Some(1), FaultKind::WrongModel);
    assert_eq!(bus.reply(&read(1, 0x00, 2)).data, [0x10, 0x75]);
}

#[test]
fn faults_from_the_config_apply_from_the_start() {
    let config = SimConfig {
        ids: vec![1, 2],
        faults: vec![(Some(2), Fault::Unplugged), (None, Fault::Echo)],
        ..SimConfig::default()
    };
    let mut bus = VirtualBus::new(config);
    let packet = request(2, 0x01);
    assert_eq!(bus.transact(&packet), packet, "only the echo");
    assert!(
        bus.events()
            .iter()
            .any(|event| matches!(event, BusEvent::Packet(packet) if packet.acted.is_empty()))
    );
}

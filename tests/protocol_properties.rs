//! Properties of the protocol core over arbitrary input: round trips, and no panic on any bytes.

use lj9da_bridge::protocol::registers::{MemoryMap, validate_write};
use lj9da_bridge::protocol::{
    Decoded, Decoder, Expect, GoalEntry, LongPacket, MmCenti, Ms10, ReplyFlags, ReturnPacket,
    ServoId,
};
use proptest::prelude::*;

fn return_packet() -> impl Strategy<Value = ReturnPacket> {
    (1u8..=127, any::<u8>(), 0u8..60)
        .prop_flat_map(|(id, flags, address)| {
            let max_len = 60 - usize::from(address);
            (
                Just(id),
                Just(flags),
                Just(address),
                proptest::collection::vec(any::<u8>(), 1..=max_len),
            )
        })
        .prop_map(|(id, flags, address, data)| ReturnPacket {
            id,
            flags: ReplyFlags(flags),
            address,
            data,
        })
}

/// Bytes that can never start a packet, so a stream of them is plain noise.
fn noise() -> impl Strategy<Value = Vec<u8>> {
    proptest::collection::vec(
        any::<u8>().prop_filter("no header byte", |b| *b != 0xFD && *b != 0xFA),
        0..40,
    )
}

fn drain(d: &mut Decoder) -> Vec<Decoded> {
    let mut out = Vec::new();
    while let Some(item) = d.poll() {
        if let Ok(item) = item {
            out.push(item);
        }
    }
    out
}

proptest! {
    #[test]
    fn return_packets_round_trip_through_the_decoder(
        packets in proptest::collection::vec(return_packet(), 1..6),
        noise in noise(),
        chunk in 1usize..64,
    ) {
        let mut stream = noise;
        for p in &packets {
            stream.extend(p.to_bytes());
        }
        let mut d = Decoder::new();
        let mut got = Vec::new();
        for piece in stream.chunks(chunk) {
            d.push(piece);
            got.extend(drain(&mut d));
        }
        let expected: Vec<Decoded> = packets.into_iter().map(Decoded::Reply).collect();
        prop_assert_eq!(got, expected);
        prop_assert_eq!(d.buffered(), 0);
    }

    #[test]
    fn long_packets_come_back_as_echoes_of_their_own_length(
        goals in proptest::collection::btree_map(1u8..=127, (-2500i16..=2500, proptest::option::of(any::<u16>())), 1..12),
    ) {
        let with_time = goals.values().any(|(_, t)| t.is_some());
        let entries: Vec<GoalEntry> = goals
            .iter()
            .map(|(id, (pos, time))| GoalEntry {
                id: ServoId::new(*id).unwrap(),
                position: MmCenti(*pos),
                time: time.map(Ms10),
            })
            .collect();
        let packet = LongPacket::goals(&entries).unwrap();
        let bytes = packet.to_bytes();
        let per_servo = if with_time { 5 } else { 3 };
        prop_assert_eq!(bytes.len(), 8 + per_servo * entries.len());
        let mut d = Decoder::new();
        d.push(&bytes);
        prop_assert_eq!(drain(&mut d), vec![Decoded::Echo { len: bytes.len() }]);
    }

    #[test]
    fn the_decoder_never_panics_and_always_drains(
        bytes in proptest::collection::vec(any::<u8>(), 0..600),
        chunk in 1usize..80,
        ack in any::<bool>(),
    ) {
        let mut d = Decoder::new();
        if ack {
            d.expect(Expect::Ack);
        }
        for piece in bytes.chunks(chunk) {
            d.push(piece);
            drain(&mut d);
        }
        // Once the wait is given up, every byte is consumed one way or another.
        d.abandon_partial();
        drain(&mut d);
        prop_assert_eq!(d.buffered(), 0);
    }

    #[test]
    fn an_accepted_write_never_carries_a_dangerous_value(
        (address, data) in safe_write(),
    ) {
        // Every case here is a write the manual allows, so every case checks something: that
        // the bridge accepts it (no false refusal), and that the map after it is safe.
        prop_assert!(
            validate_write(address, &data).is_ok(),
            "a safe write at {address} refused: {data:02X?}: {:?}",
            validate_write(address, &data)
        );
        let after = factory_map_after(address, &data);
        prop_assert!(is_safe(&after), "{:02X?}", after.bytes());
        let before = factory_map();
        prop_assert_eq!(&after.bytes()[..4], &before.bytes()[..4], "fixed area untouched");
    }

    #[test]
    fn a_write_that_would_leave_a_dangerous_value_is_refused(
        (address, data) in guarded_write(),
    ) {
        // Whole writable registers, one of them guarded with any value at all: the bridge
        // accepts the write exactly when the map after it is safe.
        let after = factory_map_after(address, &data);
        prop_assert_eq!(
            validate_write(address, &data).is_ok(),
            is_safe(&after),
            "write at {} of {:02X?}", address, data
        );
    }

    #[test]
    fn a_write_outside_the_writable_registers_is_refused(
        address in 0u8..64,
        data in proptest::collection::vec(any::<u8>(), 0..70),
    ) {
        // Anything at all: accepted only if it covers whole writable registers, and then safe.
        let end = usize::from(address) + data.len();
        let whole_writable = !data.is_empty()
            && end <= 60
            && WRITABLE_RUNS.iter().any(|run| {
                let starts: Vec<u8> = run.iter().map(|&(a, _)| a).collect();
                let ends: Vec<usize> = run.iter().map(|&(a, n)| usize::from(a + n)).collect();
                starts.contains(&address) && ends.contains(&end)
            });
        match validate_write(address, &data) {
            Ok(()) => {
                prop_assert!(whole_writable, "accepted a write at {} of {:02X?}", address, data);
                prop_assert!(is_safe(&factory_map_after(address, &data)));
            }
            Err(_) => prop_assert!(
                !whole_writable || !is_safe(&factory_map_after(address, &data)),
                "refused a safe write of whole writable registers at {} of {:02X?}", address, data
            ),
        }
    }
}

/// The writable registers (address, size) in runs of consecutive addresses, from the manual's
/// memory map: a write may cover any whole registers of one run.
static WRITABLE_RUNS: [&[(u8, u8)]; 3] = [
    // Servo ID, Reverse, Baud Rate, Return Delay, Plus and Minus Position Limit.
    &[
        (0x04, 1),
        (0x05, 1),
        (0x06, 1),
        (0x07, 1),
        (0x08, 2),
        (0x0A, 2),
    ],
    // Compliance margins and slopes, Punch, Goal Position, Goal Time.
    &[
        (0x18, 1),
        (0x19, 1),
        (0x1A, 1),
        (0x1B, 1),
        (0x1C, 2),
        (0x1E, 2),
        (0x20, 2),
    ],
    // Max Force, Force Enable.
    &[(0x23, 1), (0x24, 1)],
];

/// The registers whose value can harm a servo or lose it, with the values the manual allows.
fn safe_value(address: u8, size: u8) -> BoxedStrategy<Vec<u8>> {
    let word = |range: std::ops::RangeInclusive<i16>| {
        // Edges and zero as often as the rest: that is where a wrong bound shows.
        let (low, high) = (*range.start(), *range.end());
        prop_oneof![Just(low), Just(high), Just(0i16.clamp(low, high)), range]
            .prop_map(|v| v.to_le_bytes().to_vec())
            .boxed()
    };
    let byte = |range: std::ops::RangeInclusive<u8>| {
        let (low, high) = (*range.start(), *range.end());
        prop_oneof![Just(low), Just(high), range]
            .prop_map(|v| vec![v])
            .boxed()
    };
    match address {
        0x04 => byte(1..=127),      // Servo ID
        0x05 => byte(0..=1),        // Reverse
        0x06 => byte(0x00..=0x0A),  // Baud Rate code
        0x08 => word(0..=2500),     // Plus Position Limit, 0.01 mm
        0x0A => word(-2500..=0),    // Minus Position Limit, 0.01 mm
        0x1C => word(0..=0x7FFF),   // Punch
        0x1E => word(-2500..=2500), // Goal Position, 0.01 mm
        0x23 => byte(0..=100),      // Max Force, %
        0x24 => byte(0..=2),        // Force Enable: off, on, brake
        _ => proptest::collection::vec(any::<u8>(), usize::from(size)).boxed(),
    }
}

/// Any value of a register, the edges just outside its allowed range included.
fn any_value(address: u8, size: u8) -> BoxedStrategy<Vec<u8>> {
    let near = |values: &[i64]| {
        proptest::sample::select(values.to_vec())
            .prop_map(move |v| (v as u16).to_le_bytes()[..usize::from(size)].to_vec())
            .boxed()
    };
    let edges = match address {
        0x04 => near(&[0, 1, 127, 128, 255]),
        0x05 => near(&[0, 1, 2, 255]),
        0x06 => near(&[0x0A, 0x0B, 0xFF]),
        0x08 => near(&[-1, 0, 2500, 2501, -2500]),
        0x0A => near(&[1, 0, -2500, -2501, 2500]),
        0x1C => near(&[0x7FFF, 0x8000, 0xFFFF]),
        0x1E => near(&[2500, 2501, -2500, -2501]),
        0x23 => near(&[100, 101, 255]),
        0x24 => near(&[2, 3, 255]),
        _ => safe_value(address, size),
    };
    prop_oneof![
        edges,
        safe_value(address, size),
        proptest::collection::vec(any::<u8>(), usize::from(size)),
    ]
    .boxed()
}

/// A write of whole registers `run[first..=last]` of one run, each value from `value`.
fn run_write(value: fn(u8, u8) -> BoxedStrategy<Vec<u8>>) -> impl Strategy<Value = (u8, Vec<u8>)> {
    (0..WRITABLE_RUNS.len())
        .prop_flat_map(|run| {
            let len = WRITABLE_RUNS[run].len();
            (Just(run), 0..len)
                .prop_flat_map(move |(run, first)| (Just(run), Just(first), first..len))
        })
        .prop_flat_map(move |(run, first, last)| {
            let registers = &WRITABLE_RUNS[run][first..=last];
            let values: Vec<_> = registers.iter().map(|&(a, n)| value(a, n)).collect();
            (Just(registers[0].0), values)
        })
        .prop_map(|(address, values)| (address, values.concat()))
}

/// Writes the manual allows: whole writable registers, every value in its range.
fn safe_write() -> impl Strategy<Value = (u8, Vec<u8>)> {
    run_write(safe_value)
}

/// Writes of whole writable registers that always cover a guarded register, with any value.
fn guarded_write() -> impl Strategy<Value = (u8, Vec<u8>)> {
    const GUARDED: [u8; 9] = [0x04, 0x05, 0x06, 0x08, 0x0A, 0x1C, 0x1E, 0x23, 0x24];
    run_write(any_value).prop_filter("covers a guarded register", |(address, data)| {
        let end = usize::from(*address) + data.len();
        GUARDED
            .iter()
            .any(|&g| (usize::from(*address)..end).contains(&usize::from(g)))
    })
}

/// Registers 0–11 as a factory-fresh servo has them (model 7510h, firmware 1, ID 1, 115 200
/// bit/s, ±25.00 mm).
fn factory_map() -> MemoryMap {
    let mut map = MemoryMap::default();
    map.store(
        0,
        &[
            0x10, 0x75, 0x01, 0x00, 0x01, 0x00, 0x07, 0x00, 0xC4, 0x09, 0x3C, 0xF6,
        ],
    );
    map
}

fn factory_map_after(address: u8, data: &[u8]) -> MemoryMap {
    let mut map = factory_map();
    if usize::from(address) + data.len() <= 60 {
        map.store(address, data);
    }
    map
}

/// Every guarded register of `map` holds a value the manual allows (the test's own reading of
/// the bytes, not the bridge's validation).
fn is_safe(map: &MemoryMap) -> bool {
    let b = map.bytes();
    let word = |a: usize| i16::from_le_bytes([b[a], b[a + 1]]);
    (1..=127).contains(&b[0x04])
        && b[0x05] <= 1
        && b[0x06] <= 0x0A
        && (0..=2500).contains(&word(0x08))
        && (-2500..=0).contains(&word(0x0A))
        && (word(0x1C) as u16) <= 0x7FFF
        && (-2500..=2500).contains(&word(0x1E))
        && b[0x23] <= 100
        && b[0x24] <= 2
}

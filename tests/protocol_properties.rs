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
        address in 0u8..64,
        data in proptest::collection::vec(any::<u8>(), 0..70),
    ) {
        if validate_write(address, &data).is_ok() {
            let mut before = MemoryMap::default();
            before.store(0, &[0x10, 0x75, 0x01, 0x00, 0x01, 0x00, 0x07, 0x00, 0xC4, 0x09, 0x3C, 0xF6]);
            let mut after = before.clone();
            after.store(address, &data);
            prop_assert!(after.servo_id().is_ok());
            prop_assert!(after.baud_rate().is_ok());
            prop_assert!((0..=2500).contains(&after.plus_limit().0));
            prop_assert!((-2500..=0).contains(&after.minus_limit().0));
            prop_assert!(after.punch_raw() <= 0x7FFF);
            prop_assert!(after.max_force_raw() <= 100);
            prop_assert!(after.force_mode().is_ok());
            prop_assert_eq!(&after.bytes()[..4], &before.bytes()[..4], "fixed area untouched");
        }
    }
}

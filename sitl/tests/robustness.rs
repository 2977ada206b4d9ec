//! Any bytes from the host, any chunking: the simulator never panics, never loses a real packet hidden in
//! garbage, and recovers after a silence.

mod common;

use std::time::Duration;

use common::{VirtualBus, request};
use lj9da_sim::protocol::checksum::xor_sum;
use lj9da_sim::protocol::frame_decoder::{Decoded, FrameDecoder};
use lj9da_sim::{BusEvent, HostPacket, SimConfig};
use proptest::prelude::*;

fn framed(body: &[u8]) -> Vec<u8> {
    let mut bytes = vec![0xFA, 0xAF];
    bytes.extend_from_slice(body);
    bytes.push(xor_sum(body));
    bytes
}

/// A frame with a good sum and arbitrary fields (data length `Length × Count`, kept small).
fn any_valid_frame() -> impl Strategy<Value = Vec<u8>> {
    (
        prop_oneof![Just(0u8), Just(1u8), Just(2u8), Just(255u8), any::<u8>()],
        prop_oneof![Just(0u8), any::<u8>()],
        any::<u8>(),
        0u8..8,
        0u8..4,
        proptest::collection::vec(any::<u8>(), 32),
    )
        .prop_map(|(id, flag, address, length, count, pool)| {
            // A long packet needs at least the VID in each block.
            let length = if id == 0 && flag == 0 && count > 0 {
                length.max(1)
            } else {
                length
            };
            let data_len = usize::from(length) * usize::from(count);
            let mut body = vec![id, flag, address, length, count];
            body.extend(pool.iter().cycle().take(data_len));
            framed(&body)
        })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 200, ..ProptestConfig::default() })]

    #[test]
    fn random_bytes_never_panic_the_bus_and_it_recovers_after_a_silence(
        bytes in proptest::collection::vec(any::<u8>(), 0..400),
        chunk in 1usize..40,
        gap_us in 0u64..3_000,
    ) {
        let mut bus = VirtualBus::new(SimConfig { ids: vec![1, 2], ..SimConfig::default() });
        for piece in bytes.chunks(chunk) {
            bus.write(piece);
            bus.wait(Duration::from_micros(gap_us));
        }
        bus.wait(Duration::from_millis(200));
        let understood = bus.events().iter().any(|event| matches!(event, BusEvent::Packet(_)));
        // After a silence, a request is answered (unless the random bytes happened to hold a valid packet,
        // which might have changed the servo).
        let answer = bus.transact(&request(1, 0x01));
        prop_assert!(understood || answer == [0x07], "{answer:02X?}");
    }

    #[test]
    fn any_valid_frame_never_panics_a_servo(frames in proptest::collection::vec(any_valid_frame(), 1..20)) {
        let mut bus = VirtualBus::with_ids(&[1, 2]);
        for frame in &frames {
            bus.write(frame);
            bus.wait(Duration::from_millis(3));
        }
        bus.wait(Duration::from_secs(2));
        prop_assert_eq!(bus.model.snapshots(bus.now).len(), 2);
        prop_assert!(bus.model.stats().packets_rx >= 1);
    }

    #[test]
    fn a_packet_behind_garbage_is_never_lost(
        garbage in proptest::collection::vec(any::<u8>(), 0..64),
        frame in any_valid_frame(),
        split in any::<prop::sample::Index>(),
    ) {
        let mut stream = garbage.clone();
        stream.extend_from_slice(&frame);
        let mut decoder = FrameDecoder::new();
        let mut out = Vec::new();
        let split = split.index(stream.len() + 1);
        for part in [&stream[..split], &stream[split..]] {
            for &byte in part {
                decoder.push(byte, (), &mut out);
            }
        }
        decoder.abandon(&mut out);
        let packets: Vec<HostPacket> = out
            .into_iter()
            .filter_map(|result| match result {
                Decoded::Packet { packet, .. } => Some(packet),
                _ => None,
            })
            .collect();
        let encoded: Vec<Vec<u8>> = packets.iter().map(HostPacket::encode).collect();
        prop_assert!(encoded.contains(&frame), "{:02X?} not found in {:02X?}", frame, encoded);
    }
}

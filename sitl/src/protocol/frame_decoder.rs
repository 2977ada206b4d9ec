//! Streaming decoder for host packets: fed one byte at a time, it hands out packets, bad-sum candidates
//! and garbage bytes.
//!
//! A candidate frame that fails (bad sum, impossible head) consumes only its first byte; the bytes after it
//! are scanned again, so a real packet hidden behind a bogus header is never lost. Each byte carries caller
//! metadata `M` (the bus model stores its wire times there) that comes back with the decoded result.
//!
//! Leniency: the manual's text gives the factory-reset packet one data byte `FFh`, its example has none
//! (spec 9.2). The example form is the packet; a frame of the text's form (`… 10 FF FF 00 FF Sum'`) is
//! also accepted, because it can only be tried after the example form has failed its sum.

use std::collections::VecDeque;

use super::HOST_HEADER;
use super::checksum::xor_sum;
use super::host_packet::{
    FLAG_FACTORY_RESET, FRAME_HEAD_LEN, HostPacket, SPECIAL_ADDRESS, announced_data_len, from_body,
};

/// One result of feeding the decoder.
#[derive(Debug, Clone, PartialEq)]
pub enum Decoded<M> {
    /// A frame whose sum was right, with the bytes it was made of.
    Packet {
        packet: HostPacket,
        bytes: Vec<(u8, M)>,
    },
    /// A frame whose sum was wrong. Only its first byte was consumed; the others are scanned again.
    BadSum { bytes: Vec<(u8, M)> },
    /// A byte that cannot start a frame.
    Garbage { byte: u8, meta: M },
}

/// The streaming decoder; see the module documentation.
#[derive(Debug, Clone)]
pub struct FrameDecoder<M> {
    buffer: VecDeque<(u8, M)>,
}

impl<M> Default for FrameDecoder<M> {
    fn default() -> Self {
        FrameDecoder {
            buffer: VecDeque::new(),
        }
    }
}

enum Step {
    NeedMore,
    Garbage,
    Frame { total: usize, body_end: usize },
    BadSum { total: usize },
}

impl<M: Clone> FrameDecoder<M> {
    pub fn new() -> Self {
        Self::default()
    }

    /// Number of bytes held while waiting for the rest of a frame.
    pub fn pending(&self) -> usize {
        self.buffer.len()
    }

    /// Forget any partial frame; returns the bytes dropped.
    pub fn reset(&mut self) -> Vec<(u8, M)> {
        self.buffer.drain(..).collect()
    }

    /// Give up on the partial frame held (e.g. after a silence on the line): its first byte is garbage and
    /// the bytes after it are scanned again, until nothing is held. Complete packets among them are decoded.
    pub fn abandon(&mut self, out: &mut Vec<Decoded<M>>) {
        while !self.buffer.is_empty() {
            let mut held = std::mem::take(&mut self.buffer).into_iter();
            if let Some((byte, meta)) = held.next() {
                out.push(Decoded::Garbage { byte, meta });
            }
            for (byte, meta) in held {
                self.push(byte, meta, out);
            }
        }
    }

    /// Feed one byte; results are appended to `out` in wire order.
    pub fn push(&mut self, byte: u8, meta: M, out: &mut Vec<Decoded<M>>) {
        self.buffer.push_back((byte, meta));
        loop {
            match self.step() {
                Step::NeedMore => return,
                Step::Garbage => {
                    if let Some((byte, meta)) = self.buffer.pop_front() {
                        out.push(Decoded::Garbage { byte, meta });
                    }
                }
                Step::BadSum { total } => {
                    let bytes = self.buffer.iter().take(total).cloned().collect();
                    self.buffer.pop_front();
                    out.push(Decoded::BadSum { bytes });
                }
                Step::Frame { total, body_end } => {
                    let bytes: Vec<(u8, M)> = self.buffer.drain(..total).collect();
                    let body: Vec<u8> = bytes[HOST_HEADER.len()..body_end]
                        .iter()
                        .map(|(byte, _)| *byte)
                        .collect();
                    match from_body(&body) {
                        Some(packet) => out.push(Decoded::Packet { packet, bytes }),
                        None => {
                            // Cannot happen for a head that passed `announced_data_len`; stay safe anyway.
                            let mut rest = bytes.into_iter();
                            if let Some((byte, meta)) = rest.next() {
                                out.push(Decoded::Garbage { byte, meta });
                            }
                            for (index, item) in rest.enumerate() {
                                self.buffer.insert(index, item);
                            }
                        }
                    }
                }
            }
        }
    }

    fn byte(&self, index: usize) -> Option<u8> {
        self.buffer.get(index).map(|(byte, _)| *byte)
    }

    fn step(&self) -> Step {
        let Some(first) = self.byte(0) else {
            return Step::NeedMore;
        };
        if first != HOST_HEADER[0] {
            return Step::Garbage;
        }
        let Some(second) = self.byte(1) else {
            return Step::NeedMore;
        };
        if second != HOST_HEADER[1] {
            return Step::Garbage;
        }
        if self.buffer.len() < FRAME_HEAD_LEN {
            return Step::NeedMore;
        }
        let head: Vec<u8> = (2..FRAME_HEAD_LEN)
            .filter_map(|index| self.byte(index))
            .collect();
        let &[id, flag, address, length, count] = head.as_slice() else {
            return Step::Garbage;
        };
        let Some(data_len) = announced_data_len(id, flag, length, count) else {
            return Step::Garbage;
        };
        let total = FRAME_HEAD_LEN + data_len + 1;
        if self.buffer.len() < total {
            return Step::NeedMore;
        }
        let body_sum = xor_sum(&self.bytes(HOST_HEADER.len(), total - 1));
        if self.byte(total - 1) == Some(body_sum) {
            return Step::Frame {
                total,
                body_end: total - 1,
            };
        }
        let factory_reset_head = flag == FLAG_FACTORY_RESET
            && address == SPECIAL_ADDRESS
            && length == 0xFF
            && count == 0;
        if factory_reset_head && self.byte(FRAME_HEAD_LEN) == Some(0xFF) {
            let Some(sum) = self.byte(FRAME_HEAD_LEN + 1) else {
                return Step::NeedMore;
            };
            if sum == body_sum ^ 0xFF {
                return Step::Frame {
                    total: FRAME_HEAD_LEN + 2,
                    body_end: FRAME_HEAD_LEN + 1,
                };
            }
        }
        Step::BadSum { total }
    }

    fn bytes(&self, from: usize, to: usize) -> Vec<u8> {
        self.buffer
            .iter()
            .skip(from)
            .take(to.saturating_sub(from))
            .map(|(byte, _)| *byte)
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::host_packet::{ShortForm, ShortPacket, SpecialCommand};

    fn decode_all(bytes: &[u8]) -> Vec<Decoded<()>> {
        let mut decoder = FrameDecoder::new();
        let mut out = Vec::new();
        for &byte in bytes {
            decoder.push(byte, (), &mut out);
        }
        out
    }

    fn packets(results: &[Decoded<()>]) -> Vec<HostPacket> {
        results
            .iter()
            .filter_map(|result| match result {
                Decoded::Packet { packet, .. } => Some(packet.clone()),
                _ => None,
            })
            .collect()
    }

    const GOAL_9MM: [u8; 10] = [0xFA, 0xAF, 0x01, 0x00, 0x1E, 0x02, 0x01, 0x84, 0x03, 0x9B];

    #[test]
    fn a_spec_vector_decodes_to_one_packet() {
        let results = decode_all(&GOAL_9MM);
        assert_eq!(
            packets(&results),
            vec![HostPacket::Short(ShortPacket::write(
                1,
                0x1E,
                &[0x84, 0x03],
                0
            ))]
        );
        assert_eq!(results.len(), 1);
    }

    #[test]
    fn a_bad_sum_is_reported_and_not_decoded() {
        let mut bytes = GOAL_9MM;
        bytes[9] ^= 0x01;
        let results = decode_all(&bytes);
        assert!(packets(&results).is_empty());
        assert!(matches!(&results[0], Decoded::BadSum { bytes } if bytes.len() == 10));
    }

    #[test]
    fn a_packet_hidden_behind_a_bogus_header_is_found() {
        // A bogus head announcing 2 data bytes swallows the start of the real packet; its sum fails,
        // the decoder rescans from its second byte and finds the real packet.
        let mut bytes = vec![0xFA, 0xAF, 0x01, 0x00, 0x1E, 0x02, 0x01];
        bytes.extend_from_slice(&GOAL_9MM);
        let results = decode_all(&bytes);
        assert_eq!(packets(&results).len(), 1);
    }

    #[test]
    fn the_factory_reset_is_accepted_in_both_forms() {
        let example = [0xFA, 0xAF, 0x01, 0x10, 0xFF, 0xFF, 0x00, 0x11];
        let text_form = [0xFA, 0xAF, 0x01, 0x10, 0xFF, 0xFF, 0x00, 0xFF, 0xEE];
        for bytes in [&example[..], &text_form[..]] {
            let found = packets(&decode_all(bytes));
            let [HostPacket::Short(short)] = found.as_slice() else {
                panic!("no packet in {bytes:02X?}")
            };
            assert_eq!(
                short.form(),
                ShortForm::Special(SpecialCommand::FactoryReset)
            );
        }
    }

    #[test]
    fn abandoning_a_bogus_head_finds_the_packet_inside_it() {
        // A long-packet head announcing 32 × 32 bytes swallows the real packet that follows.
        let mut bytes = vec![0xFA, 0xAF, 0x00, 0x00, 0x1E, 0x20, 0x20];
        bytes.extend_from_slice(&GOAL_9MM);
        let mut decoder = FrameDecoder::new();
        let mut out = Vec::new();
        for byte in bytes {
            decoder.push(byte, (), &mut out);
        }
        assert!(packets(&out).is_empty());
        decoder.abandon(&mut out);
        assert_eq!(packets(&out).len(), 1);
        assert_eq!(decoder.pending(), 0);
    }

    #[test]
    fn an_impossible_head_is_garbage() {
        // Long packet head with Length 0 and Count 3.
        let results = decode_all(&[0xFA, 0xAF, 0x00, 0x00, 0x1E, 0x00, 0x03]);
        assert!(matches!(results[0], Decoded::Garbage { byte: 0xFA, .. }));
    }
}

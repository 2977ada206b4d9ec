//! The streaming decoder for bytes coming back from the bus.
//!
//! Feed it whatever chunks the port delivers ([`Decoder::push`]) and take complete items out
//! ([`Decoder::poll`]): return packets, ACK bytes, and echoes of our own command packets (many
//! USB RS485 adapters hear their own transmission). Like rust-mavlink's frame decoder, a
//! candidate that fails (bad sum, impossible header) is dropped one byte at a time, so a real
//! header that starts inside garbage is never lost.
//!
//! The ACK is a single byte `07h` with no framing; it can only be told apart from noise by
//! context, so the caller says when one is due with [`Decoder::expect`].

use super::checksum::xor_sum;
use super::error::DecodeError;
use super::reply::{ReplyFlags, ReturnPacket};
use super::{ACK_BYTE, COMMAND_HEADER, MEMORY_MAP_LEN, RETURN_HEADER};

/// Bytes before the data of any packet: header (2), ID, Flags, Address, Length, Count.
const HEAD_LEN: usize = 7;
/// The most servos a plausible echoed long packet addresses.
const MAX_ECHO_SERVOS: usize = 127;
/// Buffered bytes kept at most; older bytes are dropped (and reported as garbage) beyond it.
const MAX_BUFFERED: usize = 8192;

/// What the caller is waiting for, which decides whether a lone `07h` is an ACK.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Expect {
    /// A return packet, or nothing: a lone `07h` is noise.
    #[default]
    Packet,
    /// An ACK: the next lone `07h` is it.
    Ack,
}

/// One complete item taken from the byte stream.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Decoded {
    Reply(ReturnPacket),
    /// The single ACK byte `07h`.
    Ack,
    /// An echo of a command packet (`FA AF …`), `len` bytes long, skipped.
    Echo {
        len: usize,
    },
}

/// A return packet whose first bytes the decoder holds (see [`Decoder::begun_reply`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BegunReply {
    /// Its bytes buffered so far.
    pub buffered: usize,
    /// Its header, once the bytes up to its Length are in.
    pub header: Option<BegunHeader>,
}

/// The header of a begun return packet: whose it is, and how long it says it is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BegunHeader {
    pub id: u8,
    pub address: u8,
    pub length: u8,
}

impl BegunReply {
    /// The bytes still to come: as its header says, or, before the header is in, as many as
    /// the longest return packet has.
    pub fn missing(&self) -> usize {
        let total = self.header.map_or(HEAD_LEN + MEMORY_MAP_LEN + 1, |h| {
            HEAD_LEN + usize::from(h.length) + 1
        });
        total.saturating_sub(self.buffered)
    }
}

/// Streaming decoder; see the module docs.
#[derive(Debug, Default, Clone)]
pub struct Decoder {
    buf: Vec<u8>,
    start: usize,
    expect: Expect,
    give_up_partial: bool,
}

enum Step {
    /// Need more bytes.
    Wait,
    /// Not a packet here: skip this many bytes.
    Skip(usize, Option<DecodeError>),
    Done(usize, Decoded),
}

impl Decoder {
    pub fn new() -> Self {
        Self::default()
    }

    /// Say whether the next lone `07h` is an ACK. Reset to [`Expect::Packet`] once an ACK is taken.
    pub fn expect(&mut self, expect: Expect) {
        self.expect = expect;
    }

    /// Append received bytes.
    pub fn push(&mut self, bytes: &[u8]) {
        if self.start > 0 && self.start >= self.buf.len() / 2 {
            self.buf.drain(..self.start);
            self.start = 0;
        }
        self.buf.extend_from_slice(bytes);
        let pending = self.buf.len() - self.start;
        if pending > MAX_BUFFERED {
            self.start += pending - MAX_BUFFERED;
        }
    }

    /// Bytes received but not yet consumed.
    pub fn buffered(&self) -> usize {
        self.buf.len() - self.start
    }

    /// The return packet begun at the front of the buffer, if its first bytes are a return
    /// packet's header: the rest of it is still on its way (or the bytes were noise).
    pub fn begun_reply(&self) -> Option<BegunReply> {
        let pending = &self.buf[self.start..];
        match pending {
            [first, ..] if *first != RETURN_HEADER[0] => None,
            [_, second, ..] if *second != RETURN_HEADER[1] => None,
            [] => None,
            _ => Some(BegunReply {
                buffered: pending.len(),
                header: (pending.len() >= HEAD_LEN - 1).then(|| BegunHeader {
                    id: pending[2],
                    address: pending[4],
                    length: pending[5],
                }),
            }),
        }
    }

    /// Forget everything buffered (e.g. after reopening the port).
    pub fn clear(&mut self) {
        self.buf.clear();
        self.start = 0;
        self.expect = Expect::Packet;
        self.give_up_partial = false;
    }

    /// The wait for the rest of a packet is over (its reply timed out): on the next polls an
    /// incomplete candidate at the front is treated as garbage, so that a complete packet
    /// starting inside it is still found.
    pub fn abandon_partial(&mut self) {
        self.give_up_partial = true;
    }

    /// The next complete item, an error for bytes that were skipped, or `None` when more bytes
    /// are needed.
    pub fn poll(&mut self) -> Option<Result<Decoded, DecodeError>> {
        loop {
            let pending = &self.buf[self.start..];
            if pending.is_empty() {
                self.give_up_partial = false;
                return None;
            }
            match self.step(pending) {
                Step::Wait if self.give_up_partial => {
                    self.start += 1;
                    return Some(Err(DecodeError::Garbage {
                        skipped: 1,
                        expecting_ack: self.expect == Expect::Ack,
                    }));
                }
                Step::Wait => return None,
                Step::Skip(n, error) => {
                    self.start += n;
                    if let Some(e) = error {
                        return Some(Err(e));
                    }
                }
                Step::Done(n, item) => {
                    self.start += n;
                    if item == Decoded::Ack {
                        self.expect = Expect::Packet;
                    }
                    return Some(Ok(item));
                }
            }
        }
    }

    fn step(&self, b: &[u8]) -> Step {
        match b[0] {
            ACK_BYTE if self.expect == Expect::Ack => Step::Done(1, Decoded::Ack),
            x if x == RETURN_HEADER[0] => Self::return_packet(b),
            x if x == COMMAND_HEADER[0] => Self::echo(b),
            _ => {
                let expect_ack = self.expect == Expect::Ack;
                let skipped = b
                    .iter()
                    .position(|&x| {
                        x == RETURN_HEADER[0]
                            || x == COMMAND_HEADER[0]
                            || (expect_ack && x == ACK_BYTE)
                    })
                    .unwrap_or(b.len());
                Step::Skip(
                    skipped,
                    Some(DecodeError::Garbage {
                        skipped,
                        expecting_ack: expect_ack,
                    }),
                )
            }
        }
    }

    fn return_packet(b: &[u8]) -> Step {
        if b.len() < 2 {
            return Step::Wait;
        }
        if b[1] != RETURN_HEADER[1] {
            return Step::Skip(
                1,
                Some(DecodeError::Garbage {
                    skipped: 1,
                    expecting_ack: false,
                }),
            );
        }
        if b.len() < HEAD_LEN {
            return Step::Wait;
        }
        let (id, flags, address, length, count) = (b[2], b[3], b[4], b[5], b[6]);
        if count != 1 {
            return Step::Skip(1, Some(DecodeError::BadCount { count }));
        }
        if usize::from(address) + usize::from(length) > MEMORY_MAP_LEN {
            return Step::Skip(1, Some(DecodeError::OutsideMap { address, length }));
        }
        let total = HEAD_LEN + usize::from(length) + 1;
        if b.len() < total {
            return Step::Wait;
        }
        let computed = xor_sum(&b[2..total - 1]);
        let received = b[total - 1];
        if computed != received {
            return Step::Skip(
                1,
                Some(DecodeError::ReplyBadChecksum {
                    id,
                    address,
                    length,
                    computed,
                    received,
                }),
            );
        }
        Step::Done(
            total,
            Decoded::Reply(ReturnPacket {
                id,
                flags: ReplyFlags(flags),
                address,
                data: b[HEAD_LEN..total - 1].to_vec(),
            }),
        )
    }

    fn echo(b: &[u8]) -> Step {
        let bad = |reason| Step::Skip(1, Some(DecodeError::BadEcho { reason }));
        if b.len() < 2 {
            return Step::Wait;
        }
        if b[1] != COMMAND_HEADER[1] {
            return Step::Skip(
                1,
                Some(DecodeError::Garbage {
                    skipped: 1,
                    expecting_ack: false,
                }),
            );
        }
        if b.len() < HEAD_LEN {
            return Step::Wait;
        }
        let (id, flags, address, length, count) = (b[2], b[3], b[4], b[5], b[6]);
        let (length, count) = (usize::from(length), usize::from(count));
        let data_len = if id == 0 && flags == 0 {
            // Long packet: (VID + data) × count.
            if length < 2 || count == 0 || count > MAX_ECHO_SERVOS {
                return bad("long packet with an impossible Length or Count");
            }
            if usize::from(address) + length - 1 > MEMORY_MAP_LEN {
                return bad("long packet writes beyond register 59");
            }
            length * count
        } else if flags & 0x80 != 0 {
            return bad("flag bit 7 set");
        } else if count == 0 {
            0
        } else if count == 1 {
            if length > MEMORY_MAP_LEN {
                return bad("short packet longer than the memory map");
            }
            length
        } else {
            return bad("short packet with Count above 1");
        };
        let total = HEAD_LEN + data_len + 1;
        if b.len() < total {
            return Step::Wait;
        }
        let computed = xor_sum(&b[2..total - 1]);
        if computed != b[total - 1] {
            return Step::Skip(
                1,
                Some(DecodeError::BadChecksum {
                    computed,
                    received: b[total - 1],
                }),
            );
        }
        Step::Done(total, Decoded::Echo { len: total })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::{
        LongPacket, ReplyRequest, ServoId, ShortPacket, packet::GoalEntry, units::MmCenti,
    };

    fn reply(id: u8, position: i16) -> ReturnPacket {
        let mut data = vec![0u8; 18];
        data[..2].copy_from_slice(&position.to_le_bytes());
        data[6] = 26; // 260 mA
        data[8] = 40; // 40 °C
        data[10..12].copy_from_slice(&1200u16.to_le_bytes());
        ReturnPacket {
            id,
            flags: ReplyFlags(0),
            address: 0x2A,
            data,
        }
    }

    /// Everything `push`ing `stream` in chunks of `chunk` bytes yields, errors dropped.
    fn decode_in_chunks(stream: &[u8], chunk: usize, ack_expected: bool) -> Vec<Decoded> {
        let mut d = Decoder::new();
        if ack_expected {
            d.expect(Expect::Ack);
        }
        let mut out = Vec::new();
        for piece in stream.chunks(chunk) {
            d.push(piece);
            while let Some(item) = d.poll() {
                if let Ok(item) = item {
                    out.push(item);
                }
            }
        }
        out
    }

    fn replies(items: &[Decoded]) -> Vec<ReturnPacket> {
        items
            .iter()
            .filter_map(|i| match i {
                Decoded::Reply(r) => Some(r.clone()),
                _ => None,
            })
            .collect()
    }

    #[test]
    fn a_begun_reply_tells_whose_it_is_and_how_much_is_missing() {
        let bytes = reply(3, 250).to_bytes();
        let mut d = Decoder::new();
        assert_eq!(d.begun_reply(), None);
        d.push(&bytes[..1]);
        let first = d.begun_reply().expect("a return header's first byte");
        assert_eq!(first.header, None);
        assert_eq!(
            first.missing(),
            HEAD_LEN + MEMORY_MAP_LEN + 1 - 1,
            "the longest reply"
        );
        d.push(&bytes[1..10]);
        let begun = d.begun_reply().unwrap();
        assert_eq!(
            begun.header,
            Some(BegunHeader {
                id: 3,
                address: bytes[4],
                length: bytes[5]
            })
        );
        assert_eq!(begun.missing(), bytes.len() - 10);
        d.push(&bytes[10..]);
        assert!(matches!(d.poll(), Some(Ok(Decoded::Reply(_)))));
        assert_eq!(d.begun_reply(), None, "nothing begun once it is whole");
        // Noise, or a command's echo, is no reply begun.
        d.push(&[0x00, 0x12]);
        assert_eq!(d.begun_reply(), None);
        let mut echo = Decoder::new();
        echo.push(&COMMAND_HEADER);
        assert_eq!(echo.begun_reply(), None);
        let mut not_header = Decoder::new();
        not_header.push(&[RETURN_HEADER[0], 0x00]);
        assert_eq!(not_header.begun_reply(), None);
    }

    #[test]
    fn same_stream_split_at_every_chunk_size() {
        let packets: Vec<ReturnPacket> = (1..=5)
            .map(|i| reply(i, i16::from(i) * 100 - 300))
            .collect();
        let stream: Vec<u8> = packets.iter().flat_map(ReturnPacket::to_bytes).collect();
        for chunk in 1..=stream.len() {
            let got = decode_in_chunks(&stream, chunk, false);
            assert_eq!(replies(&got), packets, "chunk size {chunk}");
        }
    }

    #[test]
    fn garbage_before_between_and_inside_frames_is_skipped() {
        let a = reply(1, 150).to_bytes();
        let b = reply(2, -150).to_bytes();
        let mut stream = vec![0x00, 0xFD, 0x13, 0xFA, 0x55, 0xFD];
        stream.extend(&a);
        stream.extend([0xAA, 0xFD, 0xDF, 0x01]);
        stream.extend(&b[..10]);
        // A header inside a broken frame: the broken frame's bytes are garbage.
        stream.extend(&a[..5]);
        stream.extend(&b);
        for chunk in 1..=stream.len() {
            let got = replies(&decode_in_chunks(&stream, chunk, false));
            assert_eq!(
                got,
                vec![reply(1, 150), reply(2, -150)],
                "chunk size {chunk}"
            );
        }
    }

    #[test]
    fn a_real_header_inside_a_bad_candidate_is_not_lost() {
        let good = reply(3, 777).to_bytes();
        // FD DF + a plausible head whose sum will fail because the real packet follows.
        let mut stream = vec![0xFD, 0xDF, 0x01, 0x00, 0x2A, 0x02, 0x01];
        stream.extend(&good);
        for chunk in 1..=stream.len() {
            let got = replies(&decode_in_chunks(&stream, chunk, false));
            assert_eq!(got, vec![reply(3, 777)], "chunk size {chunk}");
        }
    }

    #[test]
    fn an_echoed_request_before_the_reply_is_skipped() {
        let request = ShortPacket::request(ServoId::new(1).unwrap(), ReplyRequest::Registers42To59)
            .to_bytes();
        let long = LongPacket::goals(&[GoalEntry {
            id: ServoId::new(1).unwrap(),
            position: MmCenti(-300),
            time: None,
        }])
        .unwrap()
        .to_bytes();
        let mut stream = long.clone();
        stream.extend(&request);
        stream.extend(reply(1, 42).to_bytes());
        for chunk in 1..=stream.len() {
            let got = decode_in_chunks(&stream, chunk, false);
            assert_eq!(
                got,
                vec![
                    Decoded::Echo { len: long.len() },
                    Decoded::Echo { len: request.len() },
                    Decoded::Reply(reply(1, 42))
                ],
                "chunk size {chunk}"
            );
        }
    }

    #[test]
    fn a_corrupted_sum_is_rejected_with_both_values() {
        let mut bytes = reply(1, 10).to_bytes();
        let last = bytes.len() - 1;
        let good_sum = bytes[last];
        bytes[last] ^= 0x66;
        let mut d = Decoder::new();
        d.push(&bytes);
        let err = d.poll().unwrap().unwrap_err();
        assert_eq!(
            err,
            DecodeError::ReplyBadChecksum {
                id: 1,
                address: 42,
                length: 18,
                computed: good_sum,
                received: good_sum ^ 0x66
            }
        );
        assert_eq!(
            err.to_string(),
            format!(
                "return packet from ID 1 (registers 42, 18 bytes) has a bad checksum: computed 0x{:02X}, packet says 0x{:02X}",
                good_sum,
                good_sum ^ 0x66
            )
        );
        while let Some(item) = d.poll() {
            assert!(
                item.is_err(),
                "nothing valid may come out of a corrupted packet"
            );
        }
    }

    #[test]
    fn a_lone_07h_is_an_ack_only_when_one_is_expected() {
        let request = ShortPacket::request(ServoId::new(9).unwrap(), ReplyRequest::Ack).to_bytes();
        let mut stream = request.clone();
        stream.push(ACK_BYTE);
        for chunk in 1..=stream.len() {
            assert_eq!(
                decode_in_chunks(&stream, chunk, true),
                vec![Decoded::Echo { len: request.len() }, Decoded::Ack]
            );
            assert_eq!(
                decode_in_chunks(&stream, chunk, false),
                vec![Decoded::Echo { len: request.len() }]
            );
        }
    }

    #[test]
    fn impossible_reply_heads_fail_fast_instead_of_waiting() {
        let mut d = Decoder::new();
        d.push(&[0xFD, 0xDF, 0x01, 0x00, 0x30, 0x20, 0x01]);
        assert_eq!(
            d.poll(),
            Some(Err(DecodeError::OutsideMap {
                address: 0x30,
                length: 0x20
            }))
        );
        let mut d = Decoder::new();
        d.push(&[0xFD, 0xDF, 0x01, 0x00, 0x2A, 0x12, 0x02]);
        assert_eq!(d.poll(), Some(Err(DecodeError::BadCount { count: 2 })));
    }

    #[test]
    fn an_abandoned_partial_frame_gives_way_to_a_complete_one_inside_it() {
        // A plausible head claiming 18 data bytes (26 in all) that never completes, and inside
        // it a whole 10-byte reply (2 registers from 2Ah).
        let short = ReturnPacket {
            id: 4,
            flags: ReplyFlags(0),
            address: 0x2A,
            data: vec![5, 0],
        };
        let mut stream = vec![0xFD, 0xDF, 0x04, 0x00, 0x2A, 0x12, 0x01];
        stream.extend(short.to_bytes());
        let mut d = Decoder::new();
        d.push(&stream);
        assert_eq!(d.poll(), None, "still waiting for the 26-byte candidate");
        d.abandon_partial();
        let mut got = Vec::new();
        while let Some(x) = d.poll() {
            if let Ok(x) = x {
                got.push(x);
            }
        }
        assert_eq!(got, vec![Decoded::Reply(short)]);
        assert_eq!(d.buffered(), 0);
    }

    #[test]
    fn errors_say_what_was_expected() {
        let mut d = Decoder::new();
        d.push(&[0x11, 0x22, 0x33]);
        let err = d.poll().unwrap().unwrap_err();
        assert_eq!(
            err.to_string(),
            "skipped 3 bytes that start no packet (expected a header FD DF)"
        );
    }
}

//! Transfers and their frames. Each frame's last byte is the tail byte: start of transfer
//! (bit 7), end of transfer (bit 6), toggle (bit 5, 0 in the first frame, then alternating)
//! and the transfer id (bits 4–0, counting up per sender and type). A payload of up to 7 bytes
//! goes in one frame; a longer one is preceded by its transfer CRC ([`super::crc`]), 2 bytes
//! low first, and cut into frames of 7 bytes and a tail byte, the last one shorter.

use super::crc::transfer_crc;
use super::frame::{CanFrame, CanId, Kind, MAX_DATA};
use std::collections::HashMap;
use std::fmt;
use std::time::{Duration, Instant};

/// A transfer whose frames stop coming for this long is dropped (the specification's
/// transfer timeout).
pub const TRANSFER_TIMEOUT: Duration = Duration::from_secs(2);

/// The longest payload put back together; longer transfers are refused.
pub const MAX_PAYLOAD: usize = 512;

const START: u8 = 0x80;
const END: u8 = 0x40;
const TOGGLE: u8 = 0x20;

/// One transfer: who sent what to whom, its transfer id and its payload.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Transfer {
    pub id: CanId,
    /// 0–31.
    pub transfer_id: u8,
    pub payload: Vec<u8>,
}

impl Transfer {
    /// The frames of this transfer of a data type whose signature is `signature`.
    pub fn frames(&self, signature: u64) -> Vec<CanFrame> {
        let raw = self.id.to_raw();
        let tid = self.transfer_id & 0x1F;
        if self.payload.len() < MAX_DATA {
            let mut data = self.payload.clone();
            data.push(START | END | tid);
            return vec![CanFrame::new(raw, &data).expect("at most 8 bytes")];
        }
        let crc = transfer_crc(signature, &self.payload);
        let mut stream = crc.to_le_bytes().to_vec();
        stream.extend_from_slice(&self.payload);
        let chunks: Vec<&[u8]> = stream.chunks(MAX_DATA - 1).collect();
        let last = chunks.len() - 1;
        chunks
            .into_iter()
            .enumerate()
            .map(|(i, chunk)| {
                let mut tail = tid;
                if i == 0 {
                    tail |= START;
                }
                if i == last {
                    tail |= END;
                }
                if i % 2 == 1 {
                    tail |= TOGGLE;
                }
                let mut data = chunk.to_vec();
                data.push(tail);
                CanFrame::new(raw, &data).expect("at most 8 bytes")
            })
            .collect()
    }
}

/// Why a frame was not taken.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum TransferError {
    /// The identifier is not DroneCAN's (a service frame to or from node 0).
    Identifier(u32),
    /// A frame in the middle of a transfer whose start was not seen (or was dropped).
    NoStart,
    /// The toggle bit or the transfer id is not the one the transfer under way expects.
    OutOfOrder,
    /// A first frame of a multi-frame transfer with less than 8 bytes.
    ShortStart,
    /// The transfer CRC does not match: a frame lost, or the wrong signature.
    Crc { expected: u16, got: u16 },
    /// Longer than [`MAX_PAYLOAD`].
    TooLong,
}

impl fmt::Display for TransferError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            TransferError::Identifier(id) => write!(f, "identifier {id:08X} is not DroneCAN's"),
            TransferError::NoStart => f.write_str("a frame of a transfer whose start was not seen"),
            TransferError::OutOfOrder => {
                f.write_str("a frame out of order (toggle or transfer id)")
            }
            TransferError::ShortStart => {
                f.write_str("a multi-frame transfer's first frame not full")
            }
            TransferError::Crc { expected, got } => {
                write!(f, "transfer CRC {got:04X}, expected {expected:04X}")
            }
            TransferError::TooLong => write!(f, "a transfer longer than {MAX_PAYLOAD} bytes"),
        }
    }
}

/// A multi-frame transfer under way.
#[derive(Debug)]
struct Session {
    transfer_id: u8,
    /// The toggle the next frame must have.
    toggle: bool,
    crc: u16,
    payload: Vec<u8>,
    signature: u64,
    last_frame_at: Instant,
}

/// Frames put back into transfers: one transfer under way per sender, kind and type.
#[derive(Debug, Default)]
pub struct Reassembler {
    sessions: HashMap<(u8, Kind, u16), Session>,
}

impl Reassembler {
    pub fn new() -> Self {
        Self::default()
    }

    /// Take `frame`, received at `now`. `signature` gives the signature of the data types
    /// wanted (`None`: not wanted, the frame is ignored). A complete transfer is returned.
    pub fn push(
        &mut self,
        frame: &CanFrame,
        now: Instant,
        signature: impl Fn(&CanId) -> Option<u64>,
    ) -> Result<Option<Transfer>, TransferError> {
        let id = CanId::parse(frame.id()).ok_or(TransferError::Identifier(frame.id()))?;
        let Some(signature) = signature(&id) else {
            return Ok(None);
        };
        let data = frame.data();
        let (&tail, body) = data.split_last().expect("a frame has a byte");
        let tid = tail & 0x1F;
        let key = (id.source, id.kind, id.data_type_id);
        self.sessions
            .retain(|_, s| now.saturating_duration_since(s.last_frame_at) < TRANSFER_TIMEOUT);
        if tail & START != 0 {
            if tail & TOGGLE != 0 {
                return Err(TransferError::OutOfOrder);
            }
            if tail & END != 0 {
                self.sessions.remove(&key);
                return Ok(Some(Transfer {
                    id,
                    transfer_id: tid,
                    payload: body.to_vec(),
                }));
            }
            if data.len() < MAX_DATA {
                return Err(TransferError::ShortStart);
            }
            self.sessions.insert(
                key,
                Session {
                    transfer_id: tid,
                    toggle: true,
                    crc: u16::from_le_bytes([body[0], body[1]]),
                    payload: body[2..].to_vec(),
                    signature,
                    last_frame_at: now,
                },
            );
            return Ok(None);
        }
        let Some(session) = self.sessions.get_mut(&key) else {
            return Err(TransferError::NoStart);
        };
        if session.transfer_id != tid || session.toggle != (tail & TOGGLE != 0) {
            self.sessions.remove(&key);
            return Err(TransferError::OutOfOrder);
        }
        if session.payload.len() + body.len() > MAX_PAYLOAD {
            self.sessions.remove(&key);
            return Err(TransferError::TooLong);
        }
        session.payload.extend_from_slice(body);
        session.toggle = !session.toggle;
        session.last_frame_at = now;
        if tail & END == 0 {
            return Ok(None);
        }
        let session = self.sessions.remove(&key).expect("just found");
        let got = transfer_crc(session.signature, &session.payload);
        if got != session.crc {
            return Err(TransferError::Crc {
                expected: session.crc,
                got,
            });
        }
        Ok(Some(Transfer {
            id,
            transfer_id: tid,
            payload: session.payload,
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SIGNATURE: u64 = 0xD8A7_4862_38EC_3AF3;

    fn array_id() -> CanId {
        CanId::parse(0x1003_F20A).unwrap()
    }

    fn transfer(len: usize, tid: u8) -> Transfer {
        Transfer {
            id: array_id(),
            transfer_id: tid,
            payload: (0..len as u8).collect(),
        }
    }

    fn wanted(_: &CanId) -> Option<u64> {
        Some(SIGNATURE)
    }

    fn tails(frames: &[CanFrame]) -> Vec<u8> {
        frames.iter().map(|f| *f.data().last().unwrap()).collect()
    }

    #[test]
    fn a_short_payload_is_one_frame_and_a_long_one_carries_its_crc() {
        let one = transfer(7, 9).frames(SIGNATURE);
        assert_eq!(tails(&one), vec![0xC9]);
        let three = transfer(16, 9).frames(SIGNATURE);
        // 2 bytes of CRC + 16 = 18 bytes: 7 + 7 + 4.
        assert_eq!(tails(&three), vec![0x89, 0x29, 0x49]);
        assert_eq!(three[2].data().len(), 5);
        let crc = transfer_crc(SIGNATURE, &transfer(16, 9).payload);
        assert_eq!(&three[0].data()[..2], &crc.to_le_bytes());
    }

    #[test]
    fn frames_come_back_as_their_transfer() {
        let t0 = Instant::now();
        let mut r = Reassembler::new();
        for len in [0, 1, 7, 8, 12, 13, 61, 200] {
            let sent = transfer(len, 3);
            let frames = sent.frames(SIGNATURE);
            let mut got = None;
            for f in &frames {
                got = r.push(f, t0, wanted).unwrap();
            }
            assert_eq!(got, Some(sent), "{len} bytes");
        }
    }

    #[test]
    fn a_lost_frame_a_wrong_toggle_or_signature_is_refused() {
        let t0 = Instant::now();
        let frames = transfer(20, 4).frames(SIGNATURE);
        // The middle frame lost: the last one is out of order.
        let mut r = Reassembler::new();
        r.push(&frames[0], t0, wanted).unwrap();
        assert_eq!(
            r.push(&frames[2], t0, wanted),
            Err(TransferError::OutOfOrder)
        );
        // Its start not seen.
        let mut r = Reassembler::new();
        assert_eq!(r.push(&frames[1], t0, wanted), Err(TransferError::NoStart));
        // Another signature: the CRC does not match.
        let mut r = Reassembler::new();
        let other = |_: &CanId| Some(0x0F08_68D0_C1A7_C6F1);
        let (last, rest) = frames.split_last().unwrap();
        for f in rest {
            r.push(f, t0, other).unwrap();
        }
        assert!(matches!(
            r.push(last, t0, other),
            Err(TransferError::Crc { .. })
        ));
        // Frames more than the timeout apart.
        let mut r = Reassembler::new();
        r.push(&frames[0], t0, wanted).unwrap();
        let late = t0 + TRANSFER_TIMEOUT;
        assert_eq!(
            r.push(&frames[1], late, wanted),
            Err(TransferError::NoStart)
        );
        // A type not wanted is ignored.
        let mut r = Reassembler::new();
        assert_eq!(r.push(&frames[0], t0, |_| None), Ok(None));
    }
}

//! ArduPilot SITL's CAN bus over multicast UDP (its default CAN transport in SITL): each CAN
//! frame is one datagram to group 239.65.82.0 + (bus − 1) on port 57732, little-endian:
//!
//! | bytes | field |
//! |---|---|
//! | 0–1 | magic, 0x2934 |
//! | 2–3 | CRC-16-CCITT (initial 0xFFFF) of the bytes from 4 on |
//! | 4–5 | flags: bit 0 CAN FD |
//! | 6–9 | the identifier; bit 31: extended (29-bit) |
//! | 10– | the data, 0–8 bytes (64 with CAN FD) |
//!
//! (ArduPilot's `CAN_Multicast` of its SITL HAL; checked below on frames ArduPlane SITL
//! sent.) Only classic extended frames are DroneCAN's: others are refused.

use super::crc;
use super::frame::CanFrame;
use std::net::Ipv4Addr;

/// The group of SITL's CAN bus 1 (the bus's number − 1 is added to the last byte).
pub const GROUP: Ipv4Addr = Ipv4Addr::new(239, 65, 82, 0);

/// The port every bus uses.
pub const PORT: u16 = 57732;

const MAGIC: u16 = 0x2934;
const EXTENDED: u32 = 1 << 31;
const FLAG_FD: u16 = 1;
const HEADER: usize = 10;

/// Why a datagram is not a frame the node takes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DatagramError {
    /// Shorter than the header, or not starting with the magic.
    NotCan,
    /// The CRC does not match.
    Crc,
    /// A CAN FD, standard-identifier or empty frame: not DroneCAN on classic CAN.
    NotClassicExtended,
}

/// The datagram of `frame`.
pub fn encode(frame: &CanFrame) -> Vec<u8> {
    let mut out = Vec::with_capacity(HEADER + frame.data().len());
    out.extend_from_slice(&MAGIC.to_le_bytes());
    out.extend_from_slice(&[0, 0]);
    out.extend_from_slice(&0u16.to_le_bytes());
    out.extend_from_slice(&(frame.id() | EXTENDED).to_le_bytes());
    out.extend_from_slice(frame.data());
    let sum = crc::add(0xFFFF, &out[4..]);
    out[2..4].copy_from_slice(&sum.to_le_bytes());
    out
}

/// The frame a datagram carries.
pub fn decode(datagram: &[u8]) -> Result<CanFrame, DatagramError> {
    if datagram.len() < HEADER || datagram[..2] != MAGIC.to_le_bytes() {
        return Err(DatagramError::NotCan);
    }
    let sum = u16::from_le_bytes([datagram[2], datagram[3]]);
    if crc::add(0xFFFF, &datagram[4..]) != sum {
        return Err(DatagramError::Crc);
    }
    let flags = u16::from_le_bytes([datagram[4], datagram[5]]);
    let id = u32::from_le_bytes([datagram[6], datagram[7], datagram[8], datagram[9]]);
    if flags & FLAG_FD != 0 || id & EXTENDED == 0 {
        return Err(DatagramError::NotClassicExtended);
    }
    CanFrame::new(id & 0x1FFF_FFFF, &datagram[HEADER..]).ok_or(DatagramError::NotClassicExtended)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dronecan::frame::{CanId, Kind};
    use crate::dronecan::messages::{self, ARRAY_COMMAND, CommandType, NODE_STATUS};
    use crate::dronecan::transfer::Reassembler;
    use std::time::Instant;

    fn unhex(text: &str) -> Vec<u8> {
        (0..text.len())
            .step_by(2)
            .map(|i| u8::from_str_radix(&text[i..i + 2], 16).unwrap())
            .collect()
    }

    /// Datagrams ArduPlane 4.7.0-dev SITL sent from its node 10 (`CAN_D1_UC_SRV_BM 15`, on the
    /// ground, disarmed): a NodeStatus, then the three frames of one ArrayCommand.
    const FROM_ARDUPLANE: [&str; 4] = [
        "3429587100000a55019f02000000000000c1",
        "3429a1f700000af203884adc010000000283",
        "342992a000000af20388000000030000bc23",
        "3429fd0900000af203880400000043",
    ];

    #[test]
    fn arduplanes_datagrams_are_its_frames_and_come_back_as_they_were() {
        let t0 = Instant::now();
        let frames: Vec<CanFrame> = FROM_ARDUPLANE
            .iter()
            .map(|h| decode(&unhex(h)).unwrap())
            .collect();
        for (frame, h) in frames.iter().zip(FROM_ARDUPLANE) {
            assert_eq!(encode(frame), unhex(h));
        }
        let status = CanId::parse(frames[0].id()).unwrap();
        assert_eq!(
            (status.kind, status.data_type_id, status.source),
            (Kind::Message, NODE_STATUS.id, 10)
        );
        // The ArrayCommand put together with its CRC (ArduPilot's, seeded by the signature):
        // servo outputs 1-4, the throttle (3) at -1.
        let mut r = Reassembler::new();
        let transfer = frames[1..]
            .iter()
            .filter_map(|f| r.push(f, t0, |_| Some(ARRAY_COMMAND.signature)).unwrap())
            .next()
            .expect("a whole transfer");
        let commands = messages::decode_array_command(&transfer.payload).unwrap();
        let got: Vec<(u8, CommandType, f32)> = commands
            .iter()
            .map(|c| (c.actuator_id, c.command_type, c.value))
            .collect();
        assert_eq!(
            got,
            vec![
                (1, CommandType::Unitless, 0.0),
                (2, CommandType::Unitless, 0.0),
                (3, CommandType::Unitless, -1.0),
                (4, CommandType::Unitless, 0.0),
            ]
        );
    }

    #[test]
    fn a_damaged_or_foreign_datagram_is_refused() {
        let mut d = unhex(FROM_ARDUPLANE[0]);
        d[12] ^= 1;
        assert_eq!(decode(&d), Err(DatagramError::Crc));
        assert_eq!(decode(&[0x34, 0x29, 0, 0]), Err(DatagramError::NotCan));
        assert_eq!(
            decode(&unhex("0000587100000a55019f02")),
            Err(DatagramError::NotCan)
        );
        // A standard (11-bit) identifier.
        let mut d = unhex(FROM_ARDUPLANE[0]);
        d[9] &= 0x7F;
        let sum = crc::add(0xFFFF, &d[4..]);
        d[2..4].copy_from_slice(&sum.to_le_bytes());
        assert_eq!(decode(&d), Err(DatagramError::NotClassicExtended));
    }
}

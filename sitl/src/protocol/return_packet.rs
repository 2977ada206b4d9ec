//! Return packets, servo → host (protocol spec 4.3):
//! `FD DF | ID | Flags | Address | Length | Count(=1) | Data[Length] | Sum`.
//!
//! The encoder is what the simulated servos send; the parser is for tests and tools that read them back.

use super::RETURN_HEADER;
use super::checksum::xor_sum;

/// Flags bit 7: temperature-limit error (force switched off).
pub const FLAG_TEMPERATURE_ERROR: u8 = 0x80;
/// Flags bit 5: temperature-limit alarm.
pub const FLAG_TEMPERATURE_ALARM: u8 = 0x20;
/// Flags bit 3: flash-write error.
pub const FLAG_FLASH_WRITE_ERROR: u8 = 0x08;

/// A decoded return packet.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ReturnPacket {
    pub id: u8,
    pub flags: u8,
    pub address: u8,
    pub count: u8,
    pub data: Vec<u8>,
}

/// Bytes of a return packet carrying `data` read from `address`.
pub fn encode(id: u8, flags: u8, address: u8, data: &[u8]) -> Vec<u8> {
    let length = u8::try_from(data.len()).unwrap_or(u8::MAX);
    let mut bytes = Vec::with_capacity(data.len() + 8);
    bytes.extend_from_slice(&RETURN_HEADER);
    bytes.extend_from_slice(&[id, flags, address, length, 1]);
    bytes.extend(data.iter().take(usize::from(length)));
    let sum = xor_sum(&bytes[RETURN_HEADER.len()..]);
    bytes.push(sum);
    bytes
}

impl ReturnPacket {
    /// Parse one return packet at the start of `bytes`; returns it and the number of bytes it used.
    /// `None` if the bytes do not start with a complete packet with a good sum.
    pub fn parse(bytes: &[u8]) -> Option<(ReturnPacket, usize)> {
        let (head, rest) = bytes.split_first_chunk::<7>()?;
        let &[h0, h1, id, flags, address, length, count] = head;
        if [h0, h1] != RETURN_HEADER {
            return None;
        }
        let data = rest.get(..usize::from(length))?;
        let sum = *rest.get(usize::from(length))?;
        let total = 8 + usize::from(length);
        if xor_sum(&bytes[2..total - 1]) != sum {
            return None;
        }
        Some((
            ReturnPacket {
                id,
                flags,
                address,
                count,
                data: data.to_vec(),
            },
            total,
        ))
    }

    /// Little-endian 16-bit value of registers `register`, `register + 1`, if both are in the packet.
    pub fn u16_at(&self, register: u8) -> Option<u16> {
        let offset = usize::from(register.checked_sub(self.address)?);
        Some(u16::from_le_bytes([
            *self.data.get(offset)?,
            *self.data.get(offset + 1)?,
        ]))
    }

    /// Signed 16-bit value of registers `register`, `register + 1`.
    pub fn i16_at(&self, register: u8) -> Option<i16> {
        self.u16_at(register).map(|value| value as i16)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SPEC_REPLY_42_59: [u8; 26] = [
        0xFD, 0xDF, 0x01, 0x00, 0x2A, 0x12, 0x01, 0x4E, 0xFB, 0x00, 0x00, 0x00, 0x00, 0x06, 0x00,
        0x2D, 0x00, 0x56, 0x04, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0xF4,
    ];

    #[test]
    fn encoding_the_spec_reply_data_gives_the_spec_bytes() {
        assert_eq!(
            encode(1, 0, 0x2A, &SPEC_REPLY_42_59[7..25]),
            SPEC_REPLY_42_59
        );
    }

    #[test]
    fn the_spec_reply_parses_to_its_values() {
        let (reply, used) = ReturnPacket::parse(&SPEC_REPLY_42_59).expect("valid reply");
        assert_eq!(used, 26);
        assert_eq!(reply.i16_at(0x2A), Some(-1202));
        assert_eq!(reply.u16_at(0x30), Some(6));
        assert_eq!(reply.u16_at(0x32), Some(45));
        assert_eq!(reply.u16_at(0x34), Some(1110));
    }

    #[test]
    fn a_corrupted_reply_does_not_parse() {
        let mut bytes = SPEC_REPLY_42_59;
        bytes[10] ^= 0x40;
        assert_eq!(ReturnPacket::parse(&bytes), None);
    }
}

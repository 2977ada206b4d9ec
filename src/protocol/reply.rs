//! Return packets (servo → host), their status flags, and the telemetry block (registers 42–59).
//!
//! ```text
//! FD DF | ID | Flags | Address | Length | Count(=1) | Data[Length] | Sum
//! ```

use super::checksum::xor_sum;
use super::error::DecodeError;
use super::registers::addr;
use super::units::{Celsius, Ma10, MmCenti, Ms10, Mv10};
use super::{MEMORY_MAP_LEN, RETURN_HEADER};
use std::fmt;

/// The status bits of a return packet's `Flags` byte.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct ReplyFlags(pub u8);

impl ReplyFlags {
    /// Bit 7: the temperature limit was reached and force was switched OFF.
    pub const TEMPERATURE_ERROR: u8 = 0x80;
    /// Bit 5: within 10 °C of the temperature limit.
    pub const TEMPERATURE_ALARM: u8 = 0x20;
    /// Bit 3: a flash write failed.
    pub const FLASH_WRITE_ERROR: u8 = 0x08;

    pub fn temperature_error(self) -> bool {
        self.0 & Self::TEMPERATURE_ERROR != 0
    }
    pub fn temperature_alarm(self) -> bool {
        self.0 & Self::TEMPERATURE_ALARM != 0
    }
    pub fn flash_write_error(self) -> bool {
        self.0 & Self::FLASH_WRITE_ERROR != 0
    }
    /// The flags that mean something (bit 1 is undefined and ignored).
    pub fn meaningful(self) -> ReplyFlags {
        ReplyFlags(
            self.0 & (Self::TEMPERATURE_ERROR | Self::TEMPERATURE_ALARM | Self::FLASH_WRITE_ERROR),
        )
    }
    /// The meaningful flags that are on here and were off in `before`: each is an alarm.
    pub fn risen_since(self, before: ReplyFlags) -> ReplyFlags {
        ReplyFlags(self.meaningful().0 & !before.0)
    }
}

impl fmt::Display for ReplyFlags {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut names = Vec::new();
        if self.temperature_error() {
            names.push("temperature error (force off)");
        }
        if self.temperature_alarm() {
            names.push("temperature alarm");
        }
        if self.flash_write_error() {
            names.push("flash write error");
        }
        if names.is_empty() {
            f.write_str("ok")
        } else {
            f.write_str(&names.join(", "))
        }
    }
}

/// A complete, checksum-verified return packet.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct ReturnPacket {
    pub id: u8,
    pub flags: ReplyFlags,
    /// First register in `data`.
    pub address: u8,
    pub data: Vec<u8>,
}

impl ReturnPacket {
    /// Bytes on the wire: 8 + data.
    pub fn wire_len(&self) -> usize {
        8 + self.data.len()
    }

    /// The packet as a servo would send it (used by tests and tools; the bridge only decodes).
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(self.wire_len());
        out.extend_from_slice(&RETURN_HEADER);
        out.extend_from_slice(&[
            self.id,
            self.flags.0,
            self.address,
            self.data.len() as u8,
            1,
        ]);
        out.extend_from_slice(&self.data);
        out.push(xor_sum(&out[2..]));
        out
    }

    /// Registers `address .. address + length` of this packet, if it carries exactly them.
    pub fn registers(&self, address: u8, length: usize) -> Result<&[u8], DecodeError> {
        if self.address != address {
            return Err(DecodeError::WrongAddress {
                expected: address,
                got: self.address,
            });
        }
        if self.data.len() != length {
            return Err(DecodeError::WrongLength {
                address,
                expected: length,
                got: self.data.len(),
            });
        }
        Ok(&self.data)
    }

    /// The telemetry block, if this is the reply to a 42–59 request.
    pub fn telemetry(&self) -> Result<Telemetry, DecodeError> {
        let regs = self.registers(addr::PRESENT_POSITION, Telemetry::LEN)?;
        Telemetry::from_registers(regs).ok_or(DecodeError::WrongLength {
            address: addr::PRESENT_POSITION,
            expected: Telemetry::LEN,
            got: regs.len(),
        })
    }
}

/// Registers 42–59 decoded: what the servo reports about itself.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Telemetry {
    pub present_position: MmCenti,
    /// Time since the move started (only with a Goal Time; 0 once it has passed).
    pub present_time: Ms10,
    /// Supply current (never 0, even with force off).
    pub present_load: Ma10,
    pub present_temperature: Celsius,
    pub present_voltage: Mv10,
}

impl Telemetry {
    /// Bytes in the block (registers 42–59).
    pub const LEN: usize = MEMORY_MAP_LEN - addr::PRESENT_POSITION as usize;

    /// Decode from the bytes of registers 42 onwards (at least the first 12 are needed).
    pub fn from_registers(regs: &[u8]) -> Option<Self> {
        let word = |reg: u8| {
            let i = usize::from(reg - addr::PRESENT_POSITION);
            Some(u16::from_le_bytes([*regs.get(i)?, *regs.get(i + 1)?]))
        };
        Some(Telemetry {
            present_position: MmCenti(word(addr::PRESENT_POSITION)? as i16),
            present_time: Ms10(word(addr::PRESENT_TIME)?),
            present_load: Ma10(word(addr::PRESENT_LOAD)?),
            present_temperature: Celsius(word(addr::PRESENT_TEMPERATURE)? as i16),
            present_voltage: Mv10(word(addr::PRESENT_VOLTAGE)?),
        })
    }

    /// Decode what registers 42–49 hold (position, present time, load) from the bytes of
    /// register 42 onwards (at least 8 are needed).
    pub fn motion_from_registers(regs: &[u8]) -> Option<Motion> {
        let word = |reg: u8| {
            let i = usize::from(reg - addr::PRESENT_POSITION);
            Some(u16::from_le_bytes([*regs.get(i)?, *regs.get(i + 1)?]))
        };
        Some(Motion {
            present_position: MmCenti(word(addr::PRESENT_POSITION)? as i16),
            present_time: Ms10(word(addr::PRESENT_TIME)?),
            present_load: Ma10(word(addr::PRESENT_LOAD)?),
        })
    }
}

/// Registers 42–49: the part of the telemetry that changes with every move.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Motion {
    pub present_position: MmCenti,
    pub present_time: Ms10,
    pub present_load: Ma10,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn motion_decodes_position_time_and_load_from_registers_42_to_49() {
        let regs = [0x4E, 0xFB, 0x0A, 0x00, 0x00, 0x00, 0x06, 0x00];
        let m = Telemetry::motion_from_registers(&regs).unwrap();
        assert_eq!(m.present_position, MmCenti(-1202));
        assert_eq!(m.present_time, Ms10(10));
        assert_eq!(m.present_load, Ma10(6));
        assert_eq!(Telemetry::motion_from_registers(&regs[..7]), None);
    }

    #[test]
    fn flags_decode_each_status_bit_and_ignore_bit_1() {
        let f = ReplyFlags(0x80 | 0x20 | 0x08 | 0x02);
        assert!(f.temperature_error() && f.temperature_alarm() && f.flash_write_error());
        assert_eq!(f.meaningful(), ReplyFlags(0xA8));
        assert_eq!(ReplyFlags(0x02).meaningful(), ReplyFlags(0));
        assert_eq!(ReplyFlags(0x02).to_string(), "ok");
    }

    #[test]
    fn telemetry_needs_the_42_to_59_block() {
        let p = ReturnPacket {
            id: 1,
            flags: ReplyFlags(0),
            address: 0x2A,
            data: vec![0; 2],
        };
        assert_eq!(
            p.telemetry(),
            Err(DecodeError::WrongLength {
                address: 0x2A,
                expected: 18,
                got: 2
            })
        );
        let p = ReturnPacket {
            address: 0,
            data: vec![0; 18],
            ..p
        };
        assert!(matches!(
            p.telemetry(),
            Err(DecodeError::WrongAddress { .. })
        ));
    }
}

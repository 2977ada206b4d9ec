//! The baud-rate table of register 6. The manual forbids any other value: writing one can make
//! the servo unreachable, so the code for an unknown rate does not exist in this type.

use super::error::ProtocolError;
use std::fmt;

/// A baud rate the LJ9DA41 supports, with its register-6 code.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum BaudRate {
    B9600 = 0x00,
    B14400 = 0x01,
    B19200 = 0x02,
    B28800 = 0x03,
    B38400 = 0x04,
    B57600 = 0x05,
    B76800 = 0x06,
    B115200 = 0x07,
    B153600 = 0x08,
    B230400 = 0x09,
    B460800 = 0x0A,
}

impl BaudRate {
    /// Every rate of the table, slowest first.
    pub const ALL: [BaudRate; 11] = [
        BaudRate::B9600,
        BaudRate::B14400,
        BaudRate::B19200,
        BaudRate::B28800,
        BaudRate::B38400,
        BaudRate::B57600,
        BaudRate::B76800,
        BaudRate::B115200,
        BaudRate::B153600,
        BaudRate::B230400,
        BaudRate::B460800,
    ];

    /// The factory default, 115 200 bit/s (code 07h).
    pub const DEFAULT: BaudRate = BaudRate::B115200;

    pub const fn code(self) -> u8 {
        self as u8
    }

    pub const fn bits_per_second(self) -> u32 {
        match self {
            BaudRate::B9600 => 9_600,
            BaudRate::B14400 => 14_400,
            BaudRate::B19200 => 19_200,
            BaudRate::B28800 => 28_800,
            BaudRate::B38400 => 38_400,
            BaudRate::B57600 => 57_600,
            BaudRate::B76800 => 76_800,
            BaudRate::B115200 => 115_200,
            BaudRate::B153600 => 153_600,
            BaudRate::B230400 => 230_400,
            BaudRate::B460800 => 460_800,
        }
    }

    /// The rate for a register-6 code; any code outside the table is refused.
    pub fn from_code(code: u8) -> Result<Self, ProtocolError> {
        Self::ALL
            .into_iter()
            .find(|b| b.code() == code)
            .ok_or(ProtocolError::UnknownBaudCode { code })
    }

    /// The rate for a speed in bit/s; any speed outside the table is refused.
    pub fn from_bits_per_second(bps: u32) -> Result<Self, ProtocolError> {
        Self::ALL
            .into_iter()
            .find(|b| b.bits_per_second() == bps)
            .ok_or(ProtocolError::UnsupportedBaud { bps })
    }

    /// Wire time of `bytes` bytes at this rate (10 bits a byte: start, 8 data, stop), in ns.
    pub const fn wire_time_ns(self, bytes: usize) -> u64 {
        (bytes as u64) * 10 * 1_000_000_000 / self.bits_per_second() as u64
    }
}

impl fmt::Display for BaudRate {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} bit/s", self.bits_per_second())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_matches_the_manual() {
        assert_eq!(BaudRate::from_code(0x04).unwrap().bits_per_second(), 38_400);
        assert_eq!(BaudRate::from_code(0x07).unwrap(), BaudRate::DEFAULT);
        assert_eq!(
            BaudRate::from_code(0x0A).unwrap().bits_per_second(),
            460_800
        );
        for (code, b) in BaudRate::ALL.iter().enumerate() {
            assert_eq!(b.code() as usize, code);
        }
    }

    #[test]
    fn unknown_codes_and_speeds_are_refused() {
        assert_eq!(
            BaudRate::from_code(0x0B),
            Err(ProtocolError::UnknownBaudCode { code: 0x0B })
        );
        assert!(BaudRate::from_code(0xFF).is_err());
        assert!(BaudRate::from_bits_per_second(921_600).is_err());
        assert!(BaudRate::from_bits_per_second(115_200).is_ok());
    }

    #[test]
    fn one_byte_at_115200_takes_86_8_us() {
        assert_eq!(BaudRate::B115200.wire_time_ns(1), 86_805);
        assert_eq!(BaudRate::B115200.wire_time_ns(26), 2_256_944);
    }
}

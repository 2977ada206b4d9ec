//! Wire time on the RS485 line: 10 bits per byte (start, 8 data, stop), no parity.

use std::time::{Duration, Instant};

/// Bits on the wire per byte.
pub const BITS_PER_BYTE: u64 = 10;

/// Wire time of one byte at `baud` (rounded up: the simulation is never faster than the wire).
pub fn byte_time(baud: u32) -> Duration {
    Duration::from_nanos((BITS_PER_BYTE * 1_000_000_000).div_ceil(u64::from(baud.max(1))))
}

/// Who put a byte on the line toward the host.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TxSource {
    /// A servo's reply; `seq` numbers the reply on this bus.
    Reply { slot: usize, id: u8, seq: u64 },
    /// The adapter echoing a host byte.
    Echo,
}

/// One byte travelling toward the host.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TxByte {
    /// When the byte's start bit begins.
    pub start: Instant,
    /// When the byte is complete: the moment it is handed to the host.
    pub at: Instant,
    pub byte: u8,
    pub source: TxSource,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_byte_at_115200_takes_86_8_microseconds() {
        assert_eq!(byte_time(115_200), Duration::from_nanos(86_806));
    }

    #[test]
    fn a_26_byte_reply_at_115200_takes_more_than_2_2_ms() {
        assert!(byte_time(115_200) * 26 >= Duration::from_micros(2_256));
    }
}

//! DSDL's bit packing (the DroneCAN specification, "Data serialization"): fields follow one
//! another with no padding; a scalar's bytes are little-endian, and each byte's bits go into
//! the stream most significant first, a last partial byte by its low bits. So `uint2 a, uint3
//! b, uint3 c` fill one byte as `aabbbccc`, and a `uint16` on a byte boundary is its two bytes
//! low first.

/// A payload being written.
#[derive(Debug, Default)]
pub struct BitWriter {
    bytes: Vec<u8>,
    bit: usize,
}

impl BitWriter {
    pub fn new() -> Self {
        Self::default()
    }

    /// The low `bits` bits of `value` (up to 64), as DSDL lays out a scalar of that width.
    pub fn put(&mut self, value: u64, bits: u32) {
        debug_assert!(bits <= 64);
        let bytes = value.to_le_bytes();
        let mut left = bits;
        for byte in bytes {
            if left == 0 {
                break;
            }
            let n = left.min(8);
            self.put_msb_first(byte, n);
            left -= n;
        }
    }

    /// `bytes` as they are, one `uint8` each.
    pub fn put_bytes(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.put(u64::from(b), 8);
        }
    }

    /// The low `n` bits of `byte`, the highest of them first.
    fn put_msb_first(&mut self, byte: u8, n: u32) {
        for i in (0..n).rev() {
            if self.bit.is_multiple_of(8) {
                self.bytes.push(0);
            }
            if byte >> i & 1 == 1 {
                let last = self.bytes.len() - 1;
                self.bytes[last] |= 0x80 >> (self.bit % 8);
            }
            self.bit += 1;
        }
    }

    /// The payload, its last byte padded with zeros.
    pub fn finish(self) -> Vec<u8> {
        self.bytes
    }
}

/// A payload being read. Reading past its end gives zeros and marks it short.
#[derive(Debug)]
pub struct BitReader<'a> {
    bytes: &'a [u8],
    bit: usize,
    short: bool,
}

impl<'a> BitReader<'a> {
    pub fn new(bytes: &'a [u8]) -> Self {
        BitReader {
            bytes,
            bit: 0,
            short: false,
        }
    }

    /// An unsigned scalar of `bits` bits (up to 64).
    pub fn get(&mut self, bits: u32) -> u64 {
        let mut bytes = [0u8; 8];
        let mut left = bits;
        for byte in &mut bytes {
            if left == 0 {
                break;
            }
            let n = left.min(8);
            *byte = self.get_msb_first(n);
            left -= n;
        }
        u64::from_le_bytes(bytes)
    }

    /// A signed scalar of `bits` bits, sign-extended.
    pub fn get_signed(&mut self, bits: u32) -> i64 {
        let raw = self.get(bits);
        let shift = 64 - bits;
        ((raw << shift) as i64) >> shift
    }

    fn get_msb_first(&mut self, n: u32) -> u8 {
        let mut out = 0u8;
        for _ in 0..n {
            let bit = match self.bytes.get(self.bit / 8) {
                Some(b) => b >> (7 - self.bit % 8) & 1,
                None => {
                    self.short = true;
                    0
                }
            };
            out = out << 1 | bit;
            self.bit += 1;
        }
        out
    }

    /// Bits not read yet.
    pub fn remaining(&self) -> usize {
        (self.bytes.len() * 8).saturating_sub(self.bit)
    }

    /// Whether a read went past the end.
    pub fn short(&self) -> bool {
        self.short
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fields_pack_most_significant_bit_first_and_bytes_little_endian() {
        let mut w = BitWriter::new();
        w.put(0b10, 2);
        w.put(0b011, 3);
        w.put(0b101, 3);
        w.put(0xBEEF, 16);
        w.put(0x5, 4);
        let bytes = w.finish();
        assert_eq!(bytes, vec![0b1001_1101, 0xEF, 0xBE, 0x50]);
        let mut r = BitReader::new(&bytes);
        assert_eq!(
            (r.get(2), r.get(3), r.get(3), r.get(16), r.get(4)),
            (0b10, 0b011, 0b101, 0xBEEF, 0x5)
        );
        assert!(!r.short());
    }

    #[test]
    fn a_scalar_across_bytes_keeps_its_low_bits_last() {
        // A uint12 after a uint4: the low byte first, then the high 4 bits.
        let mut w = BitWriter::new();
        w.put(0xA, 4);
        w.put(0x123, 12);
        let bytes = w.finish();
        let mut r = BitReader::new(&bytes);
        assert_eq!((r.get(4), r.get(12)), (0xA, 0x123));
        let mut r = BitReader::new(&[0xFF]);
        assert_eq!(r.get_signed(8), -1);
        assert_eq!(r.get(8), 0);
        assert!(r.short());
    }
}

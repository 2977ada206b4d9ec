//! CRC-32 (IEEE 802.3: polynomial 0x04C11DB7 reflected as 0xEDB88320, initial value and final
//! XOR 0xFFFFFFFF), the checksum of every record. The same CRC as zlib, PNG and Ethernet, so a
//! record can be checked with any common tool. Computed by `crc32fast`.

/// The CRC-32 of `bytes`.
pub fn crc32(bytes: &[u8]) -> u32 {
    crc32fast::hash(bytes)
}

#[cfg(test)]
mod tests {
    use super::crc32;

    #[test]
    fn matches_the_standard_check_value() {
        // The "check" value of CRC-32/ISO-HDLC for the ASCII digits 1–9.
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
        assert_eq!(crc32(b""), 0);
        assert_eq!(crc32(&[0]), 0xD202_EF8D);
    }
}

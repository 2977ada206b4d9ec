//! The packet checksum: XOR of every byte from `ID` through the last data byte.

/// XOR of `bytes` (the caller passes the packet without its two header bytes and its sum).
pub fn xor_sum(bytes: &[u8]) -> u8 {
    bytes.iter().fold(0, |acc, b| acc ^ b)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sum_is_xor_of_id_through_data() {
        // Long-packet example from the manual: 00 00 1E 03 03 01 64 00 02 64 00 05 F4 01 → ED.
        let body = [
            0x00, 0x00, 0x1E, 0x03, 0x03, 0x01, 0x64, 0x00, 0x02, 0x64, 0x00, 0x05, 0xF4, 0x01,
        ];
        assert_eq!(xor_sum(&body), 0xED);
        assert_eq!(xor_sum(&[]), 0);
    }
}

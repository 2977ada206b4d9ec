//! The transfer CRC: CRC-16-CCITT (polynomial 0x1021, initial value 0xFFFF, no reflection, no
//! final XOR), first over the data type's signature (8 bytes, little-endian), then over the
//! payload. Only a transfer of more than one frame carries it.

/// CRC-16-CCITT over `bytes`, continuing from `crc`.
pub fn add(mut crc: u16, bytes: &[u8]) -> u16 {
    for &byte in bytes {
        crc ^= u16::from(byte) << 8;
        for _ in 0..8 {
            crc = if crc & 0x8000 != 0 {
                (crc << 1) ^ 0x1021
            } else {
                crc << 1
            };
        }
    }
    crc
}

/// The CRC of a transfer of `payload` of the data type whose signature is `signature`.
pub fn transfer_crc(signature: u64, payload: &[u8]) -> u16 {
    add(add(0xFFFF, &signature.to_le_bytes()), payload)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_ccitt_check_value() {
        // CRC-16/CCITT-FALSE of "123456789".
        assert_eq!(add(0xFFFF, b"123456789"), 0x29B1);
    }
}

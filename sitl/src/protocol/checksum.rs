//! The packet sum: XOR of every byte from `ID` through the last data byte (headers excluded).

/// XOR of all `bytes`.
pub fn xor_sum(bytes: &[u8]) -> u8 {
    bytes.iter().fold(0, |sum, byte| sum ^ byte)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sum_of_the_manual_goal_position_example_is_1c() {
        assert_eq!(xor_sum(&[0x01, 0x00, 0x1E, 0x02, 0x01, 0x00, 0x00]), 0x1C);
    }

    #[test]
    fn sum_of_nothing_is_zero() {
        assert_eq!(xor_sum(&[]), 0);
    }
}

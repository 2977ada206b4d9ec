//! The LJ9DA41 memory map (protocol spec, section 6): register numbers, factory defaults, who may write
//! where, and the baud-rate table.

/// Number of registers, 0–59.
pub const MAP_LEN: usize = 60;
/// Registers 4–29 are the ROM area: saved by a flash write, restored by a factory reset.
pub const ROM_START: usize = 4;
/// One past the last ROM-area register.
pub const ROM_END: usize = 30;
/// Length of the ROM area.
pub const ROM_LEN: usize = ROM_END - ROM_START;

/// The LJ9DA41's model number (registers 0–1: `10h, 75h`).
pub const LJ9DA41_MODEL_NUMBER: u16 = 0x7510;
/// Firmware version reported in register 2.
pub const FIRMWARE_VERSION: u8 = 0x01;
/// Register 14–15: the temperature limit, 85 °C.
pub const TEMPERATURE_LIMIT_C: u16 = 85;
/// The position limits may never be set beyond ±25.00 mm (0.01 mm units).
pub const STROKE_LIMIT_MM_CENTI: i16 = 2500;

/// Register numbers.
pub mod reg {
    pub const MODEL_NUMBER: usize = 0;
    pub const FIRMWARE_VERSION: usize = 2;
    pub const SERVO_ID: usize = 4;
    pub const REVERSE: usize = 5;
    pub const BAUD_RATE: usize = 6;
    pub const RETURN_DELAY_MS: usize = 7;
    pub const PLUS_POSITION_LIMIT: usize = 8;
    pub const MINUS_POSITION_LIMIT: usize = 10;
    pub const TEMPERATURE_LIMIT: usize = 14;
    pub const PLUS_COMPLIANCE_MARGIN: usize = 24;
    pub const MINUS_COMPLIANCE_MARGIN: usize = 25;
    pub const PLUS_COMPLIANCE_SLOPE: usize = 26;
    pub const MINUS_COMPLIANCE_SLOPE: usize = 27;
    pub const PUNCH: usize = 28;
    pub const GOAL_POSITION: usize = 30;
    pub const GOAL_TIME: usize = 32;
    pub const MAX_FORCE: usize = 35;
    pub const FORCE_ENABLE: usize = 36;
    pub const PRESENT_POSITION: usize = 42;
    pub const PRESENT_TIME: usize = 44;
    pub const PRESENT_LOAD: usize = 48;
    pub const PRESENT_TEMPERATURE: usize = 50;
    pub const PRESENT_VOLTAGE: usize = 52;
    pub const LAST: usize = 59;
}

/// Who may write a register.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Access {
    ReadOnly,
    ReadWrite,
    /// "Write nothing there": writes are ignored.
    Reserved,
}

/// Access rule of register `register` (anything past 59 is reserved).
pub fn access(register: usize) -> Access {
    match register {
        0..=2 | 14 | 15 | 42..=45 | 48..=53 => Access::ReadOnly,
        4..=11 | 24..=33 | 35 | 36 => Access::ReadWrite,
        _ => Access::Reserved,
    }
}

/// Factory values of registers 4–29 (index 0 = register 4), with ID 1 at 115 200 bit/s.
pub const FACTORY_ROM: [u8; ROM_LEN] = [
    0x01, // 4  Servo ID
    0x00, // 5  Reverse
    0x07, // 6  Baud rate: 115 200
    0x00, // 7  Return delay, ms
    0xC4, 0x09, // 8–9   Plus position limit +25.00 mm
    0x3C, 0xF6, // 10–11 Minus position limit −25.00 mm
    0x00, 0x00, // 12–13 reserved
    0x55, 0x00, // 14–15 Temperature limit 85 °C
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, // 16–23 reserved
    0x08, 0x08, // 24–25 Compliance margins
    0x00, 0x00, // 26–27 Compliance slopes
    0xC4, 0x09, // 28–29 Punch (spec 9.5: the ROM table's value)
];

/// Power-on values of registers 30–59 (index 0 = register 30). The live registers (42–53) are refreshed
/// from the servo's state; 37–41 and 59 are reserved registers with the manual's defaults.
pub const POWER_ON_RAM: [u8; MAP_LEN - ROM_END] = [
    0x00, 0x00, // 30–31 Goal position
    0x00, 0x00, // 32–33 Goal time
    0x00, // 34 reserved
    0x64, // 35 Max force 100 %
    0x00, // 36 Force enable: OFF
    0x01, 0x64, 0x00, 0x00, 0x00, // 37–41 reserved
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, // 42–53 live values
    0x00, 0x00, 0x00, 0x00, 0x00, // 54–58 reserved
    0xFF, // 59 reserved
];

/// The whole map as it reads right after power-on with `rom` in flash.
pub fn power_on_map(rom: &[u8; ROM_LEN], model_number: u16) -> [u8; MAP_LEN] {
    let mut map = [0u8; MAP_LEN];
    map[reg::MODEL_NUMBER..reg::MODEL_NUMBER + 2].copy_from_slice(&model_number.to_le_bytes());
    map[reg::FIRMWARE_VERSION] = FIRMWARE_VERSION;
    map[ROM_START..ROM_END].copy_from_slice(rom);
    map[ROM_END..].copy_from_slice(&POWER_ON_RAM);
    map
}

/// Register 6 codes and their bit rates.
pub const BAUD_TABLE: [(u8, u32); 11] = [
    (0x00, 9_600),
    (0x01, 14_400),
    (0x02, 19_200),
    (0x03, 28_800),
    (0x04, 38_400),
    (0x05, 57_600),
    (0x06, 76_800),
    (0x07, 115_200),
    (0x08, 153_600),
    (0x09, 230_400),
    (0x0A, 460_800),
];

/// Bit rate of a register-6 code; `None` for the codes the manual forbids.
pub fn baud_from_code(code: u8) -> Option<u32> {
    BAUD_TABLE
        .iter()
        .find(|(known, _)| *known == code)
        .map(|(_, baud)| *baud)
}

/// Register-6 code of a bit rate; `None` if the servo cannot use it.
pub fn code_from_baud(baud: u32) -> Option<u8> {
    BAUD_TABLE
        .iter()
        .find(|(_, known)| *known == baud)
        .map(|(code, _)| *code)
}

/// Read a little-endian 16-bit register pair.
pub fn get_u16(map: &[u8; MAP_LEN], register: usize) -> u16 {
    match (map.get(register), map.get(register + 1)) {
        (Some(&low), Some(&high)) => u16::from_le_bytes([low, high]),
        _ => 0,
    }
}

/// Read a signed little-endian 16-bit register pair.
pub fn get_i16(map: &[u8; MAP_LEN], register: usize) -> i16 {
    get_u16(map, register) as i16
}

/// Write a little-endian 16-bit register pair.
pub fn set_u16(map: &mut [u8; MAP_LEN], register: usize, value: u16) {
    if let Some(pair) = map.get_mut(register..register + 2) {
        pair.copy_from_slice(&value.to_le_bytes());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn power_on_map_has_the_manual_defaults() {
        let map = power_on_map(&FACTORY_ROM, LJ9DA41_MODEL_NUMBER);
        assert_eq!(&map[0..2], &[0x10, 0x75]);
        assert_eq!(map[reg::SERVO_ID], 1);
        assert_eq!(map[reg::BAUD_RATE], 7);
        assert_eq!(get_i16(&map, reg::PLUS_POSITION_LIMIT), 2500);
        assert_eq!(get_i16(&map, reg::MINUS_POSITION_LIMIT), -2500);
        assert_eq!(get_u16(&map, reg::TEMPERATURE_LIMIT), 85);
        assert_eq!(&map[24..30], &[0x08, 0x08, 0x00, 0x00, 0xC4, 0x09]);
        assert_eq!(map[reg::MAX_FORCE], 0x64);
        assert_eq!(&map[37..42], &[0x01, 0x64, 0x00, 0x00, 0x00]);
        assert_eq!(map[reg::LAST], 0xFF);
    }

    #[test]
    fn baud_codes_round_trip_and_unknown_codes_are_none() {
        for (code, baud) in BAUD_TABLE {
            assert_eq!(baud_from_code(code), Some(baud));
            assert_eq!(code_from_baud(baud), Some(code));
        }
        assert_eq!(baud_from_code(0x0B), None);
        assert_eq!(code_from_baud(921_600), None);
    }

    #[test]
    fn access_rules_follow_the_map() {
        assert_eq!(access(0), Access::ReadOnly);
        assert_eq!(access(3), Access::Reserved);
        assert_eq!(access(4), Access::ReadWrite);
        assert_eq!(access(14), Access::ReadOnly);
        assert_eq!(access(20), Access::Reserved);
        assert_eq!(access(34), Access::Reserved);
        assert_eq!(access(36), Access::ReadWrite);
        assert_eq!(access(38), Access::Reserved);
        assert_eq!(access(42), Access::ReadOnly);
        assert_eq!(access(46), Access::Reserved);
        assert_eq!(access(59), Access::Reserved);
        assert_eq!(access(60), Access::Reserved);
    }
}
